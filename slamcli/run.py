"""``run_pipeline``: one pipeline over one log into a run folder, as named steps.

open (the source, what to read, where to start) -> track (every frame, then ``finish``) ->
score (against the source's ground truth, with report.png) -> export (trajectories, products,
result.mcap, the occupancy map) -> record (run.json, which lists every output). The folder is
all or nothing (:class:`~slamcli.rundir.RunDir`).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, is_dataclass
from pathlib import Path
from typing import Any

from slamcli.errors import ConfigError, DataLossError, InputError, PipelineError
from slamcli.formats.base import ReadAhead, ReadStats, Source, SourceInfo
from slamcli.interrupts import watched
from slamcli.pipelines import Evaluation, Pipeline
from slamcli.rundir import RunDir, Timings, hash_input
from slamcli.types import ImuFrame, LandmarkMap, ProgressFn, SlamResult, Trajectory
from slamcli.worker import Background

log = logging.getLogger(__name__)


@dataclass
class RunOutcome:
    """What a run produced: the folder, the result, the figures and files of run.json.

    Attributes:
        record: run.json as written (its ``metrics`` and ``counts`` are ``metrics`` and
            ``counts``); gates read it here.
        skipped_hint: the source's hint about its skipped frames (None: images).
    """

    run_dir: Path
    result: SlamResult
    input_path: Path
    info: SourceInfo
    metrics: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    outputs: list[Path] = field(default_factory=list)
    data_loss: list[str] = field(default_factory=list)
    evaluation: str = "se3"
    record: dict[str, Any] = field(default_factory=dict)
    skipped_hint: str | None = None


@dataclass
class _Tracked:
    """What the source gave and the pipeline made of it."""

    info: SourceInfo
    result: SlamResult
    frames: int
    stats: ReadStats
    truth: _Truth
    input_hash: dict[str, Any]


@dataclass
class _Truth:
    """The source's ground truth: trajectory, surveyed landmarks, each robot's trajectory."""

    trajectory: Trajectory | None
    landmarks: LandmarkMap | None
    robots: dict[int, Trajectory]


def run_pipeline(
    input_path: str | Path,
    pipeline: str,
    out: str | Path,
    *,
    force: bool = False,
    config: Any = None,
    source_options: Mapping[str, Any] | None = None,
    max_frames: int | None = None,
    command: str = "",
    mcap: bool = False,
    glb: bool = False,
    build_map: bool = False,
    progress: ProgressFn | None = None,
    map_progress: ProgressFn | None = None,
) -> RunOutcome:
    """Run a pipeline over a source and write its run folder.

    Writes ``trajectory.tum``, ``report.png`` (when ground truth exists), ``result.mcap`` (with
    ``mcap=True``), ``keyframes.tum``, ``mesh.ply`` (and ``mesh.glb`` with ``glb=True``) and
    ``points.ply`` when the pipeline makes them, and ``run.json`` (schema in
    docs/run-folders.md). The pipeline's evaluation decides how it is scored against the
    source's ground truth: ``se2`` (planar ATE, landmark RMSE, NEES) or ATE and RPE after
    ``se3`` or ``sim3`` alignment; ``metrics["alignment"]`` records which.

    With ``build_map`` the occupancy map is built from the run as ``slamcli map build`` does
    with its defaults (``map.yaml``, ``map.pgm``, ``map.png``, ``map.json``), from the poses
    the run gave each frame, inside the same folder before it is committed; a pipeline whose
    runs have no map refuses it before the run.

    The folder is all or nothing (:class:`~slamcli.rundir.RunDir`): ``out`` is checked for
    writing before any work, and a failed or interrupted run leaves an earlier folder as it was.
    """
    from slamcli.pipelines import get_pipeline

    options = dict(source_options or {})
    with RunDir(out, force=force) as run:
        timings = Timings()
        pipe: Pipeline = get_pipeline(pipeline)(config)
        tracked = _track(input_path, options, pipe, build_map, max_frames, progress, timings)
        result = tracked.result
        if result.trajectory is None or len(result.trajectory) == 0:
            raise PipelineError(f"{input_path}: the {pipeline} pipeline produced no poses")
        evaluation = pipe.evaluation
        with timings.stage("export"):
            _export(run, result, glb)
        metrics = _score(run, result, tracked.truth, evaluation, timings)
        if mcap:
            from slamcli.formats.mcap.write import write_result_log

            with timings.stage("export"):
                write_result_log(run.output("result.mcap"), result, force=True)
        if build_map and result.grid is None:
            _build_map(run, pipeline, result, input_path, options, evaluation, map_progress)
        counts = {
            "frames_read": tracked.stats.read,
            "frames_skipped": tracked.stats.skipped,
            "frames_processed": tracked.frames,
            **result.counts,
            "doubts": len(result.metrics.get("doubts", ())),
        }
        record = _record(
            run,
            pipe,
            tracked,
            command or f"run {pipeline}",
            options,
            counts,
            metrics,
            timings,
            run_options={"max_frames": max_frames, "mcap": mcap, "glb": glb, "map": build_map},
        )
    return RunOutcome(
        run.path,
        result,
        Path(input_path),
        tracked.info,
        metrics,
        counts,
        [run.file(name) for name in record["outputs"]],
        [*tracked.stats.data_loss, *result.data_loss],
        evaluation=evaluation,
        record=record,
        skipped_hint=tracked.stats.skipped_hint,
    )


def _track(
    input_path: str | Path,
    options: dict[str, Any],
    pipe: Pipeline,
    build_map: bool,
    max_frames: int | None,
    progress: ProgressFn | None,
    timings: Timings,
) -> _Tracked:
    """Open the source, feed the pipeline every frame, finish it and read the ground truth."""
    from slamcli.formats import open_source

    reference = _reference(options)
    if reference is not None:
        options = {k: v for k, v in options.items() if k != "groundtruth"}
    odometry = options.pop("odometry", None)
    if odometry not in (None, "log", "none"):
        raise ConfigError(f"--odometry {odometry}: expected 'log' or 'none'")
    # The input's hash (for run.json) is read beside the run when the pipeline works on two
    # cores: hashing lets go of the interpreter lock, and a short run's start is spent
    # importing, which holds it.
    digest = Background(hash_input, input_path) if pipe.read_ahead else None
    try:
        with open_source(input_path, **options) as source:
            with timings.stage("open"):
                info, kinds = _open(source, pipe, build_map)
                if odometry == "none":
                    kinds = tuple(k for k in kinds if k != "odometry")
            # info's count is an estimate for some formats (MCAP pairs by log time there): it
            # sizes the progress bar but never limits the run.
            total = info.frames if max_frames is None else min(info.frames, max_frames)
            items = _first_frames(source.frames(kinds), max_frames)
            with timings.stage("track"):
                frames = _feed(pipe, items, total, progress)
            with timings.stage("finish"), watched() as interrupted:
                result = pipe.finish()
                interrupted()
            # After the frames: a source may give ground truth at the times of the frames it
            # read.
            with timings.stage("groundtruth"):
                truth = _Truth(
                    source.groundtruth() if reference is None else reference,
                    source.landmark_truth(),
                    source.groundtruths(),
                )
            stats = source.stats
    except BaseException:
        pipe.close()
        raise
    input_hash = digest.result() if digest is not None else hash_input(input_path)
    return _Tracked(info, result, frames, stats, truth, input_hash)


def _first_frames(items: Iterator[Any], limit: int | None) -> Iterator[Any]:
    """``items`` up to its ``limit``-th frame (all without a limit); IMU samples come between
    the frames and are not counted. Nothing after the last frame is read."""
    if limit is None:
        yield from items
        return
    if limit <= 0:
        return
    counted = 0
    for item in items:
        yield item
        if not isinstance(item, ImuFrame):
            counted += 1
            if counted >= limit:
                return


def _reference(options: dict[str, Any]) -> Trajectory | None:
    """The ground truth given as a trajectory file (``groundtruth`` naming a file rather than
    ``log``, the poses a laser log carries), read before the run so a bad file fails first."""
    given = options.get("groundtruth")
    if given is None or given == "log":
        return None
    from slamcli.formats.trajectory import read_trajectory

    path = Path(str(given))
    if not path.is_file():
        raise InputError(
            f"--groundtruth {given}: no such file",
            hint="give a trajectory file (TUM, EuRoC or KITTI), or 'log' for the poses a "
            "laser log carries",
        )
    return read_trajectory(path)


def _open(source: Source, pipe: Pipeline, build_map: bool) -> tuple[SourceInfo, tuple[str, ...]]:
    """What the source holds, the frame kinds the pipeline reads from it (which may settle
    how it is scored), and, for a planar pipeline, the log's start pose."""
    info = source.info()
    kinds = pipe.frame_kinds(info)
    if pipe.evaluation == "se2":
        pipe.set_start(source.start_pose())
    if build_map:
        _check_mappable(pipe)
    return info, kinds


