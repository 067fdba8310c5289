"""2-D lidar SLAM: scans matched to submaps, loops closed on a pose graph, a map ray cast.

Frame by frame (:meth:`LidarSlam.process`):

1. **Guess.** The scan's pose in the local frame is first guessed from odometry (the motion
   between the odometry poses at this scan and the last), or, in a log without odometry,
   from the last motion repeated (constant velocity).
2. **Match.** A branch-and-bound correlative search around the guess, on the likelihood field
   of the matching submap, then a continuous refinement (:mod:`slamcli.scans.matching`).
3. **Node.** When the pose moved enough since the last node, the scan becomes a node of the
   pose graph, tied to the last node by the matched motion, and is inserted into the active
   submaps (:mod:`slamcli.pipelines.lidar.submaps`).
4. **Loops.** A node is searched for in the finished submaps near its estimate, in a window
   that grows with the distance travelled since the last loop closed; a match above the score
   threshold that also passes geometric verification (most points on the submap's walls)
   becomes a loop edge with a robust kernel, and the graph is re-solved (GTSAM,
   Levenberg-Marquardt); loop edges the solution rejects are dropped.

:meth:`LidarSlam.finish` solves once more and gives every scan its pose (its node's, or its
last node's and the matched motion since), and the map: the submaps laid at their optimised
poses, free along the beams, occupied at their ends, unknown elsewhere.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import PipelineError
from slamcli.formats.base import SourceInfo
from slamcli.geometry.planar import (
    between_planar,
    compose_planar,
    invert_planar,
    planar_to_se3,
    se3_to_planar,
    transform_points_planar,
)
from slamcli.graphs.pose_graph import Edge, optimize_se2
from slamcli.pipelines import PipelineBase
from slamcli.pipelines.lidar.config import LidarConfig
from slamcli.pipelines.lidar.maps import submap_mosaic
from slamcli.pipelines.lidar.submaps import Submap, SubmapSet
from slamcli.pipelines.timing import Stats
from slamcli.scans.matching import Match, fit_fraction, fit_score, refine, search
from slamcli.scans.points import scan_points, voxel_filter
from slamcli.types import OdometryFrame, ScanFrame, SlamResult, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

_LOCAL_DEPTH = 3
"""Pyramid levels of the local search (8 cells at the top)."""
_LOOP_DEPTH = 6
"""Pyramid levels of the loop search (64 cells at the top)."""
_ALWAYS_COUNTED = (
    "scans_not_matched",
    "scans_out_of_order",
    "loop_searches",
    "loops_rejected_by_fit",
    "loops_rejected_by_graph",
    "optimisations",
)
_SOLVE_EVERY = 10
"""Nodes between two solves of the graph while loops keep closing."""


_SEARCH_POINTS = 200
"""Points of a scan the correlative searches score (evenly picked); refinement uses all."""


def _thinned(points: F64, most: int) -> F64:
    if len(points) <= most:
        return points
    return points[np.linspace(0, len(points) - 1, most).astype(np.int64)]


@dataclass
class _Scan:
    """One scan's record: its stamp, the node it hangs from and its pose relative to it."""

    stamp_ns: int
    node: int
    node_from_scan: F64


