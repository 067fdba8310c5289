"""Trajectory accuracy: ATE and RPE with Umeyama SE(3)/Sim(3) alignment.

The numbers agree with evo 1.38 (``evo_ape`` / ``evo_rpe``) given the same files and options:

- **Association** (``evo --t_max_diff --t_offset``): the trajectory with fewer poses (the
  estimate when both have as many) is walked in order; each of its stamps takes the nearest
  stamp of the other trajectory, shifted by the offset, if it is within ``max_diff_s``.
  Between two equally near stamps the earlier one wins. When the other trajectory repeats a
  stamp, a stamp before it takes its first row and a stamp at or after it takes its last row.
  Several poses may match the same pose of the other trajectory, and rows with repeated stamps
  are evaluated as separate poses. KITTI files have no stamps and pair by index.
- **Alignment** of the estimate onto the ground truth from the matched positions: ``se3``
  (Umeyama, ``--align``), ``sim3`` (``--align --correct_scale``), ``scale`` (scale only,
  ``--correct_scale``), ``none``.
- **ATE**: distances between matched positions after alignment (evo APE, translation part).
- **RPE** (``--delta N --delta_unit f|m``, translation part and ``angle_deg``): relative poses
  between non-overlapping consecutive pairs of matched poses: every N-th pose, or a new pose
  whenever the path travelled since the last one reaches N metres. The estimate is aligned
  first, as ``evo_rpe --align`` does. A rigid alignment leaves relative poses unchanged, but
  ``sim3`` and ``scale`` scale their translations, and with ``m`` the path length that picks
  the pairs is measured on the aligned estimate.
- **Statistics**: rmse, mean, median, std (population, ddof=0), min, max, sse.

Times are int64 nanoseconds. The association alone works in float64 seconds, each stamp being
the double nearest to its exact value (what parsing the file's decimal text gives), because
that is what evo compares: a stamp exactly halfway between two others, or exactly ``max_diff``
away, is decided by the rounding of those doubles, and real files contain such cases.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.geometry import compose, inverse, so3_log, umeyama

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

AlignMode = Literal["se3", "sim3", "scale", "none"]
DeltaUnit = Literal["frames", "m"]
ALIGN_MODES: tuple[str, ...] = ("se3", "sim3", "scale", "none")
DELTA_UNITS: tuple[str, ...] = ("frames", "m")
STAT_KEYS: tuple[str, ...] = ("rmse", "mean", "median", "std", "min", "max", "sse")

MIN_PAIRS_ALIGNED = 3
"""Fewest matched poses for an alignment (Umeyama needs three non-collinear points)."""

_NS_PER_S = 1_000_000_000


class StampedPoses(Protocol):
    """Anything with (N,) int64 non-decreasing ``stamps_ns`` and (N, 4, 4) ``world_from_body``.

    :class:`slamcli.types.Trajectory` and :class:`slamcli.formats.trajectory.PoseTable` both fit.
    """

    @property
    def stamps_ns(self) -> I64: ...

    @property
    def world_from_body(self) -> F64: ...


@dataclass(frozen=True)
class Matched:
    """Poses of ground truth and estimate paired one to one.

    Attributes:
        gt_index: (M,) int64 rows of the ground truth used by each pair.
        est_index: (M,) int64 rows of the estimate used by each pair.
        stamps_ns: (M,) int64 the estimate's stamps of the pairs (without the offset).
        gt: (M, 4, 4) float64 ground-truth poses.
        est: (M, 4, 4) float64 estimated poses, not aligned.
        possible: how many pairs there could have been (poses of the shorter trajectory).
    """

    gt_index: I64
    est_index: I64
    stamps_ns: I64
    gt: F64
    est: F64
    possible: int

    def __len__(self) -> int:
        return int(self.gt_index.shape[0])


@dataclass(frozen=True)
class ErrorStats:
    """Summary of an error array, in the unit of the errors."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    sse: float

    @classmethod
    def of(cls, errors: F64) -> ErrorStats:
        """Statistics of a non-empty (K,) error array; std is the population std (ddof=0)."""
        e = np.asarray(errors, dtype=np.float64)
        sq = e * e
        return cls(
            rmse=float(np.sqrt(np.mean(sq))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            sse=float(np.sum(sq)),
        )

    def to_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in STAT_KEYS}


