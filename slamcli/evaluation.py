"""Trajectory accuracy: ATE and RPE with Umeyama SE(3)/Sim(3) or planar SE(2) alignment, and
the relative errors of Kümmerle et al. (2009) over a ``.relations`` file.

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
  ``--correct_scale``), ``none``; and ``se2``, the planar rigid fit of x, y and yaw about +z
  (:func:`~slamcli.geometry.rigid_fit_2d` on the x-y positions), which evo does not have.
- **ATE**: distances between matched positions after alignment (evo APE, translation part); with
  ``se2`` distances in the x-y plane.
- **RPE** (``--delta N --delta_unit f|m``, translation part and ``angle_deg``): relative poses
  between non-overlapping consecutive pairs of matched poses: every N-th pose, or a new pose
  whenever the path travelled since the last one reaches N metres, or (``seconds``, not in evo) the
  first pose at least N seconds after the last one. The estimate is aligned first, as
  ``evo_rpe --align`` does. A rigid alignment leaves relative poses unchanged, but ``sim3`` and
  ``scale`` scale their translations, and with ``m`` the path length that picks the pairs is
  measured on the aligned estimate.
- **Planar RPE** (with ``se2``, and :func:`planar_rpe`): as Kümmerle et al. (2009) define it for
  SE(2). Every pose is taken as (x, y, yaw), yaw the heading of the body x axis; for a pair
  (i, j) the relative poses ``δ* = gt_i⁻¹ gt_j`` and ``δ = est_i⁻¹ est_j`` give the translation
  error ``|t(δ) - t(δ*)|`` (the norm of the translation of ``δ*⁻¹ δ``) and the rotation error
  ``|wrap(yaw(δ) - yaw(δ*))|``.
- **Relations** (:func:`relations_error`): a ``.relations`` file
  (:mod:`slamcli.formats.relations`) lists reference motions between the poses at two stamps.
  Each stamp takes the estimate's pose of nearest stamp (after the offset) within
  ``max_diff_s``; a relation without both is counted as missing. The errors are those of the
  RPE between the relation and the estimate's motion: planar as above, or in SE(3).
- **Statistics**: rmse, mean, median, std (population, ddof=0), min, max, sse.

Times are int64 nanoseconds. The association alone works in float64 seconds, each stamp being
the double nearest to its exact value (what parsing the file's decimal text gives), because
that is what evo compares: a stamp exactly halfway between two others, or exactly ``max_diff``
away, is decided by the rounding of those doubles, and real files contain such cases.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.geometry import (
    between_planar,
    compose,
    inverse,
    planar_to_se3,
    rigid_fit_2d,
    se3_to_planar,
    so3_log,
    umeyama,
    wrap_angle,
)

if TYPE_CHECKING:
    from slamcli.formats.relations import Relations

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

AlignMode = Literal["se3", "sim3", "scale", "se2", "none"]
DeltaUnit = Literal["frames", "m", "seconds"]
ALIGN_MODES: tuple[str, ...] = ("se3", "sim3", "scale", "se2", "none")
DELTA_UNITS: tuple[str, ...] = ("frames", "m", "seconds")
STAT_KEYS: tuple[str, ...] = ("rmse", "mean", "median", "std", "min", "max", "sse")

MIN_PAIRS_ALIGNED = 3
"""Fewest matched poses for an alignment (Umeyama needs three non-collinear points)."""

_NS_PER_S = 1_000_000_000

PLANAR_TILT_DEG = 10.0
"""With ``se2``, a warning when a matched pose's body z axis tilts more than this from the
world's: its yaw (the heading of the body x axis) is then not the planar heading."""


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
        delta_unit: ``frames``, ``m`` or ``seconds``.
        pairs: (K, 2) int64 indices into the matched poses (i, j) of each relative pose.
        trans_m: (K,) float64 translation error of each relative pose, metres.
        rot_deg: (K,) float64 rotation error of each relative pose, degrees.
        trans: statistics of ``trans_m``.
        rot: statistics of ``rot_deg``.
        planar: errors of (x, y, yaw) poses in SE(2) (Kümmerle), not in SE(3).
    """

    delta: float
    delta_unit: str
    pairs: I64
    trans_m: F64
    rot_deg: F64
    trans: ErrorStats
    rot: ErrorStats
    planar: bool = False

    @property
    def count(self) -> int:
        """How many pose pairs were compared."""
        return int(self.pairs.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """``{"trans": {stats}, "rot_deg": {stats}}``; planar errors also give ``"pairs"`` (the
        count) first, as Kümmerle's figures are reported with it."""
        out: dict[str, Any] = {"pairs": self.count} if self.planar else {}
        out["trans"] = self.trans.to_dict()
        out["rot_deg"] = self.rot.to_dict()
        return out


