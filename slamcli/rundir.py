"""Run directories: safe preparation, atomic writes and the ``run.json`` record.

Every file is written to a hidden temporary name in its destination folder and renamed into
place only once complete, so an interrupted or failed run never leaves a truncated output and
never clobbers an earlier result.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import platform
import sys
import tempfile
import time
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

from slamcli.errors import ExportError, InputError

RUN_SCHEMA_VERSION = 1
"""Version of the run.json layout (documented in README.md, 'run.json')."""

_PACKAGES = (
    "numpy",
    "scipy",
    "opencv-python-headless",
    "open3d-cpu",
    "open3d",
    "pycolmap",
    "trimesh",
    "mcap",
    "rosbags",
    "typer",
    "rich",
    "matplotlib",
)
_FULL_HASH_LIMIT = 256 * 1024 * 1024
_FAST_HASH_BLOCK = 4 * 1024 * 1024


def _current_umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_UMASK = _current_umask()


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` if the block succeeds.

    The temporary file keeps the destination's suffix so writers that choose a format by
    extension (OpenCV, matplotlib, Open3D) behave as for the real name.
    """
    dest = Path(path)
    if not dest.parent.is_dir():
        raise ExportError(f"{dest}: folder {dest.parent} does not exist")
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{dest.stem}.", suffix=f".tmp{dest.suffix}", dir=dest.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    # mkstemp creates the file owner-only; outputs get the permissions a plain open() would.
    tmp.chmod(0o666 & ~_UMASK)
    try:
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


def hash_input(path: str | Path) -> dict[str, Any]:
    """Describe an input for run.json: size and a content hash.

    Files up to 256 MiB get a full SHA-256; larger files a fast hash of their size, first and
    last 4 MiB (``"hash": "fast-sha256:…"``). A folder hashes every file in it, in sorted order,
    with the same rule per file.
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    files = sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p]
    digest = hashlib.sha256()
    total = 0
    fast = False
    for f in files:
        size = f.stat().st_size
        total += size
        if p.is_dir():
            digest.update(f.relative_to(p).as_posix().encode() + b"\0")
        with f.open("rb") as fh:
            if size <= _FULL_HASH_LIMIT:
                for block in iter(functools.partial(fh.read, 1 << 20), b""):
                    digest.update(block)
            else:
                fast = True
                digest.update(str(size).encode())
                digest.update(fh.read(_FAST_HASH_BLOCK))
                fh.seek(size - _FAST_HASH_BLOCK)
                digest.update(fh.read(_FAST_HASH_BLOCK))
    return {
        "path": str(p.resolve()),
        "kind": "folder" if p.is_dir() else "file",
        "files": len(files),
        "bytes": total,
        "hash": ("fast-sha256:" if fast else "sha256:") + digest.hexdigest(),
    }


def package_versions() -> dict[str, str]:
    """Installed versions of the libraries results depend on (without importing them)."""
    out = {"python": platform.python_version()}
    for name in _PACKAGES:
        with contextlib.suppress(metadata.PackageNotFoundError):
            out[name] = metadata.version(name)
    return out


class Timings:
    """Wall-clock seconds per named stage, in the order the stages first ran."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start

    def as_dict(self) -> dict[str, float]:
        return {k: round(v, 4) for k, v in self.seconds.items()}


class RunDir:
    """An output folder for one run.

    ``RunDir(out, force=False)`` refuses a non-empty folder unless ``force``; the folder is
    created with the first file written, so a run that fails before writing leaves nothing.
    Files go in with :meth:`write_text`, :meth:`write_json` or :meth:`atomic`, each
    atomically, and are listed in run.json's ``outputs``.
    """

    def __init__(self, path: str | Path, force: bool = False) -> None:
        self.path = Path(path)
        if self.path.exists() and not self.path.is_dir():
            raise ExportError(
                f"{self.path}: exists and is not a folder", hint="choose another --out"
            )
        if self.path.is_dir() and any(self.path.iterdir()) and not force:
            raise ExportError(
                f"{self.path}: output folder is not empty",
                hint="pass --force to overwrite it, or choose another --out",
            )
        self.outputs: list[str] = []

    def file(self, name: str) -> Path:
        """Destination path of an output inside the run folder (created when first needed)."""
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise ExportError(
                f"{self.path}: cannot create the output folder ({exc.strerror})"
            ) from exc
        return self.path / name

    def output(self, name: str) -> Path:
        """Destination of an output whose writer is atomic itself; it is listed in run.json."""
        if name not in self.outputs:
            self.outputs.append(name)
        return self.file(name)

    @contextlib.contextmanager
    def atomic(self, name: str) -> Iterator[Path]:
        """Temporary path for output ``name``; renamed into place when the block succeeds."""
        with atomic_path(self.file(name)) as tmp:
            yield tmp
        if name not in self.outputs:
            self.outputs.append(name)

    def write_text(self, name: str, text: str) -> Path:
        with self.atomic(name) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return self.file(name)

    def write_json(self, name: str, data: Any) -> Path:
        return self.write_text(name, json.dumps(data, indent=2) + "\n")

    def write_run_json(
        self,
        *,
        command: str,
        inputs: list[dict[str, Any]],
        config: dict[str, Any] | None = None,
        seeds: dict[str, int] | None = None,
        timings: Timings | None = None,
        counts: dict[str, Any] | None = None,
        metrics: dict[str, Any] | None = None,
        extra: dict[str, Any] | None = None,
    ) -> Path:
        """Write run.json (schema in README.md); it lists every output written before it."""
        from slamcli import __version__

        record: dict[str, Any] = {
            "schema_version": RUN_SCHEMA_VERSION,
            "slamcli_version": __version__,
            "command": command,
            "argv": list(sys.argv),
            "created_unix": round(time.time(), 3),
            "inputs": inputs,
            "config": config or {},
            "seeds": seeds or {},
            "packages": package_versions(),
            "timings_s": timings.as_dict() if timings else {},
            "counts": counts or {},
            "metrics": metrics or {},
            "outputs": [*self.outputs, "run.json"],
        }
        if extra:
            record.update(extra)
        return self.write_json("run.json", record)
