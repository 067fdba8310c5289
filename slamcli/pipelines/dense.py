"""Dense RGB-D SLAM: frame-to-model tracking seeded by the visual tracker, TSDF fusion.

Each frame goes through these stages:

- ``_track`` (``front_end=visual``, the default): the visual pipeline's tracker
  (:class:`~slamcli.pipelines.visual.VisualSlam`: motion model, local map, local bundle
  adjustment) poses the frame; the pose is refined with Open3D's multi-scale tensor RGB-D
  odometry against a ray cast of the TSDF volume, and the frame's pose is ``model_weight`` of
  the way from the feature pose to the refined one. The two err differently (features are
  sharp in rotation, depth in translation), so the blend beats both. A refinement that throws,
  finds too few correspondences or strays from the feature pose is dropped. Frames the visual
  tracker cannot pose (no texture, lost) are tracked by the dense tracker alone, which also
  places each new visual map in the volume's frame.
- ``_track`` (``front_end=frames``): ORB features of the previous frame, lifted with depth,
  give a PnP seed; the same refinement follows, then frame-to-frame odometry, features alone
  or relocalisation against the keyframes when it is not trusted; a frame with none is lost.
- ``_integrate``: frames with a trusted pose and enough valid depth are fused into an Open3D
  ``VoxelBlockGrid`` (TSDF, weight, colour).
- ``_add_keyframe``: every few frames (or after enough motion) a keyframe keeps its images,
  packed, for the final rebuild. With ``front_end=frames`` earlier keyframes near it in pose and
  similar in ORB appearance are verified by PnP and RGB-D odometry as loops.
- ``finish``: with the visual front end, its loop closure (place recognition, GTSAM pose graph)
  and final refinement give each frame its final feature pose, which takes the correction the
  model made when the frame was tracked. With ``front_end=frames``, the keyframe pose graph is
  optimised with Open3D's line-process global optimisation (which prunes false loops) and every
  frame follows its keyframe. Either way the volume is rebuilt from the keyframes at their final
  poses before the mesh and points are extracted.

Every frame with a pose goes into the trajectory; every skipped or recovered frame is counted
by reason in ``SlamResult.counts``. Open3D objects never leave this module.
"""

from __future__ import annotations

import logging
import math
import time
from collections import defaultdict
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.config import setting
from slamcli.errors import ConfigError, PipelineError
from slamcli.geometry import blend_poses, compose, inverse, rotation_angle
from slamcli.geometry.camera import undistort_image
from slamcli.pipelines.rgbd_odometry import rgbd_odometry_multi_scale
from slamcli.pipelines.timing import StageTimer
from slamcli.pipelines.visual import VisualConfig, VisualSlam
from slamcli.types import PinholeCamera, RgbdFrame, SlamResult, Trajectory, TriangleMesh
from slamcli.vision.features import lift
from slamcli.vision.matching import match_ratio
from slamcli.vision.pnp import pnp_opencv, pose_change, within

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

_METHODS = ("hybrid", "point_to_plane", "intensity")
# Tracking outcomes whose frames are fused into the volume.
_TRUSTED = ("tracked_first", "tracked_model", "tracked_visual", "recovered_f2f")
# While frames are lost, the constant-velocity prediction moves on for this many frames, then
# waits where it is: a long gap compounded at the last speed would fly off the map.
_PREDICT_LOST_FRAMES = 5