def _feed(pipe: Pipeline, items: Any, total: int, progress: ProgressFn | None) -> int:
    """Every frame of ``items`` into the pipeline, decoded ahead on a reader thread when it
    asks for it; returns how many."""
    frames = 0
    ahead = pipe.read_ahead
    with (
        ReadAhead(items, ahead) if ahead else nullcontext(items) as reader,
        watched() as interrupted,
    ):
        for frame in reader:
            pipe.process(frame)
            interrupted()
            if isinstance(frame, ImuFrame):
                # IMU samples come between the frames a run counts.
                continue
            frames += 1
            if progress:
                progress(frames, max(total, frames))
    return frames


def _check_mappable(pipe: Pipeline) -> None:
    """Refuse ``build_map`` for a run that can have no occupancy map, before its frames."""
    from slamcli.mapping.build import MAP_KINDS
    from slamcli.pipelines import PIPELINES

    if "map.yaml" in PIPELINES[pipe.name].produces:
        return  # the pipeline's own map is the run's map
    if pipe.name not in MAP_KINDS:
        raise InputError(
            f"--map: a {pipe.name} run has no map to build (maps come from "
            f"{', '.join(sorted(MAP_KINDS))} runs)",
        )
    if pipe.evaluation == "sim3":
        raise InputError(
            "--map: a monocular visual run has no metric scale to build a map with",
            hint="run with depth (mode=rgbd or auto on an RGB-D input)",
        )


