"""``run_pipeline``: source -> pipeline -> result -> exports -> run.json, in one call."""

from __future__ import annotations

import contextlib
import itertools
import logging
from collections.abc import Callable, Iterator, Mapping
from contextlib import nullcontext
from dataclasses import asdict, dataclass, field, is_dataclass, replace
from pathlib import Path
from typing import Any

from slamcli.errors import DataLossError, InputError, PipelineError
from slamcli.formats.base import ReadAhead, SourceInfo
from slamcli.rundir import RunDir, Timings, hash_input
from slamcli.types import LandmarkMap, ProgressFn, SlamResult, Trajectory, TriangleMesh
from slamcli.worker import Background

log = logging.getLogger(__name__)


@dataclass
class RunOutcome:
    """What a run produced: the folder, the result, and the metrics written to run.json."""

    run_dir: Path
    result: SlamResult
    input_path: Path
    info: SourceInfo
    metrics: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    outputs: list[Path] = field(default_factory=list)
    data_loss: list[str] = field(default_factory=list)
    evaluation: str = "se3"


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
    ``points.ply`` when the pipeline makes them, and ``run.json`` (schema in README.md). The
    pipeline's declared evaluation decides how it is scored against the source's ground truth:
    ``se2`` (planar ATE, landmark RMSE, NEES) or ATE and RPE after ``se3`` or ``sim3``
    alignment; ``metrics["alignment"]`` records which.

    With ``build_map`` the occupancy map is built from the run as ``slamcli map build`` does
    with its defaults (``map.yaml``, ``map.pgm``, ``map.png``, ``map.json``), inside the same
    folder before it is committed; a pipeline whose runs have no map refuses it before the run.

    The folder is all or nothing (:class:`~slamcli.rundir.RunDir`): ``out`` is checked for
    writing before any work, and a failed or interrupted run leaves an earlier folder as it was.
    """
    with RunDir(out, force=force) as run:
        outcome = _run_into(
            run,
            input_path,
            pipeline,
            config=config,
            source_options=source_options,
            max_frames=max_frames,
            command=command,
            mcap=mcap,
            glb=glb,
            progress=progress,
            build_map=build_map,
        )
        if build_map:
            from slamcli.mapping.output import map_run

            _, written = map_run(run.staging, force=True, progress=map_progress)
            # Before run.json, as run.json lists them.
            outcome.outputs[-1:-1] = written
            run.relocate_records()
    return replace(outcome, outputs=[run.final(p) for p in outcome.outputs])


def _check_mappable(pipeline: str, pipe: Any) -> None:
    """Refuse ``build_map`` for a run that can have no occupancy map, before its frames."""
    from slamcli.mapping.build import MAP_KINDS

    if pipeline not in MAP_KINDS:
        raise InputError(
            f"--map: a {pipeline} run has no map to build (maps come from "
            f"{', '.join(sorted(MAP_KINDS))} runs)",
        )
    if getattr(pipe, "mono", False):
        raise InputError(
            "--map: a monocular visual run has no metric scale to build a map with",
            hint="run with depth (mode=rgbd or auto on an RGB-D input)",
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
            hint=f"'slamcli info {where} --deep' names every unreadable image",
        )
    if outcome.data_loss:
        return DataLossError(
            f"{where}: the log is damaged; the run used what could be read",
            hint="--strict stops instead; 'mcap recover' can rebuild a damaged MCAP file",
        )
    return None


def _run_into(
    run: RunDir,
    input_path: str | Path,
    pipeline: str,
    *,
    config: Any,
    source_options: Mapping[str, Any] | None,
    max_frames: int | None,
    command: str,
    mcap: bool,
    glb: bool,
    progress: ProgressFn | None,
    build_map: bool = False,
) -> RunOutcome:
    """:func:`run_pipeline`'s work, writing into the staged ``run``."""
    from slamcli.formats import open_source
    from slamcli.pipelines import get_pipeline, get_spec

    timings = Timings()
    spec = get_spec(pipeline)
    pipeline_cls = get_pipeline(pipeline)
    pipe = pipeline_cls(config)
    with open_source(input_path, **dict(source_options or {})) as source:
        with timings.stage("open"):
            info = source.info()
            # Planar pipelines start at the log's ground-truth pose when it has one.
            if spec.evaluation == "se2":
                pipe.set_start(source.start_pose())
            # A pipeline may choose what to read by what the source holds (visual: RGB-D or
            # colour only), and with it how it is scored.
            kinds = (
                pipe.frame_kinds(info) if hasattr(pipe, "frame_kinds") else pipeline_cls.consumes
            )
            if build_map:
                _check_mappable(pipeline, pipe)
        evaluation = getattr(pipe, "evaluation", spec.evaluation)
        # info's count is an estimate for some formats (MCAP pairs by log time there): it sizes
        # the progress bar but never limits the run.
        total = info.frames if max_frames is None else min(info.frames, max_frames)
        frames = 0
        # A pipeline that asks for it gets its frames decoded ahead on a reader thread.
        ahead = int(getattr(pipe, "read_ahead", 0))
        items = itertools.islice(source.frames(kinds), max_frames)
        with (
            timings.stage("track"),
            ReadAhead(items, ahead) if ahead else nullcontext(items) as reader,
            _interrupts_kept() as interrupted,
        ):
            for frame in reader:
                pipe.process(frame)
                interrupted()
                frames += 1
                if progress:
                    progress(frames, max(total, frames))
        # The input's hash (for run.json) is read beside the pipeline's last steps when the
        # pipeline works on two cores.
        digest = Background(hash_input, input_path) if ahead else None
        with timings.stage("finish"), _interrupts_kept() as interrupted:
            result = pipe.finish()
            interrupted()
        # After the frames: a source may give ground truth at the times of the frames it read.
        with timings.stage("groundtruth"):
            groundtruth = source.groundtruth()
            true_landmarks = source.landmark_truth()
            source_groundtruths: dict[int, Trajectory] = (
                source.groundtruths() if hasattr(source, "groundtruths") else {}
            )
        stats = source.stats
    if result.trajectory is None or len(result.trajectory) == 0:
        raise PipelineError(f"{input_path}: the {pipeline} pipeline produced no poses")

    from slamcli.formats.trajectory import write_tum

    outputs = []
    with timings.stage("export"):
        outputs.append(write_tum(run.output("trajectory.tum"), result.trajectory))

    # The pipeline's own figures (per-stage ms/frame, loop closures, ...) plus the evaluation.
    metrics: dict[str, Any] = dict(result.metrics)
    metrics["alignment"] = evaluation
    metrics["memory"] = peak_memory()
    if evaluation == "se2":
        metrics.update(_evaluate_planar(groundtruth, true_landmarks, result, run, timings))
        outputs.append(run.file("report.png"))
    elif groundtruth is not None:
        metrics.update(
            _evaluate(groundtruth, result.trajectory, run, timings, evaluation, result.mesh)
        )
        if "report.png" in run.outputs:
            outputs.append(run.file("report.png"))
    else:
        log.info("%s has no ground truth: no accuracy figures", input_path)

    robots: dict[int, Trajectory] = getattr(pipe, "robot_trajectories", {})
    if len(robots) > 1:
        with timings.stage("export"):
            for ident, traj in sorted(robots.items()):
                outputs.append(write_tum(run.output(f"trajectory_robot{ident}.tum"), traj))
        truths = source_groundtruths
        if truths:
            with timings.stage("evaluate"):
                metrics["robots"] = _evaluate_robots(truths, robots)
        with timings.stage("report"):
            metrics.setdefault("robots", {})["plotted"] = _plot_robots(
                run, robots, truths, metrics["robots"], result, true_landmarks
            )
        if "report.png" not in [p.name for p in outputs]:
            outputs.append(run.file("report.png"))

    counts = {
        "frames_read": stats.read,
        "frames_skipped": stats.skipped,
        "frames_processed": frames,
        **result.counts,
    }
    with timings.stage("export"):
        outputs += _write_products(run, result, glb)

    if mcap:
        from slamcli.formats.mcap.write import write_result_log

        with timings.stage("export"):
            dest = run.output("result.mcap")
            outputs.append(write_result_log(dest, result, force=True).path)

    cfg = (
        asdict(pipe.config)
        if is_dataclass(pipe.config) and not isinstance(pipe.config, type)
        else {}
    )
    run.write_run_json(
        command=command or f"run {pipeline}",
        inputs=[digest.result() if digest is not None else hash_input(input_path)],
        config={
            pipeline: cfg,
            "source": dict(source_options or {}),
            "run": {"max_frames": max_frames, "mcap": mcap, "glb": glb, "map": build_map},
        },
        seeds=pipe.seeds(),
        timings=timings,
        counts=counts,
        metrics=metrics,
        extra={"pipeline": pipeline, "source": info.to_dict(), "data_loss": stats.data_loss},
    )
    outputs.append(run.file("run.json"))
    return RunOutcome(
        run.path,
        result,
        Path(input_path),
        info,
        metrics,
        counts,
        outputs,
        list(stats.data_loss),
        evaluation=evaluation,
    )