@dataclass(frozen=True)
class RpeResult:
    """Relative pose errors.

    Attributes:
        delta: the pair spacing, in ``delta_unit``.
        delta_unit: ``frames`` or ``m``.
        pairs: (K, 2) int64 indices into the matched poses (i, j) of each relative pose.
        trans_m: (K,) float64 translation error of each relative pose, metres.
        rot_deg: (K,) float64 rotation error of each relative pose, degrees.
        trans: statistics of ``trans_m``.
        rot: statistics of ``rot_deg``.
    """

    delta: float
    delta_unit: str
    pairs: I64
    trans_m: F64
    rot_deg: F64
    trans: ErrorStats
    rot: ErrorStats

    def to_dict(self) -> dict[str, Any]:
        return {"trans": self.trans.to_dict(), "rot_deg": self.rot.to_dict()}


@dataclass(frozen=True)
class EvalResult:
    """Everything :func:`evaluate` computed.

    Attributes:
        alignment: ``se3``, ``sim3``, ``scale`` or ``none``.
        matched: the paired poses (indices and stamps, for plots and run records).
        aligned_est: (M, 4, 4) float64 matched estimate after alignment.
        rotation: (3, 3) float64 and translation: (3,) float64 metres and scale of the
            alignment ``p_gt ≈ scale * rotation @ p_est + translation``.
        ate_m: (M,) float64 position error of each pair after alignment, metres.
        ate: statistics of ``ate_m``.
        rpe: relative pose errors, when asked for.
    """

    alignment: str
    matched: Matched
    aligned_est: F64
    rotation: F64
    translation: F64
    scale: float
    ate_m: F64
    ate: ErrorStats
    rpe: RpeResult | None = None

    @property
    def pairs(self) -> int:
        return len(self.matched)

    def to_dict(self) -> dict[str, Any]:
        """``{"alignment", "pairs", "ate": {stats}, ["rpe": {"trans", "rot_deg"}], "scale"}``."""
        out: dict[str, Any] = {
            "alignment": self.alignment,
            "pairs": self.pairs,
            "ate": self.ate.to_dict(),
        }
        if self.rpe is not None:
            out["rpe"] = self.rpe.to_dict()
        out["scale"] = self.scale
        return out


def _checked(poses: StampedPoses, name: str) -> tuple[I64, F64]:
    stamps = np.asarray(poses.stamps_ns, dtype=np.int64).reshape(-1)
    mats = np.asarray(poses.world_from_body, dtype=np.float64)
    if mats.ndim != 3 or mats.shape[1:] != (4, 4) or mats.shape[0] != stamps.shape[0]:
        raise InputError(
            f"{name}: needs (N,) stamps and (N, 4, 4) poses, got {stamps.shape} and {mats.shape}"
        )
    if stamps.size == 0:
        raise InputError(f"{name}: has no poses")
    if np.any(np.diff(stamps) < 0):
        raise InputError(f"{name}: stamps must not decrease")
    return stamps, mats


def associate(
    gt: StampedPoses, est: StampedPoses, max_diff_s: float = 0.01, offset_s: float = 0.0
) -> Matched:
    """Pair ground-truth and estimated poses by nearest timestamps (evo's nearest_time sync).

    Args:
        gt: reference poses, stamps non-decreasing.
        est: estimated poses, stamps non-decreasing.
        max_diff_s: largest accepted stamp difference, seconds.
        offset_s: added to the estimate's stamps before matching, seconds.

    Raises:
        InputError: when nothing matches.
    """
    matched = _associate(gt, est, max_diff_s, offset_s)
    if len(matched) == 0:
        raise _too_few(matched, 1, max_diff_s, offset_s)
    return matched


