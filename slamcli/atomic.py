"""Atomic file writes and the up-front check that an output location can be written.

Every output file is written to a hidden temporary name in its destination folder and renamed
into place only once complete, so an interrupted or failed write never leaves a truncated file
and never clobbers an earlier one. Formats, run folders and plans all write through here.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from slamcli.errors import ExportError, InputError, SlamcliError


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _current_umask()
FILE_MODE = 0o666 & ~_UMASK
"""Permissions a plain ``open()`` would give a new file; mkstemp's owner-only mode is widened
to this so outputs are readable as users expect."""
DIR_MODE = 0o777 & ~_UMASK
"""Permissions a plain ``mkdir()`` would give a new folder (mkdtemp makes it owner-only)."""

UNWRITABLE_HINT = "choose another --out, or make that folder writable (permissions, free space)"


def unwritable(path: str | Path, exc: OSError, what: str = "cannot write") -> ExportError:
    """An ExportError naming ``path`` and the operating system's reason, with a hint."""
    reason = exc.strerror or str(exc)
    where = exc.filename if exc.filename else path
    return ExportError(f"{where}: {what} ({reason})", hint=UNWRITABLE_HINT)


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds.

    The temporary file keeps the destination's suffix so writers that choose a format by
    extension (OpenCV, matplotlib, Open3D) behave as for the real name.
    """
    dest = Path(path)
    if not dest.parent.is_dir():
        raise ExportError(f"{dest}: folder {dest.parent} does not exist")
    try:
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{dest.stem}.", suffix=f".tmp{dest.suffix}", dir=dest.parent
        )
    except OSError as exc:
        raise unwritable(dest, exc) from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        tmp.chmod(FILE_MODE)
        yield tmp
        tmp.replace(dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write UTF-8 text to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def write_json_atomic(path: str | Path, data: Any) -> Path:
    """Write ``data`` as indented JSON atomically."""
    return write_text_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def check_writable_folder(folder: str | Path) -> None:
    """Raise ExportError unless a file can be created (and removed) in ``folder``.

    Called before any work, so an unwritable output location (read-only, full, a file where a
    folder should be) fails at once with the reason instead of after a long computation.
    """
    path = Path(folder)
    if not path.is_dir():
        raise ExportError(
            f"{path}: not a folder" if path.exists() else f"{path}: folder does not exist",
            hint=UNWRITABLE_HINT,
        )
    try:
        fd, probe = tempfile.mkstemp(prefix=".slamcli-probe-", dir=path)
        try:
            os.write(fd, b"probe")
        finally:
            os.close(fd)
            Path(probe).unlink()
    except OSError as exc:
        raise unwritable(path, exc) from exc


def check_writable_file(path: str | Path) -> None:
    """Raise ExportError unless ``path`` can be written: it is not a folder, and its folder
    exists and takes a new file."""
    dest = Path(path)
    if dest.is_dir():
        raise ExportError(f"{dest}: is a folder", hint="give the output a file name")
    check_writable_folder(dest.parent)


_WRITE_ERRNOS = {
    errno.ENOSPC,
    errno.EROFS,
    errno.EFBIG,
    *([errno.EDQUOT] if hasattr(errno, "EDQUOT") else []),
}
_ACCESS_ERRNOS = {errno.EACCES, errno.EPERM}


def os_error(exc: OSError) -> SlamcliError:
    """A one-line error for an operating-system failure no library code turned into a
    SlamcliError: the path it names and the system's reason, with a hint where the reason
    tells what to do (a full or read-only disk: write elsewhere; permissions: check them)."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    msg = reason
    if exc.filename is not None:
        where = str(exc.filename)
        if exc.filename2 is not None:
            where += f" -> {exc.filename2}"
        msg = f"{where}: {reason}"
    if exc.errno in _WRITE_ERRNOS:
        return ExportError(msg, hint=UNWRITABLE_HINT)
    if exc.errno in _ACCESS_ERRNOS:
        return InputError(msg, hint="check the permissions of that file or folder")
    return InputError(msg)
