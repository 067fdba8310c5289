"""Frame-to-model tracking of the dense pipeline.

A frame is registered to a ray cast of the TSDF volume with Open3D's multi-scale tensor RGB-D
odometry, from a seed pose: with ``front_end=frames`` (:meth:`ModelTracker.track`), ORB
features of the previous frame, lifted with depth, give a PnP seed checked against the
constant-velocity prediction; the refinement follows, then frame-to-frame odometry, the
features alone or relocalisation against the keyframes when it is not trusted; a frame with
none is lost.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import compose, inverse
from slamcli.pipelines.dense.config import DenseConfig
from slamcli.pipelines.dense.frames import Frame, Keyframe, Rig
from slamcli.pipelines.dense.volume import Volume
from slamcli.pipelines.rgbd_odometry import rgbd_odometry_multi_scale
from slamcli.pipelines.timing import Stats
from slamcli.vision.matching import match_ratio
from slamcli.vision.pnp import pnp_opencv, within

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

# While frames are lost, the constant-velocity prediction moves on for this many frames, then
# waits where it is: a long gap compounded at the last speed would fly off the map.
_PREDICT_LOST_FRAMES = 5


@dataclass
class Model:
    """What frames are tracked against: the TSDF volume (None until a frame is fused) and the
    keyframes."""

    volume: Volume | None = None
    keyframes: list[Keyframe] = field(default_factory=list)


@dataclass
class Track:
    """The poses of the frames that have one: their stamps, world_from_cam (4, 4) poses and
    input indices, in input order."""

    stamps: list[int] = field(default_factory=list)
    poses: list[F64] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)


class ModelTracker:
    """Registration of frames against the model and the previous frame, with the motion
    prior: ``previous_pose`` and ``velocity`` (constant velocity), ``reference`` (the last
    fused frame, with its pose)."""

    def __init__(self, config: DenseConfig, rig: Rig, model: Model, stats: Stats) -> None:
        self.config, self.rig, self.model, self.stats = config, rig, model, stats
        self.previous_pose: F64 | None = None
        self.velocity = np.eye(4)
        self.lost_run = 0
        self.reference: Frame | None = None
        self.reference_pose = np.eye(4)

    def moved(self, pose: F64) -> None:
        """The frame just tracked has world_from_cam ``pose``: the motion prior follows it."""
        if self.previous_pose is not None and self.lost_run == 0:
            self.velocity = compose(inverse(self.previous_pose), pose)
        else:
            self.velocity = np.eye(4)
        self.lost_run = 0
        self.previous_pose = pose

    def lost(self) -> None:
        """The frame just tracked was lost: the prediction moves on for a few frames."""
        self.lost_run += 1
        if self.previous_pose is not None and self.lost_run <= _PREDICT_LOST_FRAMES:
            self.previous_pose = compose(self.previous_pose, self.velocity)

    def track(self, cur: Frame) -> tuple[F64 | None, str]:
        """Pose ``cur`` by PnP against the previous frame, refined against the model (see the
        module's description)."""
        cfg = self.config
        if self.previous_pose is None:
            return np.eye(4), "tracked_first"
        predicted = compose(self.previous_pose, self.velocity)
        seed_pose = None
        if self.reference is not None:
            with self.stats.timed("features"):
                ref_from_cur, _ = self.pnp(self.reference, cur, cfg.pnp_min_inliers)
            if ref_from_cur is not None:
                seed_pose = compose(self.reference_pose, ref_from_cur)
                if not self._plausible(seed_pose, predicted):
                    self.stats.counts["pnp_rejected_jump"] += 1
                    seed_pose = None
        depth_ok = cur.valid_fraction >= cfg.min_valid_depth_fraction
        start = predicted if seed_pose is None else seed_pose
        if depth_ok and self.model.volume is not None:
            with self.stats.timed("track_model"):
                refined = self.refine_model(cur, start)
            if refined is not None and self._accept(refined, predicted, seed_pose):
                return refined, "tracked_model"
            if self.reference is not None:
                with self.stats.timed("track_f2f"):
                    refined = self._refine_f2f(cur, start)
                if refined is not None and self._accept(refined, predicted, seed_pose):
                    return refined, "recovered_f2f"
        if seed_pose is not None:
            return seed_pose, "recovered_pnp"
        with self.stats.timed("relocalise"):
            relocalised = self._relocalise(cur)
        if relocalised is not None:
            return relocalised, "recovered_relocalised"
        return None, "lost_no_registration"

    def pnp(self, ref: Frame, cur: Frame, min_inliers: int) -> tuple[F64 | None, int]:
        """``ref_from_cur`` (4, 4) from ORB matches and PnP RANSAC (or None), and the inlier
        count of the attempt."""
        cfg = self.config
        usable = np.isfinite(ref.points_cam[:, 0])
        if np.count_nonzero(usable) < min_inliers or len(cur.descriptors) < min_inliers:
            return None, 0
        idx = np.flatnonzero(usable)
        matches = match_ratio(ref.descriptors[idx], cur.descriptors, cfg.match_ratio)
        if len(matches) < min_inliers:
            return None, 0
        return pnp_opencv(
            ref.points_cam[idx[matches[:, 0]]],
            cur.keypoints[matches[:, 1]].astype(np.float64),
            self.rig.camera.K,
            seed=cfg.seed,
            iterations=cfg.pnp_iterations,
            threshold_px=cfg.pnp_reprojection_px,
            min_inliers=min_inliers,
        )

    def refine_model(self, cur: Frame, seed_pose: F64) -> F64 | None:
        """Register ``cur`` to a ray cast of the volume seen from ``seed_pose``."""
        assert self.model.volume is not None
        with self.stats.timed("raycast"):
            model = self.model.volume.ray_cast(seed_pose, self.rig.downsample)
        if model is None:
            return None
        model_from_cur = self.odometry(cur.small, model, np.eye(4), self._method)
        return None if model_from_cur is None else compose(seed_pose, model_from_cur)

    def _refine_f2f(self, cur: Frame, seed_pose: F64) -> F64 | None:
        """Register ``cur`` to the previous frame with depth (photometric + geometric)."""
        assert self.reference is not None
        init = compose(inverse(self.reference_pose), seed_pose)
        o3d_hybrid = self.rig.o3d.t.pipelines.odometry.Method.Hybrid
        ref_from_cur = self.odometry(cur.small, self.reference.small, init, o3d_hybrid)
        return None if ref_from_cur is None else compose(self.reference_pose, ref_from_cur)

    def odometry(self, source: Any, target: Any, init: F64, method: Any) -> F64 | None:
        """``target_from_source`` (4, 4) by multi-scale RGB-D odometry, or None on failure."""
        odo = self.rig.o3d.t.pipelines.odometry
        cfg = self.config
        try:
            result = rgbd_odometry_multi_scale(
                self.rig.o3d,
                source,
                target,
                self.rig.small_intrinsics(),
                self.rig.o3d.core.Tensor(np.ascontiguousarray(init)),
                1.0,
                cfg.depth_max_m,
                [odo.OdometryConvergenceCriteria(n) for n in cfg.odometry_iterations],
                method,
                odo.OdometryLossParams(cfg.depth_outlier_m),
            )
        except RuntimeError as exc:
            # Open3D reports a degenerate system ("Singular 6x6 linear system") this way.
            self.stats.counts["odometry_singular"] += 1
            log.debug("RGB-D odometry failed: %s", exc)
            return None
        if result.fitness < cfg.min_fitness:
            self.stats.counts["odometry_low_fitness"] += 1
            return None
        return np.asarray(result.transformation.numpy(), dtype=np.float64)

    def _accept(self, pose: F64, predicted: F64, seed_pose: F64 | None) -> bool:
        """A refined pose is trusted when it stays within the motion prior and, when there is
        a feature seed, close to it."""
        if not self._plausible(pose, predicted):
            self.stats.counts["rejected_jump"] += 1
            return False
        cfg = self.config
        if seed_pose is not None and not within(
            seed_pose, pose, cfg.max_seed_disagreement_m, cfg.max_seed_disagreement_deg
        ):
            self.stats.counts["rejected_seed_disagreement"] += 1
            return False
        return True

    def _plausible(self, pose: F64, predicted: F64) -> bool:
        """Whether ``pose`` stays within the motion limits of the prediction."""
        return within(predicted, pose, self.config.max_jump_m, self.config.max_jump_deg)

    def _relocalise(self, cur: Frame) -> F64 | None:
        """Pose from PnP against the latest keyframes, most inliers first; None if none fits."""
        for kf in reversed(self.model.keyframes[-self.config.relocalise_keyframes :]):
            kf_from_cur, _ = self.pnp(kf.frame, cur, self.config.pnp_min_inliers)
            if kf_from_cur is not None:
                return compose(kf.world_from_cam, kf_from_cur)
        return None

    def information(self, source: Frame, target: Frame, target_from_source: F64) -> F64:
        """(6, 6) information of a relative pose from the depth correspondences it explains."""
        odo = self.rig.o3d.t.pipelines.odometry
        info = odo.compute_odometry_information_matrix(
            source.small.depth,
            target.small.depth,
            self.rig.small_intrinsics(),
            self.rig.o3d.core.Tensor(np.ascontiguousarray(target_from_source)),
            self.config.depth_outlier_m,
            1.0,
            self.config.depth_max_m,
        )
        return np.asarray(info.numpy(), dtype=np.float64)

    @property
    def _method(self) -> Any:
        """Open3D's odometry loss for ``odometry_method``."""
        odo = self.rig.o3d.t.pipelines.odometry
        return {
            "hybrid": odo.Method.Hybrid,
            "point_to_plane": odo.Method.PointToPlane,
            "intensity": odo.Method.Intensity,
        }[self.config.odometry_method]