def _associate(gt: StampedPoses, est: StampedPoses, max_diff_s: float, offset_s: float) -> Matched:
    if not (max_diff_s >= 0.0 and np.isfinite(max_diff_s)):
        raise ConfigError(f"the association window must be >= 0 seconds, got {max_diff_s}")
    if not np.isfinite(offset_s):
        raise ConfigError(f"the time offset must be a finite number of seconds, got {offset_s}")
    gt_stamps, gt_poses = _checked(gt, "ground truth")
    est_stamps, est_poses = _checked(est, "estimate")
    est_longer = est_stamps.size > gt_stamps.size
    if est_longer:
        short, long_ = seconds_f64(gt_stamps), seconds_f64(est_stamps) + offset_s
    else:
        short, long_ = seconds_f64(est_stamps), seconds_f64(gt_stamps) - offset_s
    short_idx, long_idx = _nearest(short, long_, max_diff_s)
    gt_idx, est_idx = (short_idx, long_idx) if est_longer else (long_idx, short_idx)
    return Matched(
        gt_index=gt_idx,
        est_index=est_idx,
        stamps_ns=est_stamps[est_idx],
        gt=gt_poses[gt_idx],
        est=est_poses[est_idx],
        possible=int(short.size),
    )


def seconds_f64(stamps_ns: I64) -> F64:
    """(N,) int64 nanoseconds -> (N,) float64 seconds, each the double nearest the exact value.

    ``stamps_ns * 1e-9`` rounds twice and can be one unit in the last place off.
    """
    ns = np.asarray(stamps_ns, dtype=np.int64)
    out = ns.astype(np.float64) / 1e9  # exact inputs, one rounding, while |ns| <= 2**53
    big = np.abs(ns) > 2**53
    if np.any(big):
        mag = np.abs(ns[big])
        whole, frac = np.divmod(mag, _NS_PER_S)
        # whole >= 2**23 here, so the binary exponent of the result is that of whole and the
        # last-place unit is 2**-shift with shift <= 30: frac << shift fits in int64.
        _, exp = np.frexp(whole.astype(np.float64))
        shift = (53 - exp).astype(np.int64)
        q, r = np.divmod(frac << shift, _NS_PER_S)
        k = (whole << shift) + q
        k += (2 * r > _NS_PER_S) | ((2 * r == _NS_PER_S) & (k % 2 == 1))
        out[big] = np.sign(ns[big]) * np.ldexp(k.astype(np.float64), -shift)
    return out


def _nearest(short: F64, long_: F64, max_diff: float) -> tuple[I64, I64]:
    """For each stamp of ``short``, the index of the nearest stamp of sorted ``long_``."""
    in_range = (short >= long_[0] - max_diff) & (short <= long_[-1] + max_diff)
    idx = np.minimum(np.searchsorted(long_, short, side="right"), long_.size - 1)
    diff_ub = long_[idx] - short
    has_lb = idx > 0
    diff_lb = np.where(has_lb, short - long_[np.maximum(idx - 1, 0)], np.inf)
    take_ub = (diff_ub <= max_diff) & (diff_ub < diff_lb)
    take_lb = has_lb & (diff_lb <= max_diff) & (diff_lb <= diff_ub)
    ok = in_range & (take_ub | take_lb)
    best = np.where(take_ub, idx, idx - 1)
    return np.flatnonzero(ok).astype(np.int64), best[ok].astype(np.int64)


def associate_by_index(gt: StampedPoses, est: StampedPoses) -> Matched:
    """Pair pose i of the ground truth with pose i of the estimate (KITTI files).

    Raises:
        InputError: when the two have different numbers of poses.
    """
    gt_stamps, gt_poses = _checked(gt, "ground truth")
    est_stamps, est_poses = _checked(est, "estimate")
    if gt_stamps.size != est_stamps.size:
        raise InputError(
            f"pairing by index needs as many estimated poses as ground-truth poses, got "
            f"{est_stamps.size} and {gt_stamps.size}",
            hint="give both KITTI files their times (--gt-times, --est-times) to pair by time",
        )
    idx = np.arange(gt_stamps.size, dtype=np.int64)
    return Matched(idx, idx, est_stamps, gt_poses, est_poses, int(gt_stamps.size))


