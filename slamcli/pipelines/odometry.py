"""Frame-to-frame RGB-D odometry: the simplest tracker, and the baseline the demo reports.

Each frame is registered to the previous one with Open3D's multi-scale tensor RGB-D odometry
(photometric + geometric "hybrid" loss by default), seeded with a constant-velocity prior.
A registration that throws, finds too few correspondences or jumps further than the motion
limits allow is not trusted: the pose is predicted from the prior and the frame is counted as
lost.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.config import setting
from slamcli.geometry import compose, inverse, rotation_angle
from slamcli.pipelines import PipelineBase
from slamcli.types import RgbdFrame, SlamResult, Trajectory

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OdometryConfig:
    """Settings of :class:`RgbdOdometry`."""

    method: str = setting(
        "hybrid",
        help="Open3D loss: photometric + geometric, geometric only, or photometric only",
        choices=("hybrid", "point_to_plane", "intensity"),
    )
    depth_max_m: float = setting(4.0, help="ignore depth beyond this", unit="m", gt=0)
    depth_outlier_m: float = setting(
        0.07, help="drop correspondences further apart than this", unit="m", gt=0
    )
    iterations: tuple[int, ...] = setting(
        (10, 5, 3), help="iterations per pyramid level, coarse last", min=1
    )
    min_fitness: float = setting(
        0.2, help="fraction of pixels that must correspond to trust a step", min=0, max=1
    )
    max_step_m: float = setting(
        0.25, help="a step this far beyond the motion prior is not trusted", unit="m", gt=0
    )
    max_step_deg: float = setting(
        20.0, help="a turn this far beyond the motion prior is not trusted", unit="deg", gt=0
    )


class RgbdOdometry(PipelineBase):
    """Pipeline ``odometry``: consumes ``rgbd`` frames, produces a trajectory."""

    name = "odometry"
    consumes = ("rgbd",)
    config_class = OdometryConfig

    def __init__(self, config: OdometryConfig | None = None) -> None:
        self.config = config or OdometryConfig()
        self._stamps: list[int] = []
        self._poses: list[NDArray[np.float64]] = []
        self._previous: Any = None
        self._velocity = np.eye(4)
        self._lost = 0

    def process(self, frame: RgbdFrame) -> None:
        current = self._to_open3d(frame)
        if self._previous is None:
            world_from_cam = np.eye(4)
        else:
            prev_from_cur = self._track(current)
            world_from_cam = compose(self._poses[-1], prev_from_cur)
            self._velocity = prev_from_cur
        self._stamps.append(frame.stamp_ns)
        self._poses.append(world_from_cam)
        self._previous = current

    def seeds(self) -> dict[str, int]:
        """Seeds of the random number generators a run uses, by generator: none, the odometry
        draws no random numbers."""
        return {}

    def finish(self) -> SlamResult:
        traj = (
            Trajectory(np.array(self._stamps, dtype=np.int64), np.stack(self._poses))
            if self._poses
            else None
        )
        return SlamResult(
            trajectory=traj,
            counts={"frames_tracked": len(self._poses) - self._lost, "frames_lost": self._lost},
        )

    def _to_open3d(self, frame: RgbdFrame) -> Any:
        from slamcli.backends import import_open3d

        o3d = import_open3d()

        depth = np.nan_to_num(frame.depth_m, nan=0.0).astype(np.float32, copy=False)
        return (
            o3d.t.geometry.RGBDImage(
                o3d.t.geometry.Image(np.ascontiguousarray(frame.rgb)),
                o3d.t.geometry.Image(np.ascontiguousarray(depth)),
            ),
            o3d.core.Tensor.from_numpy(frame.camera.K),
        )

    def _track(self, current: Any) -> NDArray[np.float64]:
        """Pose of the current camera in the previous camera's frame."""
        from slamcli.backends import import_open3d
        from slamcli.pipelines.rgbd_odometry import rgbd_odometry_multi_scale

        o3d = import_open3d()

        odo = o3d.t.pipelines.odometry
        cfg = self.config
        method = {
            "hybrid": odo.Method.Hybrid,
            "point_to_plane": odo.Method.PointToPlane,
            "intensity": odo.Method.Intensity,
        }[cfg.method]
        (rgbd_cur, intrinsics), (rgbd_prev, _) = current, self._previous
        # Open3D estimates source_to_target; with source = current and target = previous that
        # is prev_from_cur, the relative motion we chain.
        try:
            result = rgbd_odometry_multi_scale(
                o3d,
                rgbd_cur,
                rgbd_prev,
                intrinsics,
                o3d.core.Tensor.from_numpy(self._velocity),
                1.0,
                cfg.depth_max_m,
                [odo.OdometryConvergenceCriteria(n) for n in cfg.iterations],
                method,
                odo.OdometryLossParams(cfg.depth_outlier_m),
            )
            step = result.transformation.numpy()
            trusted = result.fitness >= cfg.min_fitness and self._plausible(step)
        except RuntimeError as exc:
            log.debug("odometry failed: %s", exc)
            trusted = False
        if trusted:
            return np.asarray(step, dtype=np.float64)
        self._lost += 1
        return self._velocity.copy()

    def _plausible(self, step: NDArray[np.float64]) -> bool:
        jump = compose(inverse(self._velocity), step)
        return bool(
            np.linalg.norm(jump[:3, 3]) <= self.config.max_step_m
            and np.degrees(rotation_angle(jump)) <= self.config.max_step_deg
        )
