"""Accuracy and consistency of planar landmark SLAM (EKF) against ground truth.

- **Association**: every estimated pose whose stamp lies inside the ground truth's time span
  is compared with the ground truth interpolated at that stamp (x, y and unwrapped yaw,
  linearly). Stamps whose two surrounding ground-truth samples are more than ``max_gap_s``
  apart (motion-capture drop-outs) are left out; a stamp that coincides with a ground-truth
  sample is always kept.
- **Alignment**: SE(2) (a rotation about +z and an x-y translation, no scale), least squares
  on the matched positions (Umeyama in 2-D). The filter starts at the ground-truth pose, so
  the unaligned figures are meaningful too and both are reported.
- **Landmarks**: estimated positions moved by the trajectory's SE(2) alignment, then paired
  with the surveyed ones by id, or (``known_ids=False``) by an optimal one-to-one assignment
  within ``match_radius_m``.
- **NEES** of the unaligned estimate with the filter's (x, y, yaw) covariances, against the
  two-sided 95 % χ² interval (:func:`nees_band`).

The dead-reckoning trajectory is evaluated with the same :func:`evaluate_planar` (no
covariance, no landmarks); :func:`dead_reckoning_ate` is that call.

**Several robots in one frame** (:func:`evaluate_common_frame`): robots mapped into one world
frame (a joint run, or separate runs merged) are each evaluated alone, then all under **one**
SE(2) alignment fitted on every robot's matched positions together, so the figures also
measure how well the robots agree with each other.
"""

from __future__ import annotations

import logging
from collections.abc import Hashable, Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.evaluation import ErrorStats
from slamcli.geometry import interpolate_planar, rotation_2d, se3_to_planar, umeyama, wrap_angle
from slamcli.geometry.chi2 import chi2_quantile
from slamcli.types import LandmarkMap, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
K = TypeVar("K", bound=Hashable)

MIN_PAIRS_SE2 = 3
"""Fewest matched poses for the SE(2) alignment."""

NEES_DOF = 3
_MAX_LISTED_IDS = 100