def align(gt: F64, est: F64, mode: str = "se3") -> tuple[F64, F64, F64, float]:
    """Align matched estimated poses onto matched ground-truth poses.

    Args:
        gt: (M, 4, 4) ground-truth poses.
        est: (M, 4, 4) estimated poses paired with ``gt``.
        mode: ``se3`` (rotation, translation), ``sim3`` (and scale), ``scale`` (the Sim(3)
            scale only, no rotation or translation) or ``none``.

    Returns:
        aligned estimate (M, 4, 4), rotation (3, 3), translation (3,) metres, scale, with
        ``aligned position = scale * rotation @ position + translation`` and aligned
        orientation ``rotation @ orientation``.
    """
    if mode not in ALIGN_MODES:
        raise ConfigError(f"alignment must be one of {', '.join(ALIGN_MODES)}, got {mode!r}")
    est = np.asarray(est, dtype=np.float64)
    rotation, translation, scale = np.eye(3), np.zeros(3), 1.0
    if mode == "none":
        return est.copy(), rotation, translation, scale
    r, t, s = umeyama(est[:, :3, 3], np.asarray(gt, dtype=np.float64)[:, :3, 3], mode != "se3")
    aligned = est.copy()
    aligned[:, :3, 3] *= s
    if mode == "scale":
        return aligned, rotation, translation, s
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = r, t
    return compose(transform, aligned), r, t, s


_align = align


def ate(gt: F64, aligned_est: F64) -> F64:
    """(M,) position errors in metres between (M, 4, 4) ground truth and aligned estimate."""
    return np.linalg.norm(np.asarray(aligned_est)[:, :3, 3] - np.asarray(gt)[:, :3, 3], axis=1)


def rpe_pairs(est: F64, delta: float, delta_unit: str = "frames") -> I64:
    """(K, 2) index pairs for the RPE, chosen on the (aligned) estimate (M, 4, 4).

    ``frames``: (0, N), (N, 2N), ...; ``m``: each pair ends at the first pose where the path
    travelled since the pair's start reaches ``delta`` metres.
    """
    n = int(np.asarray(est).shape[0])
    if delta_unit == "frames":
        if delta != int(delta) or delta < 1:
            raise ConfigError(f"RPE delta in frames must be a whole number >= 1, got {delta}")
        ids = np.arange(0, n, int(delta), dtype=np.int64)
    elif delta_unit == "m":
        if not delta > 0.0:
            raise ConfigError(f"RPE delta in metres must be > 0, got {delta}")
        ids = _ids_by_path(np.asarray(est)[:, :3, 3], float(delta))
    else:
        raise ConfigError(
            f"RPE delta unit must be one of {', '.join(DELTA_UNITS)}, got {delta_unit!r}"
        )
    return np.stack([ids[:-1], ids[1:]], axis=1)


def _ids_by_path(positions: F64, delta: float) -> I64:
    """Start of every pair when cutting the path into pieces of at least ``delta`` metres."""
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    travelled = np.concatenate([[0.0], np.cumsum(steps)])
    n = travelled.size
    ids = [0]
    # One search per pair, not per pose; the two loops only settle float rounding at the cut.
    while True:
        start = ids[-1]
        nxt = max(int(np.searchsorted(travelled, travelled[start] + delta)), start + 1)
        while nxt - 1 > start and travelled[nxt - 1] - travelled[start] >= delta:
            nxt -= 1
        while nxt < n and travelled[nxt] - travelled[start] < delta:
            nxt += 1
        if nxt >= n:
            break
        ids.append(nxt)
    return np.array(ids, dtype=np.int64)