@dataclass(frozen=True)
class DenseConfig:
    """Settings of :class:`DenseSlam`. Lengths in metres, angles in degrees."""

    voxel_size_m: float = setting(0.01, help="TSDF voxel edge", unit="m", gt=0.0, max=0.5)
    block_resolution: int = setting(
        16,
        help="voxels per block edge; a block holds block_resolution**3 voxels",
        choices=(8, 16, 32),
    )
    block_count: int = setting(
        0,
        help="initial voxel-block capacity; 0 sizes it from the first integrated frame. The "
        "volume grows with the scene either way, so this only saves early regrowth",
        unit="blocks",
        min=0,
    )
    block_growth: float = setting(
        1.5,
        help="when a frame's blocks would not fit, the capacity grows to this multiple of the "
        "blocks then needed; a block of 16**3 voxels holds 80 kB",
        min=1.1,
        max=4.0,
    )
    depth_min_m: float = setting(
        0.1, help="depth readings nearer than this are ignored", unit="m", min=0.0
    )
    depth_max_m: float = setting(
        3.0, help="depth readings further than this are ignored", unit="m", gt=0.0
    )
    sdf_trunc_voxels: float = setting(
        8.0, help="TSDF truncation distance", unit="voxels", min=1.0, max=64.0
    )
    min_valid_depth_fraction: float = setting(
        0.2,
        help="a frame with a smaller share of valid depth pixels is tracked if possible but "
        "never integrated",
        min=0.0,
        max=1.0,
    )
    track_downsample: int = setting(
        2,
        help="the frame-to-model registration runs on images shrunk by this factor (ray "
        "casting costs grow with the pixel count); never below 160 pixels wide, where the "
        "coarse pyramid levels would have too few pixels",
        choices=(1, 2, 4),
    )
    odometry_method: str = setting(
        "point_to_plane",
        help="loss of the frame-to-model refinement: photometric + geometric, geometric only, "
        "or photometric only",
        choices=_METHODS,
    )
    odometry_iterations: tuple[int, ...] = setting(
        (6, 4, 2), help="odometry iterations per pyramid level, coarse to fine", min=1, max=100
    )
    depth_outlier_m: float = setting(
        0.07,
        help="odometry correspondences further apart than this are rejected",
        unit="m",
        gt=0.0,
    )
    min_fitness: float = setting(
        0.1,
        help="least share of pixels with a correspondence for a trusted registration",
        min=0.0,
        max=1.0,
    )
    max_jump_m: float = setting(
        0.15, help="largest deviation from the constant-velocity prediction", unit="m", gt=0.0
    )
    max_jump_deg: float = setting(
        15.0,
        help="largest turn away from the constant-velocity prediction",
        unit="deg",
        gt=0.0,
        max=180.0,
    )
    max_seed_disagreement_m: float = setting(
        0.05,
        help="largest offset between the feature seed and the dense refinement before the "
        "refinement is distrusted",
        unit="m",
        gt=0.0,
    )
    max_seed_disagreement_deg: float = setting(
        4.0,
        help="largest rotation between the feature seed and the dense refinement before the "
        "refinement is distrusted",
        unit="deg",
        gt=0.0,
        max=180.0,
    )
    orb_features: int = setting(1000, help="ORB keypoints per frame", min=1, max=100000)
    match_ratio: float = setting(0.8, help="Lowe ratio for ORB descriptor matches", gt=0.0, max=1.0)
    pnp_reprojection_px: float = setting(
        3.0, help="RANSAC inlier threshold of PnP", unit="px", gt=0.0
    )
    pnp_iterations: int = setting(200, help="RANSAC iterations of PnP", min=1)
    pnp_min_inliers: int = setting(
        25, help="least PnP inliers for a feature pose; EPnP needs 4", min=4
    )
    relocalise_keyframes: int = setting(
        8, help="how many of the latest keyframes relocalisation tries", min=1
    )
    keyframe_every: int = setting(
        10,
        help="frames between keyframes at most; with front_end=visual no keyframe is made "
        "within keyframe_min_m and keyframe_min_deg of one from loop_min_frames or more "
        "before, so revisits add none",
        min=1,
    )
    keyframe_min_m: float = setting(
        0.1, help="motion since the last keyframe that makes a new one", unit="m", gt=0.0
    )
    keyframe_min_deg: float = setting(
        10.0, help="turn since the last keyframe that makes a new one", unit="deg", gt=0.0
    )
    loop_min_frames: int = setting(
        45, help="frames between two keyframes before they may close a loop", min=1
    )
    loop_max_distance_m: float = setting(
        1.0, help="largest distance between the poses of loop candidates", unit="m", min=0.0
    )
    loop_max_angle_deg: float = setting(
        45.0,
        help="largest angle between the poses of loop candidates",
        unit="deg",
        min=0.0,
        max=180.0,
    )
    loop_min_match_ratio: float = setting(
        0.08,
        help="least share of ORB descriptors with a ratio-test match for a loop candidate",
        min=0.0,
        max=1.0,
    )
    loop_max_candidates: int = setting(
        2,
        help="loop candidates verified per keyframe, best appearance first; 0 closes no loops",
        min=0,
    )
    loop_min_inliers: int = setting(30, help="least PnP inliers for a loop", min=4)
    loop_min_fitness: float = setting(
        0.3, help="least RGB-D odometry fitness for a loop", min=0.0, max=1.0
    )
    loop_max_disagreement_m: float = setting(
        0.02,
        help="largest offset between the PnP and the dense estimate of a loop's relative pose",
        unit="m",
        min=0.0,
    )
    loop_max_disagreement_deg: float = setting(
        1.5,
        help="largest rotation between the PnP and the dense estimate of a loop's relative pose",
        unit="deg",
        min=0.0,
        max=180.0,
    )
    pose_graph_prune: float = setting(
        0.25, help="edge-prune threshold of the line process", min=0.0, max=1.0
    )
    pose_graph_max_correspondence_m: float = setting(
        0.03, help="correspondence distance of the global optimisation", unit="m", gt=0.0
    )
    pose_graph_loop_preference: float = setting(
        0.1, help="weight of loop edges against odometry edges", min=0.0
    )
    reintegrate_min_shift_m: float = setting(
        0.002,
        help="the volume is rebuilt when the optimisation moves a keyframe further than this",
        unit="m",
        min=0.0,
    )
    reintegrate_min_shift_deg: float = setting(
        0.1,
        help="the volume is rebuilt when the optimisation turns a keyframe further than this",
        unit="deg",
        min=0.0,
    )
    mesh_weight_threshold: float = setting(
        3.0,
        help="least integration weight of voxels in the mesh and points; after a rebuild from "
        "the keyframes it shrinks with their share of the frames, to one at least",
        min=0.0,
    )
    undistort: bool = setting(
        True,
        help="remap frames whose camera has lens distortion onto the same pinhole (colour "
        "bilinear, depth nearest-neighbour) before anything else; the volume, ray casts and "
        "odometry all assume a pinhole camera",
        choices=(True, False),
    )
    seed: int = setting(0, help="seeds OpenCV's RNG (PnP RANSAC)", min=0, max=2**31 - 1)
    front_end: str = setting(
        "visual",
        help="what gives each frame's pose before the frame-to-model refinement: the visual "
        "pipeline's tracker (its local map, motion model and local bundle adjustment; loops "
        "closed by its place recognition and GTSAM pose graph), or ORB PnP against the "
        "previous frame with the dense pipeline's own loop closure",
        choices=("visual", "frames"),
    )
    model_weight: float = setting(
        0.25,
        help="with front_end=visual, the share of the frame-to-model refinement in each pose: 0 "
        "keeps the visual tracker's pose, 1 takes the refined one",
        min=0.0,
        max=1.0,
    )
    threads: int = setting(
        2,
        help="1 does everything on one core; 2 decodes the next frames and extracts their "
        "features beside tracking and fusion (same results either way)",
        choices=(1, 2),
    )

    def __post_init__(self) -> None:
        # Single values are range-checked where they are read (load_config); what remains is
        # what one field's range cannot say.
        if self.depth_min_m >= self.depth_max_m:
            raise ConfigError(
                f"dense.depth_min_m: expected less than dense.depth_max_m "
                f"({self.depth_max_m}), got {self.depth_min_m!r}",
                hint="set dense.depth_min_m below dense.depth_max_m",
            )
        if not self.odometry_iterations:
            raise ConfigError(
                "dense.odometry_iterations: expected at least one pyramid level, got []",
                hint="for example --set dense.odometry_iterations=[6, 4, 2]",
            )


@dataclass
class _Frame:
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
        source: the input frame, until the visual front end has tracked it.
        features: its ORB features for the visual front end, until then.
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
    source: RgbdFrame | None = None
    features: Any = None


@dataclass
class _Keyframe:
    """A keyframe: the frame and its pose when it was made (world_from_cam (4, 4)).

    Once the next keyframe exists, the frame's images are packed (``packed``: the depth as a
    lossless 16-bit PNG in 1/5000 m steps, the colour as a JPEG) and released from ``frame``:
    its features stay, for place recognition and PnP, and the images are decoded again when a
    loop is verified or the volume is rebuilt. ``info_to_previous`` is the (6, 6) information
    of the odometry edge from the previous keyframe, computed while both images were at hand.
    """

    id: int
    frame: _Frame
    world_from_cam: F64
    packed: tuple[bytes, bytes] | None = None
    info_to_previous: F64 | None = None


@dataclass
class _Loop:
    """A verified loop: ``cand_from_cur`` (4, 4) maps keyframe ``cur`` into keyframe ``cand``."""

    cand: int
    cur: int
    cand_from_cur: F64
    information: F64
    record: dict[str, Any] = field(default_factory=dict)