def _score(
    run: RunDir,
    result: SlamResult,
    truth: _Truth,
    evaluation: Evaluation,
    timings: Timings,
) -> dict[str, Any]:
    """The pipeline's own figures (per-stage ms/frame, loop closures, ...), the memory used,
    and the accuracy against the ground truth, with report.png."""
    from slamcli.scoring import (
        evaluate_planar_run,
        evaluate_robots,
        evaluate_run,
        evaluate_scan_run,
    )

    metrics: dict[str, Any] = dict(result.metrics)
    metrics["alignment"] = evaluation
    metrics["memory"] = peak_memory()
    if result.grid is not None:
        metrics.update(evaluate_scan_run(truth.trajectory, result, run, timings))
    elif evaluation == "se2":
        metrics.update(evaluate_planar_run(truth.trajectory, truth.landmarks, result, run, timings))
    elif truth.trajectory is not None:
        metrics.update(evaluate_run(truth.trajectory, result, run, timings, evaluation))
    else:
        log.info("%s has no ground truth: no accuracy figures", run.path)
    if len(result.robots) > 1:
        metrics["robots"] = evaluate_robots(truth.robots, truth.landmarks, result, run, timings)
    return metrics


IMU_STATES_HEADER = (
    "stamp_ns,vx_mps,vy_mps,vz_mps,gyro_bias_x_radps,gyro_bias_y_radps,gyro_bias_z_radps,"
    "accel_bias_x_mps2,accel_bias_y_mps2,accel_bias_z_mps2"
)
"""The columns of imu_states.csv: a visual-inertial run's keyframes, velocity in the world
frame, biases in the IMU's."""


def _write_imu_states(path: Path, states: Any) -> None:
    """imu_states.csv: one row per keyframe (:data:`IMU_STATES_HEADER`)."""
    lines = [IMU_STATES_HEADER]
    for row in states:
        lines.append(",".join([str(int(row[0])), *(f"{v:.9g}" for v in row[1:])]))
    path.write_text("\n".join(lines) + "\n")


def _export(run: RunDir, result: SlamResult, glb: bool) -> None:
    """trajectory.tum and each robot's, the filter's path, landmarks.csv, keyframes.tum,
    imu_states.csv,
    mesh.ply (and .glb), graph.g2o and points.ply, for what the pipeline made."""
    from slamcli.formats.trajectory import write_tum

    assert result.trajectory is not None
    write_tum(run.output("trajectory.tum"), result.trajectory)
    if len(result.robots) > 1:
        for ident, traj in sorted(result.robots.items()):
            write_tum(run.output(f"trajectory_robot{ident}.tum"), traj)
    if result.filtered is not None:
        write_tum(run.output("trajectory_filtered.tum"), result.filtered)
    if result.landmarks is not None:
        from slamcli.formats.landmark_map import write_landmarks_csv

        write_landmarks_csv(run.output("landmarks.csv"), result.landmarks)
    if result.keyframes is not None and len(result.keyframes):
        write_tum(run.output("keyframes.tum"), result.keyframes)
    if result.imu_states is not None and len(result.imu_states):
        _write_imu_states(run.output("imu_states.csv"), result.imu_states)
    if result.mesh is not None and len(result.mesh.faces):
        from slamcli.formats.mesh import write_glb, write_ply

        write_ply(run.output("mesh.ply"), result.mesh)
        if glb:
            write_glb(run.output("mesh.glb"), result.mesh)
    if result.pose_graph is not None and len(result.pose_graph[0]):
        from slamcli.graphs.pose_graph import save_g2o

        poses, edges = result.pose_graph
        save_g2o(run.output("graph.g2o"), poses, edges, fixed=(0,))
    if result.points is not None and len(result.points):
        from slamcli.formats.mesh import write_points_ply

        write_points_ply(run.output("points.ply"), result.points, result.point_colors)
    if result.grid is not None:
        _export_grid(run, result)


