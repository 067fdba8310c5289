"""Frames and keyframes of the dense pipeline, and the camera rig that prepares them.

:class:`Rig` holds what the first frame fixes: the camera (undistorted when it has lens
distortion and ``undistort`` is on), the tracking images' scale and Open3D. It prepares each
frame (no state is changed: it may run on a second thread): depth cleaned and cut to the depth
range, the front end's features, the tracking image.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import PipelineError
from slamcli.formats.images import pack_rgbd, unpack_rgbd
from slamcli.geometry.camera import undistort_image
from slamcli.pipelines.dense.config import DenseConfig
from slamcli.pipelines.dense.volume import open3d, tracking_camera
from slamcli.types import PinholeCamera, RgbdFrame
from slamcli.vision.features import lift

F64 = NDArray[np.float64]

Features = tuple[NDArray[np.float32], NDArray[np.uint8], Any]
"""What a front end extracts from a frame: (M, 2) float32 keypoints, (M, 32) uint8 ORB
descriptors (M may be 0), and what else it needs to track the frame."""


@dataclass
class Frame:
    """One input frame, prepared for tracking.

    Attributes:
        index: position in the input (0-based).
        stamp_ns: colour stamp.
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32 metres, 0 where invalid or outside the depth range.
        valid_fraction: share of pixels with valid depth.
        keypoints: (M, 2) float32 ORB keypoint pixels.
        descriptors: (M, 32) uint8 ORB descriptors (M may be 0).
        points_cam: (M, 3) float64 keypoints lifted with depth, camera frame; NaN rows where
            the depth is invalid.
        small: Open3D RGB-D image at the tracking scale (colour float32 in [0, 1]).
        front: what the front end needs to track the frame, until it has (the visual front
            end: the input frame and its features).
    """

    index: int
    stamp_ns: int
    rgb: NDArray[np.uint8]
    depth: NDArray[np.float32]
    valid_fraction: float
    keypoints: NDArray[np.float32]
    descriptors: NDArray[np.uint8]
    points_cam: F64
    small: Any
    front: Any = None


@dataclass
class Keyframe:
    """A keyframe: the frame and its pose when it was made (world_from_cam (4, 4)).

    Once the next keyframe exists, the frame's images are packed (``packed``, see
    :func:`~slamcli.formats.images.pack_rgbd`) and released from ``frame``: its features stay,
    for PnP, and the images are decoded again when a loop is verified or the volume is
    rebuilt. ``info_to_previous`` is the (6, 6) information of the odometry edge from the
    previous keyframe, computed while both images were at hand (``front_end=frames``).
    """

    id: int
    frame: Frame
    world_from_cam: F64
    packed: tuple[bytes, bytes] | None = None
    info_to_previous: F64 | None = None


_RELEASED_RGB = np.zeros((0, 0, 3), dtype=np.uint8)
_RELEASED_DEPTH = np.zeros((0, 0), dtype=np.float32)


class Rig:
    """The camera of a run and the images tracking works on (see the module's description)."""

    def __init__(self, config: DenseConfig) -> None:
        self.config = config
        self.o3d: Any = None
        self._camera: PinholeCamera | None = None
        self._raw_camera: PinholeCamera | None = None
        self._undistort = False
        self.downsample = 1

    @property
    def camera(self) -> PinholeCamera:
        """The camera of the prepared images (the first frame's, undistorted if need be)."""
        assert self._camera is not None
        return self._camera

    def check(self, frame: RgbdFrame) -> None:
        """The frame's images and camera agree, and the camera is the first frame's (which
        sets up the camera and the tracking scale).

        Raises:
            PipelineError: they disagree, or the camera changed.
        """
        cam = frame.camera
        h, w = frame.depth_m.shape[:2]
        if frame.rgb.shape[:2] != (h, w) or (cam.height, cam.width) != (h, w):
            raise PipelineError(
                f"frame {frame.name or frame.stamp_ns}: colour {frame.rgb.shape[1]}x"
                f"{frame.rgb.shape[0]}, depth {w}x{h} and camera {cam.width}x{cam.height} "
                "must agree",
                hint="give the camera calibration that matches the images",
            )
        cfg = self.config
        if self._raw_camera is None:
            self._raw_camera = cam
            self.o3d = open3d()
            self._undistort = cfg.undistort and cam.is_distorted
            self._camera = cam.undistorted() if self._undistort else cam
            self.downsample = max(
                1, min(cfg.track_downsample, 2 ** int(math.log2(max(1, w // 160))))
            )
        elif cam != self._raw_camera:
            raise PipelineError(
                f"frame {frame.name or frame.stamp_ns}: the camera changed mid-sequence",
                hint="the dense pipeline needs one fixed camera",
            )

    def prepare(
        self, frame: RgbdFrame, features: Callable[[RgbdFrame, NDArray[np.uint8]], Features]
    ) -> Frame:
        """Clean the images, take the front end's ``features`` (of the input frame and the
        prepared colour image) and build the tracking image. ``index`` is set when the frame
        is tracked."""
        cfg = self.config
        cam = frame.camera
        camera = self.camera
        depth = np.nan_to_num(np.asarray(frame.depth_m, dtype=np.float32), nan=0.0, posinf=0.0)
        rgb = np.ascontiguousarray(frame.rgb, dtype=np.uint8)
        if self._undistort:
            rgb = undistort_image(cam, rgb)
            depth = undistort_image(cam, depth, nearest=True)
        depth[(depth < cfg.depth_min_m) | (depth > cfg.depth_max_m)] = 0.0
        valid_fraction = float(np.count_nonzero(depth)) / depth.size
        keypoints, desc, front = features(frame, rgb)
        return Frame(
            index=-1,
            stamp_ns=frame.stamp_ns,
            rgb=rgb,
            depth=depth,
            valid_fraction=valid_fraction,
            keypoints=keypoints,
            descriptors=desc,
            points_cam=lift(keypoints, depth, camera),
            small=self.tracking_image(rgb, depth),
            front=front,
        )

    def pack(self, kf: Keyframe) -> None:
        """Keep ``kf``'s images compressed and release the arrays (see :class:`Keyframe`)."""
        if kf.packed is not None:
            return
        frame = kf.frame
        packed = pack_rgbd(frame.rgb, frame.depth)
        if packed is None:
            return
        kf.packed = packed
        kf.frame = replace(frame, rgb=_RELEASED_RGB, depth=_RELEASED_DEPTH, small=None)

    def images(self, kf: Keyframe) -> Frame:
        """``kf``'s frame with its images (decoded from ``packed`` when they were released)."""
        if kf.packed is None:
            return kf.frame
        rgb, depth = unpack_rgbd(kf.packed)
        return replace(kf.frame, rgb=rgb, depth=depth, small=self.tracking_image(rgb, depth))

    def small_intrinsics(self) -> Any:
        """The (3, 3) intrinsics of the tracking images, as an Open3D tensor."""
        return self.o3d.core.Tensor(tracking_camera(self.camera, self.downsample).K)

    def full_image(self, frame: Frame) -> Any:
        """Open3D RGB-D image of a frame at full resolution (colour float32 in [0, 1])."""
        geometry = self.o3d.t.geometry
        colour = frame.rgb.astype(np.float32) / np.float32(255.0)
        return geometry.RGBDImage(geometry.Image(colour), geometry.Image(frame.depth))

    def tracking_image(self, rgb: NDArray[np.uint8], depth: NDArray[np.float32]) -> Any:
        """Open3D RGB-D image shrunk by ``track_downsample``: colour by area averaging, depth
        by averaging only blocks whose readings are all valid and agree within 3 cm."""
        import cv2

        o3d = self.o3d
        k = self.downsample
        small_cam = tracking_camera(self.camera, k)
        hs, ws = small_cam.height, small_cam.width
        colour = rgb[: hs * k, : ws * k].astype(np.float32) / np.float32(255.0)
        blocks = depth[: hs * k, : ws * k].reshape(hs, k, ws, k)
        if k > 1:
            colour = cv2.resize(colour, (ws, hs), interpolation=cv2.INTER_AREA)
            lo, hi = blocks.min(axis=(1, 3)), blocks.max(axis=(1, 3))
            small = np.where((lo > 0) & (hi - lo < 0.03), blocks.mean(axis=(1, 3)), 0.0)
        else:
            small = blocks[:, 0, :, 0]
        return o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(np.ascontiguousarray(colour)),
            o3d.t.geometry.Image(np.ascontiguousarray(small, dtype=np.float32)),
        )
