"""``slamcli run ekf``: EKF landmark SLAM from odometry and range-bearing observations.

Frames arrive in time order. An :class:`~slamcli.types.OdometryFrame` with (v, ω) sets the
control applied until the next odometry stamp (the robot is first moved to the new stamp with the
previous control); one with only a pose contributes the relative motion since the previous pose.
A :class:`~slamcli.types.LandmarkFrame` moves the robot to its stamp and updates the filter with
each observation.

**Landmarks with ids** (known correspondences) are updated when the innovation passes the χ²
gate. A new id becomes a landmark once ``promote_after`` of its observations agree with each
other, unless they agree with a landmark already mapped under another id: barcode misreads come
in short bursts, and a burst must not create a landmark. **Observations without ids** are
paired by nearest neighbour or JCBB (``association``); one far outside every gate starts a
tentative landmark, promoted after ``promote_after`` pairings, deleted when it is predicted
visible but missed ``prune_tentative_misses`` times first. Confirmed landmarks that are
predicted visible and keep being missed (``prune_misses`` misses, more than ``prune_miss_ratio``
of their chances) are deleted too. Visibility is the envelope of ranges and bearings seen so far.

**Keeping the filter honest.** Wheel odometry is often the commanded velocity; its errors are
proportional to speed and turn rate, so the control noise grows with them, and a floor on the
heading noise keeps the heading uncertainty growing while the robot stands or drives straight.
When ``lockout_after`` observations of known landmarks in a row fail the gate, the filter has
become over-confident: the robot's pose covariance is inflated (``recovery_sigma_*``) and the
scan is tried again; each such recovery is counted.
"""