def _evaluate(
    groundtruth: Trajectory,
    estimate: Trajectory,
    run: RunDir,
    timings: Timings,
    align: str,
    mesh: TriangleMesh | None = None,
) -> dict[str, Any]:
    from slamcli.evaluation import evaluate
    from slamcli.report import plot_evaluation

    with timings.stage("evaluate"):
        try:
            ev = evaluate(groundtruth, estimate, align=align, rpe_delta=1)
        except InputError as exc:
            log.warning("no accuracy figures: %s", exc.msg)
            return {}
    with timings.stage("report"):
        plot_evaluation(run.output("report.png"), ev, "ground truth", "estimate", mesh=mesh)
    return {"evaluation": ev.to_dict()}


def _evaluate_planar(
    groundtruth: Trajectory | None,
    true_landmarks: LandmarkMap | None,
    result: SlamResult,
    run: RunDir,
    timings: Timings,
) -> dict[str, Any]:
    """SE(2) ATE, landmark RMSE and NEES of a planar run (when there is ground truth), the same
    for dead reckoning, and report.png (a map of landmarks with 3σ ellipses in any case)."""
    from slamcli.planar_eval import evaluate_planar
    from slamcli.report import plot_landmark_run

    assert result.trajectory is not None
    metrics: dict[str, Any] = {}
    evaluation = None
    if groundtruth is not None:
        with timings.stage("evaluate"):
            known = result.metrics.get("association") == "known"
            try:
                smoothed = result.filtered is not None
                evaluation = evaluate_planar(
                    groundtruth,
                    result.trajectory,
                    est_cov=None if smoothed else result.pose_covariances,
                    landmarks=result.landmarks,
                    true_landmarks=true_landmarks,
                    known_ids=known,
                )
                metrics["evaluation"] = evaluation.to_dict()
                if result.filtered is not None:
                    # The filter's own path: its accuracy, and the consistency of its
                    # covariances (NEES), which belong to it.
                    filt = evaluate_planar(
                        groundtruth, result.filtered, est_cov=result.pose_covariances
                    )
                    metrics["evaluation"]["trajectory"] = "smoothed"
                    metrics["evaluation"]["nees"] = filt.to_dict().get("nees")
                    # The report's NEES panel shows the filter's, the one that has covariances.
                    evaluation = replace(evaluation, nees=filt.nees)
                    metrics["filtered"] = {
                        "ate": filt.ate.to_dict(),
                        "ate_unaligned": filt.ate_unaligned.to_dict(),
                    }
                if result.dead_reckoning is not None:
                    dr = evaluate_planar(groundtruth, result.dead_reckoning)
                    metrics["dead_reckoning"] = {
                        "ate": dr.ate.to_dict(),
                        "ate_unaligned": dr.ate_unaligned.to_dict(),
                    }
            except InputError as exc:
                log.warning("no accuracy figures: %s", exc.msg)
                evaluation = None
    with timings.stage("report"):
        plot_landmark_run(
            run.output("report.png"),
            estimate=result.trajectory,
            landmarks=result.landmarks,
            evaluation=evaluation,
            true_landmarks=true_landmarks,
            dead_reckoning=result.dead_reckoning,
            series=result.series,
        )
    return metrics