def rpe(gt: F64, aligned_est: F64, pairs: I64) -> tuple[F64, F64]:
    """Relative pose errors of (K, 2) index pairs.

    For a pair (i, j) the error is ``E = (Q_i⁻¹ Q_j)⁻¹ (P_i⁻¹ P_j)`` with Q the ground truth
    and P the estimate (inverses use Rᵀ). Returns the translation norms of E in metres and its
    rotation angles in degrees, both (K,).
    """
    q = np.asarray(gt, dtype=np.float64)
    p = np.asarray(aligned_est, dtype=np.float64)
    i, j = pairs[:, 0], pairs[:, 1]
    q_rel = compose(inverse(q[i]), q[j])
    p_rel = compose(inverse(p[i]), p[j])
    err = compose(inverse(q_rel), p_rel)
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    rot = np.rad2deg(np.linalg.norm(so3_log(err[:, :3, :3]), axis=1))
    return trans, rot


def evaluate(
    gt: StampedPoses,
    est: StampedPoses,
    *,
    align: str = "se3",
    max_diff_s: float = 0.01,
    offset_s: float = 0.0,
    by_index: bool = False,
    rpe_delta: float | None = None,
    delta_unit: str = "frames",
) -> EvalResult:
    """Associate, align and measure an estimated trajectory against ground truth.

    Args:
        gt: reference poses (a Trajectory or a PoseTable), stamps non-decreasing.
        est: estimated poses.
        align: ``se3``, ``sim3``, ``scale`` or ``none`` (see :func:`align`).
        max_diff_s: association window, seconds.
        offset_s: added to the estimate's stamps for the association, seconds.
        by_index: pair by row index instead of by time (KITTI).
        rpe_delta: also compute the RPE with pairs this far apart (None: no RPE).
        delta_unit: ``frames`` or ``m``.

    Raises:
        InputError: too few matched poses, or an RPE delta that gives no pairs.
        ConfigError: an option out of range.
    """
    if align not in ALIGN_MODES:
        raise ConfigError(f"alignment must be one of {', '.join(ALIGN_MODES)}, got {align!r}")
    matched = associate_by_index(gt, est) if by_index else _associate(gt, est, max_diff_s, offset_s)
    need = 1 if align == "none" else MIN_PAIRS_ALIGNED
    if rpe_delta is not None:
        need = max(need, 2)
    if len(matched) < need:
        raise _too_few(matched, need, None if by_index else max_diff_s, offset_s)
    aligned, rotation, translation, scale = _align(matched.gt, matched.est, align)
    errors = ate(matched.gt, aligned)
    rpe_result = None
    if rpe_delta is not None:
        pairs = rpe_pairs(aligned, rpe_delta, delta_unit)
        if pairs.shape[0] == 0:
            raise InputError(
                f"RPE with delta {rpe_delta:g} {delta_unit} found no pose pairs among "
                f"{len(matched)} matched poses",
                hint="use a smaller --rpe-delta",
            )
        trans, rot = rpe(matched.gt, aligned, pairs)
        rpe_result = RpeResult(
            float(rpe_delta),
            delta_unit,
            pairs,
            trans,
            rot,
            ErrorStats.of(trans),
            ErrorStats.of(rot),
        )
    return EvalResult(
        alignment=align,
        matched=matched,
        aligned_est=aligned,
        rotation=rotation,
        translation=translation,
        scale=float(scale),
        ate_m=errors,
        ate=ErrorStats.of(errors),
        rpe=rpe_result,
    )


def _too_few(matched: Matched, need: int, max_diff_s: float | None, offset_s: float) -> InputError:
    if max_diff_s is None:
        return InputError(
            f"only {len(matched)} pose pair(s), at least {need} needed",
            hint="evaluate longer trajectories",
        )
    return InputError(
        f"only {len(matched)} of {matched.possible} poses matched in time "
        f"(max difference {max_diff_s:g} s, offset {offset_s:g} s), at least {need} needed",
        hint="check that both files use the same clock; widen --t-max-diff, or shift the "
        "estimate's stamps with --t-offset",
    )


__all__ = [
    "ALIGN_MODES",
    "DELTA_UNITS",
    "STAT_KEYS",
    "ErrorStats",
    "EvalResult",
    "Matched",
    "RpeResult",
    "StampedPoses",
    "align",
    "associate",
    "associate_by_index",
    "ate",
    "evaluate",
    "rpe",
    "rpe_pairs",
    "seconds_f64",
]
