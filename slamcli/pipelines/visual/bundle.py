"""Bundle adjustment of the visual pipeline's map: the problem's arrays read off the map, the
solve (pycolmap, :func:`~slamcli.vision.bundle_adjustment.bundle_adjust`) now or on the side
process, and its result taken back into the map."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.pipelines.timing import Stats
from slamcli.pipelines.visual.atlas import Keyframe, SparseMap
from slamcli.pipelines.visual.config import VisualConfig
from slamcli.pipelines.visual.frames import Rig
from slamcli.worker import Pending, SideProcess

if TYPE_CHECKING:
    from slamcli.inertial.bundle import InertialTerms
    from slamcli.pipelines.visual.inertial import Inertial

I64 = NDArray[np.int64]


@dataclass
class BaJob:
    """A bundle adjustment's input arrays (``args``, ``kwargs`` of ``bundle_adjust``) and
    what is needed to take its result back into the map."""

    kfs: list[Keyframe]
    fixed: NDArray[np.bool_]
    pids: I64
    of: list[int]
    op: list[int]
    okp: list[int]
    args: tuple[Any, ...]
    kwargs: dict[str, Any]
    chain: list[int] = field(default_factory=list)


class BundleAdjuster:
    """Bundle adjustments of one map, with at most one running apart.

    An RGB-D local bundle adjustment started at a keyframe runs on the side process (with
    threads=2), and is taken into the map at the next keyframe (or before anything that needs
    the map settled: a loop, a merge, a new map, the end): a point fixed by the frame
    sequence, never by timing, so threads=1 (in place) gives the same results.
    """

    def __init__(
        self, config: VisualConfig, rig: Rig, smap: SparseMap, stats: Stats, side: SideProcess
    ) -> None:
        self.config, self.rig, self.map, self.stats, self.side = config, rig, smap, stats, side
        self._pending: tuple[BaJob, Pending[Any]] | None = None
        self.inertial: Inertial | None = None

    def start(
        self,
        kfs: list[Keyframe],
        fixed: NDArray[np.bool_],
        pids: I64,
        iterations: int,
        inertial: InertialTerms | None = None,
    ) -> None:
        """Start adjusting keyframes ``kfs`` (``fixed`` held) and points ``pids`` on the side
        process, with the inertial terms of its first keyframes when given; :meth:`settle`
        takes the result in."""
        job = self._job(kfs, fixed, pids, iterations, inertial)
        if job is not None:
            self._pending = (job, self.side.submit(_solver(job), *job.args, **job.kwargs))

    def bundle(
        self,
        kfs: list[Keyframe],
        fixed: NDArray[np.bool_],
        pids: I64,
        iterations: int,
        inertial: InertialTerms | None = None,
    ) -> None:
        """Bundle-adjust keyframes ``kfs`` (``fixed`` held) and points ``pids`` now, with the
        inertial terms of its first keyframes when given; drop the observations that end up
        outliers."""
        job = self._job(kfs, fixed, pids, iterations, inertial)
        if job is not None:
            self._apply(job, _solver(job)(*job.args, **job.kwargs))

    def _job(
        self,
        kfs: list[Keyframe],
        fixed: NDArray[np.bool_],
        pids: I64,
        iterations: int,
        inertial: InertialTerms | None = None,
    ) -> BaJob | None:
        """The arrays of a bundle adjustment (a copy: the map may move on while it runs)."""
        # Every observation of the points by the problem's keyframes, read off the keyframes'
        # keypoint -> point tables, ordered by point (in the order of ``pids``), then frame.
        rank = np.full(self.map.n, -1, dtype=np.int64)
        rank[pids] = np.arange(pids.size)
        parts = []
        for i, k in enumerate(kfs):
            kps = np.flatnonzero(k.point_ids >= 0)
            kps = kps[rank[k.point_ids[kps]] >= 0]
            parts.append(np.stack([rank[k.point_ids[kps]], np.full(kps.size, i), kps]))
        if not parts:
            return None
        table = np.concatenate(parts, axis=1)
        table = table[:, np.lexsort((table[1], table[0]))]
        prow, frame_of, kp_of = table[0], table[1], table[2]
        uv = np.empty((kp_of.size, 2))
        sig = np.empty(kp_of.size)
        dep = np.empty(kp_of.size)
        for i, k in enumerate(kfs):
            rows = np.flatnonzero(frame_of == i)
            kps = kp_of[rows]
            uv[rows] = k.keypoints[kps]
            sig[rows] = self.map.sigma[k.octaves[kps].astype(np.int64)]
            dep[rows] = k.depth[kps]
        # A point seen once in the problem, without depth, cannot be placed by it (with depth
        # it can, and must follow its keyframe).
        views = np.bincount(prow, minlength=pids.size)
        placed = views >= 2
        if not self.rig.mono:
            single = views[prow] == 1
            placed[prow[single & np.isfinite(dep)]] = True
        keep = placed[prow]
        if not keep.any():
            return None
        prow, frame_of, kp_of = prow[keep], frame_of[keep], kp_of[keep]
        uv, sig, dep = uv[keep], sig[keep], dep[keep]
        kept_rows = np.flatnonzero(placed)
        new_row = np.cumsum(placed) - 1
        pids = pids[kept_rows]
        op = new_row[prow]
        of, okp = frame_of.tolist(), kp_of.tolist()
        args = (
            self.rig.camera,
            np.stack([k.cam_from_world for k in kfs]),
            self.map.pos[pids].copy(),
            frame_of,
            op,
            uv,
            sig,
        )
        kwargs = {
            "fixed_frames": fixed.copy(),
            "max_iterations": iterations,
            "obs_depth": None if self.rig.mono else dep,
            "baseline_m": self.rig.baseline_m,
        }
        chain: list[int] = []
        if inertial is not None:
            kwargs["inertial"] = inertial
            chain = [kfs[i].id for i in inertial.chain.tolist()]
        return BaJob(list(kfs), fixed.copy(), pids, of, op.tolist(), okp, args, kwargs, chain)

    def _apply(self, job: BaJob, result: Any) -> None:
        """Move the job's free keyframes and its points where the adjustment put them, and
        drop its outlier observations. The map may have changed since the job was made (a
        keyframe culled, a point culled or fused away): what no longer exists is skipped."""
        for i, k in enumerate(job.kfs):
            if not job.fixed[i]:
                k.cam_from_world = result.cam_from_world[i]
        alive = self.map.alive[job.pids]
        self.map.pos[job.pids[alive]] = result.points[alive]
        bad = np.flatnonzero(~result.inlier)
        removed = 0
        for b in bad.tolist():
            kf, kp = job.kfs[job.of[b]], job.okp[b]
            if kf.point_ids[kp] == job.pids[job.op[b]]:
                self.map.forget(kf, kp)
                removed += 1
        self.stats.counts["ba_outliers_removed"] += removed
        self.map.update_geometry(job.pids[self.map.alive[job.pids]], descriptors=False)
        if job.chain and self.inertial is not None:
            self.inertial.take(job.chain, result.velocities, result.biases)

    def settle(self, within: str | None = None) -> bool:
        """Take the local bundle adjustment that runs apart, if any, into the map; returns
        whether there was one. The wait is timed as ``ba_wait``, and taken out of the stage
        ``within`` that is timing the caller."""
        if self._pending is None:
            return False
        job, pending = self._pending
        self._pending = None
        start = time.perf_counter()
        result = pending.result()
        waited = (time.perf_counter() - start) * 1e3
        self.stats.ms["ba_wait"] += waited
        if within is not None:
            self.stats.ms[within] -= waited
        self._apply(job, result)
        return True

    def global_ba(self, main: int | None) -> None:
        """Adjust every keyframe and point of map ``main`` (its first keyframe held)."""
        self.settle()
        if main is None:
            return
        kfs = self.map.live(main)
        if len(kfs) < 2:
            return
        pids = np.unique(np.concatenate([k.point_ids[k.point_ids >= 0] for k in kfs]))
        pids = pids[self.map.alive[pids]]
        fixed = np.zeros(len(kfs), bool)
        terms = None
        if self.inertial is not None and self.inertial.active(main):
            # The inertial chain first (its oldest keyframe anchors the gauge), the keyframes
            # made before the initialisation, which have no state, after it, free.
            chain = self.inertial.chain(main)
            others = [k for k in kfs if k.id not in self.inertial.states]
            kfs = chain + others
            fixed = np.zeros(len(kfs), bool)
            terms = self.inertial.terms(chain, held=0, anchored=True)
        else:
            fixed[0] = True
        self.bundle(kfs, fixed, pids, 20, terms)
        self.stats.counts["global_ba"] += 1


def _solver(job: BaJob) -> Any:
    """The function that solves ``job``: GTSAM's visual-inertial adjustment when it has
    inertial terms, else pycolmap's."""
    if "inertial" in job.kwargs:
        from slamcli.inertial.bundle import inertial_bundle_adjust

        return inertial_bundle_adjust
    from slamcli.vision.bundle_adjustment import bundle_adjust

    return bundle_adjust
