"""Monocular initialisation of the visual pipeline: the first two keyframes of a map from two
views (ORB-SLAM's Initializer)."""

from __future__ import annotations

from typing import Any

import numpy as np

from slamcli.pipelines.visual.atlas import Keyframe
from slamcli.pipelines.visual.frames import Frame
from slamcli.pipelines.visual.inertial import Inertial
from slamcli.pipelines.visual.local_mapping import LocalMapping
from slamcli.pipelines.visual.parts import Part, Shared
from slamcli.vision.matching import TH_HIGH, match_ratio
from slamcli.vision.two_view import two_view_geometry


class MonoInitializer(Part):
    """Two-view initialisation: the first frame with enough features is the reference; a later
    one with enough matches and parallax to it gives the map's first two keyframes and points
    (homography or fundamental matrix, triangulation, a bundle adjustment, the scale set so the
    reference's median depth is 1). ``info`` describes the initialisation once it happened."""

    def __init__(self, shared: Shared, mapper: LocalMapping) -> None:
        super().__init__(shared)
        self.mapper = mapper
        self._ref: Frame | None = None
        self.info: dict[str, Any] | None = None
        self.inertial: Inertial | None = None

    def reset(self) -> None:
        """Start again from the next frame (a new map is started)."""
        self._ref = None

    def initialise(self, cur: Frame) -> tuple[Frame, Keyframe, Keyframe] | None:
        """Try to initialise a map with frame ``cur``: the reference frame and the map's first
        two keyframes (made from it and from ``cur``), or None while there is no map yet."""
        ref = self._ref
        if len(cur.features) < 100:
            return None
        if ref is None:
            self._ref = cur
            return None
        pairs = match_ratio(ref.descriptors, cur.descriptors, 0.9, TH_HIGH)
        if len(pairs):
            moved = np.linalg.norm(ref.keypoints[pairs[:, 0]] - cur.keypoints[pairs[:, 1]], axis=1)
            # ORB-SLAM searches a 100-pixel window around the reference keypoint.
            pairs = pairs[moved <= 100.0 * max(1.0, self.rig.camera.width / 640.0)]
        if len(pairs) < 100:
            self.stats.counts["init_too_few_matches"] += 1
            self._ref = cur
            return None
        found = two_view_geometry(
            self.rig.camera,
            ref.keypoints[pairs[:, 0]],
            cur.keypoints[pairs[:, 1]],
            self.map.sigma[ref.octaves[pairs[:, 0]]],
            min_parallax_deg=self.config.mono_min_parallax_deg,
            min_points=self.config.mono_min_points,
            seed=self.config.seed,
        )
        if found.points is None:
            self.stats.counts[f"init_rejected_{found.reason}"] += 1
            return None
        if self.inertial is not None and not self.inertial.agrees(
            ref.stamp_ns, cur.stamp_ns, found.cur_from_ref[:3, :3]
        ):
            # Two views can fit a wrong motion (a homography's other decomposition, a
            # near-planar scene); the gyroscope knows the rotation between them.
            self.stats.counts["init_rejected_gyro"] += 1
            self._ref = cur
            return None
        good = found.good
        # Scale: median depth 1 in the reference.
        median = float(np.median(found.points[good, 2]))
        cur_from_ref = found.cur_from_ref.copy()
        cur_from_ref[:3, 3] /= median
        world = found.points[good] / median
        ref.cam_from_world = np.eye(4)
        cur.cam_from_world = cur_from_ref
        kf0 = self.mapper.new_keyframe(ref)
        kf1 = self.mapper.new_keyframe(cur)
        kf1.parent = kf0.id
        pids = self.map.add_points(kf0, pairs[good, 0], world)
        for kp, pid in zip(pairs[good, 1].tolist(), pids.tolist(), strict=True):
            self.map.observe(kf1, kp, pid)
        self.map.update_geometry(pids)
        self.mapper.ba.bundle([kf0, kf1], np.array([True, False]), pids, 20)
        # Re-normalise after the adjustment.
        live = kf0.point_ids[kf0.point_ids >= 0]
        depths = self.map.pos[live, 2]
        if live.size < self.config.mono_min_points or not np.all(np.isfinite(depths)):
            self.stats.counts["init_rejected_after_ba"] += 1
            self.mapper.discard_map(kf0.map_id)
            return None
        scale = 1.0 / float(np.median(depths))
        self.map.pos[live] *= scale
        kf1.cam_from_world[:3, 3] *= scale
        self.atlas.open_map(ref.index)
        self.stats.counts["init_" + found.model] += 1
        self.info = {
            "model": found.model,
            "frames": [ref.index, cur.index],
            "points": int(live.size),
            "median_parallax_deg": round(found.parallax_deg, 3),
        }
        self._ref = None
        return ref, kf0, kf1