def _export_grid(run: RunDir, result: SlamResult) -> None:
    """The map a pipeline made itself (lidar): map.yaml, map.pgm, map.png and map.json."""
    import numpy as np

    from slamcli.geometry.planar import se3_to_planar
    from slamcli.mapping.build import BuiltMap
    from slamcli.mapping.output import write_map

    assert result.grid is not None and result.trajectory is not None
    prob = result.grid.prob
    known = ~np.isnan(prob)
    report = {
        "kind": "scans",
        "resolution_m": result.grid.resolution_m,
        "size_cells": [int(prob.shape[1]), int(prob.shape[0])],
        "origin": list(result.grid.origin_xy_yaw),
        "known_cells": int(known.sum()),
        "occupied_cells": int((prob[known] >= 0.65).sum()),
    }
    path_xy = se3_to_planar(result.trajectory.world_from_body)[:, :2]
    for written in write_map(run.staging, BuiltMap(result.grid, report, path_xy)):
        run.output(written.name)


def _build_map(
    run: RunDir,
    pipeline: str,
    result: SlamResult,
    input_path: str | Path,
    options: dict[str, Any],
    evaluation: Evaluation,
    progress: ProgressFn | None,
) -> None:
    """The occupancy map of the run, from the poses it gave each frame: map.yaml, map.pgm,
    map.png and map.json in the run folder."""
    from slamcli.mapping.build import MapInput, build
    from slamcli.mapping.output import write_map

    given = MapInput.from_result(
        pipeline, result, input_path, options, run.path, mono=evaluation == "sim3"
    )
    for written in write_map(run.staging, build(given, progress=progress)):
        run.output(written.name)


def _record(
    run: RunDir,
    pipe: Pipeline,
    tracked: _Tracked,
    command: str,
    options: dict[str, Any],
    counts: dict[str, Any],
    metrics: dict[str, Any],
    timings: Timings,
    run_options: dict[str, Any],
) -> dict[str, Any]:
    """Write run.json (schema in docs/run-folders.md); returns what it holds."""
    cfg = (
        asdict(pipe.config)
        if is_dataclass(pipe.config) and not isinstance(pipe.config, type)
        else {}
    )
    return run.write_run_json(
        command=command,
        inputs=[tracked.input_hash],
        config={pipe.name: cfg, "source": options, "run": run_options},
        seeds=pipe.seeds(),
        timings=timings,
        counts=counts,
        metrics=metrics,
        extra={
            "pipeline": pipe.name,
            "source": tracked.info.to_dict(),
            "data_loss": [*tracked.stats.data_loss, *tracked.result.data_loss],
        },
    )


def peak_memory() -> dict[str, float]:
    """Peak resident memory (MB) of this process so far, and the largest of its finished
    child processes (a pipeline's side process), as the operating system counts them."""
    import resource
    import sys

    # ru_maxrss is in kilobytes on Linux, in bytes on macOS.
    unit = 1.0 if sys.platform == "darwin" else 1024.0
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * unit / 2**20
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * unit / 2**20
    return {"peak_rss_mb": round(own, 1), "children_peak_rss_mb": round(children, 1)}


def data_loss_error(outcome: RunOutcome) -> DataLossError | None:
    """The error a finished run reports when it skipped frames or salvaged a damaged log
    (exit code 3), or None when nothing was lost. ``run``, ``demo`` and ``batch`` share it."""
    skipped = outcome.counts.get("frames_skipped", 0)
    where = outcome.input_path
    if skipped:
        return DataLossError(
            f"{where}: {skipped} frame(s) skipped because they were missing or unreadable; "
            "the results above exclude them",
            hint=outcome.skipped_hint
            or f"'slamcli info {where} --deep' names every unreadable image",
        )
    if outcome.data_loss:
        more = len(outcome.data_loss) - 1
        return DataLossError(
            f"{where}: the input is damaged; the run used what could be read: "
            f"{outcome.data_loss[0]}" + (f" (and {more} more, in run.json)" if more else ""),
            hint="--strict stops instead; 'mcap recover' can rebuild a damaged MCAP file"
            if where.suffix == ".mcap"
            else "--strict stops instead",
        )
    return None
