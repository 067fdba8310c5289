"""Run directories: all-or-nothing output folders and the ``run.json`` record.

A run writes into a hidden staging folder beside its ``--out`` and renames it into place only
once every output is written, so an interrupted or failed run leaves either nothing or the
earlier complete folder, never a mix of old and new files.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import hashlib
import json
import os
import platform
import re
import shutil
import sys
import tempfile
import time
from collections.abc import Iterator
from importlib import metadata
from pathlib import Path
from typing import Any

from slamcli.atomic import (
    DIR_MODE,
    atomic_path,
    check_writable_folder,
    unwritable,
    write_json_atomic,
)
from slamcli.errors import ExportError, InputError
from slamcli.interrupts import watched

RUN_SCHEMA_VERSION = 1
"""Version of the run.json layout (documented in docs/run-folders.md)."""

LIST_LIMIT = 100
"""Longest list of names (strings) run.json records in full; a longer one (a source's missing
or unreadable files, damage found while reading) is summarised by :func:`summarise_lists`."""
LIST_KEPT = 10
"""Names a summarised list keeps, its first."""
_WHOLE = ("argv", "inputs", "outputs")
"""run.json entries never summarised: the command line, the inputs and the files written."""

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
    """An all-or-nothing output folder for one run.

    ``RunDir(out, force=False)`` refuses a non-empty ``out`` unless ``force``, then creates a
    hidden staging folder ``.<name>.staging-<pid>-XXXX`` beside it (which also proves the
    location is writable, before any work starts). Files go into the staging folder with
    :meth:`write_text`, :meth:`write_json`, :meth:`atomic` or :meth:`output` and are listed in
    run.json's ``outputs``. :meth:`commit` renames the staging folder onto ``out``; an earlier
    folder is moved aside first and deleted only once the new one is in place. Used as a
    context manager it commits when the block succeeds and removes the staging folder when it
    raises (KeyboardInterrupt included), leaving any earlier folder untouched.

    ``path`` is always the final folder: paths reported to users are built from it, while
    writers are given paths inside ``staging``.
    """

    def __init__(self, path: str | Path, force: bool = False) -> None:
        self.path = Path(path)
        # A symlinked --out (runs kept on another disk) is replaced where it points, so the
        # link keeps working and the rename stays on the target's file system.
        self._target = self.path.resolve() if self.path.is_symlink() else self.path
        self.force = force
        self.outputs: list[str] = []
        self.committed = False
        if self.path.exists() and not self.path.is_dir():
            raise ExportError(
                f"{self.path}: exists and is not a folder", hint="choose another --out"
            )
        self._refuse_unsafe_target()
        clean_stale_staging(self._target)
        if self.path.is_dir() and any(self.path.iterdir()) and not force:
            raise ExportError(
                f"{self.path}: output folder is not empty",
                hint="pass --force to overwrite it, or choose another --out",
            )
        parent = self._target.parent
        self._created_parents = _missing_parents(parent)
        existing = self._created_parents[-1].parent if self._created_parents else parent
        if not existing.is_dir():
            raise ExportError(
                f"{existing}: is not a folder, so {self.path} cannot be created in it",
                hint="choose another --out",
            )
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            self._remove_created_parents()
            raise unwritable(parent, exc, "cannot create the output folder") from exc
        self.staging = self._make_staging()

    def _refuse_unsafe_target(self) -> None:
        """The finished folder replaces ``path`` as a whole: refuse the home folder and one
        holding the working directory, which would vanish from under the shell."""
        if not self.path.is_dir():
            return
        target = self.path.resolve()
        cwd = Path.cwd().resolve()
        if target == cwd or target in cwd.parents or target == Path.home().resolve():
            raise ExportError(
                f"{self.path}: is the home folder or holds the working directory; a run "
                "folder is put in place as a whole, replacing what was there",
                hint="give --out the name of a new folder",
            )

    def _make_staging(self) -> Path:
        # Ctrl-C waits until the new folder is on the list that exit-time cleanup empties.
        with watched(deferred=True):
            try:
                staging = Path(
                    tempfile.mkdtemp(
                        prefix=f".{self._target.name}.staging-{os.getpid()}-",
                        dir=self._target.parent,
                    )
                )
            except OSError as exc:
                self._remove_created_parents()
                raise unwritable(
                    self._target.parent, exc, "cannot create the output folder"
                ) from exc
            _LIVE_STAGING.add(staging)
        try:
            staging.chmod(DIR_MODE)
            check_writable_folder(staging)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            self._remove_created_parents()
            raise
        return staging

    def _remove_created_parents(self) -> None:
        for folder in self._created_parents:
            with contextlib.suppress(OSError):
                folder.rmdir()

    def __enter__(self) -> RunDir:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *_: object) -> None:
        # The folder is committed only when the block finished; any exception, Ctrl-C
        # included, discards the staging folder and leaves an earlier run as it was.
        if exc_type is None:
            self.commit()
        else:
            self.abort()

    def staged(self, name: str) -> Path:
        """Where to write ``name`` (a path relative to the run folder) before the commit."""
        if self.committed:
            raise ExportError(f"{self.path}: already complete; nothing more can be written")
        return self.staging / name

    def file(self, name: str) -> Path:
        """Final path of output ``name``: what to report; it exists once committed."""
        return self.path / name

    def final(self, path: str | Path) -> Path:
        """The final path of ``path``, given inside the staging folder (others unchanged)."""
        p = Path(path)
        try:
            return self.path / p.relative_to(self.staging)
        except ValueError:
            return p

    def output(self, name: str) -> Path:
        """Staged destination of an output whose writer is atomic itself; listed in run.json."""
        if name not in self.outputs:
            self.outputs.append(name)
        return self.staged(name)

    @contextlib.contextmanager
    def atomic(self, name: str) -> Iterator[Path]:
        """Temporary path for output ``name``; moved into the staging folder when the block
        succeeds."""
        with atomic_path(self.staged(name)) as tmp:
            yield tmp
        if name not in self.outputs:
            self.outputs.append(name)

    def write_text(self, name: str, text: str) -> Path:
        """Write output ``name``; returns its final path."""
        with self.atomic(name) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return self.file(name)

    def write_json(self, name: str, data: Any) -> Path:
        """Write output ``name`` as indented JSON; returns its final path."""
        return self.write_text(name, json.dumps(data, indent=2) + "\n")

    def commit(self) -> Path:
        """Put the staged folder in place of ``path``; returns ``path``.

        An existing folder is renamed aside first and deleted only after the new one is in
        place; if the swap fails, it is renamed back and the staged files are removed.
        """
        if self.committed:
            return self.path
        # Ctrl-C during the swap is held until the folder is in place and recorded as such,
        # so it can neither split the swap nor strand the set-aside old folder.
        with watched(deferred=True):
            try:
                aside = self._swap_in()
            except OSError as exc:
                self.abort()
                raise unwritable(
                    self.path, exc, "cannot put the finished output folder in place"
                ) from exc
            except BaseException:
                self.abort()
                raise
            self.committed = True
            _LIVE_STAGING.discard(self.staging)
            if aside is not None:
                shutil.rmtree(aside, ignore_errors=True)
        return self.path

    def _swap_in(self) -> Path | None:
        """Rename the staging folder onto the target, an existing target aside first; returns
        the set-aside folder (to delete) or None. On failure the target is as it was."""
        target = self._target
        aside: Path | None = None
        if target.exists():
            aside = Path(
                tempfile.mkdtemp(prefix=f".{target.name}.old-{os.getpid()}-", dir=target.parent)
            )
            try:
                target.replace(aside)
            except BaseException:
                aside.rmdir()
                raise
        try:
            self.staging.replace(target)
        except BaseException:
            if aside is not None:
                aside.replace(target)
            raise
        return aside

    def abort(self) -> None:
        """Remove the staging folder; ``path`` keeps whatever it held before the run."""
        if not self.committed:
            shutil.rmtree(self.staging, ignore_errors=True)
            _LIVE_STAGING.discard(self.staging)
            self._remove_created_parents()

    def relocate_records(self) -> None:
        """Point paths that JSON records in the staging folder hold (map.json's run folder,
        plan.json's map) at the final folder instead. Call before :meth:`commit`."""
        swaps = [
            (str(self.staging.resolve()), str(self.path.resolve())),
            (str(self.staging), str(self.path)),
        ]

        def fix(value: Any) -> Any:
            if isinstance(value, str):
                for old, new in swaps:
                    if value == old or value.startswith(old + os.sep):
                        return new + value[len(old) :]
                return value
            if isinstance(value, list):
                return [fix(v) for v in value]
            if isinstance(value, dict):
                return {k: fix(v) for k, v in value.items()}
            return value

        for record in sorted(self.staging.rglob("*.json")):
            data = json.loads(record.read_text(encoding="utf-8"))
            fixed = fix(data)
            if fixed != data:
                write_json_atomic(record, fixed)

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
    ) -> dict[str, Any]:
        """Write run.json (schema in docs/run-folders.md); it lists every output written
        before it.

        Returns what it holds.
        """
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
        where = str(inputs[0].get("path", "")) if inputs else ""
        record = {k: v if k in _WHOLE else summarise_lists(v, where) for k, v in record.items()}
        text = json.dumps(record, indent=2) + "\n"
        self.write_text("run.json", text)
        # As a reader of the file sees it (tuples as lists, keys as strings).
        written: dict[str, Any] = json.loads(text)
        return written


