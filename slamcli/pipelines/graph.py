"""``slamcli run graph``: landmark SLAM as a factor graph (GTSAM), one robot or several.

Each robot's odometry is integrated between **keyposes** (one at every observation frame, and
one every ``keypose_interval`` s without observations) with the EKF's motion model, so each
``BetweenFactorPose2`` carries the covariance that model grows over the interval. Observations
become ``BearingRangeFactor2D`` factors (Huber kernel) to ``Point2`` landmarks.

**Association.** A keypose is predicted from the current estimate of the previous one and the
odometry; its uncertainty grows from a floor (reset whenever observations were accepted) with
the odometry's. Known ids: an observation joins its landmark when the innovation passes the χ²
gate; a new id becomes a landmark once ``promote_after_known`` of its observations agree with
each other (barcode misreads come in short bursts, and a burst must not create a landmark), and
then they all become factors. Unknown ids: nearest neighbour or JCBB
(:mod:`slamcli.ekf.association`) against the current landmark estimates; an observation far
outside every gate starts a landmark, written out once it has ``promote_after`` observations.

**Solvers.** ``isam2`` updates the estimate every ``update_every`` keyposes with observations;
``batch`` builds the same graph and runs Levenberg–Marquardt every ``batch_every`` such updates
(for the association) and at the end.

**Several robots** (frames tagged by :class:`~slamcli.formats.landmarks.RobotFrame`): one
graph. The first robot anchors the world frame (a prior at its start, as ``run ekf``: the
ground truth or the origin). The others start at unknown poses: their keyposes are held back,
dead-reckoned in their own frame, until ``align_min_landmarks`` of the landmarks they saw are
mapped; a 2-D rigid fit of their early landmark positions onto the map (by id) places them, and
their held keyposes then enter the graph as if live, with only a very weak prior on their first
pose. A sighting of one robot by another becomes a ``BearingRangeFactorPose2`` from the
observer's keypose to a keypose of the seen robot at the same instant.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, cast

import numpy as np
from numpy.typing import NDArray

from slamcli.config import setting
from slamcli.ekf.association import UNMATCHED, Candidates, agree_with_mean
from slamcli.ekf.filter import inverse_observation, observe_jacobians, relative_motion
from slamcli.errors import PipelineError
from slamcli.geometry.align import rigid_fit_2d
from slamcli.geometry.planar import (
    between_planar,
    compose_planar,
    planar_to_se3,
    se3_to_planar,
    wrap_angle,
)
from slamcli.graphs.landmark_graph import (
    Backend,
    Relative,
    between_covariance,
    blend_dense,
    landmark_key,
    pose_key,
)
from slamcli.pipelines import PipelineBase
from slamcli.pipelines.ekf import LandmarkAssociation, LandmarkNoise, usable_observations
from slamcli.types import LandmarkFrame, LandmarkMap, OdometryFrame, SlamResult, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class GraphConfig(LandmarkAssociation, LandmarkNoise):
    """Settings of :class:`GraphSlam`. Lengths in metres, angles in degrees, times in seconds.

    Attributes:
        solver: ``isam2`` (incremental) or ``batch`` (Levenberg–Marquardt).
        batch_every: with ``batch``, solver updates between two solves.
        update_every: keyposes with observations between two solver updates (the new ones
            are predicted from the last estimate meanwhile).
        keypose_interval: a keypose at least this often without observations, s.
        odometry_floor_m, odometry_floor_deg: standard deviations added to every odometry
            factor, so that none is singular.
        robust_width: Huber kernel width on the whitened range-bearing residual (0 = none).
        promote_after: observations a landmark without id needs to be written out.
        pose_sigma_m, pose_sigma_deg: uncertainty of a keypose's estimate after observations,
            the floor of the association's predicted pose uncertainty.
        landmark_sigma_m: uncertainty of a landmark's estimate, for the association.
        initial_sigma_m, initial_sigma_deg: prior on the first robot's start.
        align_min_landmarks: mapped landmarks another robot must have seen to be placed.
        align_max_rms: largest RMS residual of that rigid fit, m.
    """

    solver: str = setting("isam2", choices=("isam2", "batch"))
    batch_every: int = setting(5, min=1)
    update_every: int = setting(10, min=1)
    keypose_interval: float = setting(1.0, gt=0.0, unit="s")
    odometry_floor_m: float = setting(0.001, gt=0.0, unit="m")
    odometry_floor_deg: float = setting(0.05, gt=0.0, unit="deg")
    robust_width: float = setting(2.0, min=0.0)
    pose_sigma_m: float = setting(0.05, gt=0.0, unit="m")
    pose_sigma_deg: float = setting(2.0, gt=0.0, unit="deg")
    landmark_sigma_m: float = setting(0.1, gt=0.0, unit="m")
    align_min_landmarks: int = setting(3, min=2)
    align_max_rms: float = setting(0.5, gt=0.0, unit="m")


WEAK_PRIOR_SIGMA_M = 1000.0
"""Standard deviation of the prior on a placed robot's first pose (m; the heading gets π):
enough to keep the system well posed, far too weak to pull the pose."""


@dataclass
class _Key:
    """A keypose: its stamp, the odometry from the previous keypose and what was seen there."""

    stamp_ns: int
    delta: F64
    cov: F64
    ids: list[int] = field(default_factory=list)
    zs: list[F64] = field(default_factory=list)


@dataclass
class _Robot:
    """One robot's state: odometry integration, keyposes and the rows of its dense path."""

    ident: int
    placed: bool = False
    t_ns: int | None = None
    control: tuple[float, float] | None = None
    odom_pose: F64 | None = None
    rel: Relative = field(default_factory=Relative)
    keys: list[_Key] = field(default_factory=list)
    done: int = 0
    offset: F64 | None = None
    gate_cov: F64 | None = None
    local: list[F64] = field(default_factory=list)
    rows_t: list[int] = field(default_factory=list)
    rows_k: list[int] = field(default_factory=list)
    rows_rel: list[F64] = field(default_factory=list)


