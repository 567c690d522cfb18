"""The plugin host: finds plugins once at start-up and builds them from config.

Built-in plugins are the modules in ``DEFAULT_PLUGINS``, with hooks written
exactly like those of third-party plugins, which are found through the
entry-point group ``hapticlab``; a built-in module is imported the first time
what it registers is used (``core/host/builtins.py``), so start-up stays light.
Environment switches:

* ``HAPTICLAB_LOAD_PLUGINS``: comma-separated entry-point names to load (empty
  string: load no third-party plugin); unset loads them all.
* ``HAPTICLAB_TRACE_PLUGINS``: when set, every hook call is traced to stderr.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import os
import sys
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property, partial
from typing import Any

import pluggy

from hapticlab.core.errors import ConfigError, PluginError
from hapticlab.core.host import hookspecs
from hapticlab.core.host.builtins import BUILTINS, BuiltinPlugin, Deferred
from hapticlab.core.host.hookspecs import KINDS as KINDS  # re-exported: callers look kinds up here
from hapticlab.core.host.options import OptionError

DEFAULT_PLUGINS: tuple[str, ...] = tuple(BUILTINS)
"""The built-in plugin modules (indexed in ``core/host/builtins.py``, imported when first used)."""


@dataclass(frozen=True)
class PluginEntry:
    """One registered thing: its kind, name, factory and the plugin it came from.

    A built-in's factory is found on first use (``core/host/builtins.py``): ``load`` gives it.
    """

    kind: str
    name: str
    load: Callable[[], Callable[..., Any]] = field(repr=False, compare=False)
    origin: str

    @cached_property
    def factory(self) -> Callable[..., Any]:
        """What builds the plugin (a class or a function), imported on first use for a built-in."""
        return self.load()


def make_plugin_manager(load_entry_points: bool = True) -> pluggy.PluginManager:
    """A plugin manager with the built-ins and (optionally) the installed third-party plugins."""
    pm = pluggy.PluginManager("hapticlab")
    pm.add_hookspecs(hookspecs)
    for module_name in DEFAULT_PLUGINS:
        pm.register(BuiltinPlugin(module_name), name=module_name)
    if load_entry_points:
        wanted = os.environ.get("HAPTICLAB_LOAD_PLUGINS")
        if wanted is None:
            pm.load_setuptools_entrypoints("hapticlab")
        else:
            for name in filter(None, (n.strip() for n in wanted.split(","))):
                pm.load_setuptools_entrypoints("hapticlab", name=name)
    pm.check_pending()
    if os.environ.get("HAPTICLAB_TRACE_PLUGINS"):
        pm.trace.root.setwriter(lambda msg: sys.stderr.write(msg))
        pm.enable_tracing()
    return pm


def _itself(factory: Callable[..., Any]) -> Callable[..., Any]:
    return factory


def _origin(pm: pluggy.PluginManager, plugin: object) -> str:
    name = pm.get_name(plugin) or str(getattr(plugin, "__name__", repr(plugin)))
    for dist_plugin, dist in pm.list_plugin_distinfo():
        if dist_plugin is plugin:
            return f"{name} ({dist.project_name} {dist.version})"
    return name


class Registry:
    """Everything the plugins registered, by kind and name.

    Built once per process from a plugin manager; lookups and construction
    afterwards are plain dictionary work.
    """

    def __init__(self, pm: pluggy.PluginManager | None = None):
        self.pm = pm if pm is not None else make_plugin_manager()
        self._entries: dict[str, dict[str, PluginEntry]] = {kind: {} for kind in KINDS}
        for kind, hook_name in KINDS.items():
            hook = getattr(self.pm.hook, hook_name)
            for impl in hook.get_hookimpls():
                origin = _origin(self.pm, impl.plugin)
                impl.function(register=self._register_callback(kind, origin))

    def _register_callback(self, kind: str, origin: str) -> Callable[[str, Callable[..., Any]], None]:
        def register(name: str, factory: Callable[..., Any]) -> None:
            if not isinstance(name, str) or not name.isidentifier():
                raise PluginError(f"{origin}: {kind} name {name!r} is not a valid identifier")
            if not callable(factory):
                raise PluginError(f"{origin}: {kind} {name!r} factory is not callable")
            existing = self._entries[kind].get(name)
            if existing is not None:
                raise PluginError(f"{kind} {name!r} registered twice: by {existing.origin} and by {origin}")
            load = factory.load if isinstance(factory, Deferred) else partial(_itself, factory)
            self._entries[kind][name] = PluginEntry(kind, name, load, origin)

        return register

    def names(self, kind: str) -> list[str]:
        """Sorted names registered for a kind."""
        return sorted(self._entries[kind])

    def entries(self) -> list[PluginEntry]:
        """Every registered entry, by kind then name."""
        return [self._entries[k][n] for k in KINDS for n in sorted(self._entries[k])]

    def get(self, kind: str, name: str) -> PluginEntry:
        """The entry for ``name``, or a PluginError listing the names there are."""
        if kind not in self._entries:
            raise PluginError(f"unknown plugin kind {kind!r}; kinds: {', '.join(KINDS)}")
        try:
            return self._entries[kind][name]
        except KeyError:
            available = ", ".join(self.names(kind)) or "none"
            raise PluginError(f"unknown {kind} {name!r}; available: {available}") from None

    def create(
        self, kind: str, name: str, options: Mapping[str, Any] | None = None, where: str | None = None, **context: Any
    ) -> Any:
        """Build the named plugin from config options, checking them against its signature.

        ``where`` is the config path used in error messages (e.g. ``"estimator"``),
        ``context`` holds keyword arguments the host provides (e.g. ``world``),
        passed only when the factory accepts them.
        """
        try:
            entry = self.get(kind, name)
        except PluginError as exc:
            raise ConfigError(f"{where or kind}.name: {exc}") from None
        kwargs = validate_options(
            entry.factory, dict(options or {}), where or kind, host_provided=frozenset(self.names("context"))
        )
        params = inspect.signature(entry.factory).parameters
        for key, value in context.items():
            if key in params:
                kwargs[key] = value
        try:
            return entry.factory(**kwargs)
        except OptionError as exc:
            raise exc.under(where or kind) from None
        except ValueError as exc:
            # Plugins refuse bad values with "option: what is wrong"; name the full key.
            message = str(exc)
            key = message.split(":", 1)[0]
            sep = "." if key in params else ": "
            raise ConfigError(f"{where or kind}{sep}{message}") from None

    def resolved_options(self, kind: str, name: str, options: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """The options a plugin runs with: its defaults updated by ``options``."""
        resolved = {
            key: default
            for key, (_, default) in option_signature(self.get(kind, name).factory).items()
            if key not in self.names("context") and default is not inspect.Parameter.empty
        }
        resolved.update(options or {})
        return resolved


def _options_class(factory: Callable[..., Any]) -> type | None:
    """The ``Options`` dataclass of the class whose ``__init__`` builds the factory's objects, or None: a
    subclass with an ``__init__`` of its own (and no ``Options`` of its own) is read from its signature."""
    if not inspect.isclass(factory):
        return None
    for klass in factory.__mro__:
        if "__init__" in vars(klass):
            options = vars(klass).get("Options")
            return options if isinstance(options, type) and dataclasses.is_dataclass(options) else None
    return None


def option_signature(factory: Callable[..., Any]) -> dict[str, tuple[Any, Any]]:
    """The keyword options a factory accepts: name -> (annotated type, default or ``Parameter.empty``).

    A factory with an ``Options`` dataclass (the typed options of the built-in estimators) takes its
    fields; any other factory its signature (a plain function or class of a third-party plugin).
    """
    options_class = _options_class(factory)
    if options_class is not None:
        hints = typing.get_type_hints(options_class)
        return {
            f.name: (
                hints.get(f.name, Any),
                f.default if f.default is not dataclasses.MISSING else inspect.Parameter.empty,
            )
            for f in dataclasses.fields(options_class)
        }
    target = factory.__init__ if inspect.isclass(factory) else factory
    try:
        hints = typing.get_type_hints(target)
    except Exception:  # an unresolvable annotation: check names only
        hints = {}
    return {
        name: (hints.get(name, Any), param.default)
        for name, param in inspect.signature(factory).parameters.items()
        if param.kind not in (param.VAR_POSITIONAL, param.VAR_KEYWORD)
    }


def option_types(factory: Callable[..., Any]) -> dict[str, Any]:
    """The keyword options a factory accepts, with their annotated types."""
    return {name: annotation for name, (annotation, _) in option_signature(factory).items()}


def _type_ok(value: Any, annotation: Any) -> bool:
    if annotation is Any:
        return True
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, arg) for arg in typing.get_args(annotation))
    if annotation is type(None):
        return value is None
    if annotation is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if origin in (list, tuple):
        args = typing.get_args(annotation)
        if not isinstance(value, (list, tuple)):
            return False
        if args and args[-1] is not Ellipsis and origin is tuple:
            return len(args) == len(value) and all(_type_ok(v, a) for v, a in zip(value, args))
        inner = args[0] if args else Any
        return all(_type_ok(v, inner) for v in value)
    if origin is dict or annotation is dict:
        return isinstance(value, dict)
    if isinstance(annotation, type):
        return isinstance(value, annotation)
    return True


_TYPE_NAMES = {float: "number", int: "whole number", str: "string", dict: "table"}


def _type_name(annotation: Any, plural: bool = False) -> str:
    """What an annotation accepts, in the toolkit's words (``float | None``: "a number")."""
    origin = typing.get_origin(annotation) or annotation
    args = [arg for arg in typing.get_args(annotation) if arg is not type(None)]
    if annotation is bool:
        return "true or false"
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(arg, plural) for arg in args)
    if origin in _TYPE_NAMES:
        name = _TYPE_NAMES[origin]
        return f"{name}s" if plural else f"a {name}"
    if origin is tuple and args and args[-1] is not Ellipsis:
        return f"{len(args)} {_type_name(args[0], True)}" if len(set(args)) == 1 else f"{len(args)} values"
    if origin in (list, tuple):
        inner = _type_name(args[0], True) if args and args[0] is not Ellipsis else "values"
        return f"lists of {inner}" if plural else f"a list of {inner}"
    return str(annotation).replace("typing.", "")


