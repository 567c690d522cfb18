"""The discrepancy workflow: find where simulation and measurement disagree, name the missing effect."""

from hapticlab.sessions.discrepancy.report import json_ready, toml_snippet
from hapticlab.sessions.discrepancy.settings import Settings
from hapticlab.sessions.discrepancy.workflow import discrepancy

__all__ = ["Settings", "discrepancy", "json_ready", "toml_snippet"]
