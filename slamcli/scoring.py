"""How a run is scored: its accuracy against the source's ground truth, and report.png.

RGB-D and monocular runs get ATE and RPE after SE(3) or Sim(3) alignment
(:func:`evaluate_run`); planar runs the SE(2) ATE, the landmark RMSE and NEES
(:func:`evaluate_planar_run`); a run of several robots each robot's ATE, and all of them under
one common alignment (:func:`evaluate_robots`).
"""

from __future__ import annotations

import logging
from dataclasses import replace
from typing import Any

from slamcli.errors import InputError
from slamcli.rundir import RunDir, Timings
from slamcli.types import LandmarkMap, SlamResult, Trajectory

log = logging.getLogger(__name__)


def evaluate_robots(
    truths: dict[int, Trajectory],
    true_landmarks: LandmarkMap | None,
    result: SlamResult,
    run: RunDir,
    timings: Timings,
) -> dict[str, Any]:
    """Each robot's ATE of a several-robot run (``result.robots``), all robots under one
    common alignment, and report.png with every robot on one map."""
    from slamcli.planar_eval import evaluate_common_frame

    robots: dict[str, Any] = {}
    if truths:
        with timings.stage("evaluate"):
            common = evaluate_common_frame(truths, dict(sorted(result.robots.items())))
            robots = common.to_dict() if common is not None else {}
    with timings.stage("report"):
        robots["plotted"] = _plot_robots(run, result.robots, truths, robots, result, true_landmarks)
    return robots


def evaluate_run(
    groundtruth: Trajectory,
    result: SlamResult,
    run: RunDir,
    timings: Timings,
    align: str,
) -> dict[str, Any]:
    """ATE and RPE of the run's trajectory after ``align`` (``se3`` or ``sim3``), and
    report.png (the trajectories, the errors, the mesh when there is one)."""
    from slamcli.evaluation import evaluate
    from slamcli.report import plot_evaluation

    assert result.trajectory is not None
    estimate, mesh = result.trajectory, result.mesh
    if result.truth_to_estimate is not None:
        groundtruth = Trajectory(
            groundtruth.stamps_ns, groundtruth.world_from_body @ result.truth_to_estimate
        )

    with timings.stage("evaluate"):
        try:
            ev = evaluate(groundtruth, estimate, align=align, rpe_delta=1)
        except InputError as exc:
            log.warning("no accuracy figures: %s", exc.msg)
            return {}
    with timings.stage("report"):
        plot_evaluation(
            run.output("report.png"),
            ev,
            "ground truth",
            "estimate",
            mesh=mesh,
            imu_states=result.imu_states,
        )
    return {"evaluation": ev.to_dict()}


def evaluate_planar_run(
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


def evaluate_scan_run(
    groundtruth: Trajectory | None,
    result: SlamResult,
    run: RunDir,
    timings: Timings,
) -> dict[str, Any]:
    """A lidar run: the SE(2) ATE and the relative pose errors over pose pairs 1 s and 10 s
    apart (Kümmerle et al. 2009) when there is ground truth, and report.png (the map, the path,
    the loop closures; the ground truth and the error over time when there is one)."""
    from slamcli.evaluation import planar_rpe
    from slamcli.planar_eval import evaluate_planar
    from slamcli.report import plot_scan_run

    assert result.trajectory is not None
    metrics: dict[str, Any] = {}
    evaluation = None
    if groundtruth is not None:
        with timings.stage("evaluate"):
            try:
                evaluation = evaluate_planar(groundtruth, result.trajectory)
                metrics["evaluation"] = evaluation.to_dict()
                rpe: dict[str, Any] = {}
                for delta in (1.0, 10.0):
                    try:
                        rpe[f"{delta:g}s"] = planar_rpe(groundtruth, result.trajectory, delta)
                    except InputError as exc:
                        log.info("no RPE over %g s: %s", delta, exc.msg)
                metrics["evaluation"]["rpe"] = {k: v.to_dict() for k, v in rpe.items()}
            except InputError as exc:
                log.warning("no accuracy figures: %s", exc.msg)
                evaluation = None
    with timings.stage("report"):
        plot_scan_run(run.output("report.png"), result, evaluation)
    return metrics
