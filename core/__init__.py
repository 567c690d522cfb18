"""Core of hapticlab: hookspecs, plugin host, data types, frames and estimator math."""

from hapticlab.core.errors import ConfigError, PluginError
from hapticlab.core.host.hookspecs import hookimpl, hookspec
from hapticlab.core.host.registry import DEFAULT_PLUGINS, Registry, make_plugin_manager

__all__ = ["DEFAULT_PLUGINS", "ConfigError", "PluginError", "Registry", "hookimpl", "hookspec", "make_plugin_manager"]
