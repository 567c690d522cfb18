"""Where numba keeps hapticlab's compiled kernels, decided once at import, before any kernel is compiled.

Every kernel is ``@njit(cache=True)``: numba writes its machine code beside the source (the package's
``__pycache__`` folders) or in the user's cache folder (``$XDG_CACHE_HOME`` or ``~/.cache``, ``numba``),
and with neither writable (a system-wide install used by a lab account without a home) it raises at
the decorator, so every command would fail at import. Then, unless ``NUMBA_CACHE_DIR`` says where:
a folder of this user in the machine's temporary directory, or where even that cannot be written, no
cache at all (the kernels compile on each run, ~50 s). One line on stderr says which.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path


def writable(folder: Path) -> bool:
    """Whether ``folder`` (made if missing) can be written: its nearest existing ancestor is writable."""
    while not folder.exists():
        if folder.parent == folder:
            return False
        folder = folder.parent
    return folder.is_dir() and os.access(folder, os.W_OK)


def user_cache() -> Path:
    """The folder numba's user-wide cache uses: ``$XDG_CACHE_HOME/numba`` or ``~/.cache/numba``."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "numba"


def choose(package: Path) -> str:
    """Set up numba's cache for the kernels under ``package``; what was done: ``"numba's own"`` (beside the
    sources or in the user's cache), ``"NUMBA_CACHE_DIR"`` (set by the user), a fallback folder, or
    ``"none"``."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return "NUMBA_CACHE_DIR"
    if writable(package / "__pycache__") or writable(user_cache()):
        return "numba's own"
    import tempfile  # only here: every command imports this module at start-up

    try:
        fallback = Path(tempfile.gettempdir()) / f"hapticlab-numba-{os.getuid()}"
    except FileNotFoundError:  # gettempdir found no writable temporary directory
        fallback = Path("/tmp") / f"hapticlab-numba-{os.getuid()}"
    if writable(fallback):
        os.environ["NUMBA_CACHE_DIR"] = str(fallback)
        sys.stderr.write(
            f"hapticlab: neither {package} nor {user_cache()} can be written: the compiled kernels are cached "
            f"in {fallback} (set NUMBA_CACHE_DIR to choose)\n"
        )
        return str(fallback)
    from numba.core.dispatcher import Dispatcher

    Dispatcher.enable_caching = lambda self: None  # type: ignore[method-assign]  # cache=True then caches nothing
    sys.stderr.write(
        f"hapticlab: no folder to cache the compiled kernels in ({package}, {user_cache()} and {fallback} "
        "cannot be written): they compile on each run (set NUMBA_CACHE_DIR to a writable folder)\n"
    )
    return "none"