@dataclass
class _Mark:
    """A landmark: its id, how it was found and how often it was observed."""

    ident: int
    known: bool
    hits: int = 1


@dataclass
class _Pending:
    """Observations of an id not yet mapped: world points, covariances, their keyposes."""

    points: list[F64] = field(default_factory=list)
    covs: list[F64] = field(default_factory=list)
    obs: list[tuple[int, int, F64, F64]] = field(default_factory=list)


class _View:
    """The current estimate seen as an EKF state (robot pose and landmarks, block-diagonal
    covariance), for :mod:`slamcli.ekf.association`."""

    def __init__(self, pose: F64, pose_cov: F64, points: F64, point_var: float) -> None:
        self.pose = pose
        self.points = points
        self.count = len(points)
        self.dim = 3 + 2 * self.count
        self.P = np.zeros((self.dim, self.dim))
        self.P[:3, :3] = pose_cov
        idx = np.arange(3, self.dim)
        self.P[idx, idx] = point_var

    def predicted(self, slot: int) -> tuple[F64, F64]:
        zhat, hr, hl = observe_jacobians(self.pose, self.points[slot])
        return zhat, np.hstack([hr, hl])

    def innovations_all(self, z: F64, r_cov: F64) -> tuple[F64, F64, F64]:
        d = self.points - self.pose[:2]
        q = np.maximum(np.sum(d * d, axis=1), 1e-12)
        r = np.sqrt(q)
        nu = np.stack(
            [z[0] - r, wrap_angle(z[1] - (np.arctan2(d[:, 1], d[:, 0]) - self.pose[2]))], axis=1
        )
        hl = np.empty((self.count, 2, 2))
        hl[:, 0, 0], hl[:, 0, 1] = d[:, 0] / r, d[:, 1] / r
        hl[:, 1, 0], hl[:, 1, 1] = -d[:, 1] / q, d[:, 0] / q
        hr = np.zeros((self.count, 2, 3))
        hr[:, :, :2] = -hl
        hr[:, 1, 2] = -1.0
        var = self.P[3, 3] if self.count else 0.0
        s = hr @ self.P[:3, :3] @ np.transpose(hr, (0, 2, 1))
        s = s + var * hl @ np.transpose(hl, (0, 2, 1)) + r_cov
        d2 = np.einsum("ni,ni->n", nu, np.linalg.solve(s, nu[:, :, None])[..., 0])
        return nu, s, d2


