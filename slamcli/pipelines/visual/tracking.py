"""Tracking of the visual pipeline: each frame's pose against the map.

The pose is predicted by a constant-velocity model, the last frame's points (map points and,
RGB-D, its keypoints lifted with depth) are searched by projection, and the pose is refined
with a robust (Cauchy) loss; failing that, the reference keyframe's points are matched by
appearance and the pose found by LO-RANSAC PnP (pycolmap). A monocular frame takes the two in
the other order (see :meth:`Tracking.locate`). Failing both, the frame is
relocalised against the keyframes of its map by place recognition and PnP. The local map (the
points of the keyframes that share points with the frame, and their best neighbours) is then
searched by projection and the pose refined again. A keyframe is wanted as ORB-SLAM decides:
when the frame tracks fewer than ``keyframe_track_ratio`` of the reference keyframe's
well-seen points (RGB-D and stereo: also when too few near points are tracked), or
``keyframe_max_frames`` frames or ``keyframe_max_seconds`` have passed.
"""

from __future__ import annotations

from itertools import chain

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse
from slamcli.pipelines.visual.atlas import FrameRecord, Keyframe
from slamcli.pipelines.visual.frames import Frame
from slamcli.pipelines.visual.inertial import Inertial
from slamcli.pipelines.visual.parts import Part, Shared
from slamcli.pipelines.visual.search import in_view, project_match
from slamcli.vision.matching import TH_HIGH, match_ratio
from slamcli.vision.pnp import absolute_pose

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class Tracking(Part):
    """The pose of each frame in the current map (ORB-SLAM's Tracking).

    Attributes:
        reference: the reference keyframe (None before a map is started).
        last: the last tracked frame (None after a lost one).
        velocity: ``cam_from_world`` of the last frame times the inverse of the one before
            (None without two tracked frames in a row).
        lost_run: frames lost in a row.
    """

    def __init__(self, shared: Shared) -> None:
        super().__init__(shared)
        self.reference: Keyframe | None = None
        self.last: Frame | None = None
        self._last_points: tuple[F64, NDArray[np.uint8], I64, I64] | None = None
        self.velocity: F64 | None = None
        self._velocity_ns = 0
        self.lost_run = 0
        self._since_reloc = 100
        self._seen_ns = 0
        self.inertial: Inertial | None = None

    def has_map(self) -> bool:
        """Whether there is a map to track in: the reference keyframe is in the current map."""
        return self.reference is not None and self.reference.map_id == self.atlas.current

    def begin(self, frames: list[tuple[Frame, Keyframe]]) -> None:
        """Tracking starts in a new map from its first keyframes: each frame takes its
        keyframe's points and pose and is recorded against it; the last is the last frame."""
        for frame, kf in frames:
            frame.point_ids = kf.point_ids.copy()
            frame.cam_from_world = kf.cam_from_world.copy()
            frame.inliers = int(np.count_nonzero(frame.point_ids >= 0))
            self.reference = kf
            self._seen_ns = frame.stamp_ns
            self._record(frame, "tracked")
        self.velocity = None
        self.set_last(frames[-1][0])

    def reset(self) -> None:
        """Forget the map tracked so far (a new one is about to be started)."""
        self.reference = None
        self.last = None
        self.velocity = None
        self.lost_run = 0

    def locate(self, cur: Frame) -> str | None:
        """Pose ``cur`` (``cur.cam_from_world``, ``cur.point_ids``): its state, ``tracked`` or
        ``relocalised``, or None when it is lost; in an initialised visual-inertial map,
        :meth:`_locate_inertial`."""
        if self.inertial is not None and self.inertial.active(self.atlas.current):
            return self._locate_inertial(cur)
        pose = None
        state = "tracked"
        with self.stats.timed("track"):
            if self.rig.mono and self.lost_run == 0:
                # Monocular: appearance first. Points searched by projection from a predicted
                # pose are found where the prediction puts them; on a repeated texture a
                # look-alike sits there too, and a pose whose step is short (a camera sliding
                # along a flat wall looks much like one turning) is confirmed by it, frame
                # after frame, until the map's scale has collapsed. Without depth nothing
                # checks that, so the prediction serves only when appearance fails.
                pose = self._track_reference(cur)
            moving = self.last is not None and self.velocity is not None
            if pose is None and moving and self.lost_run == 0:
                pose = self._track_motion(cur)
            if pose is None and self.lost_run == 0 and not self.rig.mono:
                pose = self._track_reference(cur)
        located = self._local_map_from(cur, pose, state)
        if located is None:
            self.lost_run += 1
            self.last = None
        return located

    def _local_map_from(
        self, cur: Frame, pose: F64 | None, state: str, wide: bool = False
    ) -> str | None:
        """From ``pose`` (relocalised first when None), the local map's search and
        refinement: ``state`` (``relocalised`` after a relocalisation), or None when either
        fails. ``wide`` as :meth:`_track_local_map`'s."""
        if pose is None:
            with self.stats.timed("relocalise"):
                pose = self._relocalise(cur)
            state = "relocalised"
            self._since_reloc = 0
        if pose is None:
            return None
        cur.cam_from_world = pose
        with self.stats.timed("local_map"):
            ok = self._track_local_map(cur, wide=wide)
        return state if ok else None

    def _locate_inertial(self, cur: Frame) -> str | None:
        """Pose ``cur`` in an initialised visual-inertial map: the IMU predicts the pose, the
        last frame's points are searched around it (else the reference keyframe's by
        appearance, else relocalisation), then the local map. When vision fails the
        prediction itself is the frame's pose, state ``inertial``, for ``imu_max_blind_s``
        after the last frame vision posed; None after that."""
        assert self.inertial is not None
        predicted = self.inertial.predict(cur.stamp_ns)
        pose = None
        state = "tracked"
        with self.stats.timed("track"):
            if predicted is not None and self.last is not None and self.lost_run == 0:
                pose = self._track_motion(cur, predicted)
            if pose is None and self.lost_run == 0:
                pose = self._track_reference(cur)
        if pose is None and predicted is not None:
            # After a blind stretch the last frame's points may be out of view: the local map
            # is searched around the prediction.
            pose = predicted
            cur.point_ids[:] = -1
        located = self._local_map_from(cur, pose, state, wide=self.lost_run > 0)
        if located is not None:
            return located
        self.last = None
        blind_s = (cur.stamp_ns - self._seen_ns) * 1e-9
        if predicted is not None and blind_s <= self.config.imu_max_blind_s:
            cur.cam_from_world = predicted
            cur.point_ids[:] = -1
            cur.inliers = 0
            self.lost_run += 1
            self._record(cur, "inertial")
            return "inertial"
        self.lost_run += 1
        return None

    def lost_too_long(self) -> bool:
        """Whether frames have been lost for ``new_map_after_lost`` in a row, or, in a
        visual-inertial map, whether the IMU can no longer pose them."""
        if self.inertial is not None and self.inertial.active(self.atlas.current):
            return True
        return self.lost_run >= self.config.new_map_after_lost

    def accept(self, cur: Frame, state: str) -> None:
        """Keep the located frame ``cur``: the motion model learns from it, and it is recorded
        against its reference keyframe."""
        self.lost_run = 0
        self._since_reloc += 1
        self._seen_ns = cur.stamp_ns
        assert cur.cam_from_world is not None
        if self.last is not None and self.last.cam_from_world is not None:
            self.velocity = cur.cam_from_world @ inverse(self.last.cam_from_world)
            self._velocity_ns = cur.stamp_ns - self.last.stamp_ns
        else:
            self.velocity = None
        self._record(cur, state)

    def follow(self, cur: Frame, kf: Keyframe) -> None:
        """``kf`` was made from ``cur``: it is the reference keyframe now, and the frame's
        matches follow the keyframe's (fused) points, its pose the keyframe's (moved by a loop
        closure or a merge)."""
        self.reference = kf
        cur.point_ids = kf.point_ids.copy()
        cur.cam_from_world = kf.cam_from_world.copy()

    def _step(self, dt_ns: int) -> F64:
        """The motion predicted over ``dt_ns``: the last step, or, when the frames are spaced
        unlike the last two (a frame missing from the log, a burst), the same velocity over
        the new interval. A car 1.2 m a frame apart is 2.4 m away after a dropped frame, and
        searched for 1.2 m away its points are matched wrong or not at all."""
        from slamcli.geometry import se3_exp, se3_log

        assert self.velocity is not None
        last_ns = self._velocity_ns
        if last_ns <= 0 or dt_ns <= 0 or 2 * last_ns <= 3 * dt_ns <= 4.5 * last_ns:
            return self.velocity
        return np.asarray(se3_exp(se3_log(self.velocity) * (dt_ns / last_ns)), dtype=np.float64)

    def _track_motion(self, cur: Frame, predicted: F64 | None = None) -> F64 | None:
        """Constant-velocity prediction (or the IMU's, ``predicted``), refined on the last
        frame's points found by projection."""
        assert self.last is not None
        assert self.last.cam_from_world is not None and self._last_points is not None
        if predicted is None:
            assert self.velocity is not None
            predicted = self._step(cur.stamp_ns - self.last.stamp_ns) @ self.last.cam_from_world
        world, desc, octv, pids = self._last_points
        th = 15.0 if self.rig.mono else 7.0
        for radius in (th, 2 * th):
            pairs = project_match(
                self.rig.camera, self.map.sigma, cur, predicted, world, desc, octv, radius, 0.9
            )
            if len(pairs) >= 20:
                break
        if len(pairs) < 20:
            self.stats.counts["motion_model_failed"] += 1
            return None
        # A seed for the local-map search, which refines again: two rounds suffice.
        est = self.rig.refine(
            predicted,
            cur.keypoints[pairs[:, 1]],
            world[pairs[:, 0]],
            self.map.sigma[cur.octaves[pairs[:, 1]]],
            cur.depth[pairs[:, 1]],
            rounds=2,
        )
        if est is None or est.num_inliers < 10:
            self.stats.counts["motion_model_failed"] += 1
            return None
        good = pairs[est.inliers]
        keep = pids[good[:, 0]] >= 0
        cur.point_ids[good[keep, 1]] = pids[good[keep, 0]]
        return est.cam_from_world

    def _track_reference(self, cur: Frame) -> F64 | None:
        """Match the reference keyframe's points by appearance; PnP."""
        kf = self.reference
        assert kf is not None
        est = self._pnp_against(cur, kf)
        if est is None:
            self.stats.counts["reference_failed"] += 1
            return None
        return est

    def _pnp_against(self, cur: Frame, kf: Keyframe, min_inliers: int = 15) -> F64 | None:
        has = np.flatnonzero(kf.point_ids >= 0)
        if has.size < min_inliers:
            return None
        pairs = match_ratio(kf.descriptors[has], cur.descriptors, 0.75, TH_HIGH)
        if len(pairs) < min_inliers:
            return None
        pids = kf.point_ids[has[pairs[:, 0]]]
        est = absolute_pose(
            self.rig.camera,
            cur.keypoints[pairs[:, 1]],
            self.map.pos[pids],
            threshold_px=self.config.pnp_threshold_px,
            min_inliers=min_inliers,
            seed=self.config.seed,
        )
        if est is None:
            return None
        cur.point_ids[:] = -1
        cur.point_ids[pairs[est.inliers, 1]] = pids[est.inliers]
        return est.cam_from_world

    def _relocalise(self, cur: Frame) -> F64 | None:
        """Place recognition against every keyframe of the current map, then PnP."""
        candidates = self.places.candidates(cur.descriptors, self.atlas.current, limit=5)
        for kf_id, _score in candidates:
            pose = self._pnp_against(cur, self.map.keyframes[kf_id], min_inliers=30)
            if pose is not None:
                self.reference = self.map.keyframes[kf_id]
                return pose
        # Without a vocabulary hit, the latest keyframes of the map.
        for kf in reversed(self.map.live(self.atlas.current)[-5:]):
            pose = self._pnp_against(cur, kf, min_inliers=30)
            if pose is not None:
                self.reference = kf
                return pose
        self.stats.counts["relocalisation_failed"] += 1
        return None

    def _track_local_map(self, cur: Frame, wide: bool = False) -> bool:
        """Search the local map by projection, refine the pose; whether tracking holds.
        ``wide`` searches as after a relocalisation (a pose predicted over a blind
        stretch)."""
        assert cur.cam_from_world is not None
        local_kfs = self._local_keyframes(cur)
        if local_kfs:
            self.reference = local_kfs[0]
        ids = [kf.point_ids[kf.point_ids >= 0] for kf in local_kfs]
        pids = np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)
        pids = pids[self.map.alive[pids] & (self.map.map_id[pids] == self.atlas.current)]
        pids = np.setdiff1d(pids, cur.point_ids[cur.point_ids >= 0])
        pose = cur.cam_from_world
        visible, dist = in_view(self.rig.camera, self.map, pose, pids)
        pids, dist = pids[visible], dist[visible]
        self.map.visible[pids] += 1
        if pids.size:
            octv = self.map.predict_octave(pids, dist)
            th = 5.0 if self._since_reloc < 2 or wide else 3.0
            pairs = project_match(
                self.rig.camera,
                self.map.sigma,
                cur,
                pose,
                self.map.pos[pids],
                self.map.desc[pids],
                octv,
                th * 2.5,
                ratio=0.8,
            )
            free = cur.point_ids[pairs[:, 1]] < 0
            cur.point_ids[pairs[free, 1]] = pids[pairs[free, 0]]
        matched = np.flatnonzero(cur.point_ids >= 0)
        if matched.size < 6:
            return False
        est = self.rig.refine(
            pose,
            cur.keypoints[matched],
            self.map.pos[cur.point_ids[matched]],
            self.map.sigma[cur.octaves[matched]],
            cur.depth[matched],
        )
        if est is None:
            return False
        outliers = matched[~est.inliers]
        cur.point_ids[outliers] = -1
        cur.cam_from_world = est.cam_from_world
        inl = cur.point_ids[cur.point_ids >= 0]
        self.map.found[inl] += 1
        cur.inliers = int(inl.size)
        need = 50 if self._since_reloc < 2 else self.config.min_tracked
        if cur.inliers < need:
            self.stats.counts["local_map_too_few"] += 1
            return False
        return True

    def _local_keyframes(self, cur: Frame) -> list[Keyframe]:
        """Keyframes seeing the frame's points (most shared first), then their neighbours."""
        from collections import Counter

        obs = self.map.obs
        counts: Counter[int] = Counter(
            chain.from_iterable(obs[p] for p in cur.point_ids[cur.point_ids >= 0].tolist())
        )
        first = sorted(
            (k for k in counts if not self.map.keyframes[k].culled),
            key=lambda k: (-counts[k], k),
        )
        if not first and self.reference is not None:
            first = [self.reference.id]
        chosen = list(first[:80])
        seen = set(chosen)
        for k in first[:80]:
            if len(chosen) >= 80:
                break
            for nb, _w in self.map.covisible(self.map.keyframes[k])[:10]:
                if nb not in seen:
                    seen.add(nb)
                    chosen.append(nb)
                    break
        return [self.map.keyframes[k] for k in chosen]

    def set_last(self, cur: Frame) -> None:
        """Keep the frame's points for the next frame's motion-model search: its map points
        and, RGB-D, its other keypoints lifted with depth (ORB-SLAM's temporary points)."""
        assert cur.cam_from_world is not None
        self.last = cur
        has = cur.point_ids >= 0
        rows = np.flatnonzero(has)
        world = self.map.pos[cur.point_ids[rows]]
        pids = cur.point_ids[rows]
        if not self.rig.mono:
            extra = np.flatnonzero(~has & np.isfinite(cur.depth))
            if extra.size:
                cam = self.rig.camera
                from slamcli.geometry.camera import unproject

                pc = unproject(cam, cur.keypoints[extra], cur.depth[extra])
                w2c = inverse(cur.cam_from_world)
                world = np.concatenate([world, pc @ w2c[:3, :3].T + w2c[:3, 3]])
                rows = np.concatenate([rows, extra])
                pids = np.concatenate([pids, np.full(extra.size, -1, np.int64)])
        self._last_points = (
            world,
            cur.descriptors[rows],
            cur.octaves[rows].astype(np.int64),
            pids,
        )

    def _record(self, cur: Frame, state: str) -> None:
        assert cur.cam_from_world is not None and self.reference is not None
        rows = np.flatnonzero(cur.point_ids >= 0)
        self.atlas.frames.append(
            FrameRecord(
                cur.stamp_ns,
                self.reference.id,
                cur.cam_from_world @ inverse(self.reference.cam_from_world),
                cur.keypoints[rows].astype(np.float32),
                self.map.sigma[cur.octaves[rows]].astype(np.float32),
                cur.depth[rows].astype(np.float32),
                cur.point_ids[rows].astype(np.int32),
                state,
            )
        )

    def wants_keyframe(self, cur: Frame) -> bool:
        """Whether the tracked frame ``cur`` should become a keyframe (see the module's
        description)."""
        kf = self.reference
        assert kf is not None
        last_kf = self.map.keyframes[-1]
        if self._since_reloc < 2:
            return False
        live = self.map.live(self.atlas.current)
        min_obs = 2 if len(live) <= 2 else 3
        if not self.rig.mono:
            # ORB-SLAM counts an RGB-D observation twice (it carries depth).
            min_obs -= 1
        ref_pids = kf.point_ids[kf.point_ids >= 0]
        ref_matches = sum(1 for p in ref_pids.tolist() if len(self.map.obs[p]) >= min_obs)
        ratio = (
            max(self.config.keyframe_track_ratio, 0.9)
            if self.rig.mono
            else self.config.keyframe_track_ratio
        )
        if len(live) < 2 and not self.rig.mono:
            ratio = 0.4
        tracked = cur.inliers
        need_close = False
        if not self.rig.mono:
            # ORB-SLAM's "close" points lie nearer than its depth threshold: for a stereo pair
            # that is the near/far split itself; RGB-D keeps three quarters of its range.
            near = self.rig.depth_max_m * (1.0 if self.rig.stereo else 0.75)
            close = np.isfinite(cur.depth) & (cur.depth < near)
            tracked_close = int(np.count_nonzero(close & (cur.point_ids >= 0)))
            untracked_close = int(np.count_nonzero(close & (cur.point_ids < 0)))
            need_close = tracked_close < 100 and untracked_close > 70
        # Offline, local mapping is never busy: ORB-SLAM's "mapping idle" condition always
        # holds, so a keyframe is made whenever tracking weakens, or after keyframe_max_frames
        # frames or keyframe_max_seconds (at 10 Hz, ten frames apart the keyframes of a turning
        # camera share too few points to hold the map's scale and rotation together).
        weak = (tracked < ref_matches * ratio or need_close) and tracked > 15
        late = (
            cur.index - last_kf.frame >= self.config.keyframe_max_frames
            or cur.stamp_ns - last_kf.stamp_ns >= round(self.config.keyframe_max_seconds * 1e9)
        )
        overdue = late and tracked > 15
        return bool(weak or overdue)