def validate_options(
    factory: Callable[..., Any], options: dict[str, Any], where: str, host_provided: frozenset[str] = frozenset()
) -> dict[str, Any]:
    """Check option names and types against the factory's signature.

    ``host_provided`` names keyword arguments the host passes itself (the
    session's contexts, e.g. ``world``): never user options. Raises ConfigError
    naming the full key (``where.key``) on an unknown key or a value of the
    wrong type. Integers are accepted where a float is expected.
    """
    accepted = {k: v for k, v in option_types(factory).items() if k not in host_provided}
    for key, value in options.items():
        if key not in accepted:
            names = sorted(accepted)
            close = difflib.get_close_matches(key, names, n=1)
            hint = f"; did you mean {close[0]}?" if close else ""
            known = ", ".join(names) or "none"
            if len(known) > 240:  # one line still: a long list only by where it is documented
                documented = _options_class(factory) or factory
                known = f"{len(names)}, documented in {documented.__module__}.{documented.__qualname__}"
            raise ConfigError(f"{where}.{key}: unknown option{hint}; known options: {known}")
        if not _type_ok(value, accepted[key]):
            hint = (
                f" (a number read as text needs quotes: --set '{where}.{key}=\"{value}\"')"
                if accepted[key] is str and isinstance(value, (int, float))
                else ""
            )
            raise ConfigError(f"{where}.{key}: must be {_type_name(accepted[key])}, got {value!r}{hint}")
        if accepted[key] is float and isinstance(value, int):
            options[key] = float(value)
    return options
