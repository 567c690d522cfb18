"""The discrepancy workflow: find where simulation and measurement disagree, name the missing effect."""

from hapticlab.sessions.discrepancy.workflow import Settings, discrepancy, json_ready, toml_snippet

__all__ = ["Settings", "discrepancy", "json_ready", "toml_snippet"]