@dataclass(frozen=True)
class RelationsResult:
    """Errors of an estimate's relative motions against reference relations.

    Attributes:
        relations: how many relations were given.
        used: (K,) int64 rows of the relations compared.
        missing: (R,) int64 rows of the relations without an estimated pose within the
            association window of t1 or of t2 (K + R = ``relations``).
        est_pairs: (K, 2) int64 rows of the estimate taken for t1 and t2 of each used relation.
        trans_m: (K,) float64 translation error of each used relation, metres.
        rot_deg: (K,) float64 rotation error of each used relation, degrees.
        trans: statistics of ``trans_m``.
        rot: statistics of ``rot_deg``.
        planar: errors of (x, y, yaw) motions in SE(2) (Kümmerle), not in SE(3).
        path: the relations file, when read from one.
    """

    relations: int
    used: I64
    missing: I64
    est_pairs: I64
    trans_m: F64
    rot_deg: F64
    trans: ErrorStats
    rot: ErrorStats
    planar: bool
    path: str | None = None

    @property
    def pairs(self) -> int:
        """How many relations were compared."""
        return int(self.used.shape[0])

    def to_dict(self) -> dict[str, Any]:
        """``{["file"], "relations", "pairs", "missing", "planar", "trans": {stats},
        "rot_deg": {stats}}``."""
        out: dict[str, Any] = {"file": self.path} if self.path is not None else {}
        out.update(
            relations=self.relations,
            pairs=self.pairs,
            missing=int(self.missing.size),
            planar=self.planar,
            trans=self.trans.to_dict(),
            rot_deg=self.rot.to_dict(),
        )
        return out


@dataclass(frozen=True)
class EvalResult:
    """Everything :func:`evaluate` computed.

    Attributes:
        alignment: ``se3``, ``sim3``, ``scale``, ``se2`` or ``none``.
        matched: the paired poses (indices and stamps, for plots and run records).
        aligned_est: (M, 4, 4) float64 matched estimate after alignment.
        rotation: (3, 3) float64 and translation: (3,) float64 metres and scale of the
            alignment ``p_gt ≈ scale * rotation @ p_est + translation``.
        ate_m: (M,) float64 position error of each pair after alignment, metres (in the x-y
            plane with ``se2``).
        ate: statistics of ``ate_m``.
        rpe: relative pose errors, when asked for.
        relations: errors over reference relations, when given.
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
    relations: RelationsResult | None = None

    @property
    def pairs(self) -> int:
        return len(self.matched)

    def to_dict(self) -> dict[str, Any]:
        """``{"alignment", "pairs", "ate": {stats}, ["rpe": {...}], ["relations": {...}],
        "scale"}`` (see :meth:`RpeResult.to_dict`, :meth:`RelationsResult.to_dict`)."""
        out: dict[str, Any] = {
            "alignment": self.alignment,
            "pairs": self.pairs,
            "ate": self.ate.to_dict(),
        }
        if self.rpe is not None:
            out["rpe"] = self.rpe.to_dict()
        if self.relations is not None:
            out["relations"] = self.relations.to_dict()
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


def _check_window(max_diff_s: float, offset_s: float) -> None:
    if not (max_diff_s >= 0.0 and np.isfinite(max_diff_s)):
        raise ConfigError(f"the association window must be >= 0 seconds, got {max_diff_s}")
    if not np.isfinite(offset_s):
        raise ConfigError(f"the time offset must be a finite number of seconds, got {offset_s}")


def _associate(gt: StampedPoses, est: StampedPoses, max_diff_s: float, offset_s: float) -> Matched:
    _check_window(max_diff_s, offset_s)
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
            scale only, no rotation or translation), ``se2`` (a rotation about +z and an x-y
            translation fitted on the x-y positions; z is left as it is) or ``none``.

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
    if mode == "se2":
        fit, _ = rigid_fit_2d(est[:, :2, 3], np.asarray(gt, dtype=np.float64)[:, :2, 3])
        transform = planar_to_se3(fit)[0]
        return compose(transform, est), transform[:3, :3], transform[:3, 3], scale
    r, t, s = umeyama(est[:, :3, 3], np.asarray(gt, dtype=np.float64)[:, :3, 3], mode != "se3")
    aligned = est.copy()
    aligned[:, :3, 3] *= s
    if mode == "scale":
        return aligned, rotation, translation, s
    transform = np.eye(4)
    transform[:3, :3], transform[:3, 3] = r, t
    return compose(transform, aligned), r, t, s


_align = align


def ate(gt: F64, aligned_est: F64, planar: bool = False) -> F64:
    """(M,) position errors in metres between (M, 4, 4) ground truth and aligned estimate; with
    ``planar``, in the x-y plane."""
    dims = 2 if planar else 3
    diff = np.asarray(aligned_est)[:, :dims, 3] - np.asarray(gt)[:, :dims, 3]
    return np.linalg.norm(diff, axis=1)


def rpe_pairs(
    est: F64, delta: float, delta_unit: str = "frames", stamps_ns: I64 | None = None
) -> I64:
    """(K, 2) index pairs for the RPE, chosen on the (aligned) estimate (M, 4, 4).

    ``frames``: (0, N), (N, 2N), ...; ``m``: each pair ends at the first pose where the path
    travelled since the pair's start reaches ``delta`` metres; ``seconds``: each pair ends at the
    first pose whose stamp (``stamps_ns``, (M,) non-decreasing) is at least ``delta`` seconds
    after the pair's start. Consecutive pairs share their end and start pose.
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
    elif delta_unit == "seconds":
        if not (delta > 0.0 and np.isfinite(delta)):
            raise ConfigError(f"RPE delta in seconds must be a finite number > 0, got {delta}")
        if stamps_ns is None or np.asarray(stamps_ns).shape != (n,):
            raise ConfigError("RPE delta in seconds needs one stamp per pose")
        ids = _ids_by_time(np.asarray(stamps_ns, dtype=np.int64), max(1, round(float(delta) * 1e9)))
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