def _plot_robots(
    run: RunDir,
    robots: dict[int, Trajectory],
    truths: dict[int, Trajectory],
    evaluation: dict[str, Any],
    result: SlamResult,
    true_landmarks: LandmarkMap | None,
) -> list[int]:
    """report.png of a several-robot run: every robot on one map, under the common alignment
    when there is one. Returns the robots drawn."""
    from slamcli.report import plot_multi_robot_run

    per = evaluation.get("per_robot", {})
    plot_multi_robot_run(
        run.output("report.png"),
        estimates=robots,
        truths=truths,
        transform=evaluation.get("transform"),
        landmarks=result.landmarks,
        true_landmarks=true_landmarks,
        ate={int(k): v["ate_common"]["rmse"] for k, v in per.items() if "ate_common" in v},
    )
    return sorted(robots)


def _evaluate_robots(
    truths: dict[int, Trajectory], estimates: dict[int, Trajectory]
) -> dict[str, Any]:
    """ATE of each robot of a several-robot run: after its own SE(2) alignment, and all robots
    under one common SE(2) alignment (one rigid fit over every robot's poses at once; the
    estimates share one world frame, so one transform must fit them all). Ground truth is
    interpolated at the estimate's stamps, which must lie inside its span."""
    import numpy as np

    from slamcli.geometry import interpolate_planar, se3_to_planar
    from slamcli.graphs.landmark_graph import rigid_fit_2d
    from slamcli.planar_eval import evaluate_planar

    per: dict[str, Any] = {}
    est_xy, gt_xy, owner = [], [], []
    for ident, est in sorted(estimates.items()):
        gt = truths.get(ident)
        if gt is None:
            continue
        try:
            own = evaluate_planar(gt, est).ate.to_dict()
        except InputError as exc:
            log.warning("robot %d: no accuracy figures: %s", ident, exc.msg)
            continue
        g = interpolate_planar(gt.stamps_ns, se3_to_planar(gt.world_from_body), est.stamps_ns)
        ok = np.isfinite(g).all(axis=1)
        est_xy.append(se3_to_planar(est.world_from_body)[ok, :2])
        gt_xy.append(g[ok, :2])
        owner.append(np.full(int(ok.sum()), ident))
        per[str(ident)] = {"ate": own}
    if not est_xy:
        return {}
    src, dst, who = np.concatenate(est_xy), np.concatenate(gt_xy), np.concatenate(owner)
    transform, rms = rigid_fit_2d(src, dst)
    c, s = np.cos(transform[2]), np.sin(transform[2])
    moved = src @ np.array([[c, s], [-s, c]]) + transform[:2]
    err = np.hypot(*(moved - dst).T)
    for key in per:
        e = err[who == int(key)]
        per[key]["ate_common"] = {
            "rmse": float(np.sqrt(np.mean(e * e))),
            "mean": float(e.mean()),
            "max": float(e.max()),
            "matched": int(e.size),
        }
    return {
        "alignment": "se2, one transform for all robots",
        "transform": transform.tolist(),
        "ate_common": {"rmse": rms, "mean": float(err.mean()), "max": float(err.max())},
        "per_robot": per,
    }


