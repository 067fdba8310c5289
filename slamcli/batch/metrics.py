"""The figures each pipeline's run.json can hold, by the names gates use.

A manifest is checked against these before anything runs, so a typo in a gate
(``"fram.lost > 0"``) is an error naming the job and the key, not a gate that fails after an
hour of runs. The names are those of :func:`slamcli.batch.gates.flatten_metrics`: accuracy
without its ``evaluation.`` prefix (``ate.rmse``), other metrics by path
(``ms_per_frame.track``), counts as written or with dots (``frames_lost``, ``frames.lost``).
"""

from __future__ import annotations

from collections.abc import Iterable

_STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _stats(*prefixes: str) -> set[str]:
    return {f"{p}.{s}" for p in prefixes for s in _STATS}


_FRAMES = {"frames_read", "frames_skipped", "frames_processed", "doubts"}
"""Counts every run has (``doubts``: reasons the run gives to doubt its own result)."""

_SE3 = _stats("ate", "rpe.trans", "rpe.rot_deg") | {"pairs", "scale"}
"""Accuracy after SE(3) or Sim(3) alignment, when the input has ground truth."""

_SE2 = (
    _stats(
        "ate",
        "ate_unaligned",
        "heading_error_deg",
        "heading_error_unaligned_deg",
        "landmarks.error_m",
        *(f"{w}.{k}" for w in ("filtered", "dead_reckoning") for k in ("ate", "ate_unaligned")),
    )
    | {f"landmarks.{k}" for k in ("rmse_m", "matched", "spurious", "duplicates", "missed")}
    | {f"landmarks.{k}" for k in ("estimated", "true")}
    | {"matched", "possible", "outside_gt_span", "in_gt_gaps", "max_gap_s"}
    | {"transform.tx_m", "transform.ty_m", "transform.yaw_deg"}
    | {f"nees.{k}" for k in ("mean", "median", "dof", "fraction_in_band", "position_mean")}
    | {"nees.samples", "nees.skipped"}
)
"""Planar accuracy (the EKF's): trajectory, heading, landmarks, consistency."""

_COUNTS: dict[str, set[str]] = {
    "odometry": {"frames_tracked", "frames_lost"},
    "dense": {
        "frames_tracked",
        "frames_lost",
        "frames_integrated",
        "frames_reintegrated",
        "frames_not_integrated_depth",
        "frames_not_integrated_untrusted",
        "keyframes",
        "loop_closures_accepted",
        "loop_closures_rejected",
        "odometry_low_fitness",
        "odometry_singular",
        "pnp_rejected_jump",
        "rejected_jump",
        "rejected_seed_disagreement",
        "relocalisation_failed",
        "tracked_first",
        "tracked_model",
        "recovered_f2f",
        "recovered_pnp",
        "recovered_relocalised",
        "lost_no_registration",
        "voxel_blocks",
        "voxel_block_budget",
        "voxel_block_growths",
        "tracked_visual",
        "frames_placed_by_front_end",
        "front_end_no_pose",
        "front_end_no_map",
        "front_end_keyframes",
        "front_end_maps",
        "front_end_map_merges",
        "front_end_map_points",
    },
    "visual": {
        *(
            f"frames_{s}"
            for s in ("tracked", "relocalised", "inertial", "lost", "initialising", "new_map")
        ),
        "frames_in_unmerged_maps",
        "imu_init_attempts",
        "imu_placed_keyframes",
        "local_inertial_ba",
        "init_rejected_gyro",
        "init_homography",
        "init_essential",
        "ba_outliers_removed",
        "essential_graph_optimisations",
        "global_ba",
        "local_ba",
        "keyframes",
        "keyframes_made",
        "keyframes_culled",
        "local_map_too_few",
        "loop_closures_accepted",
        "loop_closures_rejected",
        "map_merges",
        "map_points",
        "maps",
        "maps_started",
        "motion_model_failed",
        "points_culled",
        "points_triangulated",
        "reference_failed",
        "relocalisation_failed",
        "init_too_few_matches",
        "init_too_little_depth",
        "init_rejected_after_ba",
    },
    "ekf": {
        "ambiguous",
        "capped",
        "landmarks",
        "landmarks_merged",
        "landmarks_new",
        "landmarks_pruned",
        "landmarks_reinitialised",
        "landmarks_tentative",
        "observations",
        "odometry",
        "recoveries",
        "rejected_by_gate",
        "smoother_observations",
        "updates",
    },
    "lidar": {
        "scans",
        "scans_not_matched",
        "scans_out_of_order",
        "nodes",
        "submaps",
        "odometry",
        "loop_searches",
        "loops_closed",
        "loops_rejected_by_fit",
        "loops_rejected_by_graph",
        "optimisations",
    },
}
"""Each pipeline's own counts."""

_COUNT_PREFIXES: dict[str, tuple[str, ...]] = {"visual": ("init_rejected_",)}
"""Counts named after a reason found at run time."""

_METRICS: dict[str, set[str]] = {
    "ekf": {f"nis.{k}" for k in ("mean", "median", "dof", "fraction_in_band")},
    "lidar": _stats(*(f"rpe.{d}.{k}" for d in ("1s", "10s") for k in ("trans", "rot_deg")))
    | {"rpe.1s.pairs", "rpe.10s.pairs"},
    "visual": {
        "initialisation.points",
        "initialisation.median_parallax_deg",
        "inertial.attempts",
    },
}
"""Each pipeline's own numeric metrics besides accuracy and timing."""


_MEMORY = {"memory.peak_rss_mb", "memory.children_peak_rss_mb"}
"""Peak resident memory, every run."""


def _accuracy(pipeline: str) -> set[str]:
    from slamcli.pipelines import get_spec

    return _SE2 if get_spec(pipeline).evaluation == "se2" else _SE3


def known_metric(pipeline: str, metric: str) -> bool:
    """Whether a run of ``pipeline`` can hold ``metric`` (given ground truth, for accuracy)."""
    if metric == "ms_per_frame" or metric.startswith("ms_per_frame."):
        return metric.count(".") <= 1
    if metric in _MEMORY:
        return True
    if metric.startswith("evaluation."):
        metric = metric[len("evaluation.") :]
    if metric in _accuracy(pipeline) or metric in _METRICS.get(pipeline, set()):
        return True
    count = metric.replace(".", "_")
    counts = _FRAMES | _COUNTS.get(pipeline, set())
    return count in counts or count.startswith(_COUNT_PREFIXES.get(pipeline, ()))


def known_metrics(pipeline: str) -> list[str]:
    """Every name :func:`known_metric` accepts for ``pipeline`` (for hints), sorted."""
    names: Iterable[str] = (
        {"ms_per_frame"}
        | _MEMORY
        | _accuracy(pipeline)
        | _METRICS.get(pipeline, set())
        | _FRAMES
        | _COUNTS.get(pipeline, set())
    )
    return sorted(names)
