"""Writing a built map: map.yaml + map.pgm (trinary map_server), map.png, map.json."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from slamcli.atomic import atomic_path, check_writable_folder, write_json_atomic
from slamcli.errors import ExportError
from slamcli.formats.occupancy import write_map_yaml
from slamcli.formats.run_folder import RUN_JSON, is_run_dir, read_run
from slamcli.mapping.build import MAP_FILES, BuiltMap, MapSettings, build_map
from slamcli.types import ProgressFn

PREVIEW_MIN_PX = 480
"""The preview is scaled up by a whole factor (at most 8) until its longer side reaches this."""


def write_map(folder: str | Path, built: BuiltMap) -> list[Path]:
    """Write map.yaml, map.pgm, map.png and map.json into ``folder`` (which must exist),
    each atomically; returns the paths.

    map.yaml/map.pgm are a trinary map_server map (occupied_thresh 0.65, free_thresh 0.196);
    map.png is a preview (free white, occupied black, unknown grey, probabilities between as
    greys, y up) with the path drawn in red; map.json holds ``built.report``.
    """
    out = Path(folder)
    written = write_map_yaml(out / "map.yaml", built.grid, mode="trinary")
    written.append(write_preview(out / "map.png", built))
    written.append(write_json_atomic(out / "map.json", built.report))
    return written


def write_preview(path: str | Path, built: BuiltMap) -> Path:
    """map.png: the grid (as :func:`~slamcli.formats.occupancy.write_map_png`) with the path."""
    import cv2

    grid = built.grid
    prob = np.asarray(grid.prob, dtype=np.float64)
    grey = np.where(np.isnan(prob), 205, np.rint(255.0 * (1.0 - np.nan_to_num(prob))))
    image = np.flipud(grey.astype(np.uint8))
    h, w = image.shape
    scale = int(min(8, max(1, -(-PREVIEW_MIN_PX // max(h, w)))))
    image = np.repeat(np.repeat(image, scale, axis=0), scale, axis=1)
    bgr = np.ascontiguousarray(np.dstack([image, image, image]))
    if len(built.path_xy) > 1:
        x0, y0, _ = grid.origin_xy_yaw
        res = grid.resolution_m
        px = (built.path_xy[:, 0] - x0) / res * scale
        py = (h - (built.path_xy[:, 1] - y0) / res) * scale
        pts = np.rint(np.stack([px, py], axis=1)).astype(np.int32).reshape(-1, 1, 2)
        cv2.polylines(bgr, [pts], False, (0, 0, 220), max(1, scale // 2), cv2.LINE_AA)
    ok, buf = cv2.imencode(".png", bgr)
    if not ok:
        raise ExportError(f"{path}: OpenCV could not encode the map preview")
    with atomic_path(path) as tmp:
        tmp.write_bytes(buf.tobytes())
    return Path(path)


def add_run_outputs(run_dir: str | Path, names: list[str]) -> None:
    """Add ``names`` to run.json's ``outputs`` (before run.json itself), atomically; nothing
    happens when the folder has no run.json."""
    if not is_run_dir(run_dir):
        return
    run = read_run(run_dir)
    record = dict(run.record)
    outputs = [o for o in record.get("outputs", []) if o not in names and o != RUN_JSON]
    record["outputs"] = [*outputs, *names, RUN_JSON]
    write_json_atomic(run.path / RUN_JSON, record)


def map_run(
    run_dir: str | Path,
    *,
    settings: MapSettings | None = None,
    input_path: str | Path | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> tuple[BuiltMap, list[Path]]:
    """Build a run folder's map and write it into that folder, listed in its run.json.

    Raises:
        ExportError: the folder already holds map files and ``force`` is False. Otherwise as
            :func:`~slamcli.mapping.build.build_map`.
    """
    run = Path(run_dir)
    present = [name for name in MAP_FILES if (run / name).exists()]
    if present and not force:
        raise ExportError(
            f"{run}: already holds {', '.join(present)}",
            hint="pass --force to replace them, or --out to write elsewhere",
        )
    if run.is_dir():
        check_writable_folder(run)
    built = build_map(run, settings=settings, input_path=input_path, progress=progress)
    written = write_map(run, built)
    add_run_outputs(run, [p.name for p in written])
    return built, written
