"""Atomic file output: an interrupted run never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path

from .errors import ExportError


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; on success it replaces ``path`` in one rename.

    The temporary name keeps the extension of ``path`` (writers such as meshio and OpenUSD pick
    the format from it). If the body raises, the temporary file is removed and ``path`` is left
    as it was. Missing parent directories are created.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write here: {exc.strerror or exc}") from exc
    try:
        yield tmp
        try:
            umask = os.umask(0)
            os.umask(umask)
            os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes the file private; give it the usual mode
            os.replace(tmp, path)
        except OSError as exc:
            raise ExportError(f"{path}: cannot write here: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(FileNotFoundError):
            os.remove(tmp)


def check_writable(path: str | os.PathLike) -> None:
    """Raise :class:`ExportError` now if ``path`` could not be written later: long runs check
    their output before they start. Leaves nothing behind (the nearest existing directory on
    the way must take a file, made and removed here, so the missing ones can be made when the
    file is written)."""
    path = Path(path).absolute()
    if path.is_dir():
        raise ExportError(f"{path}: is a directory")
    ancestor = path.parent
    while not ancestor.exists():
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise ExportError(f"{path}: cannot write here: {ancestor} is not a directory")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise ExportError(f"{path}: cannot write here: {ancestor} is not writable")
    try:  # a file made and removed: what os.access cannot tell (root on a read-only mount, /proc)
        fd, probe = tempfile.mkstemp(prefix=".wcut-probe.", dir=ancestor)
        os.close(fd)
        os.remove(probe)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write here: {exc.strerror or exc}") from None