class DenseSlam:
    """Pipeline ``dense``: consumes ``rgbd`` frames, produces poses, a mesh and points."""

    name = "dense"
    consumes = ("rgbd",)
    config_class = DenseConfig

    def __init__(self, config: DenseConfig | None = None) -> None:
        self.config = config or DenseConfig()
        # With two threads, frames are decoded ahead on a reader thread (see run_pipeline).
        self.read_ahead = 2 if self.config.threads == 2 else 0
        self._camera: PinholeCamera | None = None
        self._raw_camera: PinholeCamera | None = None
        self._undistort = False
        self._downsample = 1
        self._pnp_inliers = 0
        self._o3d: Any = None
        self._volume: _Volume | None = None
        self._stamps: list[int] = []
        self._poses: list[F64] = []
        self._frame_of_pose: list[int] = []
        self._previous_pose: F64 | None = None
        self._velocity = np.eye(4)
        self._lost_run = 0
        self._reference: _Frame | None = None
        self._reference_pose = np.eye(4)
        self._keyframes: list[_Keyframe] = []
        self._loops: list[_Loop] = []
        self._loop_records: list[dict[str, Any]] = []
        # Frames fused into the volume. Only keyframes keep their images (packed, about 0.3 MB
        # each at 640x480), so memory follows the keyframes, not the log: a rebuild after loop
        # closure fuses the keyframes.
        self._integrated = 0
        self._counts: dict[str, int] = defaultdict(int)
        self._ms: dict[str, float] = defaultdict(float)
        self._frames = 0
        self._best_valid_fraction = 0.0
        self._pool: ThreadPoolExecutor | None = None
        self._pending: list[Future[_Frame]] = []
        # front_end=visual: the visual tracker, the volume-from-map transform of each of its
        # maps, and each pose's tracker pose and map (None where the dense tracker alone
        # placed the frame).
        self._visual: VisualSlam | None = None
        if self.config.front_end == "visual":
            cfg = self.config
            self._visual = VisualSlam(VisualConfig(threads=cfg.threads, seed=cfg.seed))
        self._map_offsets: dict[int, F64] = {}
        self._seed: tuple[F64, int] | None = None
        self._seed_of_pose: list[tuple[F64, int] | None] = []
        self._front_end_result: SlamResult | None = None

    # -- the pipeline -------------------------------------------------------------------------

    def seeds(self) -> dict[str, int]:
        """Seeds of the random number generators a run uses, by generator: OpenCV's (PnP
        RANSAC) gets ``config.seed`` before every PnP."""
        return {"opencv": self.config.seed}

    def process(self, frame: RgbdFrame) -> None:
        """Track, integrate and maybe keyframe one RGB-D frame. With two threads, the next
        frame's images are prepared (depth cleaned, ORB features, tracking image) on a second
        core while this one is tracked; frames are still tracked in order."""
        # Stage timers nest (the ray cast is part of tracking), so the total is timed on its own.
        with self._timed("total"):
            self._check_camera(frame)
            if self.config.threads == 2:
                if self._pool is None:
                    self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="prepare")
                self._pending.append(self._pool.submit(self._prepare, frame))
                if len(self._pending) > 1:
                    self._process(self._pending.pop(0))
            else:
                self._process(self._prepare(frame))

    def _process(self, prepared: _Frame | Future[_Frame]) -> None:
        with self._timed("prepare"):
            cur = prepared.result() if isinstance(prepared, Future) else prepared
        cur.index = self._frames
        self._best_valid_fraction = max(self._best_valid_fraction, cur.valid_fraction)
        self._frames += 1
        self._seed = None
        pose, status = self._track(cur)
        self._counts[status] += 1
        if pose is None:
            self._counts["frames_lost"] += 1
            self._lost_run += 1
            if self._previous_pose is not None and self._lost_run <= _PREDICT_LOST_FRAMES:
                self._previous_pose = compose(self._previous_pose, self._velocity)
            return
        if self._previous_pose is not None and self._lost_run == 0:
            self._velocity = compose(inverse(self._previous_pose), pose)
        else:
            self._velocity = np.eye(4)
        self._lost_run = 0
        self._previous_pose = pose
        self._stamps.append(cur.stamp_ns)
        self._poses.append(pose)
        self._frame_of_pose.append(cur.index)
        self._seed_of_pose.append(self._seed)
        self._counts["frames_tracked"] += 1
        trusted = status in _TRUSTED
        depth_ok = cur.valid_fraction >= self.config.min_valid_depth_fraction
        if not depth_ok:
            self._counts["frames_not_integrated_depth"] += 1
        elif not trusted:
            self._counts["frames_not_integrated_untrusted"] += 1
        if trusted and depth_ok:
            with self._timed("integrate"):
                self._integrate(cur, pose)
            self._reference, self._reference_pose = cur, pose
            if self._wants_keyframe(cur, pose):
                with self._timed("loop"):
                    self._add_keyframe(cur, pose)

    def finish(self) -> SlamResult:
        """Optimise the pose graph, rebuild the volume and extract the mesh and points.

        Raises:
            PipelineError: no frame was read, or none had enough valid depth to build a map.
        """
        with self._timed("total"):
            while self._pending:
                self._process(self._pending.pop(0))
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        if self._frames == 0:
            if self._visual is not None:
                self._visual.close()
            raise PipelineError("the dense pipeline received no RGB-D frames")
        if self._volume is None:
            if self._visual is not None:
                self._visual.close()
            raise PipelineError(
                f"none of the {self._frames} frames had usable depth: at best "
                f"{100 * self._best_valid_fraction:.1f}% of the pixels read between "
                f"{self.config.depth_min_m} and {self.config.depth_max_m} m (need "
                f"{100 * self.config.min_valid_depth_fraction:.0f}%)",
                hint="check the depth stream and its depth factor (TUM: 5000 units per metre), "
                "or widen dense.depth_min_m / dense.depth_max_m",
            )
        finish_start = time.perf_counter()
        with self._timed("optimise"):
            corrections = self._optimise() if self._visual is None else self._front_end_poses()
        if corrections is not None:
            with self._timed("reintegrate"):
                if self._visual is None:
                    self._apply_corrections(corrections)
                else:
                    self._rebuild(corrections)
        with self._timed("extract"):
            mesh, points, colors = self._volume.extract(self._weight_threshold(corrections))
        trajectory = Trajectory(np.array(self._stamps, dtype=np.int64), np.stack(self._poses))
        keyframes = Trajectory(
            np.array([k.frame.stamp_ns for k in self._keyframes], dtype=np.int64),
            np.stack([k.world_from_cam for k in self._keyframes]).reshape(-1, 4, 4),
        )
        counts = dict(self._counts)
        counts.setdefault("frames_lost", 0)
        counts["keyframes"] = len(self._keyframes)
        counts["frames_integrated"] = self._integrated
        loop_records = self._loop_records
        if self._front_end_result is not None:
            front = self._front_end_result
            loop_records = front.metrics.get("loop_closures", [])
            for key in ("keyframes", "maps", "map_merges", "map_points"):
                counts[f"front_end_{key}"] = int(front.counts.get(key, 0))
        counts["loop_closures_accepted"] = sum(bool(r["accepted"]) for r in loop_records)
        counts["loop_closures_rejected"] = sum(not r["accepted"] for r in loop_records)
        counts["voxel_blocks"] = self._volume.size
        counts["voxel_block_budget"] = self._volume.capacity
        counts["voxel_block_growths"] = self._volume.growths
        self._ms["total"] += (time.perf_counter() - finish_start) * 1e3
        stages = {k: v / self._frames for k, v in sorted(self._ms.items())}
        return SlamResult(
            trajectory=trajectory,
            keyframes=keyframes,
            points=points,
            point_colors=colors,
            mesh=mesh,
            metrics={
                "ms_per_frame": stages,
                "loop_closures": loop_records,
            },
            counts=counts,
        )

    # -- stages -------------------------------------------------------------------------------

    def _check_camera(self, frame: RgbdFrame) -> None:
        """The frame's images and camera agree, and the camera is the first frame's (which
        sets up the pipeline's camera and tracking scale)."""
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
            self._o3d = _open3d()
            self._undistort = cfg.undistort and cam.is_distorted
            self._camera = cam.undistorted() if self._undistort else cam
            self._downsample = max(
                1, min(cfg.track_downsample, 2 ** int(math.log2(max(1, w // 160))))
            )
        elif cam != self._raw_camera:
            raise PipelineError(
                f"frame {frame.name or frame.stamp_ns}: the camera changed mid-sequence",
                hint="the dense pipeline needs one fixed camera",
            )

    def _prepare(self, frame: RgbdFrame) -> _Frame:
        """Clean the images, extract ORB features and build the tracking image (no state is
        changed: it may run on a second thread). ``index`` is set when the frame is tracked."""
        import cv2

        cfg = self.config
        cam = frame.camera
        camera = self._camera
        assert camera is not None
        depth = np.nan_to_num(np.asarray(frame.depth_m, dtype=np.float32), nan=0.0, posinf=0.0)
        rgb = np.ascontiguousarray(frame.rgb, dtype=np.uint8)
        if self._undistort:
            rgb = undistort_image(cam, rgb)
            depth = undistort_image(cam, depth, nearest=True)
        depth[(depth < cfg.depth_min_m) | (depth > cfg.depth_max_m)] = 0.0
        valid_fraction = float(np.count_nonzero(depth)) / depth.size
        features = None
        if self._visual is not None:
            # The visual tracker finds its own features (on the raw image); the frame's
            # ORB keypoints are not used.
            features = self._visual.extract(frame)
            keypoints = np.zeros((0, 2), dtype=np.float32)
            desc = np.zeros((0, 32), dtype=np.uint8)
        else:
            gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
            orb = cv2.ORB.create(nfeatures=cfg.orb_features)
            kps, found = orb.detectAndCompute(gray, None)
            keypoints = np.array([k.pt for k in kps], dtype=np.float32).reshape(-1, 2)
            desc = np.zeros((0, 32), np.uint8) if found is None else np.asarray(found, np.uint8)
        return _Frame(
            index=-1,
            stamp_ns=frame.stamp_ns,
            rgb=rgb,
            depth=depth,
            valid_fraction=valid_fraction,
            keypoints=keypoints,
            descriptors=desc,
            points_cam=lift(keypoints, depth, camera),
            small=self._tracking_image(rgb, depth),
            source=frame if features is not None else None,
            features=features,
        )

    def _track(self, cur: _Frame) -> tuple[F64 | None, str]:
        """World-from-camera pose of ``cur`` (or None when lost) and how it was found."""
        if self._visual is None:
            return self._track_frames(cur)
        return self._track_visual(cur)

    def _track_visual(self, cur: _Frame) -> tuple[F64 | None, str]:
        """Pose ``cur`` with the visual tracker, refined against the model and blended by
        ``model_weight``; the dense tracker alone when the visual one has no pose, and for the
        first frame of each of its maps (which places that map in the volume's frame)."""
        cfg = self.config
        assert self._visual is not None and cur.source is not None
        with self._timed("front_end"):
            tracked = self._visual.track(cur.source, cur.features)
        cur.source = cur.features = None
        if tracked is None:
            self._counts["front_end_no_pose"] += 1
            return self._track_frames(cur)
        online, map_id = tracked
        offset = self._map_offsets.get(map_id)
        if offset is None:
            pose, status = self._track_frames(cur)
            if pose is not None:
                self._map_offsets[map_id] = compose(pose, inverse(online))
                self._seed = (online, map_id)
            return pose, status
        self._seed = (online, map_id)
        seed = compose(offset, online)
        depth_ok = cur.valid_fraction >= cfg.min_valid_depth_fraction
        if not (depth_ok and self._volume is not None and cfg.model_weight > 0):
            return seed, "tracked_visual"
        with self._timed("track_model"):
            refined = self._refine_model(cur, seed)
        if refined is None:
            return seed, "tracked_visual"
        if not within(seed, refined, cfg.max_seed_disagreement_m, cfg.max_seed_disagreement_deg):
            self._counts["rejected_seed_disagreement"] += 1
            return seed, "tracked_visual"
        return blend_poses(seed, refined, cfg.model_weight), "tracked_model"

    def _track_frames(self, cur: _Frame) -> tuple[F64 | None, str]:
        """Pose ``cur`` by PnP against the previous frame, refined against the model (see the
        module's description)."""
        cfg = self.config
        if self._previous_pose is None:
            return np.eye(4), "tracked_first"
        predicted = compose(self._previous_pose, self._velocity)
        seed_pose = None
        if self._reference is not None:
            with self._timed("features"):
                ref_from_cur = self._pnp(self._reference, cur, cfg.pnp_min_inliers)
            if ref_from_cur is not None:
                seed_pose = compose(self._reference_pose, ref_from_cur)
                if not self._plausible(seed_pose, predicted):
                    self._counts["pnp_rejected_jump"] += 1
                    seed_pose = None
        depth_ok = cur.valid_fraction >= cfg.min_valid_depth_fraction
        start = predicted if seed_pose is None else seed_pose
        if depth_ok and self._volume is not None:
            with self._timed("track_model"):
                refined = self._refine_model(cur, start)
            if refined is not None and self._accept(refined, predicted, seed_pose):
                return refined, "tracked_model"
            if self._reference is not None:
                with self._timed("track_f2f"):
                    refined = self._refine_f2f(cur, start)
                if refined is not None and self._accept(refined, predicted, seed_pose):
                    return refined, "recovered_f2f"
        if seed_pose is not None:
            return seed_pose, "recovered_pnp"
        with self._timed("relocalise"):
            relocalised = self._relocalise(cur)
        if relocalised is not None:
            return relocalised, "recovered_relocalised"
        return None, "lost_no_registration"

    def _integrate(self, cur: _Frame, pose: F64) -> None:
        """Fuse a trusted frame into the volume and keep it for a later rebuild."""
        if self._volume is None:
            assert self._camera is not None
            self._volume = _Volume(self._o3d, self.config, self._camera, self.config.block_count)
        self._volume.integrate(cur.depth, cur.rgb, pose)
        self._integrated += 1

    def _wants_keyframe(self, cur: _Frame, pose: F64) -> bool:
        if not self._keyframes:
            return True
        if self._visual is not None and self._near_keyframe(cur, pose):
            # Keyframes only feed the final rebuild here: a view kept on an earlier pass adds
            # nothing, so revisiting a mapped room adds no keyframes.
            return False
        last = self._keyframes[-1]
        if cur.index - last.frame.index >= self.config.keyframe_every:
            return True
        moved_m, turned_deg = pose_change(last.world_from_cam, pose)
        return moved_m >= self.config.keyframe_min_m or turned_deg >= self.config.keyframe_min_deg

    def _near_keyframe(self, cur: _Frame, pose: F64) -> bool:
        """Whether a keyframe of an earlier pass (``loop_min_frames`` or more before ``cur``)
        lies within ``keyframe_min_m`` and ``keyframe_min_deg`` of ``pose``."""
        cfg = self.config
        earlier = [k for k in self._keyframes if cur.index - k.frame.index >= cfg.loop_min_frames]
        if not earlier:
            return False
        poses = np.stack([k.world_from_cam for k in earlier])
        near = np.linalg.norm(poses[:, :3, 3] - pose[:3, 3], axis=1) < cfg.keyframe_min_m
        if not near.any():
            return False
        turned = np.degrees(rotation_angle(compose(inverse(poses[near]), pose)))
        return bool(np.any(turned < cfg.keyframe_min_deg))

    def _add_keyframe(self, cur: _Frame, pose: F64) -> None:
        kf = _Keyframe(len(self._keyframes), cur, pose.copy())
        if self._keyframes:
            prev = self._keyframes[-1]
            if self._visual is None:
                # The odometry edge of the keyframe pose graph (front_end=frames).
                prev_from_kf = compose(inverse(prev.world_from_cam), kf.world_from_cam)
                kf.info_to_previous = self._information(kf.frame, prev.frame, prev_from_kf)
            self._pack(prev)
        self._keyframes.append(kf)
        if self._visual is None:
            self._close_loops(kf)

    def _pack(self, kf: _Keyframe) -> None:
        """Keep ``kf``'s images compressed and release the arrays (see :class:`_Keyframe`)."""
        import cv2

        if kf.packed is not None:
            return
        frame = kf.frame
        steps = np.rint(frame.depth * _DEPTH_STEPS_PER_M).astype(np.uint16)
        ok_d, depth_png = cv2.imencode(".png", steps)
        bgr = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR)
        ok_c, colour_jpg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
        if not (ok_d and ok_c):
            return
        kf.packed = (depth_png.tobytes(), colour_jpg.tobytes())
        kf.frame = replace(frame, rgb=_RELEASED_RGB, depth=_RELEASED_DEPTH, small=None)

    def _images(self, kf: _Keyframe) -> _Frame:
        """``kf``'s frame with its images (decoded from ``packed`` when they were released)."""
        import cv2

        if kf.packed is None:
            return kf.frame
        depth_png, colour_jpg = kf.packed
        steps = np.asarray(cv2.imdecode(np.frombuffer(depth_png, np.uint8), cv2.IMREAD_UNCHANGED))
        depth = steps.astype(np.float32) / np.float32(_DEPTH_STEPS_PER_M)
        bgr = np.asarray(cv2.imdecode(np.frombuffer(colour_jpg, np.uint8), cv2.IMREAD_COLOR))
        rgb = np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
        return replace(kf.frame, rgb=rgb, depth=depth, small=self._tracking_image(rgb, depth))

    def _close_loops(self, kf: _Keyframe) -> None:
        """Find, verify and record loop closures between ``kf`` and earlier keyframes."""
        cfg = self.config
        candidates = []
        for old in self._keyframes[:-1]:
            if kf.frame.index - old.frame.index < cfg.loop_min_frames:
                continue
            if not within(
                old.world_from_cam,
                kf.world_from_cam,
                cfg.loop_max_distance_m,
                cfg.loop_max_angle_deg,
            ):
                continue
            matches = match_ratio(old.frame.descriptors, kf.frame.descriptors, cfg.match_ratio)
            ratio = len(matches) / max(
                1, min(len(old.frame.descriptors), len(kf.frame.descriptors))
            )
            if ratio >= cfg.loop_min_match_ratio:
                candidates.append((-ratio, old.id, old))
        candidates.sort(key=lambda c: (c[0], c[1]))
        for neg_ratio, _, old in candidates[: cfg.loop_max_candidates]:
            record = self._verify_loop(old, kf, -neg_ratio)
            self._loop_records.append(record)
            if record["accepted"]:
                log.info(
                    "loop closure: keyframe %d (frame %d) -> %d (frame %d), fitness %.2f",
                    kf.id,
                    kf.frame.index,
                    old.id,
                    old.frame.index,
                    record["fitness"],
                )

    def _optimise(self) -> F64 | None:
        """Optimise the keyframe pose graph; (K, 4, 4) corrected keyframe poses, or None when
        no loop survived or nothing moved enough to matter."""
        if not self._loops:
            return None
        o3d = self._o3d
        reg = o3d.pipelines.registration
        graph = reg.PoseGraph()
        for kf in self._keyframes:
            graph.nodes.append(reg.PoseGraphNode(kf.world_from_cam))
        for a, b in zip(self._keyframes[:-1], self._keyframes[1:], strict=True):
            a_from_b = compose(inverse(a.world_from_cam), b.world_from_cam)
            info = b.info_to_previous
            assert info is not None
            graph.edges.append(reg.PoseGraphEdge(b.id, a.id, a_from_b, info, uncertain=False))
        for loop in self._loops:
            graph.edges.append(
                reg.PoseGraphEdge(
                    loop.cur, loop.cand, loop.cand_from_cur, loop.information, uncertain=True
                )
            )
        option = reg.GlobalOptimizationOption(
            max_correspondence_distance=self.config.pose_graph_max_correspondence_m,
            edge_prune_threshold=self.config.pose_graph_prune,
            preference_loop_closure=self.config.pose_graph_loop_preference,
            reference_node=0,
        )
        reg.global_optimization(
            graph,
            reg.GlobalOptimizationLevenbergMarquardt(),
            reg.GlobalOptimizationConvergenceCriteria(),
            option,
        )
        kept = {(e.source_node_id, e.target_node_id) for e in graph.edges if e.uncertain}
        for loop in self._loops:
            if (loop.cur, loop.cand) not in kept:
                loop.record["accepted"] = False
                loop.record["reason"] = "pruned by the pose-graph optimisation"
        if not kept:
            return None
        corrected = np.stack([np.asarray(n.pose, dtype=np.float64) for n in graph.nodes])
        return corrected if self._moved_enough(corrected) else None

    def _weight_threshold(self, rebuilt: F64 | None) -> float:
        """The least voxel weight in the mesh: ``mesh_weight_threshold`` for a volume of every
        integrated frame; a volume rebuilt from the keyframes alone saw each surface fewer
        times, so the threshold shrinks with the keyframes' share of the frames (never below
        one observation)."""
        threshold = self.config.mesh_weight_threshold
        if rebuilt is None or self._integrated == 0:
            return threshold
        share = len(self._keyframes) / self._integrated
        return min(threshold, max(1.0, threshold * share))

    def _moved_enough(self, corrected: F64) -> bool:
        """Whether the corrected keyframe poses (K, 4, 4) move a keyframe far enough from
        where it was fused for the volume to be rebuilt."""
        old = np.stack([k.world_from_cam for k in self._keyframes])
        shift = compose(inverse(old), corrected)
        moved_m = float(np.max(np.linalg.norm(shift[:, :3, 3], axis=1)))
        moved_deg = float(np.degrees(np.max(rotation_angle(shift))))
        log.info("the final poses move keyframes by up to %.4f m, %.3f deg", moved_m, moved_deg)
        return (
            moved_m >= self.config.reintegrate_min_shift_m
            or moved_deg >= self.config.reintegrate_min_shift_deg
        )

    def _front_end_poses(self) -> F64 | None:
        """Final poses with the visual front end: each frame the visual tracker placed gets
        its final visual pose (after loop closure, the pose graph and the last refinement)
        times the correction the model refinement made to it when it was tracked; the other
        frames follow the nearest such frame by their tracked motion. The first placed frame
        keeps its pose. Returns the keyframes' final poses when they moved enough for the
        volume to be rebuilt, else None."""
        assert self._visual is not None
        try:
            self._front_end_result = front = self._visual.finish()
        except PipelineError as exc:
            # No map came out of the visual tracker: the tracked poses stand.
            log.info("the visual front end made no map (%s); keeping the tracked poses", exc)
            self._visual.close()
            self._counts["front_end_no_map"] += 1
            return None
        assert front.trajectory is not None
        final_of = {
            int(s): p
            for s, p in zip(
                front.trajectory.stamps_ns, front.trajectory.world_from_body, strict=True
            )
        }
        tracked = self._poses
        final: list[F64 | None] = [None] * len(tracked)
        for i, (stamp, seed) in enumerate(zip(self._stamps, self._seed_of_pose, strict=True)):
            visual = final_of.get(int(stamp))
            if seed is None or visual is None:
                continue
            online, map_id = seed
            correction = compose(inverse(compose(self._map_offsets[map_id], online)), tracked[i])
            final[i] = compose(visual, correction)
        placed = [i for i, p in enumerate(final) if p is not None]
        if not placed:
            return None
        first = placed[0]
        anchor = compose(tracked[first], inverse(final[first]))  # type: ignore[arg-type]
        out = [None if p is None else compose(anchor, p) for p in final]
        # Frames the visual tracker did not place keep their tracked motion from the nearest
        # placed frame before them (after them, for frames before the first).
        for i in range(first + 1, len(out)):
            if out[i] is None:
                out[i] = compose(out[i - 1], compose(inverse(tracked[i - 1]), tracked[i]))  # type: ignore[arg-type]
        for i in range(first - 1, -1, -1):
            out[i] = compose(out[i + 1], compose(inverse(tracked[i + 1]), tracked[i]))  # type: ignore[arg-type]
        self._counts["frames_placed_by_front_end"] = len(placed)
        self._poses = [p for p in out if p is not None]
        if not self._keyframes:
            return None
        index_of = {f: k for k, f in enumerate(self._frame_of_pose)}
        corrected = np.stack([self._poses[index_of[kf.frame.index]] for kf in self._keyframes])
        if not self._moved_enough(corrected):
            return None
        return corrected

    def _apply_corrections(self, corrected: F64) -> None:
        """Move every pose with its keyframe's correction and rebuild the volume from the
        keyframes at their corrected poses."""
        old = np.stack([k.world_from_cam for k in self._keyframes])
        # Each pose follows the latest keyframe at or before it.
        kf_frames = np.array([k.frame.index for k in self._keyframes])
        owner = np.clip(np.searchsorted(kf_frames, self._frame_of_pose, side="right") - 1, 0, None)
        delta = compose(corrected, inverse(old))
        self._poses = list(compose(delta[owner], np.stack(self._poses)))
        self._rebuild(corrected)

    def _rebuild(self, corrected: F64) -> None:
        """Rebuild the volume from the keyframes at their corrected poses (K, 4, 4)."""
        for kf, pose in zip(self._keyframes, corrected, strict=True):
            kf.world_from_cam = pose
        assert self._camera is not None
        # The rebuilt volume covers about the same blocks: it starts with that room, and the
        # old one is released first so the two never hold memory at once.
        assert self._volume is not None
        capacity = math.ceil(self.config.block_growth * self._volume.size)
        self._volume = None
        volume = _Volume(self._o3d, self.config, self._camera, capacity)
        for kf in self._keyframes:
            frame = self._images(kf)
            volume.integrate(frame.depth, frame.rgb, kf.world_from_cam)
        self._volume = volume
        self._counts["frames_reintegrated"] = len(self._keyframes)

    # -- registration ------------------------------------------------------------------------

    def _pnp(self, ref: _Frame, cur: _Frame, min_inliers: int) -> F64 | None:
        """``ref_from_cur`` (4, 4) from ORB matches and PnP RANSAC, or None.

        The inlier count of the last attempt is left in ``self._pnp_inliers``.
        """
        self._pnp_inliers = 0
        cfg = self.config
        assert self._camera is not None
        usable = np.isfinite(ref.points_cam[:, 0])
        if np.count_nonzero(usable) < min_inliers or len(cur.descriptors) < min_inliers:
            return None
        idx = np.flatnonzero(usable)
        matches = match_ratio(ref.descriptors[idx], cur.descriptors, cfg.match_ratio)
        if len(matches) < min_inliers:
            return None
        ref_from_cur, self._pnp_inliers = pnp_opencv(
            ref.points_cam[idx[matches[:, 0]]],
            cur.keypoints[matches[:, 1]].astype(np.float64),
            self._camera.K,
            seed=cfg.seed,
            iterations=cfg.pnp_iterations,
            threshold_px=cfg.pnp_reprojection_px,
            min_inliers=min_inliers,
        )
        return ref_from_cur

    def _refine_model(self, cur: _Frame, seed_pose: F64) -> F64 | None:
        """Register ``cur`` to a ray cast of the volume seen from ``seed_pose``."""
        assert self._volume is not None
        with self._timed("raycast"):
            model = self._volume.ray_cast(seed_pose, self._downsample)
        if model is None:
            return None
        model_from_cur = self._odometry(cur.small, model, np.eye(4), self._method())
        return None if model_from_cur is None else compose(seed_pose, model_from_cur)

    def _refine_f2f(self, cur: _Frame, seed_pose: F64) -> F64 | None:
        """Register ``cur`` to the previous frame with depth (photometric + geometric)."""
        assert self._reference is not None
        init = compose(inverse(self._reference_pose), seed_pose)
        o3d_hybrid = self._o3d.t.pipelines.odometry.Method.Hybrid
        ref_from_cur = self._odometry(cur.small, self._reference.small, init, o3d_hybrid)
        return None if ref_from_cur is None else compose(self._reference_pose, ref_from_cur)

    def _odometry(self, source: Any, target: Any, init: F64, method: Any) -> F64 | None:
        """``target_from_source`` (4, 4) by multi-scale RGB-D odometry, or None on failure."""
        odo = self._o3d.t.pipelines.odometry
        cfg = self.config
        try:
            result = rgbd_odometry_multi_scale(
                self._o3d,
                source,
                target,
                self._small_intrinsics(),
                self._o3d.core.Tensor(np.ascontiguousarray(init)),
                1.0,
                cfg.depth_max_m,
                [odo.OdometryConvergenceCriteria(n) for n in cfg.odometry_iterations],
                method,
                odo.OdometryLossParams(cfg.depth_outlier_m),
            )
        except RuntimeError as exc:
            # Open3D reports a degenerate system ("Singular 6x6 linear system") this way.
            self._counts["odometry_singular"] += 1
            log.debug("RGB-D odometry failed: %s", exc)
            return None
        if result.fitness < cfg.min_fitness:
            self._counts["odometry_low_fitness"] += 1
            return None
        return np.asarray(result.transformation.numpy(), dtype=np.float64)

    def _accept(self, pose: F64, predicted: F64, seed_pose: F64 | None) -> bool:
        """A refined pose is trusted when it stays within the motion prior and, when there is
        a feature seed, close to it."""
        if not self._plausible(pose, predicted):
            self._counts["rejected_jump"] += 1
            return False
        cfg = self.config
        if seed_pose is not None and not within(
            seed_pose, pose, cfg.max_seed_disagreement_m, cfg.max_seed_disagreement_deg
        ):
            self._counts["rejected_seed_disagreement"] += 1
            return False
        return True

    def _plausible(self, pose: F64, predicted: F64) -> bool:
        return within(predicted, pose, self.config.max_jump_m, self.config.max_jump_deg)

    def _relocalise(self, cur: _Frame) -> F64 | None:
        """Pose from PnP against the latest keyframes, most inliers first; None if none fits."""
        for kf in reversed(self._keyframes[-self.config.relocalise_keyframes :]):
            kf_from_cur = self._pnp(kf.frame, cur, self.config.pnp_min_inliers)
            if kf_from_cur is not None:
                return compose(kf.world_from_cam, kf_from_cur)
        return None

    def _verify_loop(self, old: _Keyframe, kf: _Keyframe, ratio: float) -> dict[str, Any]:
        """Check a loop candidate by PnP, then RGB-D odometry; accepted loops are kept."""
        cfg = self.config
        record: dict[str, Any] = {
            "keyframes": [old.id, kf.id],
            "frames": [old.frame.index, kf.frame.index],
            "match_ratio": round(ratio, 4),
            "inliers": 0,
            "fitness": 0.0,
            "accepted": False,
            "reason": "",
        }
        old_from_cur = self._pnp(old.frame, kf.frame, cfg.loop_min_inliers)
        record["inliers"] = self._pnp_inliers
        if old_from_cur is None:
            record["reason"] = f"fewer than {cfg.loop_min_inliers} PnP inliers"
            return record
        kf_frame, old_frame = self._images(kf), self._images(old)
        odo = self._o3d.t.pipelines.odometry
        assert self._camera is not None
        try:
            result = rgbd_odometry_multi_scale(
                self._o3d,
                self._full_image(kf_frame),
                self._full_image(old_frame),
                self._o3d.core.Tensor(self._camera.K),
                self._o3d.core.Tensor(old_from_cur),
                1.0,
                cfg.depth_max_m,
                [odo.OdometryConvergenceCriteria(n) for n in cfg.odometry_iterations],
                odo.Method.Hybrid,
                odo.OdometryLossParams(cfg.depth_outlier_m),
            )
        except RuntimeError as exc:
            record["reason"] = f"RGB-D odometry failed: {exc}".splitlines()[0][:120]
            return record
        refined = np.asarray(result.transformation.numpy(), dtype=np.float64)
        record["fitness"] = round(float(result.fitness), 4)
        disagree_m, disagree_deg = pose_change(old_from_cur, refined)
        record["pnp_vs_dense_m"] = round(disagree_m, 5)
        drift_m, drift_deg = pose_change(compose(old.world_from_cam, refined), kf.world_from_cam)
        record["drift_m"] = round(drift_m, 5)
        record["drift_deg"] = round(drift_deg, 4)
        if result.fitness < cfg.loop_min_fitness:
            record["reason"] = f"fitness below {cfg.loop_min_fitness}"
        elif (
            disagree_m > cfg.loop_max_disagreement_m or disagree_deg > cfg.loop_max_disagreement_deg
        ):
            record["reason"] = "PnP and RGB-D odometry disagree"
        else:
            record["accepted"] = True
            record["reason"] = "verified"
            info = self._information(kf_frame, old_frame, refined)
            self._loops.append(_Loop(old.id, kf.id, refined, info, record))
        return record

    def _information(self, source: _Frame, target: _Frame, target_from_source: F64) -> F64:
        """(6, 6) information of a relative pose from the depth correspondences it explains."""
        odo = self._o3d.t.pipelines.odometry
        info = odo.compute_odometry_information_matrix(
            source.small.depth,
            target.small.depth,
            self._small_intrinsics(),
            self._o3d.core.Tensor(np.ascontiguousarray(target_from_source)),
            self.config.depth_outlier_m,
            1.0,
            self.config.depth_max_m,
        )
        return np.asarray(info.numpy(), dtype=np.float64)

    # -- helpers ------------------------------------------------------------------------------

    def _method(self) -> Any:
        odo = self._o3d.t.pipelines.odometry
        return {
            "hybrid": odo.Method.Hybrid,
            "point_to_plane": odo.Method.PointToPlane,
            "intensity": odo.Method.Intensity,
        }[self.config.odometry_method]

    def _full_image(self, frame: _Frame) -> Any:
        """Open3D RGB-D image of a frame at full resolution (colour float32 in [0, 1])."""
        geometry = self._o3d.t.geometry
        colour = frame.rgb.astype(np.float32) / np.float32(255.0)
        return geometry.RGBDImage(geometry.Image(colour), geometry.Image(frame.depth))

    def _small_intrinsics(self) -> Any:
        assert self._camera is not None
        return self._o3d.core.Tensor(_tracking_camera(self._camera, self._downsample).K)

    def _tracking_image(self, rgb: NDArray[np.uint8], depth: NDArray[np.float32]) -> Any:
        """Open3D RGB-D image shrunk by ``track_downsample``: colour by area averaging, depth
        by averaging only blocks whose readings are all valid and agree within 3 cm."""
        import cv2

        o3d = self._o3d
        k = self._downsample
        assert self._camera is not None
        small_cam = _tracking_camera(self._camera, k)
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

    def _timed(self, stage: str) -> StageTimer:
        return StageTimer(self._ms, stage)


_DEPTH_STEPS_PER_M = 5000.0
_RELEASED_RGB = np.zeros((0, 0, 3), dtype=np.uint8)
_RELEASED_DEPTH = np.zeros((0, 0), dtype=np.float32)


class _Volume:
    """An Open3D ``VoxelBlockGrid`` TSDF with colour that grows with the scene.

    Open3D allocates (and zeroes) every block of the capacity up front, 80 kB per 16**3 block,
    so the capacity follows the data: it starts at ``capacity`` blocks (or what the first frame
    needs) and is raised before a frame whose blocks might not fit.
    """

    def __init__(self, o3d: Any, config: DenseConfig, camera: PinholeCamera, capacity: int) -> None:
        self._o3d = o3d
        self._cfg = config
        self._camera = camera
        # Open3D's TSDF integration reads the depth pixel by truncating the voxel's projected
        # coordinate, while its ray cast shoots rays through pixel centres: without this half
        # pixel the model sits half a pixel off, and frame-to-model tracking drifts by that
        # much every frame.
        k_integrate = camera.K.copy()
        k_integrate[:2, 2] += 0.5
        self._K = o3d.core.Tensor(k_integrate)
        self._grid = o3d.t.geometry.VoxelBlockGrid(
            ("tsdf", "weight", "color"),
            (o3d.core.float32, o3d.core.float32, o3d.core.float32),
            ((1), (1), (3)),
            config.voxel_size_m,
            config.block_resolution,
            max(1, capacity),
        )
        self.growths = 0
        self._integrated = 0
        self._last_blocks: Any = None

    @property
    def size(self) -> int:
        """Number of allocated voxel blocks."""
        return int(self._grid.hashmap().size())

    @property
    def capacity(self) -> int:
        """Number of voxel blocks the volume holds before it must grow."""
        return int(self._grid.hashmap().capacity())

    def reserve(self, new_blocks: int) -> None:
        """Make room for ``new_blocks`` more blocks (an upper bound), growing by
        ``block_growth``.

        Open3D would grow the hash map by itself, but to twice its capacity whenever the size
        plus the frame's blocks (new or not) exceed it; growing first keeps the steady state at
        ``block_growth`` times the need.
        """
        needed = self.size + new_blocks
        if needed > self.capacity:
            capacity = math.ceil(self._cfg.block_growth * needed)
            log.debug("TSDF volume grows from %d to %d blocks", self.capacity, capacity)
            self._grid.hashmap().reserve(capacity)
            self.growths += 1

    def integrate(self, depth: NDArray[np.float32], rgb: NDArray[np.uint8], pose: F64) -> None:
        """Fuse depth (H, W) metres and colour (H, W, 3) seen from world_from_cam ``pose``."""
        o3d, cfg = self._o3d, self._cfg
        depth_img = o3d.t.geometry.Image(np.ascontiguousarray(depth))
        colour = o3d.t.geometry.Image(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0)
        extrinsic = o3d.core.Tensor(np.ascontiguousarray(inverse(pose)))
        blocks = self._grid.compute_unique_block_coordinates(
            depth_img, self._K, extrinsic, 1.0, cfg.depth_max_m, cfg.sdf_trunc_voxels
        )
        self.reserve(len(blocks))
        self._grid.integrate(
            blocks,
            depth_img,
            colour,
            self._K,
            extrinsic,
            1.0,
            cfg.depth_max_m,
            cfg.sdf_trunc_voxels,
        )
        self._last_blocks = blocks
        self._integrated += 1

    def ray_cast(self, pose: F64, downsample: int) -> Any:
        """Model RGB-D image (depth metres, colour in [0, 1]) seen from ``pose`` at the
        tracking scale, or None when the volume shows nothing there."""
        o3d, cfg = self._o3d, self._cfg
        cam = _tracking_camera(self._camera, downsample)
        extrinsic = o3d.core.Tensor(np.ascontiguousarray(inverse(pose)))
        # A fresh volume has weight 1 per fused frame; the threshold grows to 3 as frames arrive.
        weight = float(min(self._integrated, 3))
        result = self._grid.ray_cast(
            self._last_blocks,
            o3d.core.Tensor(cam.K),
            extrinsic,
            cam.width,
            cam.height,
            ["depth", "color"],
            1.0,
            cfg.depth_min_m,
            cfg.depth_max_m,
            weight,
            cfg.sdf_trunc_voxels,
        )
        depth = result["depth"]
        if int(np.count_nonzero(depth.numpy())) == 0:
            return None
        return o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(result["color"]), o3d.t.geometry.Image(depth)
        )

    def extract(
        self, weight_threshold: float
    ) -> tuple[TriangleMesh, NDArray[np.float64], NDArray[np.uint8]]:
        """Marching-cubes mesh and surface points (N, 3) metres with colours (N, 3) uint8."""
        weight = min(weight_threshold, float(self._integrated))
        mesh = self._grid.extract_triangle_mesh(weight)
        vertices = mesh.vertex.positions.numpy().astype(np.float64)
        faces = mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3)
        colours = _to_uint8(mesh.vertex.colors.numpy()) if "colors" in mesh.vertex else None
        cloud = self._grid.extract_point_cloud(weight)
        points = cloud.point.positions.numpy().astype(np.float64)
        point_colours = (
            _to_uint8(cloud.point.colors.numpy())
            if "colors" in cloud.point
            else np.zeros((len(points), 3), dtype=np.uint8)
        )
        return TriangleMesh(vertices, faces, colours), points, point_colours


def _tracking_camera(camera: PinholeCamera, downsample: int) -> PinholeCamera:
    """The camera of the tracking images: shrunk by ``downsample`` and cropped at the right and
    bottom to whole multiples of 8 pixels (Open3D's ray cast never returns otherwise: its range
    map works in 8x8 tiles)."""
    small = camera.scaled(1.0 / downsample)
    width = camera.width // downsample // _RANGE_TILE * _RANGE_TILE
    height = camera.height // downsample // _RANGE_TILE * _RANGE_TILE
    return replace(small, width=width, height=height)


_RANGE_TILE = 8


def _to_uint8(colours: NDArray[Any]) -> NDArray[np.uint8]:
    return np.asarray(np.clip(np.rint(colours * 255.0), 0, 255), dtype=np.uint8)


def _open3d() -> Any:
    from slamcli.backends import import_open3d

    return import_open3d()