def nees_band(dof: int, n_runs: int = 1, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided ``confidence`` interval of the (run-averaged) NEES/NIS of ``dof`` DoF.

    With ``n_runs`` Monte-Carlo runs the average of the runs' NEES is χ²(dof·n_runs)/n_runs.
    """
    if dof < 1 or n_runs < 1:
        raise ValueError(f"nees_band needs dof >= 1 and n_runs >= 1, got {dof}, {n_runs}")
    a = (1.0 - confidence) / 2.0
    k = dof * n_runs
    return chi2_quantile(a, k) / n_runs, chi2_quantile(1.0 - a, k) / n_runs


@dataclass(frozen=True)
class LandmarkEval:
    """Estimated landmarks against surveyed ones, after the trajectory's SE(2) alignment.

    Attributes:
        known_ids: paired by id (True) or by assignment within ``match_radius_m``.
        match_radius_m: the gate of the assignment (unused with ids).
        aligned_xy: (K, 2) estimated positions in the ground truth's frame.
        pairs: (P, 2) int64 rows (estimate index, true index) of matched landmarks.
        errors_m: (P,) distances of the pairs, metres.
        spurious: int64 indices of estimated landmarks matched to no true one (and, without
            ids, not a duplicate).
        duplicates: int64 indices of estimated landmarks mapping a true landmark another
            estimate already matched (same id twice, or nearest matched true landmark within
            the radius).
        missed: int64 indices of true landmarks no estimate matched.
        rmse_m: root mean square of ``errors_m``; None without pairs.
    """

    known_ids: bool
    match_radius_m: float
    aligned_xy: F64
    pairs: I64
    errors_m: F64
    spurious: I64
    duplicates: I64
    missed: I64
    rmse_m: float | None
    estimated_ids: I64
    true_ids: I64

    @property
    def matched(self) -> int:
        return int(self.pairs.shape[0])

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "rmse_m": self.rmse_m,
            "matched": self.matched,
            "spurious": int(self.spurious.size),
            "duplicates": int(self.duplicates.size),
            "missed": int(self.missed.size),
            "estimated": int(self.aligned_xy.shape[0]),
            "true": int(self.true_ids.size),
            "association": "id" if self.known_ids else f"assignment <= {self.match_radius_m:g} m",
            "alignment": "se2 (trajectory)",
        }
        if self.errors_m.size:
            out["error_m"] = ErrorStats.of(self.errors_m).to_dict()
        if self.known_ids and 0 < self.spurious.size <= _MAX_LISTED_IDS:
            out["unmatched_ids"] = [int(i) for i in self.estimated_ids[self.spurious]]
        return out


@dataclass(frozen=True)
class NeesEval:
    """Normalised estimation error squared of the unaligned estimate.

    Attributes:
        stamps_ns: (Q,) stamps with a usable (positive definite) covariance.
        values: (Q,) pose NEES, 3 DoF (x, y, yaw).
        position: (Q,) position-only NEES, 2 DoF.
        band: the two-sided 95 % interval for one run, 3 DoF.
        skipped: matched poses left out for a singular or non-finite covariance (e.g. the
            filter's exactly known first pose).
    """

    stamps_ns: I64
    values: F64
    position: F64
    band: tuple[float, float]
    skipped: int

    @property
    def mean(self) -> float:
        return float(np.mean(self.values))

    @property
    def median(self) -> float:
        return float(np.median(self.values))

    @property
    def fraction_in_band(self) -> float:
        lo, hi = self.band
        return float(np.mean((self.values >= lo) & (self.values <= hi)))

    @property
    def consistent(self) -> bool:
        lo, hi = self.band
        return bool(lo <= self.mean <= hi)

    @property
    def position_mean(self) -> float:
        return float(np.mean(self.position))

    def to_dict(self) -> dict[str, Any]:
        return {
            "mean": self.mean,
            "median": self.median,
            "dof": NEES_DOF,
            "band95": [self.band[0], self.band[1]],
            "fraction_in_band": self.fraction_in_band,
            "consistent": self.consistent,
            "position_mean": self.position_mean,
            "position_band95": list(nees_band(2)),
            "samples": int(self.values.size),
            "skipped": self.skipped,
        }


@dataclass(frozen=True)
class PlanarEval:
    """Everything :func:`evaluate_planar` computed.

    Attributes:
        stamps_ns: (M,) int64 stamps of the matched estimated poses.
        est_index: (M,) int64 rows of the estimate used.
        gt: (M, 3) ground truth (x, y, yaw) interpolated at ``stamps_ns``.
        est: (M, 3) the estimate, unaligned.
        aligned: (M, 3) the estimate after the SE(2) alignment.
        angle_rad, translation: the alignment ``p_gt ≈ R(angle) p_est + translation``.
        ate_m / ate_unaligned_m: (M,) position errors, metres.
        heading_deg / heading_unaligned_deg: (M,) absolute heading errors, degrees.
        possible: poses of the estimate; ``outside_span`` of them lie outside the ground
            truth's time span, ``in_gaps`` fall in ground-truth gaps > ``max_gap_s``.
    """

    stamps_ns: I64
    est_index: I64
    gt: F64
    est: F64
    aligned: F64
    angle_rad: float
    translation: F64
    ate_m: F64
    ate_unaligned_m: F64
    heading_deg: F64
    heading_unaligned_deg: F64
    ate: ErrorStats
    ate_unaligned: ErrorStats
    heading: ErrorStats
    heading_unaligned: ErrorStats
    possible: int
    outside_span: int
    in_gaps: int
    max_gap_s: float
    landmarks: LandmarkEval | None = None
    landmark_count: int | None = None
    nees: NeesEval | None = None

    @property
    def matched(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def rotation(self) -> F64:
        """(2, 2) rotation of the alignment."""
        return rotation_2d(self.angle_rad)

    def transform_xy(self, xy: F64) -> F64:
        """(K, 2) positions in the estimate's frame -> the ground truth's frame."""
        return np.asarray(xy, dtype=np.float64) @ self.rotation.T + self.translation

    def transform_cov(self, cov: F64) -> F64:
        """(K, 2, 2) position covariances rotated like :meth:`transform_xy` (R C Rᵀ)."""
        r = self.rotation
        return np.einsum("ij,kjl,ml->kim", r, np.asarray(cov, dtype=np.float64), r)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able summary for run.json (statistics and counts, no per-pose arrays)."""
        out: dict[str, Any] = {
            "alignment": "se2",
            "transform": {
                "yaw_deg": float(np.rad2deg(self.angle_rad)),
                "tx_m": float(self.translation[0]),
                "ty_m": float(self.translation[1]),
            },
            "matched": self.matched,
            "possible": self.possible,
            "outside_gt_span": self.outside_span,
            "in_gt_gaps": self.in_gaps,
            "max_gap_s": self.max_gap_s,
            "ate": self.ate.to_dict(),
            "ate_unaligned": self.ate_unaligned.to_dict(),
            "heading_error_deg": self.heading.to_dict(),
            "heading_error_unaligned_deg": self.heading_unaligned.to_dict(),
        }
        if self.landmarks is not None:
            out["landmarks"] = self.landmarks.to_dict()
        elif self.landmark_count is not None:
            out["landmarks"] = {"estimated": self.landmark_count}
        if self.nees is not None:
            out["nees"] = self.nees.to_dict()
        return out


def _span(stamps: I64) -> str:
    return f"{stamps[0] * 1e-9:.3f} s to {stamps[-1] * 1e-9:.3f} s"


def _associate(
    gt_stamps: I64, gt_xyt: F64, est_stamps: I64, max_gap_s: float
) -> tuple[I64, F64, int, int]:
    """Rows of the estimate kept, ground truth there, and the counts outside span / in gaps."""
    inside = (est_stamps >= gt_stamps[0]) & (est_stamps <= gt_stamps[-1])
    q = est_stamps[inside]
    hi = np.searchsorted(gt_stamps, q, side="left")  # first gt stamp >= q
    exact = gt_stamps[np.minimum(hi, gt_stamps.size - 1)] == q
    lo = np.maximum(hi - 1, 0)
    gap_ns = gt_stamps[np.minimum(hi, gt_stamps.size - 1)] - gt_stamps[lo]
    ok = exact | (gap_ns <= round(max_gap_s * 1e9))
    rows = np.flatnonzero(inside)[ok].astype(np.int64)
    gt_at = interpolate_planar(gt_stamps, gt_xyt, est_stamps[rows])
    return rows, gt_at, int(np.count_nonzero(~inside)), int(np.count_nonzero(~ok))


def evaluate_planar(
    gt: Trajectory,
    est: Trajectory,
    *,
    est_cov: F64 | None = None,
    landmarks: LandmarkMap | None = None,
    true_landmarks: LandmarkMap | None = None,
    known_ids: bool = True,
    max_gap_s: float = 0.5,
    match_radius_m: float = 1.0,
) -> PlanarEval:
    """Associate, align (SE(2)) and measure a planar estimate against planar ground truth.

    Args:
        gt: ground-truth poses (planar, embedded in SE(3)).
        est: estimated poses.
        est_cov: (N, 3, 3) covariance of (x, y, yaw) for each row of ``est``: adds the NEES.
        landmarks: estimated landmarks; with ``true_landmarks`` adds the landmark figures.
        true_landmarks: surveyed landmarks in the ground truth's frame.
        known_ids: pair landmarks by id; otherwise by optimal assignment.
        max_gap_s: leave out stamps whose surrounding ground-truth samples are further apart.
        match_radius_m: largest accepted distance of an assigned landmark pair.

    Raises:
        InputError: no overlap in time, too few matched poses, or arrays of the wrong shape.
    """
    if len(gt) == 0 or len(est) == 0:
        raise InputError(
            f"planar evaluation needs poses in both trajectories, got {len(gt)} ground-truth "
            f"and {len(est)} estimated"
        )
    if not (max_gap_s > 0.0 and np.isfinite(max_gap_s)):
        raise InputError(f"max_gap_s must be a positive number of seconds, got {max_gap_s}")
    gt_stamps = gt.stamps_ns
    est_stamps = est.stamps_ns
    if est_stamps[-1] < gt_stamps[0] or est_stamps[0] > gt_stamps[-1]:
        raise InputError(
            f"the estimate ({_span(est_stamps)}) and the ground truth ({_span(gt_stamps)}) do "
            "not overlap in time",
            hint="check that both use the same clock",
        )
    rows, gt_xyt, outside, in_gaps = _associate(
        gt_stamps, se3_to_planar(gt.world_from_body), est_stamps, max_gap_s
    )
    if rows.size < MIN_PAIRS_SE2:
        raise InputError(
            f"only {rows.size} of {len(est)} estimated poses have ground truth "
            f"({outside} outside its span {_span(gt_stamps)}, {in_gaps} in gaps longer than "
            f"{max_gap_s:g} s), at least {MIN_PAIRS_SE2} needed",
            hint="check the clocks, or allow longer ground-truth gaps",
        )
    est_xyt = se3_to_planar(est.world_from_body)[rows]

    r, t, _ = umeyama(est_xyt[:, :2], gt_xyt[:, :2])
    angle = float(np.arctan2(r[1, 0], r[0, 0]))
    aligned = np.empty_like(est_xyt)
    aligned[:, :2] = est_xyt[:, :2] @ r.T + t
    aligned[:, 2] = wrap_angle(est_xyt[:, 2] + angle)

    ate_m = np.linalg.norm(aligned[:, :2] - gt_xyt[:, :2], axis=1)
    ate_raw = np.linalg.norm(est_xyt[:, :2] - gt_xyt[:, :2], axis=1)
    head = np.rad2deg(np.abs(wrap_angle(aligned[:, 2] - gt_xyt[:, 2])))
    head_raw = np.rad2deg(np.abs(wrap_angle(est_xyt[:, 2] - gt_xyt[:, 2])))

    lm_eval = None
    if landmarks is not None and true_landmarks is not None:
        lm_eval = _landmark_eval(
            landmarks, true_landmarks, rotation_2d(angle), t, known_ids, match_radius_m
        )
    nees = None
    if est_cov is not None:
        nees = _nees(est_stamps[rows], est_xyt, gt_xyt, _checked_cov(est_cov, len(est))[rows])

    return PlanarEval(
        stamps_ns=est_stamps[rows],
        est_index=rows,
        gt=gt_xyt,
        est=est_xyt,
        aligned=aligned,
        angle_rad=angle,
        translation=np.asarray(t, dtype=np.float64),
        ate_m=ate_m,
        ate_unaligned_m=ate_raw,
        heading_deg=head,
        heading_unaligned_deg=head_raw,
        ate=ErrorStats.of(ate_m),
        ate_unaligned=ErrorStats.of(ate_raw),
        heading=ErrorStats.of(head),
        heading_unaligned=ErrorStats.of(head_raw),
        possible=len(est),
        outside_span=outside,
        in_gaps=in_gaps,
        max_gap_s=float(max_gap_s),
        landmarks=lm_eval,
        landmark_count=None if landmarks is None else len(landmarks),
        nees=nees,
    )


def dead_reckoning_ate(
    gt: Trajectory, dr_traj: Trajectory, *, max_gap_s: float = 0.5
) -> PlanarEval:
    """The odometry-only trajectory measured like the filter's estimate (no NEES, no map)."""
    return evaluate_planar(gt, dr_traj, max_gap_s=max_gap_s)


@dataclass(frozen=True)
class RobotInCommonFrame:
    """One robot's figures in :func:`evaluate_common_frame`.

    Attributes:
        own: the robot evaluated alone: its own SE(2) alignment, ``own.ate`` under it and
            ``own.ate_unaligned`` in the estimates' shared frame.
        errors_m: (M,) position errors of ``own``'s matched poses under the common alignment, m.
        ate: statistics of ``errors_m``.
    """

    own: PlanarEval
    errors_m: F64
    ate: ErrorStats

    @property
    def matched(self) -> int:
        return int(self.errors_m.shape[0])


@dataclass(frozen=True)
class CommonFrameEval(Generic[K]):
    """Several robots' estimates against their ground truths under one SE(2) alignment.

    Attributes:
        transform: (3,) x, y (m) and yaw (rad) of the one alignment of all robots,
            ``p_gt ≈ R(yaw) p_est + (x, y)``.
        robots: per robot that could be evaluated, its figures (in the estimates' order).
        ate: statistics of every robot's errors under the common alignment together, m.
    """

    transform: F64
    robots: dict[K, RobotInCommonFrame]
    ate: ErrorStats

    @property
    def matched(self) -> int:
        return sum(r.matched for r in self.robots.values())

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: the transform as [x, y, yaw], ``ate_common`` over all robots and, per
        robot (keyed by ``str(id)``), ``ate`` under its own alignment and ``ate_common``."""
        return {
            "alignment": "se2, one transform for all robots",
            "transform": [float(v) for v in self.transform],
            "ate_common": self.ate.to_dict() | {"matched": self.matched},
            "per_robot": {
                str(k): {
                    "ate": r.own.ate.to_dict(),
                    "ate_common": r.ate.to_dict() | {"matched": r.matched},
                }
                for k, r in self.robots.items()
            },
        }


def evaluate_common_frame(
    truths: Mapping[K, Trajectory],
    estimates: Mapping[K, Trajectory],
    *,
    max_gap_s: float = 0.5,
) -> CommonFrameEval[K] | None:
    """ATE of robots whose estimates share one world frame, each alone and all under one SE(2)
    alignment.

    Each robot with ground truth is evaluated alone (:func:`evaluate_planar`); its matched
    poses are pooled with the other robots' and one least-squares SE(2) fit over all of them
    (Umeyama in 2-D, as for one robot) is the common alignment. A robot without ground truth,
    or whose own evaluation fails (no overlap in time, too few matched poses: logged), is
    left out.

    Args:
        truths: ground truth per robot id, planar poses embedded in SE(3).
        estimates: estimate per robot id, all in one world frame; evaluated in this order.
        max_gap_s: as for :func:`evaluate_planar`.

    Returns:
        The figures, or None when no robot could be evaluated.
    """
    own: dict[K, PlanarEval] = {}
    for key, est in estimates.items():
        gt = truths.get(key)
        if gt is None:
            continue
        try:
            own[key] = evaluate_planar(gt, est, max_gap_s=max_gap_s)
        except InputError as exc:
            log.warning("%s: no accuracy figures: %s", key, exc.msg)
    if not own:
        return None
    rot, t, _ = umeyama(
        np.concatenate([e.est[:, :2] for e in own.values()]),
        np.concatenate([e.gt[:, :2] for e in own.values()]),
    )
    robots: dict[K, RobotInCommonFrame] = {}
    for key, e in own.items():
        err = np.linalg.norm(e.est[:, :2] @ rot.T + t - e.gt[:, :2], axis=1)
        robots[key] = RobotInCommonFrame(own=e, errors_m=err, ate=ErrorStats.of(err))
    return CommonFrameEval(
        transform=np.array([t[0], t[1], np.arctan2(rot[1, 0], rot[0, 0])]),
        robots=robots,
        ate=ErrorStats.of(np.concatenate([r.errors_m for r in robots.values()])),
    )


def _checked_cov(cov: F64, n: int) -> F64:
    c = np.asarray(cov, dtype=np.float64)
    if c.shape != (n, 3, 3):
        raise InputError(f"pose covariances must be ({n}, 3, 3) like the estimate, got {c.shape}")
    return c


def _nees(stamps: I64, est: F64, gt: F64, cov: F64) -> NeesEval:
    e = est - gt
    e[:, 2] = wrap_angle(e[:, 2])
    sym = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    finite = np.all(np.isfinite(sym), axis=(1, 2))
    eig = np.linalg.eigvalsh(np.where(finite[:, None, None], sym, np.eye(3)))
    # Positive definite and not numerically singular; the exactly known first pose is not.
    ok = finite & (eig[:, 0] > 1e-12 * np.maximum(eig[:, -1], 1e-300))
    if not np.any(ok):
        raise InputError("no matched pose has a positive definite covariance for the NEES")
    e_ok, p_ok = e[ok], sym[ok]
    values = np.einsum("ki,ki->k", e_ok, np.linalg.solve(p_ok, e_ok[:, :, None])[:, :, 0])
    e2 = e_ok[:, :2]
    position = np.einsum("ki,ki->k", e2, np.linalg.solve(p_ok[:, :2, :2], e2[:, :, None])[:, :, 0])
    return NeesEval(
        stamps_ns=stamps[ok],
        values=values,
        position=position,
        band=nees_band(NEES_DOF),
        skipped=int(np.count_nonzero(~ok)),
    )


def _landmark_eval(
    est: LandmarkMap,
    truth: LandmarkMap,
    rot: F64,
    trans: F64,
    known_ids: bool,
    radius: float,
) -> LandmarkEval:
    est_ids = np.asarray(est.ids, dtype=np.int64).reshape(-1)
    true_ids = np.asarray(truth.ids, dtype=np.int64).reshape(-1)
    exy = np.asarray(est.xy, dtype=np.float64).reshape(-1, 2)
    txy = np.asarray(truth.xy, dtype=np.float64).reshape(-1, 2)
    if exy.shape[0] != est_ids.size or txy.shape[0] != true_ids.size:
        raise InputError("landmark maps need as many (K, 2) positions as ids")
    aligned = exy @ rot.T + trans
    empty = np.zeros(0, dtype=np.int64)
    if known_ids:
        true_row = {int(i): k for k, i in enumerate(true_ids)}
        pairs_l: list[tuple[int, int]] = []
        spurious_l: list[int] = []
        dup_l: list[int] = []
        seen: set[int] = set()
        for k, i in enumerate(est_ids.tolist()):
            if i not in true_row:
                spurious_l.append(k)
            elif i in seen:
                dup_l.append(k)
            else:
                seen.add(i)
                pairs_l.append((k, true_row[i]))
        pairs = np.array(pairs_l, dtype=np.int64).reshape(-1, 2)
        spurious = np.array(spurious_l, dtype=np.int64)
        duplicates = np.array(dup_l, dtype=np.int64)
    elif exy.shape[0] and txy.shape[0]:
        from scipy.optimize import linear_sum_assignment

        dist = np.linalg.norm(aligned[:, None, :] - txy[None, :, :], axis=2)
        gated = dist <= radius
        # Pairs beyond the gate cost more than any set of gated pairs: the assignment first
        # matches as many landmarks as possible within the radius, then the closest.
        big = 1.0 + float(np.sum(np.where(gated, dist, 0.0)))
        ri, ci = linear_sum_assignment(np.where(gated, dist, big))
        keep = gated[ri, ci]
        pairs = np.stack([ri[keep], ci[keep]], axis=1).astype(np.int64)
        unmatched = np.setdiff1d(np.arange(exy.shape[0]), pairs[:, 0]).astype(np.int64)
        matched_true = np.zeros(txy.shape[0], dtype=bool)
        matched_true[pairs[:, 1]] = True
        nearest = np.argmin(dist[unmatched], axis=1) if unmatched.size else empty
        is_dup = (
            matched_true[nearest] & gated[unmatched, nearest]
            if unmatched.size
            else np.zeros(0, dtype=bool)
        )
        duplicates, spurious = unmatched[is_dup], unmatched[~is_dup]
    else:
        pairs = np.zeros((0, 2), dtype=np.int64)
        spurious, duplicates = np.arange(exy.shape[0], dtype=np.int64), empty
    missed = np.setdiff1d(np.arange(txy.shape[0]), pairs[:, 1]).astype(np.int64)
    errors = np.linalg.norm(aligned[pairs[:, 0]] - txy[pairs[:, 1]], axis=1)
    return LandmarkEval(
        known_ids=known_ids,
        match_radius_m=float(radius),
        aligned_xy=aligned,
        pairs=pairs,
        errors_m=errors,
        spurious=spurious,
        duplicates=duplicates,
        missed=missed,
        rmse_m=float(np.sqrt(np.mean(errors**2))) if errors.size else None,
        estimated_ids=est_ids,
        true_ids=true_ids,
    )


__all__ = [
    "MIN_PAIRS_SE2",
    "CommonFrameEval",
    "LandmarkEval",
    "NeesEval",
    "PlanarEval",
    "RobotInCommonFrame",
    "dead_reckoning_ate",
    "evaluate_common_frame",
    "evaluate_planar",
    "nees_band",
]