class LidarSlam(PipelineBase):
    """2-D lidar SLAM to an occupancy map (see the module docstring)."""

    name = "lidar"
    config_class = LidarConfig
    consumes = ("scan", "odometry")

    def __init__(self, config: LidarConfig | None = None) -> None:
        self.config = config or LidarConfig()
        self.stats = Stats()
        self.counts = self.stats.counts
        self._start = np.zeros(3)
        self._submaps = SubmapSet(self.config.resolution_m, self.config.scans_per_submap)
        # Nodes: local poses (the front end's frame) and global poses (the graph's).
        self._local: list[F64] = []
        self._global: list[F64] = []
        self._edges: list[Edge] = []
        self._scans: list[_Scan] = []
        self._last_local: F64 | None = None
        self._last_motion = np.zeros(3)
        self._last_stamp: int | None = None
        self._last_node_stamp: int | None = None
        self._odom: F64 | None = None
        self._odom_at_last: F64 | None = None
        self._travelled = 0.0
        self._since_loop = 0.0
        self._loops: list[tuple[int, int]] = []
        self._searched_at = -math.inf
        self._solved_at = 0

    # -- set-up ---------------------------------------------------------------------------------

    def frame_kinds(self, info: SourceInfo) -> tuple[str, ...]:
        """Scans, and odometry when the log has some (a topic, tf, or a laser log's poses):
        logs of scans alone are normal (handheld scanners, early bags)."""
        has_odometry = any(s.kind == "odometry" and s.count for s in info.streams) or bool(
            info.details.get("scan_odometry")
        )
        return ("scan", "odometry") if has_odometry else ("scan",)

    def set_start(self, pose: F64 | None) -> None:
        """The start pose (x, y, yaw), e.g. the ground truth's; None = the origin."""
        self._start = np.zeros(3) if pose is None else np.asarray(pose, dtype=np.float64)

    # -- frames ---------------------------------------------------------------------------------

    def process(self, frame: object) -> None:
        if isinstance(frame, OdometryFrame):
            if frame.world_from_body is not None:
                self._odom = se3_to_planar(frame.world_from_body[None])[0]
                self.counts["odometry"] += 1
            return
        if not isinstance(frame, ScanFrame):
            raise PipelineError(
                f"the lidar pipeline takes scans and odometry, not {type(frame).__name__}"
            )
        if self._last_stamp is not None and frame.stamp_ns <= self._last_stamp:
            self.counts["scans_out_of_order"] += 1
            return
        self.counts["scans"] += 1
        with self.stats.timed("total"):
            self._scan(frame)

    def _scan(self, frame: ScanFrame) -> None:
        with self.stats.timed("points"):
            points = scan_points(frame, self.config.max_range_m)
            sparse = voxel_filter(points, self.config.voxel_m)
        with self.stats.timed("match"):
            pose = self._match(sparse, self._guess())
        self._advance(pose, frame.stamp_ns)
        if self._is_node(pose, frame.stamp_ns):
            node = self._add_node(pose, frame, points)
            with self.stats.timed("loops"):
                self._close_loops(node, sparse)
        last = len(self._local) - 1
        self._scans.append(_Scan(frame.stamp_ns, last, between_planar(self._local[last], pose)))

    def _guess(self) -> F64:
        if self._last_local is None:
            return self._start.copy()
        prior = self.config.motion_prior
        use_odom = prior in ("auto", "odometry") and self._odom is not None
        if prior == "odometry" and self._odom is None:
            raise PipelineError(
                "motion_prior=odometry, but the log has no odometry before this scan",
                hint="use --set motion_prior=auto (constant velocity without odometry)",
            )
        if use_odom and self._odom_at_last is not None:
            assert self._odom is not None
            return compose_planar(self._last_local, between_planar(self._odom_at_last, self._odom))
        if prior in ("auto", "constant_velocity"):
            return compose_planar(self._last_local, self._last_motion)
        return self._last_local.copy()

    def _match(self, points: F64, guess: F64) -> F64:
        c = self.config
        sub = self._submaps.matching()
        if sub is None or not len(points):
            return guess
        reach = transform_points_planar(guess, points)
        pad = c.search_window_m + (1 << _LOCAL_DEPTH) * c.resolution_m
        box = np.concatenate([reach.min(axis=0) - pad, reach.max(axis=0) + pad])
        pyramid = sub.pyramid(c.field_sigma_m, _LOCAL_DEPTH, box)
        found = search(
            pyramid,
            _thinned(points, _SEARCH_POINTS),
            guess,
            c.search_window_m,
            math.radians(c.search_window_deg),
            min_score=c.min_match_score,
        )
        if found is None:
            self.counts["scans_not_matched"] += 1
            return guess
        refined = refine(pyramid.field, points, found.pose, target=guess)
        start = fit_score(pyramid.field, points, found.pose)
        return refined.pose if refined.score >= start else found.pose

    def _advance(self, pose: F64, stamp_ns: int) -> None:
        if self._last_local is not None:
            self._last_motion = between_planar(self._last_local, pose)
            self._travelled += float(np.hypot(*self._last_motion[:2]))
        self._last_local = pose
        self._last_stamp = stamp_ns
        self._odom_at_last = None if self._odom is None else self._odom.copy()

    def _is_node(self, pose: F64, stamp_ns: int) -> bool:
        if not self._local:
            return True
        c = self.config
        moved = between_planar(self._local[-1], pose)
        assert self._last_node_stamp is not None
        return bool(
            np.hypot(moved[0], moved[1]) >= c.motion_min_m
            or abs(moved[2]) >= math.radians(c.motion_min_deg)
            or (stamp_ns - self._last_node_stamp) * 1e-9 >= c.motion_max_s
        )

    def _add_node(self, pose: F64, scan: ScanFrame, points: F64) -> int:
        c = self.config
        node = len(self._local)
        if node == 0:
            glob = self._start.copy()
        else:
            rel = between_planar(self._local[-1], pose)
            glob = compose_planar(self._global[-1], rel)
            self._since_loop += float(np.hypot(rel[0], rel[1]))
            info = np.diag(
                [c.edge_sigma_m**-2, c.edge_sigma_m**-2, math.radians(c.edge_sigma_deg) ** -2]
            )
            self._edges.append(Edge(node - 1, node, rel, information=info, kind="scan"))
        self._local.append(pose)
        self._global.append(glob)
        self._last_node_stamp = scan.stamp_ns
        sensor = compose_planar(pose, scan.body_from_sensor)
        world_points = transform_points_planar(pose, points)
        misses = self._misses(scan, pose)
        with self.stats.timed("insert"):
            self._submaps.insert(node, world_points, sensor[:2], misses)
        self.counts["nodes"] += 1
        return node

    def _misses(self, scan: ScanFrame, pose: F64) -> F64:
        """Far ends (local frame) of the beams that saw nothing, cut at ``max_range_m``."""
        none = scan.no_returns()
        if not none.any():
            return np.empty((0, 2))
        reach = min(float(scan.range_max_m), self.config.max_range_m)
        a = scan.angles()[none]
        local = np.stack([reach * np.cos(a), reach * np.sin(a)], axis=1)
        body = transform_points_planar(scan.body_from_sensor, local)
        return transform_points_planar(pose, body)

    # -- loop closure -----------------------------------------------------------------------

    def _window(self) -> tuple[float, float]:
        c = self.config
        lin = min(c.loop_window_m + c.loop_growth * self._since_loop, c.loop_window_max_m)
        ang = min(
            c.loop_window_deg + c.loop_growth * 10.0 * self._since_loop, c.loop_window_max_deg
        )
        return lin, math.radians(ang)

    def _candidates(self, node: int) -> list[Submap]:
        c = self.config
        here = self._global[node][:2]
        lin, _ = self._window()
        reach = c.loop_search_m + lin
        found: list[tuple[float, Submap]] = []
        for sub in self._submaps.all:
            if not sub.finished or node - sub.nodes[-1] < c.loop_min_gap:
                continue
            xy = np.array([self._global[k][:2] for k in sub.nodes])
            d = float(np.min(np.hypot(*(xy - here).T)))
            if d <= reach:
                found.append((d, sub))
        found.sort(key=lambda t: (t[0], t[1].index))
        return [sub for _, sub in found[:2]]

    def _close_loops(self, node: int, points: F64) -> None:
        c = self.config
        if not len(points) or self._travelled - self._searched_at < c.loop_every_m:
            return
        self._searched_at = self._travelled
        closed = False
        lin, ang = self._window()
        for sub in self._candidates(node):
            anchor = sub.anchor
            # The node's pose in the submap's (local) frame, from the graph's estimate.
            guess = compose_planar(
                self._local[anchor], between_planar(self._global[anchor], self._global[node])
            )
            pyramid = self._submaps.loop_pyramid(sub, c.field_sigma_m, _LOOP_DEPTH)
            self.counts["loop_searches"] += 1
            found = search(
                pyramid, _thinned(points, _SEARCH_POINTS), guess, lin, ang, c.loop_min_score
            )
            if found is None:
                continue
            refined: Match = refine(pyramid.field, points, found.pose)
            if np.hypot(*(refined.pose[:2] - found.pose[:2])) > 2 * c.resolution_m:
                refined = found
            if fit_fraction(pyramid.field, points, refined.pose) < c.loop_min_fit:
                self.counts["loops_rejected_by_fit"] += 1
                continue
            rel = between_planar(self._local[anchor], refined.pose)
            info = np.diag(
                [c.loop_sigma_m**-2, c.loop_sigma_m**-2, math.radians(c.loop_sigma_deg) ** -2]
            )
            self._edges.append(Edge(anchor, node, rel, information=info, robust=True, kind="loop"))
            self._loops.append((anchor, node))
            closed = True
        if closed:
            # A loop after a long stretch without one corrects much: solve now, so that the
            # next searches start from the corrected poses. Otherwise solve now and then.
            if self._since_loop >= c.loop_window_max_m or node - self._solved_at >= _SOLVE_EVERY:
                with self.stats.timed("optimise"):
                    self._optimise()
                self._solved_at = node
            self._since_loop = 0.0

    def _optimise(self) -> None:
        """Re-solve the graph; loop edges the solution finds to be outliers are dropped."""
        c = self.config
        if len(self._global) < 2:
            return
        for _ in range(2):
            result = optimize_se2(
                np.array(self._global), self._edges, kernel=c.loop_kernel, fixed=(0,)
            )
            self._global = list(result.poses)
            self.counts["optimisations"] += 1
            if not len(result.outliers):
                return
            bad = set(result.outliers.tolist())
            kept = [e for k, e in enumerate(self._edges) if k not in bad]
            self.counts["loops_rejected_by_graph"] += len(self._edges) - len(kept)
            self._loops = [(e.a, e.b) for e in kept if e.kind == "loop"]
            self._edges = kept

    # -- result -------------------------------------------------------------------------------

    def finish(self) -> SlamResult:
        with self.stats.timed("total"):
            return self._finish()

    def _finish(self) -> SlamResult:
        if not self._scans:
            raise PipelineError(
                "no scans reached the lidar pipeline",
                hint="check the log's scan topic with 'slamcli info' (--scan-topic chooses one)",
            )
        if self._loops:
            with self.stats.timed("optimise"):
                self._optimise()
        glob = np.array(self._global)
        local = np.array(self._local)
        nodes = np.array([s.node for s in self._scans])
        rel = np.array([s.node_from_scan for s in self._scans])
        poses = compose_planar(glob[nodes], rel)
        stamps = np.array([s.stamp_ns for s in self._scans], dtype=np.int64)
        trajectory = Trajectory(stamps, planar_to_se3(poses))
        node_stamps = np.array(
            [self._scans[k].stamp_ns for k in self._first_scan_of_nodes()], dtype=np.int64
        )
        keyframes = Trajectory(node_stamps, planar_to_se3(glob))
        world_from_local = [
            compose_planar(glob[s.anchor], invert_planar(local[s.anchor]))
            for s in self._submaps.all
        ]
        with self.stats.timed("map"):
            grid = submap_mosaic(self._submaps.all, world_from_local)
        occupied = np.argwhere(np.nan_to_num(grid.prob, nan=0.0) >= 0.65)
        centres = (occupied[:, ::-1] + 0.5) * grid.resolution_m + np.array(grid.origin_xy_yaw[:2])
        points = np.column_stack([centres, np.zeros(len(centres))])
        for name in _ALWAYS_COUNTED:
            self.counts[name] += 0  # present in run.json, for gates, even when nothing happened
        self.counts["loops_closed"] = len(self._loops)
        self.counts["submaps"] = len(self._submaps.all)
        frames = max(1, self.counts["scans"])
        return SlamResult(
            trajectory=trajectory,
            keyframes=keyframes,
            grid=grid,
            points=points,
            pose_graph=(glob, list(self._edges)),
            counts=dict(self.counts),
            metrics={
                "loops": [[int(a), int(b)] for a, b in self._loops],
                "ms_per_frame": self.stats.per_frame(frames),
            },
        )

    def _first_scan_of_nodes(self) -> list[int]:
        first: dict[int, int] = {}
        for k, s in enumerate(self._scans):
            first.setdefault(s.node, k)
        return [first[n] for n in range(len(self._local))]
