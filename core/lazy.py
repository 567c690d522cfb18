"""Names a package exports but imports on first use (a module ``__getattr__``, PEP 562).

``import hapticlab`` and the command line's parser stay light: what pulls in numba, scipy or the review's
numerics is imported when a caller first reads the name, and kept in the package from then on.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(package: str, homes: Mapping[str, str]) -> Callable[[str], Any]:
    """A ``__getattr__`` for the module ``package``: ``name`` imported from the module ``homes[name]`` on first
    use and set on ``package`` (the next read does not come here); any other name is an AttributeError."""

    def attribute(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(home), name)
        setattr(sys.modules[package], name, value)
        return value

    return attribute