from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.config import setting
from slamcli.ekf.association import (
    UNMATCHED,
    Candidates,
    agree_with_mean,
    jcbb,
    nearest_neighbour,
)
from slamcli.ekf.filter import LandmarkEkf, arc_step, inverse_observation, relative_motion
from slamcli.ekf.smoother import Event, Observation, Row, Step, Velocity, smooth_path
from slamcli.errors import PipelineError
from slamcli.geometry.chi2 import chi2_quantile
from slamcli.geometry.planar import between_planar, planar_to_se3, se3_to_planar, wrap_angle
from slamcli.pipelines import PipelineBase
from slamcli.types import LandmarkFrame, LandmarkMap, OdometryFrame, SlamResult, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class LandmarkNoise:
    """The start and the noise models shared by the landmark pipelines (``ekf``, ``graph``):
    odometry noise that grows with speed and turn rate, and range-bearing noise.

    Attributes:
        start: where the (first) robot starts: ``groundtruth`` (the log's ground-truth pose at its
            first frame, when it has one) or ``origin``.
        initial_sigma_m, initial_sigma_deg: uncertainty of the starting pose.
        v_noise_speed, v_noise_turn: speed noise per m/s of speed and per rad/s of turn rate,
            as a density per √s (the error of commanded velocities grows with them).
        w_noise_speed, w_noise_turn: turn-rate noise per m/s and per rad/s, per √s.
        v_noise_floor: speed noise density when standing, m/s/√s.
        heading_noise_floor: turn-rate noise density that is always there, deg/s/√s.
        spot_turn_noise, spot_speed: turn-rate noise per rad/s of commanded turn rate when
            turning on the spot (speed below ``spot_speed``), where wheels often slip or stick.
        step_noise_rel, step_noise_floor, step_heading_noise: noise of relative-pose odometry:
            a fraction of each step's length, a floor in m, and degrees per metre travelled.
        range_sigma, range_sigma_rel: range noise: a constant (m) plus a fraction of the range.
        bearing_sigma: bearing noise, deg.
    """

    start: str = setting("groundtruth", choices=("groundtruth", "origin"))
    initial_sigma_m: float = setting(0.01, gt=0.0, unit="m")
    initial_sigma_deg: float = setting(1.0, gt=0.0, unit="deg")
    v_noise_speed: float = setting(0.15, min=0.0, unit="1/√s")
    v_noise_turn: float = setting(0.05, min=0.0, unit="m/rad/√s")
    w_noise_speed: float = setting(0.15, min=0.0, unit="rad/m/√s")
    w_noise_turn: float = setting(0.15, min=0.0, unit="1/√s")
    v_noise_floor: float = setting(0.005, min=0.0, unit="m/s/√s")
    spot_turn_noise: float = setting(1.0, min=0.0, unit="1/√s")
    spot_speed: float = setting(0.05, min=0.0, unit="m/s")
    heading_noise_floor: float = setting(0.5, min=0.0, unit="deg/s/√s")
    step_noise_rel: float = setting(0.05, min=0.0)
    step_noise_floor: float = setting(0.01, min=0.0, unit="m")
    step_heading_noise: float = setting(1.0, min=0.0, unit="deg/m")
    range_sigma: float = setting(0.15, gt=0.0, unit="m")
    range_sigma_rel: float = setting(0.01, min=0.0)
    bearing_sigma: float = setting(1.0, gt=0.0, unit="deg")

    def start_pose(self, pose: F64 | None) -> F64 | None:
        """Where the (first) robot starts, from the source's start pose (x, y, yaw) or None:
        that pose with ``start = "groundtruth"``, else None (the origin)."""
        if self.start == "groundtruth" and pose is not None:
            return np.asarray(pose, dtype=np.float64)
        return None

    def control_psd(self, v: float, w: float) -> NDArray[np.float64]:
        """(2,) noise densities of speed and turn rate (per √s), squared, while driving at
        ``v`` m/s and ``w`` rad/s."""
        av, aw = abs(v), abs(w)
        sv = self.v_noise_speed * av + self.v_noise_turn * aw + self.v_noise_floor
        turn = self.spot_turn_noise if av < self.spot_speed else self.w_noise_turn
        sw = self.w_noise_speed * av + turn * aw + np.radians(self.heading_noise_floor)
        return np.array([sv * sv, sw * sw])

    def step_covariance(self, delta: NDArray[np.float64]) -> NDArray[np.float64]:
        """(3, 3) covariance of a relative-pose odometry step ``delta`` (x, y, yaw)."""
        dist = float(np.hypot(delta[0], delta[1]))
        s = self.step_noise_rel * dist + self.step_noise_floor
        sh = np.radians(self.step_heading_noise) * dist + self.step_noise_rel * abs(float(delta[2]))
        return np.diag([s * s, s * s, sh * sh])

    def observation_covariance(self, rng: float) -> NDArray[np.float64]:
        """(2, 2) covariance of a range-bearing observation at range ``rng`` m."""
        sr = self.range_sigma + self.range_sigma_rel * rng
        sb = np.radians(self.bearing_sigma)
        return np.diag([sr * sr, sb * sb])


@dataclass(frozen=True)
class LandmarkAssociation:
    """How the landmark pipelines (``ekf``, ``graph``) pair observations with landmarks and map
    new ones.

    Attributes:
        gate_prob: χ² probability of the association gate (2 degrees of freedom).
        new_landmark_prob: an observation without id starts a landmark only when it lies
            outside this χ² probability of every landmark.
        association: pairing of observations without ids: ``nn`` or ``jcbb``.
        promote_after: pairings before a new landmark without id counts.
        promote_after_known: agreeing observations before a new id becomes a landmark (more
            than a burst of misread codes lasts).
    """

    gate_prob: float = setting(0.999, gt=0.5, lt=1.0)
    new_landmark_prob: float = setting(0.99999, gt=0.5, lt=1.0)
    association: str = setting("nn", choices=("nn", "jcbb"))
    promote_after: int = setting(3, min=1)
    promote_after_known: int = setting(6, min=1)

    @property
    def gate(self) -> float:
        """The association gate on a pairing's squared Mahalanobis distance (2 dof)."""
        return chi2_quantile(self.gate_prob, 2)

    @property
    def new_gate(self) -> float:
        """The squared Mahalanobis distance to every landmark beyond which an observation
        without id starts a landmark (2 dof)."""
        return chi2_quantile(self.new_landmark_prob, 2)

    def joint_gate(self, pairs: int) -> float:
        """JCBB's gate on the joint distance of ``pairs`` pairings (2 dof each)."""
        return _joint_gate(self.gate_prob, pairs)

    def pair(
        self, state: LandmarkEkf, zs: F64, r_covs: F64, cands: Candidates
    ) -> NDArray[np.int64]:
        """The landmark slot paired with each of a scan's observations without ids
        (``UNMATCHED`` for none), by :attr:`association` (JCBB only for two or more).

        Args:
            state: the robot and landmarks (the filter, or a view of a graph's estimate).
            zs, r_covs: (K, 2) range-bearing observations and their (K, 2, 2) covariances.
            cands: their individual compatibility with every landmark.
        """
        if self.association == "jcbb" and len(zs) > 1:
            return jcbb(state, zs, r_covs, cands, self.gate, self.joint_gate)
        return nearest_neighbour(cands, self.gate)

    def association_used(self, with_id: int, without_id: int) -> str:
        """What a run used, from its counts of observations with and without ids: ``known``,
        ``mixed`` or :attr:`association`."""
        if with_id and without_id:
            return "mixed"
        return "known" if with_id or not without_id else self.association