class GraphSlam(PipelineBase):
    """Landmark SLAM as a GTSAM factor graph (see the module docstring)."""

    name = "graph"
    config_class = GraphConfig
    consumes = ("odometry", "landmarks")

    def __init__(self, config: GraphConfig | None = None) -> None:
        self.config = config or GraphConfig()
        c = self.config
        self._gate = c.gate
        self._new_gate = c.new_gate
        self._backend: Backend | None = None
        self._start: F64 | None = None
        self._robots: dict[int, _Robot] = {}
        self._anchor: int | None = None
        self._marks: dict[int, _Mark] = {}
        self._pending: dict[int, _Pending] = {}
        self._sightings: list[tuple[int, int, int, int, F64]] = []
        self._next_id = 0
        self._obs_keys = 0
        self._deferred = False
        self._with_id = 0
        self._without_id = 0
        self.counts: Counter[str] = Counter()
        self.placed_at: dict[int, float] = {}

    # -- set-up -----------------------------------------------------------------------------

    def set_start(self, pose: F64 | None) -> None:
        """The first robot's starting pose (x, y, yaw), e.g. ground truth; None = origin."""
        self._start = self.config.start_pose(pose)

    def _graph(self) -> Backend:
        if self._backend is None:
            c = self.config
            self._backend = Backend(c.solver, c.robust_width, c.batch_every)
        return self._backend

    def _robot(self, ident: int) -> _Robot:
        robot = self._robots.get(ident)
        if robot is None:
            robot = self._robots[ident] = _Robot(ident)
            if self._anchor is None:
                self._anchor = ident
        return robot

    # -- frames -----------------------------------------------------------------------------

    def process(self, frame: Any) -> None:
        from slamcli.formats.landmarks import RobotFrame

        if isinstance(frame, RobotFrame):
            robot, inner, sighting = frame.robot, frame.frame, frame.sighting
        else:
            robot, inner, sighting = 0, frame, False
        if isinstance(inner, OdometryFrame):
            self._odometry(self._robot(robot), inner)
        elif isinstance(inner, LandmarkFrame):
            if sighting:
                self._sighting(self._robot(robot), inner)
            else:
                self._observations(self._robot(robot), inner)
        else:
            raise PipelineError(
                f"the graph pipeline takes odometry and landmark frames, not {type(inner).__name__}"
            )

    def _advance(self, robot: _Robot, stamp_ns: int) -> None:
        """Integrate the robot's current control up to ``stamp_ns``."""
        if robot.t_ns is not None and robot.control is not None and stamp_ns > robot.t_ns:
            v, w = robot.control
            robot.rel.velocity(v, w, (stamp_ns - robot.t_ns) * 1e-9, self.config.control_psd(v, w))
        if robot.t_ns is None or stamp_ns > robot.t_ns:
            robot.t_ns = stamp_ns

    def _odometry(self, robot: _Robot, frame: OdometryFrame) -> None:
        self.counts["odometry"] += 1
        if frame.v is not None and frame.omega is not None:
            self._advance(robot, frame.stamp_ns)
            robot.control = (float(frame.v), float(frame.omega))
        elif frame.world_from_body is not None:
            pose = se3_to_planar(frame.world_from_body)[0]
            if robot.odom_pose is not None:
                delta = between_planar(robot.odom_pose, pose)
                robot.rel.step(delta, self.config.step_covariance(delta))
            robot.odom_pose = pose
            robot.t_ns = frame.stamp_ns if robot.t_ns is None else max(robot.t_ns, frame.stamp_ns)
        else:
            raise PipelineError(
                f"odometry at {frame.stamp_ns * 1e-9:.3f} s has neither (v, omega) nor a pose"
            )
        if not robot.keys:
            self._keypose(robot, frame.stamp_ns)
        elif frame.stamp_ns - robot.keys[-1].stamp_ns >= self.config.keypose_interval * 1e9:
            self._keypose(robot, frame.stamp_ns)
            self._settle(robot)
        self._row(robot, frame.stamp_ns)

    def _row(self, robot: _Robot, stamp_ns: int) -> None:
        if robot.rows_t and robot.rows_t[-1] == stamp_ns:
            robot.rows_k[-1] = len(robot.keys) - 1
            robot.rows_rel[-1] = robot.rel.pose.copy()
            return
        robot.rows_t.append(stamp_ns)
        robot.rows_k.append(len(robot.keys) - 1)
        robot.rows_rel.append(robot.rel.pose.copy())

    def _keypose(self, robot: _Robot, stamp_ns: int) -> int:
        """The index of a keypose at ``stamp_ns`` (a new one unless the last is at it)."""
        self._advance(robot, stamp_ns)
        if robot.keys and robot.keys[-1].stamp_ns == stamp_ns:
            return len(robot.keys) - 1
        robot.keys.append(_Key(stamp_ns, robot.rel.pose.copy(), robot.rel.cov.copy()))
        robot.rel = Relative()
        prev = robot.local[-1] if robot.local else np.zeros(3)
        robot.local.append(
            compose_planar(prev, robot.keys[-1].delta) if len(robot.keys) > 1 else prev
        )
        self._row(robot, stamp_ns)
        return len(robot.keys) - 1

    def _observations(self, robot: _Robot, frame: LandmarkFrame) -> None:
        ids, zs = usable_observations(frame)
        self.counts["observations"] += len(zs)
        if not len(zs):
            return
        k = self._keypose(robot, frame.stamp_ns)
        key = robot.keys[k]
        key.ids.extend(ids.tolist())
        key.zs.extend(zs)
        self._settle(robot)

    def _sighting(self, robot: _Robot, frame: LandmarkFrame) -> None:
        """Sightings of other robots (``frame.ids`` are their numbers)."""
        for ident, rng, brg in zip(
            frame.ids.tolist(), frame.ranges_m.tolist(), frame.bearings_rad.tolist(), strict=True
        ):
            other = self._robots.get(int(ident))
            if other is None or other is robot or other.t_ns is None or not (rng > 0):
                self.counts["robot_sightings_unused"] += 1
                continue
            a = self._keypose(robot, frame.stamp_ns)
            b = self._keypose(other, frame.stamp_ns)
            self._sightings.append(
                (robot.ident, a, other.ident, b, np.array([rng, wrap_angle(brg)]))
            )
            self._settle(other)
        self._settle(robot)

    # -- placing keyposes ---------------------------------------------------------------------

    def _settle(self, robot: _Robot) -> None:
        """Put the robot's finished keyposes (all but the newest, which may still collect
        observations) into the graph, or try to place a robot that is not yet placed."""
        catching_up = False
        if not robot.placed:
            if robot.ident == self._anchor:
                robot.placed = True
                robot.offset = self._start if self._start is not None else np.zeros(3)
            elif not self._align(robot):
                return
            else:
                catching_up = True
        # A robot's held keyposes go to the solver together: its first ones may see only
        # landmarks of its own, and until the later ones that tie it to the map arrive, that
        # part of the graph hangs on the weak prior alone (an indeterminate system).
        self._deferred = catching_up
        while robot.done < len(robot.keys) - 1:
            self._place(robot, robot.done)
            robot.done += 1
        self._deferred = False
        self._add_sightings()

    def _place(self, robot: _Robot, k: int) -> None:
        c = self.config
        g = self._graph()
        key = robot.keys[k]
        xk = pose_key(robot.ident, k)
        floor = np.array([c.pose_sigma_m**2, c.pose_sigma_m**2, np.radians(c.pose_sigma_deg) ** 2])
        if k == 0:
            assert robot.offset is not None
            guess = robot.offset.copy()
            if robot.ident == self._anchor:
                sm, sd = c.initial_sigma_m, np.radians(c.initial_sigma_deg)
                pcov = np.diag([sm * sm, sm * sm, sd * sd])
            else:
                pcov = np.diag([WEAK_PRIOR_SIGMA_M**2] * 2 + [np.pi**2])
            g.add_pose(xk, guess)
            g.prior(xk, guess, pcov)
            gate_cov = np.diag(floor) if robot.ident == self._anchor else np.diag(floor) * 4
        else:
            prev = g.pose(pose_key(robot.ident, k - 1))
            guess, jp, jd = relative_motion(prev, key.delta)
            assert robot.gate_cov is not None
            gate_cov = jp @ robot.gate_cov @ jp.T + jd @ key.cov @ jd.T
            of = np.array([c.odometry_floor_m**2] * 2 + [np.radians(c.odometry_floor_deg) ** 2])
            g.add_pose(xk, guess)
            g.odometry(
                pose_key(robot.ident, k - 1),
                xk,
                key.delta,
                between_covariance(key.delta, key.cov, of),
            )
        robot.gate_cov = gate_cov
        if not key.zs:
            return
        ids = np.asarray(key.ids, dtype=np.int64)
        zs = np.asarray(key.zs, dtype=np.float64)
        r_covs = np.stack([self.config.observation_covariance(float(z[0])) for z in zs])
        known = ids >= 0
        self._with_id += int(known.sum())
        self._without_id += int((~known).sum())
        accepted = 0
        if known.any():
            accepted += self._known(xk, guess, gate_cov, ids[known], zs[known], r_covs[known])
        if (~known).any():
            accepted += self._unknown(xk, guess, gate_cov, zs[~known], r_covs[~known])
        if accepted:
            robot.gate_cov = np.diag(floor)
        self._obs_keys += 1
        if self._obs_keys % c.update_every == 0 and not self._deferred:
            g.flush()

    def _known(
        self, xk: int, pose: F64, pose_cov: F64, ids: NDArray[np.int64], zs: F64, r_covs: F64
    ) -> int:
        g = self._graph()
        var = self.config.landmark_sigma_m**2
        accepted = 0
        for k in np.argsort(ids, kind="stable").tolist():
            ident = int(ids[k])
            lk = landmark_key(ident)
            if ident not in self._marks:
                self._pending_observation(xk, pose, pose_cov, ident, zs[k], r_covs[k])
                continue
            view = _View(pose, pose_cov, g.point(lk)[None, :], var)
            d2 = float(view.innovations_all(zs[k], r_covs[k])[2][0])
            if d2 < self._gate:
                g.landmark(xk, lk, zs[k], r_covs[k])
                self._marks[ident].hits += 1
                self.counts["updates"] += 1
                accepted += 1
            else:
                self.counts["rejected_by_gate"] += 1
        return accepted

    def _pending_observation(
        self, xk: int, pose: F64, pose_cov: F64, ident: int, z: F64, r_cov: F64
    ) -> None:
        """Collect observations of an unmapped id; map it once enough of them agree."""
        g = self._graph()
        lm, gr, gz = inverse_observation(pose, z)
        pend = self._pending.setdefault(ident, _Pending())
        pend.points.append(lm)
        pend.covs.append(gr @ pose_cov @ gr.T + gz @ r_cov @ gz.T)
        pend.obs.append((xk, ident, z, r_cov))
        need = self.config.promote_after_known
        if len(pend.points) < need:
            return
        pts, covs = np.array(pend.points[-need:]), np.array(pend.covs[-need:])
        if not agree_with_mean(pts, covs, self._gate):
            return
        lk = landmark_key(ident)
        g.add_point(lk, pts.mean(axis=0))
        self._marks[ident] = _Mark(ident, known=True, hits=0)
        for pk, _, zz, rc in pend.obs[-need:]:
            g.landmark(pk, lk, zz, rc)
            self._marks[ident].hits += 1
        self.counts["landmarks_new"] += 1
        self.counts["updates"] += need
        del self._pending[ident]

    def _unknown(self, xk: int, pose: F64, pose_cov: F64, zs: F64, r_covs: F64) -> int:
        g = self._graph()
        c = self.config
        idents = sorted(i for i, m in self._marks.items() if not m.known)
        points = (
            np.stack([g.point(landmark_key(i)) for i in idents]) if idents else np.empty((0, 2))
        )
        view = _View(pose, pose_cov, points, c.landmark_sigma_m**2)
        cands = Candidates.of(cast(Any, view), zs, r_covs)
        pairing = c.pair(cast(Any, view), zs, r_covs, cands)
        _, nearest = cands.best()
        accepted = 0
        for i in range(len(zs)):
            slot = int(pairing[i])
            if slot != UNMATCHED:
                ident = idents[slot]
                g.landmark(xk, landmark_key(ident), zs[i], r_covs[i])
                self._marks[ident].hits += 1
                self.counts["updates"] += 1
                accepted += 1
            elif nearest[i] > self._new_gate:
                ident = self._next_id
                self._next_id += 1
                lk = landmark_key(ident)
                g.add_point(lk, inverse_observation(pose, zs[i])[0])
                g.landmark(xk, lk, zs[i], r_covs[i])
                self._marks[ident] = _Mark(ident, known=False)
                self.counts["landmarks_new"] += 1
            else:
                self.counts["ambiguous"] += 1
        return accepted

    # -- several robots ---------------------------------------------------------------------

    def _align(self, robot: _Robot) -> bool:
        """Place a robot by fitting its early landmark positions (own frame) onto the map."""
        c = self.config
        g = self._graph()
        local: dict[int, list[F64]] = {}
        for key, pose in zip(robot.keys, robot.local, strict=True):
            for ident, z in zip(key.ids, key.zs, strict=True):
                mark = self._marks.get(ident)
                if ident >= 0 and mark is not None and mark.hits >= c.promote_after_known:
                    local.setdefault(ident, []).append(inverse_observation(pose, z)[0])
        ids = sorted(i for i, pts in local.items() if len(pts) >= 2)
        if len(ids) < c.align_min_landmarks:
            return False
        src = np.stack([np.median(np.stack(local[i]), axis=0) for i in ids])
        dst = np.stack([g.point(landmark_key(i)) for i in ids])
        transform, rms = rigid_fit_2d(src, dst)
        if rms > c.align_max_rms:
            return False
        robot.offset = transform
        robot.placed = True
        self.counts["robots_placed"] += 1
        self.placed_at[robot.ident] = robot.keys[-1].stamp_ns * 1e-9
        log.info(
            "robot %d placed by %d landmarks (rms %.3f m) at %.1f s",
            robot.ident,
            len(ids),
            rms,
            robot.keys[-1].stamp_ns * 1e-9,
        )
        return True

    def _add_sightings(self) -> None:
        g = self._graph()
        keep = []
        for a, ka, b, kb, z in self._sightings:
            xa, xb = pose_key(self._robots[a].ident, ka), pose_key(self._robots[b].ident, kb)
            if not (g.has(xa) and g.has(xb)):
                keep.append((a, ka, b, kb, z))
                continue
            pa, pb = g.pose(xa), g.pose(xb)
            cov = self._robots[a].gate_cov
            assert cov is not None
            view = _View(pa, cov, pb[None, :2], self.config.landmark_sigma_m**2 * 4)
            r_cov = self.config.observation_covariance(float(z[0]))
            if float(view.innovations_all(z, r_cov)[2][0]) < self._gate:
                g.sighting(xa, xb, z, r_cov)
                self.counts["robot_sightings"] += 1
            else:
                self.counts["robot_sightings_rejected"] += 1
        self._sightings = keep

    # -- output -----------------------------------------------------------------------------

    def finish(self) -> SlamResult:
        if not self._robots or not any(r.keys for r in self._robots.values()):
            raise PipelineError("the log gave the graph pipeline no odometry or observations")
        for robot in self._robots.values():
            if robot.keys:
                robot.done = max(robot.done, 0)
                self._settle_all(robot)
        unplaced = [r.ident for r in self._robots.values() if not r.placed]
        if unplaced:
            raise PipelineError(
                f"robot(s) {', '.join(map(str, unplaced))} never saw "
                f"{self.config.align_min_landmarks} landmarks the map shares, so they could not "
                "be placed in the first robot's frame",
                hint="lower align_min_landmarks, or leave these robots out of --robot",
            )
        g = self._graph()
        g.finish()
        trajectories: dict[int, Trajectory] = {}
        for robot in self._robots.values():
            n = len(robot.keys)
            key_poses = np.stack([g.pose(pose_key(robot.ident, k)) for k in range(n)])
            key_rel = np.stack([k.delta for k in robot.keys])
            dense = blend_dense(
                np.asarray([k.stamp_ns for k in robot.keys], dtype=np.int64),
                key_poses,
                key_rel,
                np.asarray(robot.rows_t, dtype=np.int64),
                np.asarray(robot.rows_rel),
                np.asarray(robot.rows_k, dtype=np.int64),
            )
            trajectories[robot.ident] = Trajectory(
                np.asarray(robot.rows_t, dtype=np.int64), planar_to_se3(dense)
            )
        keep = sorted(
            i for i, m in self._marks.items() if m.known or m.hits >= self.config.promote_after
        )
        xy = np.stack([g.point(landmark_key(i)) for i in keep]) if keep else np.empty((0, 2))
        covs = g.marginal_points([landmark_key(i) for i in keep])
        counts = dict(self.counts)
        counts["landmarks"] = len(keep)
        counts["landmarks_tentative"] = len(self._marks) - len(keep)
        counts["keyposes"] = sum(len(r.keys) for r in self._robots.values())
        counts["robots"] = len(self._robots)
        for kind, n in g.factor_counts.items():
            counts[f"factors_{kind}"] = n
        metrics: dict[str, Any] = {
            "association": self.config.association_used(self._with_id, self._without_id),
            "solver": self.config.solver,
            "graph_error": g.error(),
        }
        if len(self._robots) > 1:
            metrics["robots_placed_at_s"] = {str(k): v for k, v in self.placed_at.items()}
        assert self._anchor is not None
        return SlamResult(
            trajectory=trajectories[self._anchor],
            landmarks=LandmarkMap(np.asarray(keep, dtype=np.int64), xy, covs),
            robots=trajectories if len(trajectories) > 1 else {},
            metrics=metrics,
            counts=counts,
        )

    def _settle_all(self, robot: _Robot) -> None:
        """At the end: the newest keypose joins the graph too."""
        if not robot.placed:
            self._settle(robot)
            if not robot.placed:
                return
        while robot.done < len(robot.keys):
            self._place(robot, robot.done)
            robot.done += 1
        self._add_sightings()
