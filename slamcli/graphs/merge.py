"""Merging landmark maps made separately (EKF runs of several robots or sessions) into one frame.

Each input is an EKF run folder (``trajectory.tum`` and ``landmarks.csv``, see
:mod:`slamcli.formats.run_folder`). All poses and landmarks are planar: x, y (m), yaw (rad).

1. **Pairwise transforms.** For every pair of runs (a, b) the rigid 2-D transform ``a_from_b``
   (x, y, yaw) that maps b's landmarks onto a's is found by RANSAC over two-point hypotheses:
   with known ids (both runs were made with their log's landmark ids) the hypotheses are pairs
   of common ids, and every common id is a candidate correspondence; with unknown ids they are
   pairs of landmarks of a and of b whose distances agree within ``inlier_m``, and each
   landmark of b pairs with its nearest landmark of a when that is within ``inlier_m`` and the
   two are each other's nearest (a constellation match). Hypotheses are all such pairs, or
   ``max_hypotheses`` of them drawn with ``seed``. The best hypothesis's inliers (within
   ``inlier_m``) are refitted by weighted least squares, each pair weighted by ``2 /
   trace(cov_a + cov_b)`` (the landmarks' covariances from landmarks.csv, plus
   ``sigma_floor_m`` squared), until the inlier set stops changing. A pair is connected with
   at least ``min_common_ids`` inliers (known ids) or ``min_inliers`` (unknown ids).
2. **Chains.** The runs reachable from the reference run (the first) through connected pairs
   are connected, by a maximum spanning tree over inlier counts; the tree composes the initial
   ``world_from_run`` transforms (the reference run's frame is the world). Runs that cannot be
   reached are *left out* of the merged map, trajectories and accuracy figures and listed as
   unconnected: a run in a frame of its own beside merged ones would look merged.
3. **Joint optimisation** (GTSAM, Levenberg–Marquardt): one ``Pose2`` per connected run
   (``world_from_run``, the reference held by a ``NonlinearEquality``) and one ``Point2`` per
   merged landmark. Landmarks are merged by the inlier pairs of every connected pair (union of
   the pairs' correspondences). Each landmark of each run gives a factor ``run_from_world ·
   landmark - measured`` with that landmark's covariance (plus the floor) as noise, under a
   Huber kernel at the 95 % χ² gate (2 dof). Merged landmarks keep their id when their members
   share one; others are numbered from the largest such id + 1.

Outputs (:func:`merge_runs`): ``trajectory_<label>.tum`` per connected run (label
``robotN``, N the run's ``--robot`` option, else its position among the inputs, 1-based; a
repeated label gets ``_2``, ``_3``), ``landmarks.csv`` (merged, with marginal covariances),
``report.png`` and ``run.json``. When a run's input log can still be opened and has ground
truth, each trajectory is compared with it after **one** SE(2) alignment shared by all runs
(fitted on all runs' matched positions together), so the figures measure how well the runs
agree in one frame.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.config import check_settings, setting
from slamcli.errors import InputError
from slamcli.formats.run_folder import RunRecord, read_run
from slamcli.geometry import (
    compose_planar,
    invert_planar,
    planar_to_se3,
    rigid_fit_2d,
    rotation_2d,
    se3_to_planar,
    transform_points_planar,
    wrap_angle,
)
from slamcli.rundir import RunDir, Timings, hash_input
from slamcli.types import LandmarkMap, ProgressFn, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

HUBER_WIDTH = math.sqrt(5.991464547107979)
"""Huber kernel width on the whitened residual norm: the 95 % χ² gate for 2 dof."""


@dataclass(frozen=True)
class MergeConfig:
    """Settings of :func:`merge_runs`.

    Attributes:
        match: ``auto`` (ids when both runs have known ids, else constellations), ``ids`` or
            ``constellation``.
        inlier_m: largest landmark disagreement of an inlier, m.
        min_common_ids: inliers a known-id pair needs to be connected.
        min_inliers: inliers a constellation pair needs to be connected.
        max_hypotheses: RANSAC hypotheses per pair (all of them when there are fewer).
        sigma_floor_m: added in quadrature to every landmark's standard deviation, m.
        default_sigma_m: a landmark's standard deviation when its run has no covariances, m.
        seed: seeds the RANSAC draws.
        max_iterations: Levenberg–Marquardt iterations.
    """

    match: str = setting("auto", choices=("auto", "ids", "constellation"))
    inlier_m: float = setting(0.5, unit="m", gt=0.0)
    min_common_ids: int = setting(3, min=2)
    min_inliers: int = setting(5, min=3)
    max_hypotheses: int = setting(2000, min=1)
    sigma_floor_m: float = setting(0.02, unit="m", gt=0.0)
    default_sigma_m: float = setting(0.2, unit="m", gt=0.0)
    seed: int = 0
    max_iterations: int = setting(100, min=1)

    def check(self) -> MergeConfig:
        """Self, or ConfigError naming the bad setting (by its option) and its allowed range."""
        return check_settings(
            self, {"match": "--match", "inlier_m": "--inlier-m", "seed": "--seed"}
        )


@dataclass(frozen=True)
class MergeInput:
    """One run to merge.

    Attributes:
        path: the run folder.
        label: ``robotN`` (unique among the inputs).
        robot: the robot number (the run's ``robot`` source option, else its 1-based position).
        trajectory: the run's trajectory.tum.
        landmarks: its landmarks.csv; ``cov`` filled with ``default_sigma_m`` when absent.
        ids_known: the run used its log's landmark ids.
        record: the run folder record.
    """

    path: Path
    label: str
    robot: int
    trajectory: Trajectory
    landmarks: LandmarkMap
    ids_known: bool
    record: RunRecord


@dataclass
class PairFit:
    """The transform between two runs found from their landmarks.

    Attributes:
        a, b: run indices (a < b).
        a_from_b: (3,) x, y (m), yaw (rad): b's frame seen from a's.
        method: ``ids`` or ``constellation``.
        candidates: common ids (ids) or landmark-pair hypotheses (constellation).
        pairs: (K, 2) int64 inlier landmark indices into a's and b's maps.
        rms_m: RMS inlier disagreement after the fit, m.
        connected: enough inliers to connect the runs.
    """

    a: int
    b: int
    a_from_b: F64
    method: str
    candidates: int
    pairs: I64
    rms_m: float
    connected: bool

    def to_dict(self, runs: Sequence[MergeInput]) -> dict[str, Any]:
        """JSON-ready summary naming the runs by label."""
        return {
            "a": runs[self.a].label,
            "b": runs[self.b].label,
            "method": self.method,
            "candidates": self.candidates,
            "inliers": len(self.pairs),
            "rms_m": self.rms_m,
            "connected": self.connected,
            "a_from_b": _pose_dict(self.a_from_b),
        }


@dataclass
class MergeResult:
    """What :func:`merge_runs` found.

    Attributes:
        runs: the inputs, in argument order.
        pairs: the fit of every pair of runs.
        connected: (R,) bool, reachable from the reference run.
        world_from_run: (R, 3) optimised x, y, yaw per run (NaN for unconnected runs).
        initial_world_from_run: (R, 3) from the spanning tree, before optimisation.
        landmarks: merged landmarks in the world frame with marginal covariances.
        members: per merged landmark, its (run, landmark index) pairs.
        residual_rms_m: (R,) RMS disagreement of each run's shared landmarks after the
            optimisation (NaN when it shares none or is unconnected).
        trajectories: per connected run index, its trajectory in the world frame.
        evaluation: ground-truth figures (see :func:`evaluate_merged`), or empty.
    """

    runs: list[MergeInput]
    pairs: list[PairFit]
    connected: NDArray[np.bool_]
    world_from_run: F64
    initial_world_from_run: F64
    landmarks: LandmarkMap
    members: list[list[tuple[int, int]]]
    residual_rms_m: F64
    trajectories: dict[int, Trajectory]
    evaluation: dict[str, Any] = field(default_factory=dict)


# --- Reading -----------------------------------------------------------------------------------


def load_runs(paths: Sequence[str | Path], config: MergeConfig | None = None) -> list[MergeInput]:
    """Read the run folders to merge.

    Raises:
        InputError: fewer than two folders, or a folder that is no run folder or has no
            trajectory.tum or landmarks.csv (the message names it).
    """
    config = (config or MergeConfig()).check()
    if len(paths) < 2:
        raise InputError(
            f"merging needs at least two run folders, got {len(paths)}",
            hint="pass the --out folders of two or more 'slamcli run ekf' runs",
        )
    runs: list[MergeInput] = []
    seen: dict[str, int] = {}
    for position, path in enumerate(paths, start=1):
        record = read_run(path)
        if not record.has("landmarks"):
            by = f" of the {record.pipeline} pipeline" if record.pipeline else ""
            raise InputError(
                f"{record.path}: a run folder{by} without landmarks.csv: nothing to merge by",
                hint="merge runs of 'slamcli run ekf', which write landmarks.csv",
            )
        landmarks = record.landmarks()
        if len(landmarks) == 0:
            raise InputError(f"{record.path}: landmarks.csv holds no landmarks")
        trajectory = record.trajectory()
        robot = record.source_options.get("robot")
        number = robot if isinstance(robot, int) and not isinstance(robot, bool) else position
        label = f"robot{number}"
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            label = f"{label}_{seen[label]}"
        cov = landmarks.cov
        if cov is None:
            cov = np.broadcast_to(np.eye(2) * config.default_sigma_m**2, (len(landmarks), 2, 2))
        metrics = record.record.get("metrics")
        ids_known = (
            isinstance(metrics, dict)
            and metrics.get("association") == "known"
            and not record.source_options.get("ignore_ids", False)
        )
        runs.append(
            MergeInput(
                path=record.path,
                label=label,
                robot=int(number),
                trajectory=trajectory,
                landmarks=LandmarkMap(landmarks.ids, landmarks.xy, np.array(cov, dtype=float)),
                ids_known=bool(ids_known),
                record=record,
            )
        )
    return runs


# --- Pairwise transforms -----------------------------------------------------------------------


def _hypotheses_2pt(dst: F64, src: F64) -> F64:
    """(H, 3) transforms from (H, 2, 2) point pairs: the one mapping src's segment onto dst's."""
    vd, vs = dst[:, 1] - dst[:, 0], src[:, 1] - src[:, 0]
    yaw = np.arctan2(vd[:, 1], vd[:, 0]) - np.arctan2(vs[:, 1], vs[:, 0])
    mid_d, mid_s = dst.mean(axis=1), src.mean(axis=1)
    t = mid_d - np.einsum("hij,hj->hi", rotation_2d(yaw), mid_s)
    return np.column_stack([t, yaw])


def _pick(rng: np.random.Generator, count: int, limit: int) -> I64:
    if count <= limit:
        return np.arange(count, dtype=np.int64)
    return np.sort(rng.choice(count, size=limit, replace=False)).astype(np.int64)


def _weights(a: MergeInput, b: MergeInput, pairs: I64, floor: float) -> F64:
    assert a.landmarks.cov is not None and b.landmarks.cov is not None
    tr = np.trace(a.landmarks.cov[pairs[:, 0]], axis1=1, axis2=2) + np.trace(
        b.landmarks.cov[pairs[:, 1]], axis1=1, axis2=2
    )
    return np.asarray(2.0 / (tr + 4 * floor**2), dtype=np.float64)


def _mutual_nearest(a_xy: F64, b_moved: F64, radius: float) -> I64:
    """(K, 2) pairs (a index, b index) of mutual nearest neighbours within ``radius``."""
    d = np.linalg.norm(b_moved[:, None] - a_xy[None], axis=2)
    nearest_a = np.argmin(d, axis=1)
    nearest_b = np.argmin(d, axis=0)
    ib = np.arange(len(b_moved))
    ok = (nearest_b[nearest_a] == ib) & (d[ib, nearest_a] <= radius)
    return np.column_stack([nearest_a[ok], ib[ok]]).astype(np.int64)


def fit_pair(
    runs: Sequence[MergeInput], a: int, b: int, config: MergeConfig, rng: np.random.Generator
) -> PairFit:
    """The transform ``a_from_b`` between runs ``a`` and ``b`` (module docstring, step 1)."""
    la, lb = runs[a].landmarks, runs[b].landmarks
    use_ids = config.match == "ids" or (
        config.match == "auto" and runs[a].ids_known and runs[b].ids_known
    )
    empty = np.zeros((0, 2), dtype=np.int64)
    if use_ids:
        common, ia, ib = np.intersect1d(la.ids, lb.ids, return_indices=True)
        cand = np.column_stack([ia, ib]).astype(np.int64)
        need = config.min_common_ids
        method, candidates = "ids", len(common)
        if len(cand) < 2:
            return PairFit(a, b, np.full(3, np.nan), method, candidates, empty, math.nan, False)
        i, j = np.triu_indices(len(cand), 1)
        pick = _pick(rng, len(i), config.max_hypotheses)
        quads = np.column_stack([cand[i[pick]], cand[j[pick]]])
        hyps = _hypotheses_2pt(
            la.xy[quads[:, [0, 2]]].reshape(-1, 2, 2), lb.xy[quads[:, [1, 3]]].reshape(-1, 2, 2)
        )
        moved = (
            np.einsum("hij,kj->hki", rotation_2d(hyps[:, 2]), lb.xy[cand[:, 1]]) + hyps[:, None, :2]
        )
        err = np.linalg.norm(moved - la.xy[cand[:, 0]][None], axis=2)
        best = hyps[int(np.argmax((err <= config.inlier_m).sum(axis=1)))]

        def inliers(pose: F64) -> I64:
            e = np.linalg.norm(
                transform_points_planar(pose, lb.xy[cand[:, 1]]) - la.xy[cand[:, 0]], axis=1
            )
            return cand[e <= config.inlier_m]

    else:
        need, method = config.min_inliers, "constellation"
        da = np.linalg.norm(la.xy[:, None] - la.xy[None], axis=2)
        db = np.linalg.norm(lb.xy[:, None] - lb.xy[None], axis=2)
        pa = np.column_stack(np.triu_indices(len(la), 1))
        nb = len(lb)
        pb = np.column_stack(np.nonzero(~np.eye(nb, dtype=bool)))  # both orders
        # Short baselines fix the rotation poorly: use segments longer than twice the tolerance.
        pa = pa[da[pa[:, 0], pa[:, 1]] > 2 * config.inlier_m]
        pb = pb[db[pb[:, 0], pb[:, 1]] > 2 * config.inlier_m]
        close = np.abs(da[pa[:, 0], pa[:, 1]][:, None] - db[pb[:, 0], pb[:, 1]][None])
        ha, hb = np.nonzero(close <= config.inlier_m)
        candidates = len(ha)
        if candidates == 0:
            return PairFit(a, b, np.full(3, np.nan), method, 0, empty, math.nan, False)
        pick = _pick(rng, candidates, config.max_hypotheses)
        hyps = _hypotheses_2pt(la.xy[pa[ha[pick]]], lb.xy[pb[hb[pick]]])
        moved = np.einsum("hij,kj->hki", rotation_2d(hyps[:, 2]), lb.xy) + hyps[:, None, :2]
        nearest = np.min(np.linalg.norm(moved[:, :, None] - la.xy[None, None], axis=3), axis=2)
        best = hyps[int(np.argmax((nearest <= config.inlier_m).sum(axis=1)))]

        def inliers(pose: F64) -> I64:
            return _mutual_nearest(la.xy, transform_points_planar(pose, lb.xy), config.inlier_m)

    pose, pairs = best, inliers(best)
    for _ in range(10):
        if len(pairs) < 2:
            break
        pose, _ = rigid_fit_2d(
            lb.xy[pairs[:, 1]],
            la.xy[pairs[:, 0]],
            _weights(runs[a], runs[b], pairs, config.sigma_floor_m),
        )
        again = inliers(pose)
        if np.array_equal(again, pairs):
            break
        pairs = again
    rms = (
        float(
            np.sqrt(
                np.mean(
                    np.sum(
                        (transform_points_planar(pose, lb.xy[pairs[:, 1]]) - la.xy[pairs[:, 0]])
                        ** 2,
                        1,
                    )
                )
            )
        )
        if len(pairs)
        else math.nan
    )
    return PairFit(a, b, pose, method, candidates, pairs, rms, len(pairs) >= need)


def connect(fits: Sequence[PairFit], count: int) -> tuple[NDArray[np.bool_], F64]:
    """Runs reachable from run 0 and their ``world_from_run`` (R, 3) along a maximum spanning
    tree of the connected pairs by inlier count (NaN rows for unreachable runs)."""
    world = np.full((count, 3), np.nan)
    world[0] = 0.0
    reached = np.zeros(count, dtype=bool)
    reached[0] = True
    edges = [f for f in fits if f.connected]
    while True:
        frontier = [f for f in edges if reached[f.a] != reached[f.b]]
        if not frontier:
            break
        f = max(frontier, key=lambda e: (len(e.pairs), -e.rms_m, -e.a, -e.b))
        if reached[f.a]:
            world[f.b] = compose_planar(world[f.a], f.a_from_b)
            reached[f.b] = True
        else:
            world[f.a] = compose_planar(world[f.b], invert_planar(f.a_from_b))
            reached[f.a] = True
    return reached, world


# --- Joint optimisation -----------------------------------------------------------------------


def _clusters(
    runs: Sequence[MergeInput], fits: Sequence[PairFit], connected: NDArray[np.bool_]
) -> list[list[tuple[int, int]]]:
    """Merged landmarks as lists of (run, landmark index), by the connected pairs' inliers."""
    nodes = [
        (r, k) for r in range(len(runs)) if connected[r] for k in range(len(runs[r].landmarks))
    ]
    index = {n: i for i, n in enumerate(nodes)}
    parent = list(range(len(nodes)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for f in fits:
        if not (f.connected and connected[f.a] and connected[f.b]):
            continue
        for ka, kb in f.pairs.tolist():
            ra, rb = find(index[(f.a, ka)]), find(index[(f.b, kb)])
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
    groups: dict[int, list[tuple[int, int]]] = {}
    for i, n in enumerate(nodes):
        groups.setdefault(find(i), []).append(n)
    return [groups[k] for k in sorted(groups)]


def _merged_ids(runs: Sequence[MergeInput], members: list[list[tuple[int, int]]]) -> I64:
    """A cluster keeps the id its members share; the others count up past the largest kept."""
    shared: list[int | None] = []
    for group in members:
        ids = {int(runs[r].landmarks.ids[k]) for r, k in group}
        known = all(runs[r].ids_known for r, _ in group)
        shared.append(ids.pop() if known and len(ids) == 1 else None)
    kept = [i for i in shared if i is not None]
    taken = set()
    out = []
    next_id = max(kept, default=-1) + 1
    for i in shared:
        if i is None or i in taken:
            i, next_id = next_id, next_id + 1
        taken.add(i)
        out.append(i)
    return np.asarray(out, dtype=np.int64)


def landmark_noise(
    runs: Sequence[MergeInput], fits: Sequence[PairFit], config: MergeConfig
) -> list[F64]:
    """Per run, (K, 2, 2) the noise of its landmarks in the joint optimisation, m².

    An EKF's landmark covariances mostly hold the uncertainty of the map's frame (shared by all
    its landmarks, and absorbed here by the run's transform): only their relative sizes within
    a run are kept (trace over the run's median trace), as isotropic covariances scaled by the
    run's own variance ``s²``. ``s²`` is half the mean squared disagreement of the run's inlier
    pairs (each pair's squared disagreement estimates the sum of two runs' variances), plus
    ``sigma_floor_m²``.
    """
    out = []
    for r, run in enumerate(runs):
        sq = []
        for f in fits:
            if f.connected and r in (f.a, f.b) and len(f.pairs):
                sq.append(f.rms_m**2 * len(f.pairs))
        count = sum(len(f.pairs) for f in fits if f.connected and r in (f.a, f.b))
        var = (
            sum(sq) / count / 2 if count else config.default_sigma_m**2
        ) + config.sigma_floor_m**2
        assert run.landmarks.cov is not None
        tr = np.trace(run.landmarks.cov, axis1=1, axis2=2)
        rel = tr / np.median(tr) if np.median(tr) > 0 else np.ones_like(tr)
        out.append(np.asarray(rel[:, None, None] * var * np.eye(2), dtype=np.float64))
    return out


def optimise(
    runs: Sequence[MergeInput],
    initial: F64,
    connected: NDArray[np.bool_],
    members: list[list[tuple[int, int]]],
    noise_cov: Sequence[F64],
    config: MergeConfig,
) -> tuple[F64, F64, F64]:
    """Jointly optimise the run transforms and merged landmarks (module docstring, step 3).

    ``noise_cov`` holds per run the (K, 2, 2) noise of its landmarks (:func:`landmark_noise`).

    Returns:
        (R, 3) world_from_run (NaN rows for unconnected runs), (L, 2) landmark positions and
        (L, 2, 2) their marginal covariances, m and m².
    """
    import gtsam

    def x_key(r: int) -> int:
        return int(gtsam.symbol("x", r))

    def l_key(c: int) -> int:
        return int(gtsam.symbol("l", c))

    def landmark_error(measured: F64) -> Any:
        def error(this: Any, values: Any, jacobians: list[F64] | None) -> F64:
            pose = values.atPose2(this.keys()[0])
            point = values.atPoint2(this.keys()[1])
            yaw = pose.theta()
            rt = rotation_2d(yaw).T
            q = rt @ (np.asarray(point) - np.array([pose.x(), pose.y()]))
            if jacobians is not None:
                jacobians[0] = np.array([[-1.0, 0.0, q[1]], [0.0, -1.0, -q[0]]])
                jacobians[1] = rt
            return np.asarray(q - measured, dtype=np.float64)

        return error

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for r in np.flatnonzero(connected).tolist():
        pose = gtsam.Pose2(*initial[r])
        values.insert(x_key(r), pose)
        if r == 0:
            graph.add(gtsam.NonlinearEqualityPose2(x_key(r), pose))
    huber = gtsam.noiseModel.mEstimator.Huber.Create(HUBER_WIDTH)
    for c, group in enumerate(members):
        start = np.mean(
            [
                transform_points_planar(initial[r], runs[r].landmarks.xy[k][None])[0]
                for r, k in group
            ],
            0,
        )
        values.insert(l_key(c), gtsam.Point2(*start))
        for r, k in group:
            noise = gtsam.noiseModel.Gaussian.Covariance(noise_cov[r][k])
            model = gtsam.noiseModel.Robust.Create(huber, noise)
            graph.add(
                gtsam.CustomFactor(
                    model, [x_key(r), l_key(c)], landmark_error(runs[r].landmarks.xy[k])
                )
            )
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.max_iterations)
    params.setOrderingType("COLAMD")
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    world = np.full((len(runs), 3), np.nan)
    for r in np.flatnonzero(connected).tolist():
        p = result.atPose2(x_key(r))
        world[r] = [p.x(), p.y(), wrap_angle(p.theta())]
    xy = np.array([np.asarray(result.atPoint2(l_key(c))) for c in range(len(members))])
    marginals = gtsam.Marginals(graph, result)
    cov = np.array([marginals.marginalCovariance(l_key(c)) for c in range(len(members))])
    return world, xy.reshape(-1, 2), cov.reshape(-1, 2, 2)


def _residuals(
    runs: Sequence[MergeInput], world: F64, xy: F64, members: list[list[tuple[int, int]]]
) -> F64:
    """(R,) RMS of each run's shared landmarks against the merged positions, m."""
    sq: list[list[float]] = [[] for _ in runs]
    for c, group in enumerate(members):
        if len({r for r, _ in group}) < 2:
            continue
        for r, k in group:
            d = transform_points_planar(world[r], runs[r].landmarks.xy[k][None])[0] - xy[c]
            sq[r].append(float(d @ d))
    return np.array([math.sqrt(np.mean(s)) if s else math.nan for s in sq])


def _moved(trajectory: Trajectory, world_from_run: F64) -> Trajectory:
    return Trajectory(
        trajectory.stamps_ns,
        np.einsum(
            "ij,njk->nik", planar_to_se3(world_from_run[None])[0], trajectory.world_from_body
        ),
    )


def merge(runs: list[MergeInput], config: MergeConfig | None = None) -> MergeResult:
    """Steps 1-3 of the module docstring on loaded runs (no files written, no ground truth)."""
    config = (config or MergeConfig()).check()
    rng = np.random.default_rng(config.seed)
    fits = [
        fit_pair(runs, a, b, config, rng) for a in range(len(runs)) for b in range(a + 1, len(runs))
    ]
    connected, initial = connect(fits, len(runs))
    members = _clusters(runs, fits, connected)
    noise = landmark_noise(runs, fits, config)
    world, xy, cov = optimise(runs, initial, connected, members, noise, config)
    return MergeResult(
        runs=runs,
        pairs=fits,
        connected=connected,
        world_from_run=world,
        initial_world_from_run=initial,
        landmarks=LandmarkMap(_merged_ids(runs, members), xy, cov),
        members=members,
        residual_rms_m=_residuals(runs, world, xy, members),
        trajectories={
            r: _moved(runs[r].trajectory, world[r]) for r in np.flatnonzero(connected).tolist()
        },
    )


# --- Ground truth ------------------------------------------------------------------------------


def _groundtruth(run: MergeInput) -> Trajectory | None:
    """The run's ground truth from its recorded input log, or None (logged) if unreachable."""
    from slamcli.formats import open_source

    try:
        with open_source(run.record.input_path(), **run.record.source_options) as source:
            return source.groundtruth()
    except InputError as exc:
        log.warning("%s: no ground truth for the merged figures: %s", run.path, exc.msg)
        return None


def evaluate_merged(result: MergeResult) -> dict[str, Any]:
    """ATE of every connected run against its ground truth under one shared SE(2) alignment
    (:func:`~slamcli.planar_eval.evaluate_common_frame`).

    Returns:
        ``{}`` when no run has reachable ground truth; else ``alignment`` (x, y, yaw of the
        shared alignment), ``per_run`` (label -> ``matched``, ``ate`` stats in m under the
        shared alignment, ``ate_unaligned`` in the merged frame, and ``ate_own_run_rmse`` the
        run's own rmse from its run.json), ``all`` (stats over every matched pose) and
        ``mean_of_rmse_m``.
    """
    from slamcli.planar_eval import evaluate_common_frame

    runs = {result.runs[r].label: result.runs[r] for r in result.trajectories}
    truths = {}
    for label, run in runs.items():
        gt = _groundtruth(run)
        if gt is not None:
            truths[label] = gt
    estimates = {result.runs[r].label: traj for r, traj in result.trajectories.items()}
    common = evaluate_common_frame(truths, estimates)
    if common is None:
        return {}
    per_run: dict[str, Any] = {}
    for label, robot in common.robots.items():
        own = runs[label].record.record.get("metrics", {}).get("evaluation", {})
        per_run[label] = {
            "matched": robot.matched,
            "ate": robot.ate.to_dict(),
            "ate_unaligned": robot.own.ate_unaligned.to_dict(),
            "ate_own_run_rmse": own.get("ate", {}).get("rmse") if isinstance(own, dict) else None,
        }
    return {
        "alignment": _pose_dict(common.transform),
        "per_run": per_run,
        "all": common.ate.to_dict(),
        "mean_of_rmse_m": float(np.mean([r.ate.rmse for r in common.robots.values()])),
    }


# --- Writing ------------------------------------------------------------------------------------


def _pose_dict(pose: F64) -> dict[str, float]:
    return {"x_m": float(pose[0]), "y_m": float(pose[1]), "yaw_deg": math.degrees(float(pose[2]))}


def _finite(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


def merge_runs(
    paths: Sequence[str | Path],
    out: str | Path,
    *,
    config: MergeConfig | None = None,
    force: bool = False,
    command: str = "merge",
    progress: ProgressFn | None = None,
) -> MergeResult:
    """Merge EKF run folders into one frame and write ``out`` (outputs in the module docstring).

    The folder is all or nothing (:class:`~slamcli.rundir.RunDir`). Unconnected runs are left
    out of the outputs and listed in run.json's ``unconnected``.

    Args:
        paths: two or more run folders; the first is the reference frame.
        out: output folder; must be empty or absent unless ``force``.
        config: matching and optimisation settings.
        force: replace a non-empty folder (once the new one is complete).
        command: recorded in run.json.
        progress: called as ``progress(done, 4)`` after reading, merging, evaluating, writing.

    Raises:
        InputError: see :func:`load_runs`. ConfigError: a bad setting.
    """
    from dataclasses import asdict

    from slamcli.formats.landmark_map import write_landmarks_csv
    from slamcli.formats.trajectory import write_tum

    config = (config or MergeConfig()).check()
    timings = Timings()

    def step(i: int) -> None:
        if progress is not None:
            progress(i, 4)

    with RunDir(out, force=force) as run:
        with timings.stage("read"):
            runs = load_runs(paths, config)
        step(1)
        with timings.stage("merge"):
            result = merge(runs, config)
        step(2)
        with timings.stage("evaluate"):
            result.evaluation = evaluate_merged(result)
        step(3)
        with timings.stage("write"):
            for r, traj in sorted(result.trajectories.items()):
                write_tum(run.output(f"trajectory_{runs[r].label}.tum"), traj)
            write_landmarks_csv(run.output("landmarks.csv"), result.landmarks)
            plot_merge(run.output("report.png"), result)
            per_run = []
            for r, m in enumerate(runs):
                per_run.append(
                    {
                        "label": m.label,
                        "robot": m.robot,
                        "path": str(m.path),
                        "connected": bool(result.connected[r]),
                        "ids_known": m.ids_known,
                        "landmarks": len(m.landmarks),
                        "world_from_run": _pose_dict(result.world_from_run[r])
                        if result.connected[r]
                        else None,
                        "initial_world_from_run": _pose_dict(result.initial_world_from_run[r])
                        if result.connected[r]
                        else None,
                        "residual_rms_m": _finite(result.residual_rms_m[r]),
                        "trajectory": f"trajectory_{m.label}.tum" if result.connected[r] else None,
                    }
                )
            shared = sum(1 for g in result.members if len({r for r, _ in g}) > 1)
            run.write_run_json(
                command=command,
                inputs=[hash_input(m.path / "run.json") | {"run": str(m.path)} for m in runs],
                config={"merge": asdict(config)},
                seeds={"ransac": config.seed},
                timings=timings,
                counts={
                    "runs": len(runs),
                    "connected": int(result.connected.sum()),
                    "landmarks": len(result.landmarks),
                    "shared_landmarks": shared,
                },
                metrics={"evaluation": result.evaluation} if result.evaluation else {},
                extra={
                    "pipeline": "merge",
                    "reference": runs[0].label,
                    "runs": per_run,
                    "connections": [f.to_dict(runs) for f in result.pairs],
                    "unconnected": [m.label for r, m in enumerate(runs) if not result.connected[r]],
                },
            )
        step(4)
    return result


def plot_merge(path: str | Path, result: MergeResult) -> Path:
    """A top view of the merged runs (one colour each), the merged landmarks with 3σ ellipses
    and, with an evaluation, each run's ground truth under the shared alignment (grey)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Ellipse

    from slamcli.atomic import atomic_path

    fig, ax = plt.subplots(figsize=(10, 8), dpi=100)
    colours = plt.get_cmap("tab10")
    for r, traj in sorted(result.trajectories.items()):
        xy = se3_to_planar(traj.world_from_body)[:, :2]
        label = result.runs[r].label
        ev = result.evaluation.get("per_run", {}).get(label)
        if ev is not None:
            label += f" (ATE {ev['ate']['rmse']:.3f} m)"
        ax.plot(xy[:, 0], xy[:, 1], lw=0.8, color=colours(r % 10), label=label)
    lm = result.landmarks
    ax.plot(lm.xy[:, 0], lm.xy[:, 1], "k+", ms=6, label="merged landmarks")
    if lm.cov is not None:
        for (x, y), c in zip(lm.xy, lm.cov, strict=True):
            vals, vecs = np.linalg.eigh(c)
            ang = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
            w, h = 6 * np.sqrt(np.maximum(vals[::-1], 0))
            ax.add_patch(Ellipse((x, y), w, h, angle=ang, fill=False, lw=0.5, color="k"))
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    connected = int(result.connected.sum())
    title = f"{connected} of {len(result.runs)} runs merged in {result.runs[0].label}'s frame"
    if result.evaluation:
        title += f"; ATE rmse over all {result.evaluation['all']['rmse']:.3f} m (one alignment)"
    ax.set_title(title)
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, lw=0.3)
    with atomic_path(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    return Path(path)


__all__ = [
    "MergeConfig",
    "MergeInput",
    "MergeResult",
    "PairFit",
    "connect",
    "evaluate_merged",
    "fit_pair",
    "load_runs",
    "merge",
    "merge_runs",
    "optimise",
    "plot_merge",
]