def _ids_by_time(stamps: I64, delta_ns: int) -> I64:
    """Start of every pair when each pair ends at the first stamp at least ``delta_ns`` (>= 1)
    after its start."""
    ids = [0]
    last = int(stamps[-1])
    while True:
        target = int(stamps[ids[-1]]) + delta_ns  # a Python int: no int64 overflow
        if target > last:
            break
        # Some stamp is >= target > the start's, so the index is in range and after the start.
        ids.append(int(np.searchsorted(stamps, target, side="left")))
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
    return _se3_errors(compose(inverse(q[i]), q[j]), compose(inverse(p[i]), p[j]))


def rpe_planar(gt: F64, est: F64, pairs: I64) -> tuple[F64, F64]:
    """Relative pose errors in SE(2) of (K, 2) index pairs, as Kümmerle et al. (2009) define them.

    Every (M, 4, 4) pose is taken as (x, y, yaw), yaw the heading of its body x axis. For a pair
    (i, j), with ``δ* = gt_i⁻¹ gt_j`` and ``δ = est_i⁻¹ est_j``, the translation error is
    ``|t(δ) - t(δ*)|`` (the translation norm of ``δ*⁻¹ δ``) and the rotation error
    ``|wrap(yaw(δ) - yaw(δ*))|``. A planar rigid alignment of the estimate changes neither.

    Returns:
        (K,) translation errors in metres and (K,) rotation errors in degrees.
    """
    g = se3_to_planar(gt)
    e = se3_to_planar(est)
    i, j = pairs[:, 0], pairs[:, 1]
    return _planar_errors(between_planar(g[i], g[j]), between_planar(e[i], e[j]))


def _se3_errors(reference: F64, estimated: F64) -> tuple[F64, F64]:
    """Translation norm (m) and rotation angle (deg) of ``reference⁻¹ estimated``, (K, 4, 4)."""
    err = compose(inverse(reference), estimated)
    trans = np.linalg.norm(err[:, :3, 3], axis=1)
    rot = np.rad2deg(np.linalg.norm(so3_log(err[:, :3, :3]), axis=1))
    return trans, rot


