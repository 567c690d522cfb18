"""Where the offline tools write: checked before the work, written whole or not at all, never over a file unasked.

Every command that writes a file (``compensate -o``/``--params-out``, ``replay -o``,
``recover -o``, ``discrepancy --json``/``--plots``, ``bench --json``/``--plots``)
goes through here:

* :func:`check_output` before the work starts: the parent folder exists and can
  be written, the target is not a folder, not one of the inputs, and does not
  exist unless ``force`` (an :class:`~hapticlab.core.errors.OutputExistsError`
  otherwise). :func:`check_plots_folder` does the same for a folder of figures.
* :func:`atomic_output` at the end: the caller writes a temporary file beside
  the target, which is renamed over it (``os.replace``) only when the writing
  ended without an error; on an error the temporary file is removed, so a
  failure never leaves half a file where a good one was.
"""

from __future__ import annotations

import os
import secrets
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

from hapticlab.core.errors import OutputExistsError, UserError


def _named(label: str, path: Path) -> str:
    return f"{label} {path}" if label else str(path)


def check_writable(folder: Path, named: str) -> None:
    """UserError unless a file can be created in ``folder`` (tried: permission bits do not stop root)."""
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".hapticlab-", suffix=".probe")
    except OSError as exc:
        raise UserError(f"{named}: cannot write in {folder} ({exc.strerror or exc})") from None
    os.close(fd)
    os.unlink(probe)


def _same_file(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def check_output(
    path: str | os.PathLike[str],
    force: bool = False,
    *,
    label: str = "",
    inputs: Iterable[str | os.PathLike[str] | None] = (),
    role: str = "input",
) -> Path:
    """Check an output path before any work is done; return it as a Path.

    ``label`` names the option in the messages (``"-o"``, ``"--json"``);
    ``inputs`` are the files the command reads (``role`` names them in the
    message: "the input", "the recording"). Raises :class:`UserError` when the
    path is a folder or another non-regular file (a device, a FIFO), its folder
    does not exist or cannot be written, or it is an input;
    :class:`OutputExistsError` when it exists and ``force`` is false.
    """
    path = Path(path)
    named = _named(label, path)
    if path.is_dir():
        raise UserError(f"{named}: is a folder; give a file name")
    if path.exists() and not path.is_file():  # never replaced, --force or not
        raise UserError(f"{named}: is not a regular file (a device, a FIFO or a socket); give a file name")
    parent = path.parent
    if not parent.is_dir():
        what = "is not a folder" if parent.exists() else "does not exist"
        raise UserError(f"{named}: folder {parent} {what}")
    for source in inputs:
        if source and path.exists() and _same_file(path, Path(source)):
            raise UserError(f"{named}: the output would overwrite the {role} {source}; write to a different file")
    if (path.exists() or path.is_symlink()) and not force:
        raise OutputExistsError(f"{named}: already exists; --force overwrites it")
    check_writable(parent, named)
    return path


def check_plots_folder(
    folder: str | os.PathLike[str], force: bool = False, *, label: str = "--plots", patterns: Iterable[str] = ("*.png",)
) -> Path:
    """Check a folder of figures before any work: it is (or can be made) a writable folder, and holds no
    file matching ``patterns`` (the figures the command writes) unless ``force``."""
    folder = Path(folder)
    named = _named(label, folder)
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{named}: exists and is not a folder")
    existing = next((p for p in (folder, *folder.parents) if p.exists()), Path("."))
    if not existing.is_dir():
        raise UserError(f"{named}: {existing} is not a folder")
    if existing == folder and not force:
        clash = sorted({p.name for pattern in patterns for p in folder.glob(pattern)})
        if clash:
            more = f" and {len(clash) - 1} more figure(s)" if len(clash) > 1 else ""
            raise OutputExistsError(f"{named}: {folder} already holds {clash[0]}{more}; --force overwrites them")
    check_writable(existing, named)
    return folder


def temporary_beside(path: Path) -> Path:
    """A fresh, unused name in ``path``'s folder, hidden, with the same suffix (writers that go by the
    suffix, such as matplotlib, still write the right format)."""
    return path.with_name(f".{path.stem}.{secrets.token_hex(4)}.partial{path.suffix}")


@contextmanager
def atomic_output(path: str | os.PathLike[str], force: bool = False, *, label: str = "") -> Iterator[Path]:
    """Write ``path`` whole or not at all: yields a temporary path beside it to write to.

    When the block ends without an error the temporary file replaces ``path``
    (``os.replace``, atomic on one file system); when it raises, the temporary
    file is removed and ``path`` is as it was. The target is checked first
    (:func:`check_output`), and again at the end when ``force`` is false, so a
    file that appeared meanwhile is not overwritten either. An ``OSError`` on
    the temporary file (a full disk) is reported against ``path``.
    """
    path = check_output(path, force, label=label)
    tmp = temporary_beside(path)
    try:
        yield tmp
        if not force and (path.exists() or path.is_symlink()):
            raise OutputExistsError(f"{_named(label, path)}: already exists; --force overwrites it")
        os.replace(tmp, path)
    except OSError as exc:
        if isinstance(exc, UserError) or str(exc.filename) != str(tmp):
            raise
        raise UserError(f"{_named(label, path)}: cannot write it ({exc.strerror or exc})") from exc
    finally:
        tmp.unlink(missing_ok=True)


def write_text(path: str | os.PathLike[str], text: str, force: bool = False, *, label: str = "") -> Path:
    """Write a text file (UTF-8) through :func:`atomic_output`; returns the path."""
    with atomic_output(path, force, label=label) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def save_figure(fig, path: Path, force: bool = False, dpi: int = 100) -> Path:
    """Write a matplotlib figure (PNG, by the suffix) through :func:`atomic_output` and close it; the path."""
    import matplotlib.pyplot as plt

    with atomic_output(path, force, label="--plots") as tmp:
        fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    return path