def usable_observations(frame: LandmarkFrame) -> tuple[NDArray[np.int64], F64]:
    """A frame's observations the landmark pipelines use: (K,) int64 ids (-1 = none) and (K, 2)
    float64 range (m, finite and > 0) and bearing (rad, wrapped to [-π, π)) rows."""
    ids = np.asarray(frame.ids, dtype=np.int64)
    zs = np.stack([frame.ranges_m, frame.bearings_rad], axis=1).astype(np.float64)
    ok = np.isfinite(zs).all(axis=1) & (zs[:, 0] > 0)
    ids, zs = ids[ok], zs[ok]
    zs[:, 1] = wrap_angle(zs[:, 1])
    return ids, zs


@dataclass(frozen=True)
class EkfConfig(LandmarkAssociation, LandmarkNoise):
    """Settings of :class:`EkfSlam`. Lengths in metres, angles in degrees, times in seconds.

    Attributes:
        iterations: linearisations of each update (1 = the plain EKF; more = the iterated
            EKF, which copes better when the heading is uncertain).
        jacobians: ``first-estimates`` evaluates the measurement Jacobians at each landmark's
            first estimate and the robot's predicted position, and the motion Jacobians between
            predicted positions (the first-estimates EKF of Huang, Mourikis and Roumeliotis), so
            that observing only landmarks mapped from the current pose cannot shrink the heading
            uncertainty, a known cause of over-confidence; ``current`` is the textbook EKF
            (and allows ``iterations`` > 1).
        smooth: write trajectory.tum smoothed against the final map (a forward localisation
            filter and a backward pass over the recorded odometry and accepted observations);
            the filter's own path is kept as trajectory_filtered.tum.
        gate_prob: χ² probability of the association and update gate (2 degrees of freedom).
        reinit_after: a landmark whose observations fail the gate this many times in a row
            while other landmarks pass is placed anew from its latest observations (it was
            mapped from misread codes).
        prune_tentative_misses: a tentative landmark missed this often while predicted visible
            is deleted.
        prune_misses, prune_miss_ratio: a confirmed landmark without id missed at least this
            often, and in more than this share of its chances, is deleted.
        max_landmarks: cap on the landmark count; further new landmarks are refused.
        merge_radius: landmarks without ids closer than this are tested for being one point
            (their difference inside the gate) and then fused.
        lockout_after: consecutive gate rejections of known landmarks that trigger a recovery.
        recovery_sigma_m, recovery_sigma_deg: standard deviations added to the robot's position
            and heading in a recovery.
    """

    iterations: int = setting(3, min=1)
    smooth: bool = setting(True)
    jacobians: str = setting("first-estimates", choices=("first-estimates", "current"))
    reinit_after: int = setting(6, min=1)
    prune_tentative_misses: int = setting(3, min=1)
    prune_misses: int = setting(10, min=1)
    prune_miss_ratio: float = setting(0.8, gt=0.0, max=1.0)
    max_landmarks: int = setting(2000, min=1)
    merge_radius: float = setting(1.0, gt=0.0, unit="m")
    lockout_after: int = setting(6, min=1)
    recovery_sigma_m: float = setting(0.1, min=0.0, unit="m")
    recovery_sigma_deg: float = setting(10.0, min=0.0, unit="deg")


