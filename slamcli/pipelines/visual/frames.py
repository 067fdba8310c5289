"""Frames as the visual pipeline tracks them, and the camera rig they come from.

:class:`Rig` holds what is fixed for a run: the camera (set by the first frame; keypoints, not
images, are undistorted), whether depth is used (RGB-D) or not (monocular), the ORB settings
and how a pose is refined against matched points. :class:`Frame` is one image ready to track:
its ORB features, undistorted keypoints, the depth under each (RGB-D) and the colour.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.pipelines import Evaluation
from slamcli.pipelines.visual.config import VisualConfig
from slamcli.types import ImageFrame, PinholeCamera, RgbdFrame
from slamcli.vision.features import Features, OrbSettings, depth_at, extract_orb
from slamcli.vision.pnp import PoseEstimate, refine_pose, refine_pose_depth

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


@dataclass
class Frame:
    """A frame being tracked.

    Attributes:
        index: position in the input (0-based).
        stamp_ns: its stamp.
        name: its name in the input (for messages).
        features: ORB features on the raw image.
        keypoints: (N, 2) undistorted pixels.
        depth: (N,) metres under each keypoint, NaN where unknown (monocular: all NaN).
        colors: (N, 3) uint8 colour under each keypoint.
        cam_from_world: (4, 4) pose once tracked.
        point_ids: (N,) map point of each keypoint, -1 for none.
        inliers: map points the pose was refined on.
    """

    index: int
    stamp_ns: int
    name: str
    features: Features
    keypoints: F64
    depth: F64
    colors: NDArray[np.uint8]
    cam_from_world: F64 | None = None
    point_ids: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    inliers: int = 0

    @property
    def descriptors(self) -> NDArray[np.uint8]:
        """(N, 32) ORB descriptors."""
        return self.features.descriptors

    @property
    def octaves(self) -> NDArray[np.int16]:
        """(N,) pyramid levels."""
        return self.features.octaves


def _refine_pose(
    camera: PinholeCamera,
    mono: bool,
    baseline_m: float,
    pose: F64,
    kp: F64,
    world: F64,
    sigma: F64,
    depth: F64,
    rounds: int = 4,
) -> PoseEstimate | None:
    """The visual pipeline's robust pose refinement (see :meth:`Rig.refine`)."""
    if mono:
        return refine_pose(camera, pose, kp, world, sigma_px=sigma, rounds=min(rounds, 3))
    return refine_pose_depth(
        camera, pose, kp, world, depth, sigma_px=sigma, baseline_m=baseline_m, rounds=rounds
    )


def refine_poses(
    camera: PinholeCamera,
    mono: bool,
    baseline_m: float,
    jobs: list[tuple[F64, F64, F64, F64, F64]],
) -> list[F64 | None]:
    """Final re-estimation of frames, each ``(pose, keypoints, points, sigma, depth)``: the
    refined pose, or None where the refinement keeps fewer than ten inliers."""
    out: list[F64 | None] = []
    for pose, kp, world, sigma, depth in jobs:
        est = _refine_pose(camera, mono, baseline_m, pose, kp, world, sigma, depth)
        out.append(est.cam_from_world if est is not None and est.num_inliers >= 10 else None)
    return out