def summarise_lists(value: Any, source: str = "") -> Any:
    """``value`` with every list of more than :data:`LIST_LIMIT` strings, at any depth,
    replaced by ``{"count", "first", "rest"}``: how many, the first :data:`LIST_KEPT`, and
    where the others are (``source``: the input, whose ``info`` reports its own lists).

    A source can name millions of files that are not there; run.json stays a summary of the
    run, kilobytes, whatever the input lists.
    """
    if isinstance(value, dict):
        return {k: summarise_lists(v, source) for k, v in value.items()}
    if isinstance(value, list | tuple):
        if len(value) > LIST_LIMIT and all(isinstance(v, str) for v in value):
            rest = f"the other {len(value) - LIST_KEPT} are not recorded here"
            if source:
                rest += f"; 'slamcli info {source} --json' reports the input's lists"
            return {"count": len(value), "first": list(value[:LIST_KEPT]), "rest": rest}
        return [summarise_lists(v, source) for v in value]
    return value


_LIVE_STAGING: set[Path] = set()
"""Staging folders of this process not yet committed or aborted."""


@atexit.register
def _remove_live_staging() -> None:
    """At exit, remove staging folders no commit claimed: a Ctrl-C that struck between creating
    a RunDir and entering its ``with`` block must leave nothing behind either."""
    for staging in list(_LIVE_STAGING):
        shutil.rmtree(staging, ignore_errors=True)
    _LIVE_STAGING.clear()


_STALE = re.compile(r"^\.(?P<name>.+)\.(?P<kind>staging|old)-(?P<pid>\d+)-[^/]*$")


def _missing_parents(folder: Path) -> list[Path]:
    """Folders that ``folder.mkdir(parents=True)`` would create, deepest first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    return missing


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:
        return True
    return True


def clean_stale_staging(path: Path) -> None:
    """Remove staging and set-aside folders of ``path`` left by a killed process.

    A set-aside folder whose process died between the two renames of a commit is the last
    complete run: when ``path`` is missing it is renamed back instead of deleted.
    """
    parent = path.parent
    if not parent.is_dir():
        return
    try:
        entries = list(parent.iterdir())
    except OSError:
        return
    for entry in entries:
        m = _STALE.match(entry.name)
        if not m or m["name"] != path.name or _pid_alive(int(m["pid"])):
            continue
        if m["kind"] == "old" and not path.exists():
            with contextlib.suppress(OSError):
                entry.replace(path)
                continue
        shutil.rmtree(entry, ignore_errors=True)
