"""Frames as the visual pipeline tracks them, and the camera rig they come from.

:class:`Rig` holds what is fixed for a run: the camera (set by the first frame; keypoints, not
images, are undistorted), where depth comes from (an RGB-D depth image, a rectified stereo
pair, or nowhere: monocular), the ORB settings and how a pose is refined against matched
points. :class:`Frame` is one image ready to track: its ORB features, undistorted keypoints,
the depth of each (under it in the depth image, or from its match in the right image) and the
colour.

A keypoint with depth is weighed as a stereo observation: its right-image column
``u - fx * baseline / depth`` is a second residual (ORB-SLAM's RGB-D mode uses a virtual
baseline; a stereo rig has a real one). Stereo keypoints further than ``stereo_far_baselines``
baselines are far points: their depth is dropped, so they constrain rotation only until local
mapping triangulates them from the motion between keyframes; when fewer than
``stereo_min_near`` are near, the nearest far ones keep theirs (:func:`near_depths`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError
from slamcli.pipelines import Evaluation
from slamcli.pipelines.visual.config import VisualConfig
from slamcli.types import ImageFrame, PinholeCamera, RgbdFrame, StereoFrame, StereoRig
from slamcli.vision.features import Features, OrbSettings, depth_at, extract_orb
from slamcli.vision.pnp import PoseEstimate, refine_pose, refine_pose_depth
from slamcli.vision.stereo import StereoMatches, StereoSettings, match_stereo
from slamcli.worker import Background

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

AnyFrame = RgbdFrame | ImageFrame | StereoFrame


def near_depths(depth_m: F64, far_m: float, min_near: int) -> F64:
    """Stereo depths (N,) metres with far points' dropped (NaN): those beyond ``far_m``, or
    without a match. When fewer than ``min_near`` depths are within ``far_m``, the nearest far
    ones are kept as well, up to ``min_near`` in all (ties in depth to the lower index)."""
    z = np.array(depth_m, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        far = ~(z <= far_m)
    missing = min_near - (z.size - int(np.count_nonzero(far)))
    if missing > 0:
        candidates = np.flatnonzero(far & np.isfinite(z))
        nearest = candidates[np.argsort(z[candidates], kind="stable")[:missing]]
        far[nearest] = False
    z[far] = np.nan
    return z


@dataclass(frozen=True)
class StereoFeatures:
    """ORB features of a stereo pair's left image, and where each was found in the right."""

    left: Features
    matches: StereoMatches


