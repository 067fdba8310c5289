"""Reading run folders: the one place that knows what a ``slamcli run`` folder holds.

A run folder is a folder holding ``run.json``. :func:`read_run` reads that record and notes
which result files exist; the files themselves are read on demand by :class:`RunRecord`'s
loaders, so a caller pays only for what it uses (``slamcli map build`` never parses the mesh,
``slamcli convert`` never opens the input log).

Which pipeline made the run is read from run.json's ``pipeline`` key; records written before
that key existed name it in ``command`` (``"run dense"``) or, for runs made by
``slamcli demo`` (``command: "demo"``), as the one pipeline section of ``config`` besides
``source``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from slamcli.errors import FormatError, InputError

if TYPE_CHECKING:
    import numpy as np
    from numpy.typing import NDArray

    from slamcli.types import LandmarkMap, OccupancyGrid, SlamResult, Trajectory, TriangleMesh

RUN_JSON = "run.json"

RUN_FILES = {
    "trajectory": "trajectory.tum",
    "keyframes": "keyframes.tum",
    "landmarks": "landmarks.csv",
    "mesh": "mesh.ply",
    "points": "points.ply",
    "map": "map.yaml",
}
"""Result files a run folder may hold, by what they hold."""

RESULT_KINDS = ("trajectory", "map", "points", "mesh")
"""What :meth:`RunRecord.result` reads: the parts a result log shows."""

_HINT = "give the --out folder of a 'slamcli run ...'"


@dataclass(frozen=True)
class RunRecord:
    """A run folder: its ``run.json`` record, its pipeline and the result files it holds.

    Attributes:
        path: the run folder.
        record: run.json as a dict.
        pipeline: the name of the pipeline that made the run (``"dense"``, ``"ekf"``, ...), or
            None when run.json does not say.
        files: the existing files of :data:`RUN_FILES`, by kind.
    """

    path: Path
    record: dict[str, Any]
    pipeline: str | None
    files: dict[str, Path]

    def has(self, kind: str) -> bool:
        """Whether the folder holds the file of ``kind`` (a key of :data:`RUN_FILES`)."""
        return kind in self.files

    def require(self, kind: str) -> Path:
        """The path of the file of ``kind``; InputError naming the folder when it is missing."""
        if kind not in self.files:
            by = f" of the {self.pipeline} pipeline" if self.pipeline else ""
            raise InputError(
                f"{self.path}: a run folder{by} without {RUN_FILES[kind]}",
                hint="pass the --out folder of a 'slamcli run ...' that wrote it",
            )
        return self.files[kind]

    @property
    def source_options(self) -> dict[str, Any]:
        """The source options the run was made with (run.json's ``config.source``)."""
        config = self.record.get("config")
        source = config.get("source") if isinstance(config, dict) else None
        return dict(source) if isinstance(source, dict) else {}

    def input_path(self, given: str | Path | None = None) -> Path:
        """The run's input log: ``given``, else run.json's first input, tried as it is
        (absolute or relative to the current folder) and then relative to the run folder.

        Raises:
            InputError: ``given`` does not exist, run.json names no input, or it moved.
        """
        if given is not None:
            p = Path(given)
            if not p.exists():
                raise InputError(f"{p}: no such file or folder (--input)")
            return p
        where = self.path / RUN_JSON
        inputs = self.record.get("inputs") or []
        if not inputs or not isinstance(inputs[0], dict) or "path" not in inputs[0]:
            raise InputError(
                f"{where}: names no input log",
                hint="pass --input PATH with the log the run was made from",
            )
        recorded = Path(str(inputs[0]["path"]))
        for candidate in (recorded, self.path / recorded):
            if candidate.exists():
                return candidate
        raise InputError(
            f"{where}: the run's input {recorded} no longer exists",
            hint="pass --input PATH with the log's new location",
        )

    def trajectory(self) -> Trajectory:
        """``trajectory.tum``; InputError when the folder has none."""
        from slamcli.formats.trajectory import read_trajectory

        return read_trajectory(self.require("trajectory"), "tum")

    def landmarks(self) -> LandmarkMap:
        """``landmarks.csv`` (EKF runs); InputError when the folder has none."""
        from slamcli.formats.landmark_map import read_landmarks_csv

        return read_landmarks_csv(self.require("landmarks"))

    def mesh(self) -> TriangleMesh:
        """``mesh.ply``; InputError when the folder has none."""
        from slamcli.formats.mesh import read_mesh

        return read_mesh(self.require("mesh"))

    def points(self) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
        """``points.ply``: (N, 3) float64 metres and (N, 3 or 4) uint8 colours or None."""
        from slamcli.formats.mesh import read_points_ply

        return read_points_ply(self.require("points"))

    def grid(self) -> OccupancyGrid:
        """``map.yaml`` with the image it names; InputError when the folder has none."""
        from slamcli.formats.occupancy import read_map

        return read_map(self.require("map"))

    def result(self) -> SlamResult:
        """The parts a result log shows (:data:`RESULT_KINDS`), read where present."""
        from slamcli.types import SlamResult

        result = SlamResult()
        if self.has("trajectory"):
            result.trajectory = self.trajectory()
        if self.has("map"):
            result.grid = self.grid()
        if self.has("points"):
            result.points, result.point_colors = self.points()
        if self.has("mesh"):
            result.mesh = self.mesh()
        return result


def is_run_dir(path: str | Path) -> bool:
    """A run folder: a folder holding the ``run.json`` every run writes."""
    p = Path(path)
    return p.is_dir() and (p / RUN_JSON).is_file()


def sub_runs(path: str | Path) -> list[str]:
    """Names of the sub-folders of ``path`` that are run folders, sorted."""
    p = Path(path)
    if not p.is_dir():
        return []
    return sorted(child.name for child in p.iterdir() if is_run_dir(child))


def read_run(path: str | Path) -> RunRecord:
    """Read a run folder's ``run.json`` and note which result files it holds.

    Raises:
        InputError: no such folder, or a folder without run.json (for a folder of runs, as
            ``slamcli demo`` writes, the message lists them).
        FormatError: run.json is not a JSON object.
    """
    p = Path(path)
    if not p.is_dir():
        what = "is a file, not a run folder" if p.exists() else "no such run folder"
        raise InputError(f"{p}: {what}", hint=_HINT)
    if not (p / RUN_JSON).is_file():
        runs = sub_runs(p)
        if runs:
            raise InputError(
                f"{p}: holds {len(runs)} runs ({', '.join(runs)}), not one run folder",
                hint=f"pass one of them, e.g. {p / runs[0]}",
            )
        raise InputError(f"{p}: not a run folder (no {RUN_JSON})", hint=_HINT)
    record = _load_record(p / RUN_JSON)
    files = {kind: p / name for kind, name in RUN_FILES.items() if (p / name).is_file()}
    return RunRecord(p, record, _pipeline(record), files)


def _load_record(path: Path) -> dict[str, Any]:
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise FormatError(path, f"not a text file ({exc.reason} at byte {exc.start})") from None
    except json.JSONDecodeError as exc:
        raise FormatError(
            path, f"not valid JSON ({exc.msg})", exc.lineno, hint="the run's record is damaged"
        ) from None
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror})") from None
    if not isinstance(record, dict):
        raise FormatError(path, f"expected a JSON object, found {type(record).__name__}")
    return record


def _pipeline(record: dict[str, Any]) -> str | None:
    """run.json's ``pipeline``, else the X of a ``command`` "run X ...", else the one pipeline
    section of ``config`` (runs made by ``slamcli demo``)."""
    declared = record.get("pipeline")
    if isinstance(declared, str) and declared:
        return declared
    words = str(record.get("command") or "").split()
    if words[:1] == ["slamcli"]:
        words = words[1:]
    if len(words) >= 2 and words[0] == "run":
        return words[1]
    config = record.get("config")
    if isinstance(config, dict):
        sections = [k for k in config if k != "source"]
        if len(sections) == 1:
            return str(sections[0])
    return None


__all__ = ["RESULT_KINDS", "RUN_FILES", "RunRecord", "is_run_dir", "read_run", "sub_runs"]