def _write_products(run: RunDir, result: SlamResult, glb: bool) -> list[Path]:
    """keyframes.tum, landmarks.csv, mesh.ply (and .glb), graph.g2o and points.ply, for what
    the pipeline made."""
    from slamcli.formats.trajectory import write_tum

    written = []
    if result.filtered is not None:
        written.append(write_tum(run.output("trajectory_filtered.tum"), result.filtered))
    if result.landmarks is not None:
        from slamcli.formats.landmark_map import write_landmarks_csv

        written.append(write_landmarks_csv(run.output("landmarks.csv"), result.landmarks))
    if result.keyframes is not None and len(result.keyframes):
        written.append(write_tum(run.output("keyframes.tum"), result.keyframes))
    if result.mesh is not None and len(result.mesh.faces):
        from slamcli.formats.mesh import write_ply

        written.append(write_ply(run.output("mesh.ply"), result.mesh))
        if glb:
            from slamcli.formats.mesh import write_glb

            written.append(write_glb(run.output("mesh.glb"), result.mesh))
    if result.pose_graph is not None and len(result.pose_graph[0]):
        from slamcli.graphs.pose_graph import save_g2o

        poses, edges = result.pose_graph
        written.append(save_g2o(run.output("graph.g2o"), poses, edges, fixed=(0,)))
    if result.points is not None and len(result.points):
        from slamcli.formats.mesh import write_points_ply

        written.append(
            write_points_ply(run.output("points.ply"), result.points, result.point_colors)
        )
    return written


@contextlib.contextmanager
def _interrupts_kept() -> Iterator[Callable[[], None]]:
    """Remember every Ctrl-C while the block runs; the yielded function raises
    KeyboardInterrupt when one came.

    Native solvers that poll for signals during a solve (pycolmap's bundle adjustment does) may
    stop early on Ctrl-C and clear the exception, and the run would go on as if nothing had
    happened. The handler here still records the signal and hands it on as before, so the next
    check ends the run. Outside the main thread the block runs as is.
    """
    import signal
    import threading

    received: list[int] = []

    def check() -> None:
        if received:
            raise KeyboardInterrupt

    if threading.current_thread() is not threading.main_thread():
        yield check
        return
    previous = signal.getsignal(signal.SIGINT)
    if not (callable(previous) or previous == signal.SIG_DFL):
        # Ctrl-C is ignored here (or handled outside Python): leave it so.
        yield check
        return

    def on_interrupt(signum: int, frame: Any) -> None:
        received.append(signum)
        if callable(previous):
            previous(signum, frame)
        elif previous == signal.SIG_DFL:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_interrupt)
    try:
        yield check
    finally:
        signal.signal(signal.SIGINT, previous)