@dataclass
class _Track:
    """Book-keeping of one landmark slot."""

    ident: int
    confirmed: bool
    known: bool = False
    hits: int = 1
    misses: int = 0
    rejected_streak: int = 0


@dataclass
class _Pending:
    """Observations of an id not yet mapped, as world positions with covariances."""

    points: list[F64] = field(default_factory=list)
    covs: list[F64] = field(default_factory=list)


class EkfSlam(PipelineBase):
    """EKF landmark SLAM pipeline (see the module docstring)."""

    name = "ekf"
    consumes = ("odometry", "landmarks")
    config_class = EkfConfig

    def __init__(self, config: EkfConfig | None = None) -> None:
        self.config = config or EkfConfig()
        c = self.config
        self._gate = c.gate
        self._new_gate = c.new_gate
        self._ekf: LandmarkEkf | None = None
        self._start: F64 | None = None
        self._t_ns: int | None = None
        self._control: tuple[float, float] | None = None
        self._odom_pose: F64 | None = None
        self._dr: F64 | None = None
        self._tracks: list[_Track] = []
        self._by_id: dict[int, int] = {}
        self._pending: dict[int, _Pending] = {}
        self._next_id = 0
        self._max_range = 0.0
        self._max_bearing = 0.0
        self._reject_streak = 0
        self._with_id = 0
        self._without_id = 0
        self._stamps: list[int] = []
        self._events: list[Event] = []
        self._redirect: dict[int, int] = {}
        self._start_cov = np.eye(3)
        self._poses: list[F64] = []
        self._covs: list[F64] = []
        self._dr_poses: list[F64] = []
        self._nis: list[tuple[int, float]] = []
        self._lm_count: list[tuple[int, int]] = []
        self.counts: dict[str, int] = {
            "odometry": 0,
            "observations": 0,
            "updates": 0,
            "rejected_by_gate": 0,
            "landmarks_new": 0,
            "landmarks_merged": 0,
            "landmarks_pruned": 0,
            "landmarks_reinitialised": 0,
            "ambiguous": 0,
            "capped": 0,
            "recoveries": 0,
        }

    # -- set-up -----------------------------------------------------------------------------

    def set_start(self, pose: F64 | None) -> None:
        """The starting pose (x, y, yaw), e.g. ground truth at the first frame; None = origin."""
        self._start = self.config.start_pose(pose)

    def _filter(self) -> LandmarkEkf:
        if self._ekf is None:
            c = self.config
            pose = self._start if self._start is not None else np.zeros(3)
            cov = np.diag(
                [c.initial_sigma_m**2, c.initial_sigma_m**2, np.radians(c.initial_sigma_deg) ** 2]
            )
            self._ekf = LandmarkEkf(pose, cov, first_estimates=c.jacobians == "first-estimates")
            self._start_cov = cov
            self._dr = pose.copy()
        return self._ekf

    # -- frames -----------------------------------------------------------------------------

    def process(self, frame: Any) -> None:
        if not isinstance(frame, OdometryFrame | LandmarkFrame):
            raise PipelineError(
                f"the ekf pipeline takes odometry and landmark frames, not {type(frame).__name__}"
            )
        try:
            if isinstance(frame, OdometryFrame):
                self._odometry(frame)
            else:
                self._observations(frame)
        except np.linalg.LinAlgError as exc:
            raise _diverged(frame.stamp_ns, f"a covariance became singular ({exc})") from exc
        # Readers bound each value, but a speed or rate that is in range and still absurd for
        # the log (1e8 m/s) overflows the covariance: stop here rather than write NaN poses.
        ekf = self._ekf
        if ekf is not None and not (
            np.isfinite(ekf.pose).all() and np.isfinite(ekf.pose_cov).all()
        ):
            raise _diverged(frame.stamp_ns, "the pose or its covariance is no longer finite")
        # Whether the overflow reaches infinity first depends on the floating-point path; a
        # position variance past (1,000 km)^2, or a negative one, is divergence either way.
        if ekf is not None:
            var = np.diagonal(ekf.pose_cov)[:2]
            if (var < 0.0).any() or (var > _DIVERGED_VARIANCE_M2).any():
                raise _diverged(
                    frame.stamp_ns,
                    f"the position variance reached {float(np.max(np.abs(var))):.3g} m²",
                )

    def _advance(self, stamp_ns: int) -> None:
        """Move the robot to ``stamp_ns`` with the current control."""
        ekf = self._filter()
        if self._t_ns is not None and self._control is not None and stamp_ns > self._t_ns:
            dt = (stamp_ns - self._t_ns) * 1e-9
            v, w = self._control
            psd = self.config.control_psd(v, w)
            ekf.predict_velocity(v, w, dt, psd)
            self._events.append(Velocity(dt, v, w, (float(psd[0]), float(psd[1]))))
            assert self._dr is not None
            dr = self._dr
            dr[0], dr[1], dr[2] = arc_step(dr[0], dr[1], dr[2], v, w, dt)[:3]
        if self._t_ns is None or stamp_ns > self._t_ns:
            self._t_ns = stamp_ns

    def _odometry(self, frame: OdometryFrame) -> None:
        self.counts["odometry"] += 1
        if frame.v is not None and frame.omega is not None:
            self._advance(frame.stamp_ns)
            self._control = (float(frame.v), float(frame.omega))
        elif frame.world_from_body is not None:
            ekf = self._filter()
            pose = se3_to_planar(frame.world_from_body)[0]
            if self._odom_pose is not None:
                delta = between_planar(self._odom_pose, pose)
                step_cov = self.config.step_covariance(delta)
                ekf.predict_relative(delta, step_cov)
                self._events.append(Step(delta, step_cov))
                assert self._dr is not None
                self._dr = relative_motion(self._dr, delta)[0]
            self._odom_pose = pose
            self._t_ns = frame.stamp_ns if self._t_ns is None else max(self._t_ns, frame.stamp_ns)
        else:
            raise PipelineError(
                f"odometry at {frame.stamp_ns * 1e-9:.3f} s has neither (v, omega) nor a pose"
            )
        self._record(frame.stamp_ns)

    def _observations(self, frame: LandmarkFrame) -> None:
        self._advance(frame.stamp_ns)
        ekf = self._filter()
        ids, zs = usable_observations(frame)
        self.counts["observations"] += len(zs)
        if len(zs):
            self._max_range = max(self._max_range, float(zs[:, 0].max()))
            self._max_bearing = max(self._max_bearing, float(np.abs(zs[:, 1]).max()))
        r_covs = (
            np.stack([self.config.observation_covariance(z[0]) for z in zs])
            if len(zs)
            else np.empty((0, 2, 2))
        )
        seen: set[int] = set()
        known = ids >= 0
        self._with_id += int(known.sum())
        self._without_id += int((~known).sum())
        if known.any():
            seen |= self._known(ids[known], zs[known], r_covs[known], frame.stamp_ns)
        if (~known).any():
            seen |= self._unknown(zs[~known], r_covs[~known], frame.stamp_ns)
        self._misses(seen)
        if (~known).any():
            self._merge(seen)
        if ekf.count and self.counts["updates"] % 200 == 0:
            ekf.symmetrize()
        self._record(frame.stamp_ns)
        self._lm_count.append((frame.stamp_ns, sum(t.confirmed for t in self._tracks)))

    # -- known correspondences --------------------------------------------------------------

    def _known(self, ids: NDArray[np.int64], zs: F64, r_covs: F64, stamp_ns: int) -> set[int]:
        ekf = self._filter()
        seen: set[int] = set()
        order = np.argsort(ids, kind="stable")
        retry: list[int] = []
        for k in order:
            ident = int(ids[k])
            slot = self._by_id.get(ident)
            if slot is None:
                self._pending_observation(ident, zs[k], r_covs[k])
                continue
            inn = ekf.innovation(slot, zs[k], r_covs[k])
            track = self._tracks[slot]
            if inn.d2 < self._gate:
                self._accept(inn, stamp_ns, zs[k], r_covs[k])
                track.hits += 1
                track.rejected_streak = 0
                self._pending.pop(ident, None)
                self._reject_streak = 0
                seen.add(slot)
            else:
                self.counts["rejected_by_gate"] += 1
                track.rejected_streak += 1
                self._reject_streak += 1
                retry.append(k)
                pend = self._pending.setdefault(ident, _Pending())
                lm, gr, gz = inverse_observation(ekf.pose, zs[k])
                pend.points.append(lm)
                pend.covs.append(gr @ ekf.pose_cov @ gr.T + gz @ r_covs[k] @ gz.T)
                if (
                    track.rejected_streak >= self.config.reinit_after
                    and self._reject_streak < track.rejected_streak
                ):
                    self._reinit(slot, zs[k], r_covs[k])
                    retry.pop()
        if retry and self._reject_streak >= self.config.lockout_after:
            self._recover()
            for k in retry:
                slot = self._by_id[int(ids[k])]
                inn = ekf.innovation(slot, zs[k], r_covs[k])
                if inn.d2 < self._gate:
                    self._accept(inn, stamp_ns, zs[k], r_covs[k])
                    self._tracks[slot].hits += 1
                    self._tracks[slot].rejected_streak = 0
                    seen.add(slot)
        return seen

    def _pending_observation(self, ident: int, z: F64, r_cov: F64) -> None:
        """Collect observations of an unmapped id; map it once enough of them agree."""
        ekf = self._filter()
        lm, gr, gz = inverse_observation(ekf.pose, z)
        cov = gr @ ekf.pose_cov @ gr.T + gz @ r_cov @ gz.T
        pend = self._pending.setdefault(ident, _Pending())
        pend.points.append(lm)
        pend.covs.append(cov)
        need = self.config.promote_after_known
        pts = np.array(pend.points[-need:])
        covs = np.array(pend.covs[-need:])
        if len(pts) < need or not agree_with_mean(pts, covs, self._gate):
            return
        if len(self._tracks) >= self.config.max_landmarks:
            self.counts["capped"] += 1
            return
        slot = ekf.add_landmark(z, r_cov)
        self._tracks.append(_Track(ident, confirmed=True, known=True, hits=len(pts)))
        self._by_id[ident] = slot
        self.counts["landmarks_new"] += 1
        del self._pending[ident]

    def _reinit(self, slot: int, z: F64, r_cov: F64) -> None:
        """Place a landmark anew from its latest observation (its first ones were misreads)."""
        ekf = self._filter()
        track = self._tracks[slot]
        pend = self._pending.pop(track.ident, _Pending())
        pts = np.array(pend.points[-self.config.reinit_after :])
        covs = np.array(pend.covs[-self.config.reinit_after :])
        if not agree_with_mean(pts, covs, self._gate):
            return
        self._remove(slot, pruned=False)
        new = ekf.add_landmark(z, r_cov)
        self._tracks.append(_Track(track.ident, confirmed=True, known=True, hits=1))
        self._by_id[track.ident] = new
        self.counts["landmarks_reinitialised"] += 1

    def _recover(self) -> None:
        c = self.config
        ekf = self._filter()
        sm, sh = c.recovery_sigma_m, np.radians(c.recovery_sigma_deg)
        ekf.inflate_pose(np.diag([sm * sm, sm * sm, sh * sh]))
        self.counts["recoveries"] += 1
        self._reject_streak = 0

    def _accept(self, inn: Any, stamp_ns: int, z: F64, r_cov: F64) -> None:
        ekf = self._filter()
        if self.config.iterations > 1 and not ekf.first_estimates:
            ekf.update_iterated(inn, z, r_cov, self.config.iterations)
        else:
            ekf.update(inn)
        self.counts["updates"] += 1
        self._nis.append((stamp_ns, inn.d2))
        self._events.append(Observation(self._tracks[inn.slot].ident, z, r_cov))

    # -- unknown correspondences ------------------------------------------------------------

    def _unknown(self, zs: F64, r_covs: F64, stamp_ns: int) -> set[int]:
        ekf = self._filter()
        cands = Candidates.of(ekf, zs, r_covs)
        pairing = self.config.pair(ekf, zs, r_covs, cands)
        _, nearest = cands.best()
        seen: set[int] = set()
        # Updates first (all innovations were computed before any of them), then new landmarks.
        for i in np.argsort(nearest, kind="stable"):
            slot = int(pairing[i])
            if slot == UNMATCHED:
                continue
            inn = ekf.innovation(slot, zs[i], r_covs[i])
            if inn.d2 < self._gate:
                self._accept(inn, stamp_ns, zs[i], r_covs[i])
                track = self._tracks[slot]
                track.hits += 1
                if not track.confirmed and track.hits >= self.config.promote_after:
                    track.confirmed = True
                seen.add(slot)
            else:
                self.counts["rejected_by_gate"] += 1
        for i in range(len(zs)):
            if pairing[i] != UNMATCHED:
                continue
            if nearest[i] > self._new_gate:
                if len(self._tracks) >= self.config.max_landmarks:
                    self.counts["capped"] += 1
                    continue
                slot = ekf.add_landmark(zs[i], r_covs[i])
                self._tracks.append(_Track(self._next_id, confirmed=self.config.promote_after <= 1))
                self._next_id += 1
                seen.add(slot)
                self.counts["landmarks_new"] += 1
            else:
                self.counts["ambiguous"] += 1
        return seen

    def _merge(self, seen: set[int]) -> None:
        """Fuse a landmark without id seen in this scan with another one (not seen in it) that
        turns out to be the same point."""
        ekf = self._filter()
        if ekf.count < 2:
            return
        lm = ekf.landmarks()
        for slot in sorted(seen, reverse=True):
            if slot >= ekf.count or self._tracks[slot].known:
                continue
            near = np.flatnonzero(np.hypot(*(lm - lm[slot]).T) < self.config.merge_radius)
            for other in near[near != slot].tolist():
                # Two landmarks seen in one scan are two points, however close.
                if other in seen or self._tracks[other].known:
                    continue
                if ekf.merge_distance(slot, other) < self._gate:
                    keep, drop = (slot, other)
                    if self._tracks[other].hits > self._tracks[slot].hits:
                        keep, drop = other, slot
                    self._redirect[self._tracks[drop].ident] = self._tracks[keep].ident
                    self._tracks[keep].hits += self._tracks[drop].hits
                    self._tracks[keep].confirmed |= self._tracks[drop].confirmed
                    last = ekf.count - 1
                    ekf.merge_landmarks(keep, drop)
                    self._tracks[drop] = self._tracks[last]
                    self._tracks.pop()
                    self.counts["landmarks_merged"] += 1
                    # Slots moved: one merge per scan; the next scan looks again.
                    return

    def _misses(self, seen: set[int]) -> None:
        """Count misses of landmarks predicted visible; delete the ones that keep missing."""
        ekf = self._filter()
        if not ekf.count or self._max_range <= 0:
            return
        lm = ekf.landmarks()
        pose = ekf.pose
        d = lm - pose[:2]
        rng = np.hypot(d[:, 0], d[:, 1])
        brg = np.abs(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose[2]))
        visible = (rng < 0.8 * self._max_range) & (brg < 0.8 * self._max_bearing)
        c = self.config
        doomed: list[int] = []
        for slot in np.nonzero(visible)[0].tolist():
            track = self._tracks[slot]
            if slot in seen or track.known:
                continue
            track.misses += 1
            if not track.confirmed:
                if track.misses >= c.prune_tentative_misses:
                    doomed.append(slot)
            elif track.misses >= c.prune_misses and track.misses > c.prune_miss_ratio * (
                track.misses + track.hits
            ):
                doomed.append(slot)
        for slot in sorted(doomed, reverse=True):
            self._remove(slot)

    def _remove(self, slot: int, pruned: bool = True) -> None:
        ekf = self._filter()
        last = ekf.count - 1
        ekf.remove_landmark(slot)
        self._tracks[slot] = self._tracks[last]
        self._tracks.pop()
        if slot < len(self._tracks) and self._tracks[slot].known:
            self._by_id[self._tracks[slot].ident] = slot
        if pruned:
            self.counts["landmarks_pruned"] += 1

    # -- output -----------------------------------------------------------------------------

    def _record(self, stamp_ns: int) -> None:
        ekf = self._filter()
        assert self._dr is not None
        if self._stamps and self._stamps[-1] >= stamp_ns:
            self._poses[-1] = ekf.pose.copy()
            self._covs[-1] = ekf.pose_cov.copy()
            self._dr_poses[-1] = self._dr.copy()
            self._events.append(Row(len(self._stamps) - 1))
            return
        self._stamps.append(stamp_ns)
        self._poses.append(ekf.pose.copy())
        self._covs.append(ekf.pose_cov.copy())
        self._dr_poses.append(self._dr.copy())
        self._events.append(Row(len(self._stamps) - 1))

    def finish(self) -> SlamResult:
        if not self._stamps:
            raise PipelineError("the log gave the ekf pipeline no odometry or observations")
        ekf = self._filter()
        c = self.config
        stamps = np.asarray(self._stamps, dtype=np.int64)
        poses = np.asarray(self._poses)
        keep = [i for i, t in enumerate(self._tracks) if t.confirmed]
        lm_ids = np.array([self._tracks[i].ident for i in keep], dtype=np.int64)
        xy = ekf.landmarks()[keep] if keep else np.empty((0, 2))
        covs = ekf.landmark_covs()[keep] if keep else np.empty((0, 2, 2))
        order = np.argsort(lm_ids, kind="stable")
        nis = np.array(self._nis, dtype=np.float64).reshape(-1, 2)
        if len(nis):
            nis[:, 0] *= 1e-9
        counts = dict(self.counts)
        counts["landmarks"] = len(keep)
        counts["landmarks_tentative"] = len(self._tracks) - len(keep)
        metrics: dict[str, Any] = {
            "association": c.association_used(self._with_id, self._without_id)
        }
        if len(nis):
            lo, hi = chi2_quantile(0.025, 2), chi2_quantile(0.975, 2)
            metrics["nis"] = {
                "mean": float(nis[:, 1].mean()),
                "median": float(np.median(nis[:, 1])),
                "dof": 2,
                "band95": [float(lo), float(hi)],
                "fraction_in_band": float(np.mean((nis[:, 1] >= lo) & (nis[:, 1] <= hi))),
            }
        series = {"nis": nis}
        if self._lm_count:
            lc = np.array(self._lm_count, dtype=np.float64)
            lc[:, 0] *= 1e-9
            series["landmarks"] = lc
        filtered = Trajectory(stamps, planar_to_se3(poses))
        trajectory = filtered
        if c.smooth:
            final = {
                self._tracks[i].ident: (ekf.landmark(i).copy(), ekf.landmark_cov(i).copy())
                for i in keep
            }

            def lookup(ident: int) -> tuple[F64, F64] | None:
                while ident in self._redirect:
                    ident = self._redirect[ident]
                return final.get(ident)

            start = self._start if self._start is not None else np.zeros(3)
            try:
                smoothed, _, used = smooth_path(
                    self._events, len(stamps), start, self._start_cov, lookup, self._gate
                )
            except np.linalg.LinAlgError as exc:
                raise _diverged(
                    None, f"smoothing the path met a singular covariance ({exc})"
                ) from exc
            trajectory = Trajectory(stamps, planar_to_se3(smoothed))
            counts["smoother_observations"] = used
        return SlamResult(
            trajectory=trajectory,
            filtered=filtered if trajectory is not filtered else None,
            landmarks=LandmarkMap(lm_ids[order], xy[order], covs[order]),
            pose_covariances=np.asarray(self._covs),
            dead_reckoning=Trajectory(stamps, planar_to_se3(np.asarray(self._dr_poses))),
            series=series,
            metrics=metrics,
            counts=counts,
        )


@functools.lru_cache(maxsize=256)
def _joint_gate(p: float, pairs: int) -> float:
    return chi2_quantile(p, 2 * pairs)


_DIVERGED_VARIANCE_M2 = 1e12
"""A position variance past this (a standard deviation of 1,000 km), or a negative one, means
the filter has diverged."""


def _diverged(stamp_ns: int | None, why: str) -> PipelineError:
    at = "" if stamp_ns is None else f" at t={stamp_ns * 1e-9:.3f} s"
    return PipelineError(
        f"the EKF diverged{at}: {why}",
        hint="check the odometry (speeds, rates) and the observations for absurd values",
    )