class Rig:
    """The camera the frames come from, set by the first frame, and what follows from it.

    ``mono`` says whether depth is used; it is settled before the first frame (by the config's
    mode, or by what the input holds: :meth:`VisualSlam.frame_kinds`).
    """

    def __init__(self, config: VisualConfig) -> None:
        self.config = config
        self.mono = config.mode == "mono"
        self.orb = OrbSettings(
            n_features=config.max_features,
            levels=config.levels,
            scale=config.scale_factor,
            fast_threshold=config.fast_threshold,
        )
        self._camera: PinholeCamera | None = None
        self._raw_camera: PinholeCamera | None = None

    @property
    def camera(self) -> PinholeCamera:
        """The undistorted camera (the first frame's)."""
        assert self._camera is not None
        return self._camera

    @property
    def evaluation(self) -> Evaluation:
        """How the trajectory is scored: ``sim3`` without depth (no metric scale), else
        ``se3``."""
        return "sim3" if self.mono else "se3"

    def extract(self, frame: RgbdFrame | ImageFrame) -> Features:
        """ORB features of ``frame``'s image (no state is changed: it may run on another
        thread)."""
        import cv2

        rgb = frame.rgb if isinstance(frame, RgbdFrame) else frame.image
        if rgb.ndim == 2:
            gray = np.ascontiguousarray(rgb, dtype=np.uint8)
        else:
            colour = np.ascontiguousarray(rgb[..., :3], dtype=np.uint8)
            gray = np.asarray(cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
        return extract_orb(gray, self.orb)

    def prepare(self, frame: RgbdFrame | ImageFrame, features: Features, index: int) -> Frame:
        """``frame`` with its ``features``, ready to track as the ``index``-th frame.

        Raises:
            InputError: the frame has no camera, its images disagree with the camera or with
                each other, or the camera differs from the first frame's.
        """
        rgb = frame.rgb if isinstance(frame, RgbdFrame) else frame.image
        cam = frame.camera
        if cam is None:
            raise InputError(
                f"frame {frame.name or frame.stamp_ns}: no camera calibration",
                hint="give one with --camera FILE",
            )
        h, w = rgb.shape[:2]
        if (cam.height, cam.width) != (h, w):
            raise InputError(
                f"frame {frame.name or frame.stamp_ns}: the image is {w}x{h} but the camera "
                f"is {cam.width}x{cam.height}",
                hint="give the camera calibration that matches the images (--camera FILE)",
            )
        if isinstance(frame, RgbdFrame) and frame.depth_m.shape[:2] != (h, w):
            raise InputError(
                f"frame {frame.name or frame.stamp_ns}: colour {w}x{h} but depth "
                f"{frame.depth_m.shape[1]}x{frame.depth_m.shape[0]}",
                hint="the visual pipeline needs depth registered to the colour image",
            )
        if self._raw_camera is None:
            self._raw_camera = cam
            self._camera = cam.undistorted()
        elif cam != self._raw_camera:
            raise InputError(
                f"frame {frame.name or frame.stamp_ns}: the camera changed mid-sequence",
                hint="the visual pipeline needs one fixed camera",
            )
        from slamcli.vision.features import undistort_keypoints

        kp_raw = features.keypoints
        kp = undistort_keypoints(cam, kp_raw)
        if isinstance(frame, RgbdFrame) and not self.mono:
            depth = np.nan_to_num(np.asarray(frame.depth_m, np.float32), nan=0.0, posinf=0.0)
            z = depth_at(kp_raw, depth)
            z[(z < self.config.depth_min_m) | (z > self.config.depth_max_m)] = np.nan
        else:
            z = np.full(len(kp), np.nan)
        u = np.clip(np.rint(kp_raw[:, 0]).astype(np.int64), 0, w - 1)
        v = np.clip(np.rint(kp_raw[:, 1]).astype(np.int64), 0, h - 1)
        colors = (
            np.repeat(rgb[v, u][:, None], 3, axis=1)
            if rgb.ndim == 2
            else np.asarray(rgb[v, u][:, :3], dtype=np.uint8)
        )
        return Frame(
            index=index,
            stamp_ns=frame.stamp_ns,
            name=frame.name,
            features=features,
            keypoints=kp,
            depth=z,
            colors=np.asarray(colors, dtype=np.uint8),
            point_ids=np.full(len(kp), -1, np.int64),
        )

    def refine(
        self, pose: F64, kp: F64, world: F64, sigma: F64, depth: F64, rounds: int = 4
    ) -> PoseEstimate | None:
        """Robust pose refinement of ``pose`` (cam_from_world) on keypoints ``kp`` (N, 2)
        matched to points ``world`` (N, 3): with the keypoints' depths for RGB-D (a
        stereo-like residual), reprojection only for monocular; ``rounds`` of outlier
        rejection."""
        return _refine_pose(
            self.camera,
            self.mono,
            self.config.depth_baseline_m,
            pose,
            kp,
            world,
            sigma,
            depth,
            rounds,
        )

    def refine_jobs(self) -> tuple[PinholeCamera, bool, float]:
        """The leading arguments of :func:`refine_poses` for this rig."""
        return (self.camera, self.mono, self.config.depth_baseline_m)