Extracted = Features | StereoFeatures


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

    ``mono`` says whether depth is used and ``stereo`` whether it comes from a stereo pair;
    both are settled before the first frame (by the config's mode, or by what the input holds:
    :meth:`VisualSlam.frame_kinds`).
    """

    def __init__(self, config: VisualConfig) -> None:
        self.config = config
        self.mono = config.mode == "mono"
        self.stereo = config.mode == "stereo"
        self._pair: StereoRig | None = None
        self._camera: PinholeCamera | None = None
        self._raw_camera: PinholeCamera | None = None
        self._body_from_camera: F64 | None = None
        # Visual-inertial: the map is metric once the IMU is initialised (also monocular),
        # and the trajectory follows the body (the IMU).
        self.inertial = False

    @property
    def camera(self) -> PinholeCamera:
        """The undistorted camera (the first frame's)."""
        assert self._camera is not None
        return self._camera

    @property
    def evaluation(self) -> Evaluation:
        """How the trajectory is scored: ``sim3`` without depth or IMU (no metric scale),
        else ``se3``."""
        return "sim3" if self.mono and not self.inertial else "se3"

    @property
    def orb(self) -> OrbSettings:
        """How ORB features are found (``stereo_max_features`` per image of a stereo pair)."""
        cfg = self.config
        return OrbSettings(
            n_features=cfg.stereo_max_features if self.stereo else cfg.max_features,
            levels=cfg.levels,
            scale=cfg.scale_factor,
            fast_threshold=cfg.fast_threshold,
        )

    @property
    def mode(self) -> str:
        """``mono``, ``stereo`` or ``rgbd``: where the keypoints' depth comes from."""
        return "mono" if self.mono else "stereo" if self.stereo else "rgbd"

    @property
    def baseline_m(self) -> float:
        """The baseline a keypoint's depth is weighed with: the stereo pair's, or RGB-D's
        virtual one (``depth_baseline_m``)."""
        if self._pair is not None:
            return self._pair.baseline_m
        return self.config.depth_baseline_m

    @property
    def depth_max_m(self) -> float:
        """The furthest depth a keypoint keeps: ``stereo_far_baselines`` baselines for a
        stereo pair, ``depth_max_m`` for RGB-D."""
        if self._pair is not None:
            return self.config.stereo_far_baselines * self._pair.baseline_m
        return self.config.depth_max_m

    @property
    def body_from_camera(self) -> F64:
        """(4, 4) pose of the (left) camera on the body the source's ground truth refers to."""
        if self._pair is not None:
            return np.asarray(self._pair.body_from_left, np.float64)
        if self._body_from_camera is not None:
            return self._body_from_camera
        return np.eye(4)

    @property
    def trajectory_from_camera(self) -> F64:
        """(4, 4) pose of the camera on what the trajectory follows: the body, except in a
        monocular run, whose map has no metric scale to carry the camera's offset on the body
        in: that trajectory follows the camera (and the ground truth is moved onto it to be
        scored, :attr:`~slamcli.types.SlamResult.truth_to_estimate`). A visual-inertial
        run's map is metric: it follows the body."""
        return np.eye(4) if self.mono and not self.inertial else self.body_from_camera

    @property
    def truth_to_trajectory(self) -> F64 | None:
        """(4, 4) pose of what the trajectory follows on the ground truth's body, when it is
        not the body (a monocular camera mounted off the body), else None."""
        body = self.body_from_camera
        off_body = self.mono and not self.inertial and not np.array_equal(body, np.eye(4))
        return body if off_body else None

    def stereo_settings(self) -> StereoSettings:
        """How left keypoints are matched in the right image."""
        return StereoSettings(min_depth_m=self.config.depth_min_m, scale=self.orb.scale)

    def extract(self, frame: AnyFrame) -> Extracted:
        """ORB features of ``frame``'s image; of a stereo pair, the left image's features and
        their matches in the right (no state is changed: it may run on another thread)."""
        if isinstance(frame, StereoFrame):
            _check_sizes(frame)
            orb = self.orb
            if self.config.threads == 2:
                # The right image's features on a thread of their own: OpenCV's ORB lets go of
                # the interpreter lock, so the two images take the time of one.
                later = Background(extract_orb, _grey(frame.right), orb)
                left = extract_orb(_grey(frame.left), orb)
                right = later.result()
            else:
                left = extract_orb(_grey(frame.left), orb)
                right = extract_orb(_grey(frame.right), orb)
            matches = match_stereo(
                left, right, frame.left, frame.right, frame.rig, self.stereo_settings()
            )
            return StereoFeatures(left, matches)
        rgb = frame.rgb if isinstance(frame, RgbdFrame) else frame.image
        return extract_orb(_grey(rgb), self.orb)

    def prepare(self, frame: AnyFrame, extracted: Extracted, index: int) -> Frame:
        """``frame`` with its ``features``, ready to track as the ``index``-th frame.

        Raises:
            InputError: the frame has no camera, its images disagree with the camera or with
                each other, or the camera differs from the first frame's.
        """
        if isinstance(frame, StereoFrame):
            assert isinstance(extracted, StereoFeatures)
            return self._prepare_pair(frame, extracted, index)
        assert isinstance(extracted, Features)
        features = extracted
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
            if isinstance(frame, ImageFrame) and frame.body_from_camera is not None:
                self._body_from_camera = np.asarray(frame.body_from_camera, np.float64)
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
        return Frame(
            index=index,
            stamp_ns=frame.stamp_ns,
            name=frame.name,
            features=features,
            keypoints=kp,
            depth=z,
            colors=_colours(rgb, kp_raw),
            point_ids=np.full(len(kp), -1, np.int64),
        )

    def _prepare_pair(self, frame: StereoFrame, extracted: StereoFeatures, index: int) -> Frame:
        """A rectified stereo pair as a frame: the left keypoints (already undistorted), each
        with the depth of its right-image match, near ones only (see the module's text)."""
        where = frame.name or str(frame.stamp_ns)
        cam = frame.rig.camera
        h, w = frame.left.shape[:2]
        if (cam.height, cam.width) != (h, w):
            raise InputError(
                f"stereo pair {where}: the images are {w}x{h} but the rectified camera is "
                f"{cam.width}x{cam.height}",
                hint="give the calibration that matches the images",
            )
        if self._pair is None:
            self._pair = frame.rig
            self._raw_camera = self._camera = cam
        elif frame.rig != self._pair:
            raise InputError(
                f"stereo pair {where}: the stereo calibration changed mid-sequence",
                hint="the visual pipeline needs one fixed stereo rig",
            )
        features = extracted.left
        z = near_depths(extracted.matches.depth_m, self.depth_max_m, self.config.stereo_min_near)
        kp = features.keypoints.astype(np.float64)
        return Frame(
            index=index,
            stamp_ns=frame.stamp_ns,
            name=frame.name,
            features=features,
            keypoints=kp,
            depth=z,
            colors=_colours(frame.left, kp),
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
            self.baseline_m,
            pose,
            kp,
            world,
            sigma,
            depth,
            rounds,
        )

    def refine_jobs(self) -> tuple[PinholeCamera, bool, float]:
        """The leading arguments of :func:`refine_poses` for this rig."""
        return (self.camera, self.mono, self.baseline_m)


def _check_sizes(frame: StereoFrame) -> None:
    """Raise InputError, naming the pair, when its two images differ in size."""
    if frame.left.shape[:2] != frame.right.shape[:2]:
        raise InputError(
            f"stereo pair {frame.name or frame.stamp_ns}: left image "
            f"{frame.left.shape[1]}x{frame.left.shape[0]} but right "
            f"{frame.right.shape[1]}x{frame.right.shape[0]}",
            hint="a rectified pair has two images of one size; check the topics or folders",
        )


def _grey(image: NDArray[np.uint8]) -> NDArray[np.uint8]:
    """``image`` as contiguous uint8 grey (RGB is converted)."""
    import cv2

    if image.ndim == 2:
        return np.ascontiguousarray(image, dtype=np.uint8)
    colour = np.ascontiguousarray(image[..., :3], dtype=np.uint8)
    return np.asarray(cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY), dtype=np.uint8)


def _colours(image: NDArray[np.uint8], kp: NDArray[np.floating]) -> NDArray[np.uint8]:
    """(N, 3) uint8 colour of ``image`` under each keypoint (grey repeated thrice)."""
    h, w = image.shape[:2]
    u = np.clip(np.rint(kp[:, 0]).astype(np.int64), 0, w - 1)
    v = np.clip(np.rint(kp[:, 1]).astype(np.int64), 0, h - 1)
    if image.ndim == 2:
        return np.repeat(image[v, u][:, None], 3, axis=1).astype(np.uint8)
    return np.asarray(image[v, u][:, :3], dtype=np.uint8)