def _planar_errors(reference: F64, estimated: F64) -> tuple[F64, F64]:
    """Translation (m) and |wrapped yaw| (deg) differences of (K, 3) x, y, yaw motions."""
    trans = np.linalg.norm(estimated[:, :2] - reference[:, :2], axis=1)
    rot = np.rad2deg(np.abs(wrap_angle(estimated[:, 2] - reference[:, 2])))
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
    relations: Relations | None = None,
) -> EvalResult:
    """Associate, align and measure an estimated trajectory against ground truth.

    Args:
        gt: reference poses (a Trajectory or a PoseTable), stamps non-decreasing.
        est: estimated poses.
        align: ``se3``, ``sim3``, ``scale``, ``se2`` or ``none`` (see :func:`align`). With
            ``se2`` the ATE is measured in the x-y plane and the RPE and relation errors in
            SE(2) (:func:`rpe_planar`).
        max_diff_s: association window, seconds.
        offset_s: added to the estimate's stamps for the association, seconds.
        by_index: pair by row index instead of by time (KITTI).
        rpe_delta: also compute the RPE with pairs this far apart (None: no RPE).
        delta_unit: ``frames``, ``m`` or ``seconds``.
        relations: also compute the errors over these reference relations
            (:func:`relations_error`, with the same window and offset, on the estimate scaled
            by the alignment's scale).

    Raises:
        InputError: too few matched poses, an RPE delta that gives no pairs, or no relation
            with estimated poses at both ends.
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
    planar = align == "se2"
    if planar:
        _warn_if_tilted(matched.gt, "ground truth")
        _warn_if_tilted(matched.est, "estimate")
    aligned, rotation, translation, scale = _align(matched.gt, matched.est, align)
    errors = ate(matched.gt, aligned, planar)
    rpe_result = None
    if rpe_delta is not None:
        rpe_result = _rpe_result(matched, aligned, rpe_delta, delta_unit, planar)
    relations_result = None
    if relations is not None:
        relations_result = relations_error(
            est, relations, max_diff_s, offset_s=offset_s, planar=planar, scale=float(scale)
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
        relations=relations_result,
    )


def _rpe_result(
    matched: Matched, aligned: F64, delta: float, delta_unit: str, planar: bool
) -> RpeResult:
    """The RPE of the matched poses, ``aligned`` being the aligned estimate."""
    pairs = rpe_pairs(aligned, delta, delta_unit, matched.stamps_ns)
    if pairs.shape[0] == 0:
        raise InputError(
            f"RPE with delta {delta:g} {delta_unit} found no pose pairs among "
            f"{len(matched)} matched poses",
            hint="use a smaller --rpe-delta",
        )
    trans, rot = (rpe_planar if planar else rpe)(matched.gt, aligned, pairs)
    return RpeResult(
        float(delta),
        delta_unit,
        pairs,
        trans,
        rot,
        ErrorStats.of(trans),
        ErrorStats.of(rot),
        planar,
    )


def _warn_if_tilted(poses: F64, name: str) -> None:
    """A warning when planar figures are asked of poses that are not planar."""
    tilt = np.rad2deg(np.arccos(np.clip(np.asarray(poses)[:, 2, 2], -1.0, 1.0)))
    worst = float(np.max(tilt))
    if worst > PLANAR_TILT_DEG:
        log.warning(
            "planar evaluation takes each pose's yaw as the heading of its body x axis, but the "
            "%s's body z axis tilts up to %.1f deg from the world's z axis (pose %d); are these "
            "the poses of a planar robot?",
            name,
            worst,
            int(np.argmax(tilt)),
        )


def planar_rpe(
    gt: StampedPoses,
    est: StampedPoses,
    delta_s: float,
    max_diff_s: float = 0.01,
    *,
    offset_s: float = 0.0,
) -> RpeResult:
    """Relative pose errors in SE(2) (Kümmerle et al. 2009) over pose pairs ``delta_s`` apart.

    The poses are associated as in :func:`associate`; the pairs are consecutive, each ending at
    the first matched pose at least ``delta_s`` seconds after its start (:func:`rpe_pairs`,
    unit ``seconds``), and the errors are those of :func:`rpe_planar`. No alignment is needed: a
    planar rigid motion of the estimate leaves its relative poses unchanged.

    Args:
        gt: reference poses (a Trajectory or a PoseTable), stamps non-decreasing.
        est: estimated poses.
        delta_s: the pair spacing, seconds (> 0).
        max_diff_s: association window, seconds.
        offset_s: added to the estimate's stamps for the association, seconds.

    Raises:
        InputError: fewer than two matched poses, or no pair ``delta_s`` apart.
        ConfigError: an option out of range.
    """
    matched = associate(gt, est, max_diff_s, offset_s)
    if len(matched) < 2:
        raise _too_few(matched, 2, max_diff_s, offset_s)
    return _rpe_result(matched, matched.est, delta_s, "seconds", planar=True)


def relations_error(
    est: StampedPoses,
    relations: Relations,
    max_diff_s: float = 0.01,
    *,
    offset_s: float = 0.0,
    planar: bool = True,
    scale: float = 1.0,
) -> RelationsResult:
    """Errors of the estimate's motions against reference relations (Kümmerle et al. 2009).

    Each relation's stamps t1 and t2 take the estimate's poses of nearest stamp (plus
    ``offset_s``) within ``max_diff_s``, with evo's tie rules (:func:`associate`); a relation
    lacking either is counted as missing. The estimate's motion ``est(t1)⁻¹ est(t2)`` is
    compared with the relation's: in SE(2) as :func:`rpe_planar` does (``planar``), otherwise
    as :func:`rpe` does in SE(3). For planar poses and relations the two agree.

    Args:
        est: estimated poses, stamps non-decreasing.
        relations: reference motions (:func:`slamcli.formats.relations.read_relations`).
        max_diff_s: largest accepted difference between a relation's stamp and an estimated
            pose's, seconds.
        offset_s: added to the estimate's stamps, seconds.
        planar: errors in SE(2) (x, y, yaw) rather than SE(3).
        scale: the estimate's translations are multiplied by this first (a Sim(3) alignment's
            scale; 1 for rigid ones, which leave relative motions unchanged).

    Raises:
        InputError: no relations, or none with estimated poses at both ends.
        ConfigError: an option out of range.
    """
    _check_window(max_diff_s, offset_s)
    if not (scale > 0.0 and np.isfinite(scale)):
        raise ConfigError(f"the estimate's scale must be a finite number > 0, got {scale}")
    stamps, poses = _checked(est, "estimate")
    source = str(relations.path) if relations.path is not None else "relations"
    if len(relations) == 0:
        raise InputError(f"{source}: no relations to evaluate")
    est_s = seconds_f64(stamps) + offset_s
    first = _nearest_or_missing(seconds_f64(relations.t1_ns), est_s, max_diff_s)
    second = _nearest_or_missing(seconds_f64(relations.t2_ns), est_s, max_diff_s)
    ok = (first >= 0) & (second >= 0)
    used = np.flatnonzero(ok).astype(np.int64)
    if used.size == 0:
        raise InputError(
            f"{source}: none of the {len(relations)} relations has estimated poses within "
            f"{max_diff_s:g} s of both its stamps (offset {offset_s:g} s)",
            hint="check that the relations and the estimate use the same clock; widen "
            "--t-max-diff, or shift the estimate's stamps with --t-offset",
        )
    a, b = poses[first[used]], poses[second[used]]
    if scale != 1.0:
        a, b = a.copy(), b.copy()
        a[:, :3, 3] *= scale
        b[:, :3, 3] *= scale
    reference = relations.first_from_second[used]
    if planar:
        estimated = between_planar(se3_to_planar(a), se3_to_planar(b))
        trans, rot = _planar_errors(se3_to_planar(reference), estimated)
    else:
        trans, rot = _se3_errors(reference, compose(inverse(a), b))
    return RelationsResult(
        relations=len(relations),
        used=used,
        missing=np.flatnonzero(~ok).astype(np.int64),
        est_pairs=np.stack([first[used], second[used]], axis=1),
        trans_m=trans,
        rot_deg=rot,
        trans=ErrorStats.of(trans),
        rot=ErrorStats.of(rot),
        planar=planar,
        path=None if relations.path is None else str(relations.path),
    )


def _nearest_or_missing(query: F64, stamps: F64, max_diff: float) -> I64:
    """For each query stamp, the row of the nearest of sorted ``stamps`` within ``max_diff``,
    or -1."""
    out = np.full(query.shape[0], -1, dtype=np.int64)
    found, rows = _nearest(query, stamps, max_diff)
    out[found] = rows
    return out


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
    "RelationsResult",
    "RpeResult",
    "StampedPoses",
    "align",
    "associate",
    "associate_by_index",
    "ate",
    "evaluate",
    "planar_rpe",
    "relations_error",
    "rpe",
    "rpe_pairs",
    "rpe_planar",
    "seconds_f64",
]
