"""Feature-based visual SLAM (ORB-SLAM-like), RGB-D or monocular, offline and deterministic.

Per frame (``process``):

- **Features.** ORB spread over the image and 8 pyramid levels (:mod:`slamcli.vision.features`);
  keypoints, not images, are undistorted. With ``threads = 2`` the next frame's features are
  extracted on the second core while the current one is tracked (the extraction is a pure
  function of the image, so the order of results never changes).
- **Tracking.** The pose is predicted by a constant-velocity model, the last frame's points
  (map points and, RGB-D, its keypoints lifted with depth) are searched by projection, and the
  pose is refined with a robust (Cauchy) loss; failing that, the reference keyframe's points are
  matched by appearance and the pose found by LO-RANSAC PnP (pycolmap); failing that, the frame
  is relocalised against all keyframes by place recognition and PnP. The local map (the points
  of the keyframes that share points with the frame, and their best neighbours) is then searched
  by projection and the pose refined again.
- **Keyframes** as ORB-SLAM decides them: when the frame tracks fewer than
  ``keyframe_track_ratio`` of the reference keyframe's well-seen points (RGB-D: also when too
  few near points are tracked), or ``keyframe_max_frames`` frames have passed.
- **Local mapping** on each keyframe: new points from depth (RGB-D) or by triangulation with
  its covisible keyframes with parallax and reprojection checks (monocular), fusion of duplicate
  points with the neighbours, culling of points seldom found where predicted, local bundle
  adjustment (pycolmap/Ceres) of the keyframe and its covisible neighbours with the keyframes
  that also see their points held fixed, and culling of keyframes whose points are seen by
  three others.
- **Place recognition** (:mod:`slamcli.vision.vocabulary`): each keyframe's bag of words is
  queried against the database; candidates must score above the keyframe's worst covisible
  neighbour, be consistent over ``loop_consistency`` consecutive keyframes, and pass
  geometric verification (PnP for RGB-D, Sim(3) for monocular) followed by a guided search.
  A verified loop fuses the duplicated points and optimises the essential graph (spanning tree,
  strong covisibility edges and loops; SE(3) or Sim(3), GTSAM), then a global bundle
  adjustment. A place recognised in another map merges the two maps.
- **Lost tracking** never aborts the run: a lost frame is relocalised; when that fails for
  ``new_map_after_lost`` frames a new map is started, and merged when a place is recognised.

``finish`` runs a last global bundle adjustment and re-estimates every frame's pose against
the final map (an offline tool can afford it), then returns the trajectory of every frame in
the main map (the one of the first keyframe, with all maps merged into it), the keyframes, the
coloured points, the pose graph, and counts of frames by tracking state, maps, merges and loop
closures with their scores and reasons.
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from itertools import chain
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.config import setting
from slamcli.errors import ConfigError, InputError, PipelineError
from slamcli.geometry import inverse
from slamcli.pipelines.timing import StageTimer
from slamcli.pipelines.visual_map import Keyframe, SparseMap
from slamcli.types import ImageFrame, PinholeCamera, RgbdFrame, SlamResult, Trajectory
from slamcli.vision.features import Features, OrbSettings, depth_at, extract_orb
from slamcli.vision.matching import TH_HIGH, TH_LOW, match_by_projection, match_ratio
from slamcli.vision.pnp import (
    PoseEstimate,
    absolute_pose,
    pose_change,
    refine_pose,
    refine_pose_depth,
)
from slamcli.vision.two_view import triangulate_checked, two_view_geometry
from slamcli.worker import Pending, SideProcess

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

_CHI2_2D = 5.991


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
    """The visual pipeline's robust pose refinement (see ``VisualSlam._refine``)."""
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


@dataclass
class _BaJob:
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


@dataclass(frozen=True)
class VisualConfig:
    """Settings of :class:`VisualSlam`. Lengths in metres, angles in degrees."""

    mode: str = setting(
        "auto",
        help="rgbd uses depth, mono colour only (a map without metric scale, scored after "
        "Sim(3) alignment); auto picks rgbd when the input has depth",
        choices=("auto", "rgbd", "mono"),
    )
    max_features: int = setting(1000, help="ORB features per frame", min=100, max=20000)
    levels: int = setting(8, help="ORB pyramid levels", min=1, max=12)
    scale_factor: float = setting(1.2, help="ORB pyramid scale between levels", gt=1.0, max=2.0)
    fast_threshold: int = setting(
        12, help="FAST corner threshold; corners are ranked and spread afterwards", min=1, max=100
    )
    depth_min_m: float = setting(
        0.1, help="depth readings nearer than this are ignored", unit="m", min=0.0
    )
    depth_max_m: float = setting(
        4.0, help="depth readings further than this are ignored", unit="m", gt=0.0
    )
    depth_baseline_m: float = setting(
        0.16,
        help="RGB-D: a keypoint's depth is weighed as the disparity of a stereo pair with this "
        "baseline (ORB-SLAM uses 0.08 for a Kinect); larger trusts depth more",
        unit="m",
        gt=0.0,
        max=1.0,
    )
    keyframe_track_ratio: float = setting(
        0.75,
        help="a keyframe is made when a frame tracks fewer than this share of its reference "
        "keyframe's points (monocular: at least 0.9)",
        gt=0.0,
        max=1.0,
    )
    keyframe_max_frames: int = setting(
        10, help="a keyframe is made at least this often (frames)", min=1
    )
    local_window: int = setting(
        10, help="covisible keyframes optimised by local bundle adjustment", min=1, max=100
    )
    ba_iterations: int = setting(10, help="iterations of each local bundle adjustment", min=1)
    min_tracked: int = setting(
        30, help="least map points a tracked frame must match after the local-map search", min=6
    )
    pnp_threshold_px: float = setting(
        4.0, help="RANSAC inlier threshold of PnP (relocalisation, loops)", unit="px", gt=0.0
    )
    loop_closure: bool = setting(True, help="detect and close loops")
    vocabulary: str = setting(
        "default",
        help="bag-of-words vocabulary for loop closure and relocalisation: 'default' (shipped "
        "with slamcli, see slamcli/data/VOCABULARY.md) or a file made by 'slamcli vocab train'",
    )
    loop_consistency: int = setting(
        3,
        help="consecutive keyframes a loop candidate must be recognised from before it is verified",
        min=1,
    )
    loop_min_inliers: int = setting(
        40, help="least matched points of a verified loop after the guided search", min=10
    )
    global_ba: bool = setting(
        True, help="global bundle adjustment after a loop closure and at the end"
    )
    final_pose_refinement: bool = setting(
        True,
        help="re-estimate every frame's pose against the final map (else frames keep the "
        "pose tracked online, moved with their keyframe)",
    )
    new_map_after_lost: int = setting(3, help="lost frames after which a new map is started", min=1)
    mono_min_parallax_deg: float = setting(
        1.0, help="monocular initialisation: least median parallax", unit="deg", gt=0.0
    )
    mono_min_points: int = setting(
        50, help="monocular initialisation: least triangulated points", min=8
    )
    threads: int = setting(
        2,
        help="1 does everything on one core; 2 decodes and extracts features of the next "
        "frames, and runs local bundle adjustment, beside tracking (same results either way)",
        choices=(1, 2),
    )
    seed: int = setting(0, help="seeds every RANSAC", min=0, max=2**31 - 1)

    def __post_init__(self) -> None:
        if self.depth_min_m >= self.depth_max_m:
            raise ConfigError(
                f"visual.depth_min_m: expected less than visual.depth_max_m "
                f"({self.depth_max_m}), got {self.depth_min_m!r}",
                hint="set visual.depth_min_m below visual.depth_max_m",
            )


@dataclass
class _Frame:
    """A frame being tracked."""

    index: int
    stamp_ns: int
    name: str
    features: Features
    keypoints: F64  # (N, 2) undistorted
    depth: F64  # (N,) metres or NaN
    colors: NDArray[np.uint8]
    cam_from_world: F64 | None = None
    point_ids: I64 = field(default_factory=lambda: np.zeros(0, np.int64))
    inliers: int = 0


@dataclass
class _FrameRecord:
    """What the trajectory needs of a tracked frame: its pose relative to its reference
    keyframe, and the points it matched (for the final re-estimation). One is kept per frame
    for the whole run, so the matches are kept in 32 bits (20 bytes a point, not 40)."""

    stamp_ns: int
    kf: int
    cam_from_kf: F64
    kp: NDArray[np.float32]
    sigma: NDArray[np.float32]
    depth: NDArray[np.float32]
    pids: NDArray[np.int32]
    state: str


class VisualSlam:
    """Pipeline ``visual``: consumes ``rgbd`` (or ``image``, monocular) frames; produces
    poses, keyframes, coloured points and a pose graph."""

    name = "visual"
    consumes: tuple[str, ...] = ("rgbd",)
    config_class = VisualConfig

    def __init__(self, config: VisualConfig | None = None) -> None:
        self.config = config or VisualConfig()
        cfg = self.config
        self.mono = cfg.mode == "mono"
        self.evaluation = "sim3" if self.mono else "se3"
        # With two threads, frames are decoded ahead on a reader thread (see run_pipeline).
        self.read_ahead = 2 if cfg.threads == 2 else 0
        self._orb = OrbSettings(
            n_features=cfg.max_features,
            levels=cfg.levels,
            scale=cfg.scale_factor,
            fast_threshold=cfg.fast_threshold,
        )
        self.map = SparseMap(cfg.scale_factor, cfg.levels)
        self._camera: PinholeCamera | None = None
        self._raw_camera: PinholeCamera | None = None
        self._pool: ThreadPoolExecutor | None = None
        # An RGB-D local bundle adjustment started at a keyframe runs on a second process with
        # threads=2, and is taken into the map at the next keyframe (or before anything that
        # needs the map settled: a loop, a merge, a new map, the end): a point fixed by the
        # frame sequence, never by timing, so threads=1 (in place) gives the same results.
        self._side = SideProcess(parallel=cfg.threads == 2)
        self._ba_pending: tuple[_BaJob, Pending[Any]] | None = None
        self._pending: list[tuple[RgbdFrame | ImageFrame, Future[Features]]] = []
        self._frames = 0
        self._last: _Frame | None = None
        self._last_points: tuple[F64, NDArray[np.uint8], I64, I64] | None = None
        self._velocity: F64 | None = None
        self._ref_kf: Keyframe | None = None
        self._map_id = 0
        self._maps: list[dict[str, Any]] = []
        self._lost_run = 0
        self._since_reloc = 100
        self._records: list[_FrameRecord] = []
        self._counts: dict[str, int] = defaultdict(int)
        self._ms: dict[str, float] = defaultdict(float)
        self._loops: list[dict[str, Any]] = []
        self._merges: list[dict[str, Any]] = []
        self._places: Any = None
        self._init_ref: _Frame | None = None
        self._textureless = 0
        self._consistent: list[tuple[set[int], int]] = []
        self._init_info: dict[str, Any] | None = None

    # -- the pipeline -------------------------------------------------------------------------

    def seeds(self) -> dict[str, int]:
        """Seeds of the random choices: COLMAP's RANSAC (PnP) and OpenCV's (two-view geometry)
        both get ``config.seed``."""
        return {"ransac": self.config.seed, "opencv": self.config.seed}

    def frame_kinds(self, info: Any) -> tuple[str, ...]:
        """The frames to read from a source described by ``info`` (a SourceInfo): RGB-D when
        it has depth and the mode allows, colour images otherwise.

        Raises:
            ConfigError: ``mode=rgbd`` for an input without depth.
        """
        streams = getattr(info, "streams", [])
        details = getattr(info, "details", {}) or {}
        # A depth stream (TUM) or a depth topic paired with the colour one (MCAP).
        has_depth = any(s.kind == "depth" and s.count > 0 for s in streams) or bool(
            details.get("depth_topic") and getattr(info, "frames", 0) > 0
        )
        mode = self.config.mode
        if mode == "rgbd" and not has_depth:
            raise ConfigError(
                f"visual.mode=rgbd, but {getattr(info, 'path', 'the input')} has no depth stream",
                hint="use --set mode=mono (or mode=auto) for colour-only input",
            )
        self.mono = mode == "mono" or (mode == "auto" and not has_depth)
        self.evaluation = "sim3" if self.mono else "se3"
        return ("image",) if self.mono else ("rgbd",)

    def process(self, frame: RgbdFrame | ImageFrame) -> None:
        """Queue a frame; with two threads its features are extracted while the previous
        frame is tracked."""
        if self.config.threads == 2:
            if self._pool is None:
                self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="orb")
                self._side.start()
            self._pending.append((frame, self._pool.submit(self._extract, frame)))
            if len(self._pending) > 1:
                ready, fut = self._pending.pop(0)
                self._track_frame(ready, fut.result())
        else:
            self._track_frame(frame, self._extract(frame))

    def finish(self) -> SlamResult:
        """Track what is queued, adjust the final map, and return the result."""
        while self._pending:
            ready, fut = self._pending.pop(0)
            self._track_frame(ready, fut.result())
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._settle_ba()
        try:
            if self._frames == 0:
                raise PipelineError("the visual pipeline received no frames")
            start = time.perf_counter()
            main = self._main_map()
            if main is None:
                self._no_map_error()
            if self.config.global_ba:
                with self._timed("global_ba"):
                    self._global_ba(main)
            with self._timed("final_poses"):
                trajectory = self._trajectory(main)
        finally:
            self._side.close()
        self._ms["total"] += (time.perf_counter() - start) * 1e3
        return self._result(main, trajectory)

    # -- as another pipeline's front end ------------------------------------------------------

    def extract(self, frame: RgbdFrame | ImageFrame) -> Features:
        """ORB features of ``frame`` for :meth:`track` (no state is changed: it may run on
        another thread)."""
        return self._extract(frame)

    def track(self, frame: RgbdFrame | ImageFrame, features: Features) -> tuple[F64, int] | None:
        """Track ``frame`` now, without the queue of :meth:`process`: its world_from_camera
        pose as tracked (in the frame of its map) and that map's id, or None while the map is
        initialising or the frame is lost. :meth:`finish` still gives the final trajectory."""
        if self.config.threads == 2:
            self._side.start()
        before = len(self._records)
        self._track_frame(frame, features)
        if len(self._records) == before:
            return None
        rec = self._records[-1]
        kf = self.map.keyframes[rec.kf]
        return inverse(rec.cam_from_kf @ kf.cam_from_world), int(kf.map_id)

    def close(self) -> None:
        """Stop the side process and the feature thread (after an error; :meth:`finish` stops
        them itself)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
        self._side.close()

    # -- frames ------------------------------------------------------------------------------

    def _extract(self, frame: RgbdFrame | ImageFrame) -> Features:
        import cv2

        rgb = frame.rgb if isinstance(frame, RgbdFrame) else frame.image
        if rgb.ndim == 2:
            gray = np.ascontiguousarray(rgb, dtype=np.uint8)
        else:
            colour = np.ascontiguousarray(rgb[..., :3], dtype=np.uint8)
            gray = np.asarray(cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY), dtype=np.uint8)
        return extract_orb(gray, self._orb)

    def _prepare(self, frame: RgbdFrame | ImageFrame, features: Features) -> _Frame:
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
        return _Frame(
            index=self._frames,
            stamp_ns=frame.stamp_ns,
            name=frame.name,
            features=features,
            keypoints=kp,
            depth=z,
            colors=np.asarray(colors, dtype=np.uint8),
            point_ids=np.full(len(kp), -1, np.int64),
        )

    def _track_frame(self, frame: RgbdFrame | ImageFrame, features: Features) -> None:
        start = time.perf_counter()
        cur = self._prepare(frame, features)
        self._frames += 1
        if len(cur.features) < 20:
            self._textureless += 1
        state = self._track(cur)
        self._counts[f"frames_{state}"] += 1
        self._ms["total"] += (time.perf_counter() - start) * 1e3

    # -- tracking ----------------------------------------------------------------------------

    def _track(self, cur: _Frame) -> str:
        """Pose ``cur``; returns its tracking state (tracked, relocalised, initialising,
        new_map, lost)."""
        if self._ref_kf is None or self._ref_kf.map_id != self._map_id:
            return self._initialise(cur)
        pose = None
        state = "tracked"
        with self._timed("track"):
            if self._last is not None and self._velocity is not None and self._lost_run == 0:
                pose = self._track_motion(cur)
            if pose is None and self._lost_run == 0:
                pose = self._track_reference(cur)
        if pose is None:
            with self._timed("relocalise"):
                pose = self._relocalise(cur)
            state = "relocalised"
            self._since_reloc = 0
        if pose is not None:
            cur.cam_from_world = pose
            with self._timed("local_map"):
                ok = self._track_local_map(cur)
            if not ok:
                pose = None
        if pose is None:
            self._lost_run += 1
            self._last = None
            if self._lost_run >= self.config.new_map_after_lost:
                self._start_new_map()
            return "lost"
        self._lost_run = 0
        self._since_reloc += 1
        assert cur.cam_from_world is not None
        if self._last is not None and self._last.cam_from_world is not None:
            self._velocity = cur.cam_from_world @ inverse(self._last.cam_from_world)
        else:
            self._velocity = None
        self._record(cur, state)
        if self._wants_keyframe(cur):
            with self._timed("mapping"):
                self._make_keyframe(cur)
        self._set_last(cur)
        return state

    def _track_motion(self, cur: _Frame) -> F64 | None:
        """Constant-velocity prediction, refined on the last frame's points found by
        projection."""
        assert self._last is not None and self._velocity is not None
        assert self._last.cam_from_world is not None and self._last_points is not None
        predicted = self._velocity @ self._last.cam_from_world
        world, desc, octv, pids = self._last_points
        th = 15.0 if self.mono else 7.0
        for radius in (th, 2 * th):
            pairs = self._project_match(cur, predicted, world, desc, octv, radius, ratio=0.9)
            if len(pairs) >= 20:
                break
        if len(pairs) < 20:
            self._counts["motion_model_failed"] += 1
            return None
        # A seed for the local-map search, which refines again: two rounds suffice.
        est = self._refine(
            predicted,
            cur.keypoints[pairs[:, 1]],
            world[pairs[:, 0]],
            self.map.sigma[cur.features.octaves[pairs[:, 1]]],
            cur.depth[pairs[:, 1]],
            rounds=2,
        )
        if est is None or est.num_inliers < 10:
            self._counts["motion_model_failed"] += 1
            return None
        good = pairs[est.inliers]
        keep = pids[good[:, 0]] >= 0
        cur.point_ids[good[keep, 1]] = pids[good[keep, 0]]
        return est.cam_from_world

    def _refine(
        self, pose: F64, kp: F64, world: F64, sigma: F64, depth: F64, rounds: int = 4
    ) -> PoseEstimate | None:
        """Robust pose refinement: with the keypoints' depths for RGB-D (a stereo-like
        residual), reprojection only for monocular; ``rounds`` of outlier rejection."""
        return _refine_pose(
            self._camera_checked(),
            self.mono,
            self.config.depth_baseline_m,
            pose,
            kp,
            world,
            sigma,
            depth,
            rounds,
        )

    def _track_reference(self, cur: _Frame) -> F64 | None:
        """Match the reference keyframe's points by appearance; PnP."""
        kf = self._ref_kf
        assert kf is not None
        est = self._pnp_against(cur, kf)
        if est is None:
            self._counts["reference_failed"] += 1
            return None
        return est

    def _pnp_against(self, cur: _Frame, kf: Keyframe, min_inliers: int = 15) -> F64 | None:
        has = np.flatnonzero(kf.point_ids >= 0)
        if has.size < min_inliers:
            return None
        pairs = match_ratio(kf.descriptors[has], cur.features.descriptors, 0.75, TH_HIGH)
        if len(pairs) < min_inliers:
            return None
        pids = kf.point_ids[has[pairs[:, 0]]]
        est = absolute_pose(
            self._camera_checked(),
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

    def _relocalise(self, cur: _Frame) -> F64 | None:
        """Place recognition against every keyframe of the current map, then PnP."""
        candidates = self._place_candidates(cur.features.descriptors, self._map_id, limit=5)
        for kf_id, _score in candidates:
            pose = self._pnp_against(cur, self.map.keyframes[kf_id], min_inliers=30)
            if pose is not None:
                self._ref_kf = self.map.keyframes[kf_id]
                return pose
        # Without a vocabulary hit, the latest keyframes of the map.
        for kf in reversed(self.map.live(self._map_id)[-5:]):
            pose = self._pnp_against(cur, kf, min_inliers=30)
            if pose is not None:
                self._ref_kf = kf
                return pose
        self._counts["relocalisation_failed"] += 1
        return None

    def _track_local_map(self, cur: _Frame) -> bool:
        """Search the local map by projection, refine the pose; whether tracking holds."""
        assert cur.cam_from_world is not None
        local_kfs = self._local_keyframes(cur)
        if local_kfs:
            self._ref_kf = local_kfs[0]
        ids = [kf.point_ids[kf.point_ids >= 0] for kf in local_kfs]
        pids = np.unique(np.concatenate(ids)) if ids else np.zeros(0, np.int64)
        pids = pids[self.map.alive[pids] & (self.map.map_id[pids] == self._map_id)]
        pids = np.setdiff1d(pids, cur.point_ids[cur.point_ids >= 0])
        pose = cur.cam_from_world
        visible, dist = self._in_view(pose, pids)
        pids, dist = pids[visible], dist[visible]
        self.map.visible[pids] += 1
        if pids.size:
            octv = self.map.predict_octave(pids, dist)
            th = 5.0 if self._since_reloc < 2 else 3.0
            pairs = self._project_match(
                cur, pose, self.map.pos[pids], self.map.desc[pids], octv, th * 2.5, ratio=0.8
            )
            free = cur.point_ids[pairs[:, 1]] < 0
            cur.point_ids[pairs[free, 1]] = pids[pairs[free, 0]]
        matched = np.flatnonzero(cur.point_ids >= 0)
        if matched.size < 6:
            return False
        est = self._refine(
            pose,
            cur.keypoints[matched],
            self.map.pos[cur.point_ids[matched]],
            self.map.sigma[cur.features.octaves[matched]],
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
            self._counts["local_map_too_few"] += 1
            return False
        return True

    def _local_keyframes(self, cur: _Frame) -> list[Keyframe]:
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
        if not first and self._ref_kf is not None:
            first = [self._ref_kf.id]
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

    def _in_view(self, cam_from_world: F64, pids: I64) -> tuple[NDArray[np.bool_], F64]:
        """Which points project into the image at a distance and angle their scale range and
        viewing direction allow; and their distances."""
        cam = self._camera_checked()
        p = self.map.pos[pids] @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = cam.fx * p[:, 0] / z + cam.cx
            v = cam.fy * p[:, 1] / z + cam.cy
        ok = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        center = -cam_from_world[:3, :3].T @ cam_from_world[:3, 3]
        ray = self.map.pos[pids] - center
        dist = np.linalg.norm(ray, axis=1)
        ok &= self.map.in_range(pids, dist)
        cos = np.einsum("ij,ij->i", ray, self.map.normal[pids]) / np.maximum(dist, 1e-12)
        ok &= cos >= 0.5
        return ok, dist

    def _project_match(
        self,
        cur: _Frame,
        cam_from_world: F64,
        world: F64,
        desc: NDArray[np.uint8],
        octaves: I64,
        radius: float,
        ratio: float,
        max_distance: int = TH_HIGH,
    ) -> I64:
        """(K, 2) pairs (point row, keypoint) found by projecting ``world`` points."""
        cam = self._camera_checked()
        p = world @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
        z = p[:, 2]
        front = np.flatnonzero(z > 1e-6)
        if front.size == 0:
            return np.zeros((0, 2), np.int64)
        uv = np.stack(
            [cam.fx * p[front, 0] / z[front] + cam.cx, cam.fy * p[front, 1] / z[front] + cam.cy],
            axis=1,
        )
        inside = (
            (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        )
        front, uv = front[inside], uv[inside]
        if front.size == 0:
            return np.zeros((0, 2), np.int64)
        pairs = match_by_projection(
            uv,
            desc[front],
            radius * self.map.sigma[octaves[front]],
            cur.keypoints,
            cur.features.descriptors,
            kp_octaves=cur.features.octaves,
            predicted_octaves=octaves[front],
            ratio=ratio,
            max_distance=max_distance,
        )
        pairs[:, 0] = front[pairs[:, 0]]
        return pairs

    def _set_last(self, cur: _Frame) -> None:
        """Keep the frame's points for the next frame's motion-model search: its map points
        and, RGB-D, its other keypoints lifted with depth (ORB-SLAM's temporary points)."""
        assert cur.cam_from_world is not None
        self._last = cur
        has = cur.point_ids >= 0
        rows = np.flatnonzero(has)
        world = self.map.pos[cur.point_ids[rows]]
        pids = cur.point_ids[rows]
        if not self.mono:
            extra = np.flatnonzero(~has & np.isfinite(cur.depth))
            if extra.size:
                cam = self._camera_checked()
                from slamcli.geometry.camera import unproject

                pc = unproject(cam, cur.keypoints[extra], cur.depth[extra])
                w2c = inverse(cur.cam_from_world)
                world = np.concatenate([world, pc @ w2c[:3, :3].T + w2c[:3, 3]])
                rows = np.concatenate([rows, extra])
                pids = np.concatenate([pids, np.full(extra.size, -1, np.int64)])
        self._last_points = (
            world,
            cur.features.descriptors[rows],
            cur.features.octaves[rows].astype(np.int64),
            pids,
        )

    def _record(self, cur: _Frame, state: str) -> None:
        assert cur.cam_from_world is not None and self._ref_kf is not None
        rows = np.flatnonzero(cur.point_ids >= 0)
        self._records.append(
            _FrameRecord(
                cur.stamp_ns,
                self._ref_kf.id,
                cur.cam_from_world @ inverse(self._ref_kf.cam_from_world),
                cur.keypoints[rows].astype(np.float32),
                self.map.sigma[cur.features.octaves[rows]].astype(np.float32),
                cur.depth[rows].astype(np.float32),
                cur.point_ids[rows].astype(np.int32),
                state,
            )
        )

    # -- keyframes and local mapping ---------------------------------------------------------

    def _wants_keyframe(self, cur: _Frame) -> bool:
        kf = self._ref_kf
        assert kf is not None
        last_kf = self.map.keyframes[-1]
        if self._since_reloc < 2:
            return False
        live = self.map.live(self._map_id)
        min_obs = 2 if len(live) <= 2 else 3
        if not self.mono:
            # ORB-SLAM counts an RGB-D observation twice (it carries depth).
            min_obs -= 1
        ref_pids = kf.point_ids[kf.point_ids >= 0]
        ref_matches = sum(1 for p in ref_pids.tolist() if len(self.map.obs[p]) >= min_obs)
        ratio = (
            max(self.config.keyframe_track_ratio, 0.9)
            if self.mono
            else self.config.keyframe_track_ratio
        )
        if len(live) < 2 and not self.mono:
            ratio = 0.4
        tracked = cur.inliers
        need_close = False
        if not self.mono:
            close = np.isfinite(cur.depth) & (cur.depth < 0.75 * self.config.depth_max_m)
            tracked_close = int(np.count_nonzero(close & (cur.point_ids >= 0)))
            untracked_close = int(np.count_nonzero(close & (cur.point_ids < 0)))
            need_close = tracked_close < 100 and untracked_close > 70
        # Offline, local mapping is never busy: ORB-SLAM's "mapping idle" condition always
        # holds, so a keyframe is made whenever tracking weakens, or after keyframe_max_frames.
        weak = (tracked < ref_matches * ratio or need_close) and tracked > 15
        overdue = cur.index - last_kf.frame >= self.config.keyframe_max_frames and tracked > 15
        return bool(weak or overdue)

    def _new_keyframe(self, cur: _Frame) -> Keyframe:
        assert cur.cam_from_world is not None
        kf = Keyframe(
            id=len(self.map.keyframes),
            frame=cur.index,
            stamp_ns=cur.stamp_ns,
            map_id=self._map_id,
            cam_from_world=cur.cam_from_world.copy(),
            keypoints=cur.keypoints,
            octaves=cur.features.octaves,
            descriptors=cur.features.descriptors,
            depth=cur.depth,
            colors=cur.colors,
            point_ids=np.full(len(cur.keypoints), -1, np.int64),
        )
        self.map.add_keyframe(kf)
        return kf

    def _make_keyframe(self, cur: _Frame) -> None:
        kf = self._new_keyframe(cur)
        assert self._ref_kf is not None
        kf.parent = self._ref_kf.id
        rows = np.flatnonzero(cur.point_ids >= 0)
        for r, pid in zip(rows.tolist(), cur.point_ids[rows].tolist(), strict=True):
            if self.map.alive[pid] and kf.id not in self.map.obs[pid]:
                self.map.observe(kf, r, pid)
        self.map.update_geometry(kf.point_ids[kf.point_ids >= 0])
        if not self.mono:
            self._points_from_depth(kf)
        else:
            self._triangulate(kf)
        # The previous keyframe's adjustment has had this keyframe's new points to finish in.
        if self._settle_ba(within="mapping"):
            self._repose(kf)
        self._fuse_neighbours(kf)
        self._cull_points(kf)
        self._local_ba(kf)
        self._cull_keyframes(kf)
        self._ref_kf = kf
        self._index_place(kf)
        if self.config.loop_closure:
            with self._timed("loop"):
                self._detect_loop(kf)
        # The frame's matches follow the keyframe's (fused) points, and its pose the keyframe's
        # (moved by a loop closure or a merge).
        cur.point_ids = kf.point_ids.copy()
        cur.cam_from_world = kf.cam_from_world.copy()
        self._counts["keyframes_made"] += 1

    def _points_from_depth(self, kf: Keyframe) -> None:
        free = np.flatnonzero((kf.point_ids < 0) & np.isfinite(kf.depth))
        if free.size == 0:
            return
        from slamcli.geometry.camera import unproject

        cam = self._camera_checked()
        pc = unproject(cam, kf.keypoints[free], kf.depth[free])
        w = inverse(kf.cam_from_world)
        self.map.add_points(kf, free, pc @ w[:3, :3].T + w[:3, 3])

    def _fuse_neighbours(self, kf: Keyframe) -> None:
        """Project the neighbours' points into the new keyframe: a match to a keypoint without
        a point adds an observation, to one with another point fuses the two."""
        neighbours = [self.map.keyframes[k] for k, _ in self.map.covisible(kf)[:10]]
        if not neighbours:
            return
        ids = np.unique(np.concatenate([nb.point_ids[nb.point_ids >= 0] for nb in neighbours]))
        ids = ids[self.map.alive[ids]]
        ids = np.setdiff1d(ids, kf.point_ids[kf.point_ids >= 0])
        self._fuse_into(kf, ids)

    def _fuse_into(self, kf: Keyframe, ids: I64, radius: float = 3.0) -> int:
        """Fuse points ``ids`` into keyframe ``kf`` by projection; returns how many matched."""
        if ids.size == 0:
            return 0
        visible, dist = self._in_view(kf.cam_from_world, ids)
        ids, dist = ids[visible], dist[visible]
        if ids.size == 0:
            return 0
        octv = self.map.predict_octave(ids, dist)
        fake = _frame_of(kf)
        pairs = self._project_match(
            fake,
            kf.cam_from_world,
            self.map.pos[ids],
            self.map.desc[ids],
            octv,
            radius,
            ratio=1.0,
            max_distance=TH_LOW,
        )
        # Reprojection check with the keypoint's scale (and, RGB-D, its depth as a stereo
        # disparity, as ORB-SLAM's Fuse).
        cam = self._camera_checked()
        p = self.map.pos[ids[pairs[:, 0]]] @ kf.cam_from_world[:3, :3].T + kf.cam_from_world[:3, 3]
        uv = np.stack([cam.fx * p[:, 0] / p[:, 2] + cam.cx, cam.fy * p[:, 1] / p[:, 2] + cam.cy], 1)
        err2 = np.sum((uv - kf.keypoints[pairs[:, 1]]) ** 2, axis=1)
        sig = self.map.sigma[kf.octaves[pairs[:, 1]]]
        z_kp = kf.depth[pairs[:, 1]]
        stereo = np.isfinite(z_kp)
        bf = cam.fx * self.config.depth_baseline_m
        disp = np.where(stereo, bf / p[:, 2] - bf / np.where(stereo, z_kp, 1.0), 0.0)
        pairs = pairs[err2 + disp**2 <= np.where(stereo, 7.815, _CHI2_2D) * sig**2]
        n = 0
        for row, kp in pairs.tolist():
            pid = int(ids[row])
            if not self.map.alive[pid]:
                continue
            other = int(kf.point_ids[kp])
            if other < 0:
                if kf.id not in self.map.obs[pid]:
                    self.map.observe(kf, kp, pid)
                    n += 1
            elif other != pid and self.map.alive[other]:
                keep, drop = (
                    (pid, other)
                    if len(self.map.obs[pid]) >= len(self.map.obs[other])
                    else (other, pid)
                )
                self.map.replace(drop, keep)
                n += 1
        return n

    def _cull_points(self, kf: Keyframe) -> None:
        """Points made in the last keyframes that are seldom found where predicted, or seen by
        too few keyframes, are removed (ORB-SLAM's recent-point culling)."""
        lo = max(0, self.map.n - 20000)
        ids = np.arange(lo, self.map.n)
        ids = ids[self.map.alive[ids] & (self.map.map_id[ids] == kf.map_id)]
        ids = ids[self.map.first_kf[ids] >= kf.id - 2]
        ratio = self.map.found[ids] / np.maximum(self.map.visible[ids], 1)
        n_obs = np.array([len(self.map.obs[p]) for p in ids.tolist()], dtype=np.int64)
        # An RGB-D point is made from one keyframe's depth; a monocular one from two views.
        th_obs = 2 if self.mono else 1
        age = kf.id - self.map.first_kf[ids]
        bad = (ratio < 0.25) | ((age >= 2) & (n_obs <= th_obs))
        for pid in ids[bad].tolist():
            self.map.cull_point(pid)
        self._counts["points_culled"] += int(np.count_nonzero(bad))

    def _local_ba(self, kf: Keyframe) -> None:

        window = [kf] + [
            self.map.keyframes[k] for k, _ in self.map.covisible(kf)[: self.config.local_window]
        ]
        window_ids = {k.id for k in window}
        pids = np.unique(np.concatenate([k.point_ids[k.point_ids >= 0] for k in window]))
        pids = pids[self.map.alive[pids]]
        if pids.size == 0:
            return
        fixed_ids: list[int] = []
        for pid in pids.tolist():
            for k in self.map.obs[pid]:
                if k not in window_ids and k not in fixed_ids and not self.map.keyframes[k].culled:
                    fixed_ids.append(k)
        fixed_ids = sorted(fixed_ids)[:40]
        if not fixed_ids and self.map.live(kf.map_id)[0].id in window_ids:
            first = self.map.live(kf.map_id)[0]
            window = [first] + [k for k in window if k.id != first.id]
            fixed = [True] + [False] * (len(window) - 1)
        else:
            fixed = [False] * len(window) + [True] * len(fixed_ids)
            window = window + [self.map.keyframes[k] for k in fixed_ids]
        self._counts["local_ba"] += 1
        if self.mono:
            # A map without depth is adjusted at once: the next keyframe triangulates its new
            # points from these poses, and scale errors left in them would compound.
            self._bundle(window, np.array(fixed), pids, self.config.ba_iterations)
            return
        job = self._ba_job(window, np.array(fixed), pids, self.config.ba_iterations)
        if job is not None:
            from slamcli.vision.bundle_adjustment import bundle_adjust

            self._ba_pending = (job, self._side.submit(bundle_adjust, *job.args, **job.kwargs))

    def _bundle(
        self, kfs: list[Keyframe], fixed: NDArray[np.bool_], pids: I64, iterations: int
    ) -> None:
        """Bundle-adjust keyframes ``kfs`` (``fixed`` held) and points ``pids`` now; drop the
        observations that end up outliers."""
        from slamcli.vision.bundle_adjustment import bundle_adjust

        job = self._ba_job(kfs, fixed, pids, iterations)
        if job is not None:
            self._ba_apply(job, bundle_adjust(*job.args, **job.kwargs))

    def _ba_job(
        self, kfs: list[Keyframe], fixed: NDArray[np.bool_], pids: I64, iterations: int
    ) -> _BaJob | None:
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
        if not self.mono:
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
            self._camera_checked(),
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
            "obs_depth": None if self.mono else dep,
            "baseline_m": self.config.depth_baseline_m,
        }
        return _BaJob(list(kfs), fixed.copy(), pids, of, op.tolist(), okp, args, kwargs)

    def _ba_apply(self, job: _BaJob, result: Any) -> None:
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
        self._counts["ba_outliers_removed"] += removed
        self.map.update_geometry(job.pids[self.map.alive[job.pids]], descriptors=False)

    def _settle_ba(self, within: str | None = None) -> bool:
        """Take the local bundle adjustment that runs apart, if any, into the map; returns
        whether there was one. The wait is timed as ``ba_wait``, and taken out of the stage
        ``within`` that is timing the caller."""
        if self._ba_pending is None:
            return False
        job, pending = self._ba_pending
        self._ba_pending = None
        start = time.perf_counter()
        result = pending.result()
        waited = (time.perf_counter() - start) * 1e3
        self._ms["ba_wait"] += waited
        if within is not None:
            self._ms[within] -= waited
        self._ba_apply(job, result)
        return True

    def _repose(self, kf: Keyframe) -> None:
        """Refine a new keyframe's pose against the older points it sees, where the adjustment
        just moved them (it was tracked against where they were); the points made from its own
        depth move with it."""
        pids = kf.point_ids
        rows = np.flatnonzero(pids >= 0)
        rows = rows[self.map.alive[pids[rows]]]
        own = rows[self.map.first_kf[pids[rows]] == kf.id]
        older = rows[self.map.first_kf[pids[rows]] != kf.id]
        if older.size < 10:
            return
        est = self._refine(
            kf.cam_from_world,
            kf.keypoints[older],
            self.map.pos[pids[older]],
            self.map.sigma[kf.octaves[older].astype(np.int64)],
            kf.depth[older],
            rounds=2,
        )
        if est is None or est.num_inliers < 10:
            return
        # world -> old camera -> new world: the own points keep their place in the camera.
        move = inverse(est.cam_from_world) @ kf.cam_from_world
        ids = pids[own]
        self.map.pos[ids] = self.map.pos[ids] @ move[:3, :3].T + move[:3, 3]
        kf.cam_from_world = est.cam_from_world

    def _cull_keyframes(self, kf: Keyframe) -> None:
        """A covisible keyframe whose points are 90% seen by three others at the same or a
        finer scale is redundant: it is culled (its pose then follows its parent)."""
        first = self.map.live(kf.map_id)[0].id
        for k, _w in self.map.covisible(kf):
            cand = self.map.keyframes[k]
            if cand.id == first or cand.id == kf.id or cand.culled or cand.loop_edges:
                continue
            rows = np.flatnonzero(cand.point_ids >= 0)
            if not self.mono:
                rows = rows[np.isfinite(cand.depth[rows])]
            if rows.size == 0:
                continue
            # How many other keyframes see each of these points at the same or a finer
            # scale: its observers are the keyframes covisible with it.
            level = cand.octaves[rows].astype(np.int64)
            row_of = np.full(self.map.n, -1, dtype=np.int64)
            row_of[cand.point_ids[rows]] = np.arange(rows.size)
            seen = np.zeros(rows.size, dtype=np.int64)
            for k2, _ in self.map.covisible(cand):
                other = self.map.keyframes[k2]
                kps = np.flatnonzero(other.point_ids >= 0)
                r = row_of[other.point_ids[kps]]
                kps, r = kps[r >= 0], r[r >= 0]
                finer = other.octaves[kps] <= level[r] + 1
                seen += np.bincount(r[finer], minlength=rows.size)
            if np.count_nonzero(seen >= 3) > 0.9 * rows.size:
                self._cull(cand)

    def _cull(self, cand: Keyframe) -> None:
        nbs = [k for k, _ in self.map.covisible(cand) if k != cand.id]
        parent = cand.parent if cand.parent is not None else (nbs[0] if nbs else None)
        if parent is None:
            return
        # Re-hang children on the parent.
        for other in self.map.keyframes:
            if other.parent == cand.id and not other.culled:
                other.parent = parent
        cand.culled = True
        self.map.version += 1
        cand.parent = parent
        cand.from_parent = cand.cam_from_world @ inverse(self.map.world_pose(parent))
        for kp in np.flatnonzero(cand.point_ids >= 0).tolist():
            self.map.forget(cand, kp)
        if self._places is not None:
            self._places.remove(cand.id)
        self._counts["keyframes_culled"] += 1

    # -- maps --------------------------------------------------------------------------------

    def _initialise(self, cur: _Frame) -> str:
        if self.mono:
            return self._initialise_mono(cur)
        has = np.isfinite(cur.depth)
        if np.count_nonzero(has) < 100:
            self._counts["init_too_little_depth"] += 1
            return "initialising"
        # A new map has a frame of its own until a merge relates it to the others.
        cur.cam_from_world = np.eye(4)
        kf = self._new_keyframe(cur)
        self._points_from_depth(kf)
        self._maps.append({"id": self._map_id, "first_frame": cur.index, "merged_into": None})
        self._ref_kf = kf
        self._index_place(kf)
        cur.point_ids = kf.point_ids.copy()
        cur.inliers = int(np.count_nonzero(kf.point_ids >= 0))
        self._velocity = None
        self._record(cur, "tracked")
        self._set_last(cur)
        self._counts["keyframes_made"] += 1
        return "new_map" if len(self._maps) > 1 else "tracked"

    def _start_new_map(self) -> None:
        self._settle_ba()
        self._map_id += 1
        self._ref_kf = None
        self._last = None
        self._velocity = None
        self._lost_run = 0
        self._init_ref = None
        self._counts["maps_started"] += 1

    def _main_map(self) -> int | None:
        kfs = self.map.live()
        if not kfs:
            return None
        return kfs[0].map_id

    def _no_map_error(self) -> None:
        if self._textureless >= self._frames * 0.9:
            raise PipelineError(
                f"no map could be made: {self._textureless} of {self._frames} frames had fewer "
                "than 20 ORB features (images without texture?)",
                hint="check the images; visual SLAM needs textured scenes",
            )
        if self.mono:
            raise PipelineError(
                f"monocular initialisation never succeeded over {self._frames} frames (it needs "
                f"{self.config.mono_min_points} points triangulated with at least "
                f"{self.config.mono_min_parallax_deg} deg of parallax: the camera must translate)",
                hint="give a sequence that moves sideways, or use RGB-D input",
            )
        raise PipelineError(
            f"no map could be made from {self._frames} frames: none had 100 keypoints with depth "
            f"between {self.config.depth_min_m} and {self.config.depth_max_m} m",
            hint="check the depth stream and its depth scale, or widen visual.depth_max_m",
        )

    # -- place recognition and loops -- filled in by the loop-closure stage ---------------------

    def _index_place(self, kf: Keyframe) -> None:
        db = self._place_db()
        if db is None:
            return
        kf.bow = db.vocabulary.bow(kf.descriptors)
        db.add(kf.id, kf.bow)

    def _place_db(self) -> Any:
        if self._places is None:
            from slamcli.vision.vocabulary import KeyframeDatabase

            self._places = KeyframeDatabase(self._vocabulary())
        return self._places

    def _vocabulary(self) -> Any:
        from slamcli.vision.vocabulary import Vocabulary

        name = self.config.vocabulary
        if name == "default":
            return Vocabulary.default()
        return Vocabulary.load(name)

    def _place_candidates(
        self, descriptors: NDArray[np.uint8], map_id: int | None, limit: int
    ) -> list[tuple[int, float]]:
        db = self._place_db()
        if db is None:
            return []
        bow = db.vocabulary.bow(descriptors)
        out = []
        for kf_id, score in db.query(bow):
            kf = self.map.keyframes[kf_id]
            if kf.culled or (map_id is not None and kf.map_id != map_id):
                continue
            out.append((kf_id, score))
            if len(out) >= limit:
                break
        return out

    def _detect_loop(self, kf: Keyframe) -> None:
        """Place recognition for a new keyframe; verified candidates close a loop (same map)
        or merge two maps."""
        db = self._place_db()
        if kf.bow is None or (len(self.map.live(kf.map_id)) < 10 and len(self._maps) < 2):
            self._consistent = []
            return
        covis = self.map.covisible(kf)
        connected = {k for k, _ in covis} | {kf.id}
        voc = db.vocabulary
        scores = [
            voc.score(kf.bow, self.map.keyframes[k].bow)
            for k, _ in covis[:30]
            if self.map.keyframes[k].bow is not None
        ]
        min_score = min(scores) if scores else 0.0
        results = {
            k: s
            for k, s in db.query(kf.bow, exclude=connected)
            if s >= min_score
            and not self.map.keyframes[k].culled
            # Keyframes just made are neighbours in time, not a revisited place.
            and not (self.map.keyframes[k].map_id == kf.map_id and kf.id - k < 10)
        }
        if not results:
            self._consistent = []
            return
        # Accumulate each candidate's score over its best neighbours; keep the groups close to
        # the best (ORB-SLAM's DetectLoopCandidates).
        groups = []
        for k, s in sorted(results.items(), key=lambda ks: (-ks[1], ks[0])):
            nbs = [n for n, _ in self.map.covisible(self.map.keyframes[k])[:10]]
            acc = s + sum(results.get(n, 0.0) for n in nbs)
            best = max(
                [(results.get(n, 0.0), n) for n in nbs] + [(s, k)], key=lambda x: (x[0], -x[1])
            )
            groups.append((acc, best[1], best[0], {k, *nbs}))
        top = max(g[0] for g in groups)
        groups = [g for g in groups if g[0] >= 0.75 * top]
        # Temporal consistency over consecutive keyframes.
        previous = self._consistent
        consistent: list[tuple[set[int], int]] = []
        ready: list[tuple[int, float]] = []
        for _acc, cand, score, group in groups:
            count = 0
            for prev_group, prev_count in previous:
                if group & prev_group:
                    count = max(count, prev_count + 1)
            consistent.append((group, count))
            if count + 1 >= self.config.loop_consistency and cand not in {c for c, _ in ready}:
                ready.append((cand, score))
        self._consistent = consistent
        for cand, score in ready[:3]:
            if self._verify_and_close(kf, self.map.keyframes[cand], score):
                self._consistent = []
                return

    def _verify_and_close(self, kf: Keyframe, cand: Keyframe, score: float) -> bool:
        """Verify a loop candidate geometrically and close the loop (or merge the maps)."""
        merge = cand.map_id != kf.map_id
        record: dict[str, Any] = {
            "type": "merge" if merge else "loop",
            "keyframes": [cand.id, kf.id],
            "frames": [cand.frame, kf.frame],
            "score": round(float(score), 4),
            "inliers": 0,
            "accepted": False,
            "reason": "",
        }
        self._loops.append(record)
        scale = 1.0
        if self.mono:
            found = self._loop_sim3(kf, cand, record)
            if found is None:
                return False
            corrected, scale = found
            record["scale"] = round(scale, 5)
        else:
            pose = self._loop_pose(kf, cand, record)
            if pose is None:
                return False
            corrected = pose
        m, deg = pose_change(inverse(kf.cam_from_world), inverse(corrected))
        record["correction_m"] = round(m, 5)
        record["correction_deg"] = round(deg, 4)
        record["accepted"] = True
        record["reason"] = "verified"
        if merge:
            self._merge_maps(kf, cand, corrected, scale)
            # The maps are one now, kf already where the loop puts it.
            corrected, scale = kf.cam_from_world.copy(), 1.0
        if self.mono:
            self._close_loop_sim3(kf, cand, corrected, scale)
        else:
            self._close_loop(kf, cand, corrected)
        return True

    def _loop_sim3(
        self, kf: Keyframe, cand: Keyframe, record: dict[str, Any]
    ) -> tuple[F64, float] | None:
        """Monocular loop verification: the similarity between the two keyframes' point
        clouds by RANSAC over matched map points (scale drifts in a monocular map), then a
        guided search of the candidate's neighbourhood with the pose it implies. Returns
        kf's corrected ``cam_from_world`` in the candidate's map and the scale that takes kf's
        map units to the candidate's."""
        from slamcli.geometry.align import umeyama

        cam = self._camera_checked()
        a = np.flatnonzero(cand.point_ids >= 0)
        b = np.flatnonzero(kf.point_ids >= 0)
        pairs = match_ratio(cand.descriptors[a], kf.descriptors[b], 0.75, TH_HIGH)
        if len(pairs) < 20:
            record["reason"] = f"{len(pairs)} appearance matches (need 20)"
            return None
        ia, ib = a[pairs[:, 0]], b[pairs[:, 1]]
        pa = self.map.pos[cand.point_ids[ia]]
        pb = self.map.pos[kf.point_ids[ib]]
        ca = pa @ cand.cam_from_world[:3, :3].T + cand.cam_from_world[:3, 3]
        cb = pb @ kf.cam_from_world[:3, :3].T + kf.cam_from_world[:3, 3]
        sig_a = self.map.sigma[cand.octaves[ia]]
        sig_b = self.map.sigma[kf.octaves[ib]]
        rng = np.random.default_rng(self.config.seed)
        best: tuple[int, NDArray[np.bool_]] = (0, np.zeros(len(pairs), bool))
        for _ in range(300):
            pick = rng.choice(len(pairs), 3, replace=False)
            try:
                r, t, sc = umeyama(cb[pick], ca[pick], with_scale=True)
            except InputError:
                continue
            ok = self._sim3_inliers(cam, r, t, sc, ca, cb, cand, kf, ia, ib, sig_a, sig_b)
            n = int(np.count_nonzero(ok))
            if n > best[0]:
                best = (n, ok)
        if best[0] < 20:
            record["reason"] = f"Sim(3) RANSAC found {best[0]} inliers (need 20)"
            return None
        r, t, sc = umeyama(cb[best[1]], ca[best[1]], with_scale=True)
        # cand_from_kf as a similarity; kf's camera in cand's world, for projection.
        cand_from_kf = np.eye(4)
        cand_from_kf[:3, :3] = r
        cand_from_kf[:3, 3] = t
        rigid = np.eye(4)
        rigid[:3, :3] = r.T
        rigid[:3, 3] = -r.T @ t
        pose = rigid @ cand.cam_from_world
        found = self._guided_loop_check(kf, cand, pose, record, scaled=False)
        return None if found is None else (found, float(sc))

    def _sim3_inliers(
        self,
        cam: PinholeCamera,
        r: F64,
        t: F64,
        sc: float,
        ca: F64,
        cb: F64,
        cand: Keyframe,
        kf: Keyframe,
        ia: I64,
        ib: I64,
        sig_a: F64,
        sig_b: F64,
    ) -> NDArray[np.bool_]:
        """Correspondences whose points reproject within the χ² gate both ways."""
        in_a = sc * cb @ r.T + t
        in_b = (ca - t) @ r / sc
        ok = (in_a[:, 2] > 0) & (in_b[:, 2] > 0)
        err = np.full(len(ca), np.inf)
        za, zb = np.where(ok, in_a[:, 2], 1.0), np.where(ok, in_b[:, 2], 1.0)
        ua = np.stack([cam.fx * in_a[:, 0] / za + cam.cx, cam.fy * in_a[:, 1] / za + cam.cy], 1)
        ub = np.stack([cam.fx * in_b[:, 0] / zb + cam.cx, cam.fy * in_b[:, 1] / zb + cam.cy], 1)
        ea = np.sum((ua - cand.keypoints[ia]) ** 2, axis=1) / sig_a**2
        eb = np.sum((ub - kf.keypoints[ib]) ** 2, axis=1) / sig_b**2
        err = np.where(ok, np.maximum(ea, eb), np.inf)
        return np.asarray(err < 9.21, dtype=bool)

    def _close_loop_sim3(self, kf: Keyframe, cand: Keyframe, corrected: F64, scale: float) -> None:
        """ORB-SLAM's monocular CorrectLoop: kf and its neighbours move to the loop's
        similarity, their points with them; the essential graph is optimised on Sim(3)
        (GTSAM), every keyframe's points follow its scale, then a global bundle adjustment."""
        from slamcli.graphs.pose_graph import Edge, optimize_sim3

        self._settle_ba()
        map_id = cand.map_id
        kfs = self.map.live(map_id)
        index = {k.id: i for i, k in enumerate(kfs)}
        connected = [kf] + [self.map.keyframes[k] for k, _ in self.map.covisible(kf)]
        connected = [k for k in connected if k.map_id == map_id and k.id in index]
        old = {k.id: inverse(k.cam_from_world) for k in kfs}  # world_from_cam, rigid
        # Similarities world_from_node: kf's corrected one has the loop's scale (its map units
        # are 1/scale of the candidate's).
        sim = {k.id: old[k.id].copy() for k in kfs}
        sc = {k.id: 1.0 for k in kfs}
        kf_new = inverse(corrected)
        for k in connected:
            rel = kf.cam_from_world @ old[k.id]  # kf_from_k, rigid, kf's units
            m = kf_new.copy()
            m[:3, :3] *= scale
            m = m @ rel
            s_k = float(np.cbrt(np.linalg.det(m[:3, :3])))
            pose = np.eye(4)
            pose[:3, :3] = m[:3, :3] / s_k
            pose[:3, 3] = m[:3, 3]
            sim[k.id], sc[k.id] = pose, s_k
        group = {cand.id} | {k for k, _ in self.map.covisible(cand)[:10]}
        extra = [(kf.id, cand.id, "loop")] + [
            (k.id, g, "loop")
            for k in connected
            for g in sorted(group)
            if g in index
            and any(g in self.map.obs[p] for p in k.point_ids[k.point_ids >= 0][:50].tolist())
        ]
        edges: list[Edge] = []
        for a, b, kind in self._graph_links(kfs, extra):
            # Loops are measured by the corrected similarities, the rest by the old poses.
            if kind == "loop":
                wa, wb = _sim_matrix(sim[a], sc[a]), _sim_matrix(sim[b], sc[b])
            else:
                wa, wb = old[a], old[b]
            rel = np.linalg.inv(wa) @ wb
            s_ab = float(np.cbrt(np.linalg.det(rel[:3, :3])))
            r = np.eye(4)
            r[:3, :3] = rel[:3, :3] / s_ab
            r[:3, 3] = rel[:3, 3]
            edges.append(Edge(index[a], index[b], r, scale=s_ab, kind=kind))
        kf.loop_edges.add(cand.id)
        cand.loop_edges.add(kf.id)
        poses = np.stack([sim[k.id] for k in kfs])
        scales = np.array([sc[k.id] for k in kfs])
        result = optimize_sim3(poses, scales, edges, fixed=(index[cand.id],))
        assert result.scales is not None
        # Points follow their reference keyframe: into its old frame, out through the new
        # similarity.
        ids = np.flatnonzero(
            self.map.alive[: self.map.n] & (self.map.map_id[: self.map.n] == map_id)
        )
        for pid in ids.tolist():
            ref = int(self.map.ref_kf[pid])
            if ref not in index:
                ref = next((k for k in self.map.obs[pid] if k in index), -1)
                if ref < 0:
                    continue
                self.map.ref_kf[pid] = ref
            i = index[ref]
            local = self.map.keyframes[ref].cam_from_world
            p = local[:3, :3] @ self.map.pos[pid] + local[:3, 3]
            w = result.poses[i]
            self.map.pos[pid] = result.scales[i] * (w[:3, :3] @ p) + w[:3, 3]
        for k in kfs:
            k.cam_from_world = inverse(result.poses[index[k.id]])
        # Frames hang from their keyframe in its units: those change by its scale.
        for rec in self._records:
            if rec.kf in index:
                rec.cam_from_kf[:3, 3] *= result.scales[index[rec.kf]]
        # Duplicated points of the loop are fused into the corrected keyframes.
        loop_ids = np.unique(
            np.concatenate([self.map.keyframes[g].point_ids for g in sorted(group)])
        )
        loop_ids = loop_ids[(loop_ids >= 0)]
        loop_ids = loop_ids[self.map.alive[loop_ids]]
        for k in connected:
            self._fuse_into(k, loop_ids, radius=4.0)
        self._counts["essential_graph_optimisations"] += 1
        if self.config.global_ba:
            self._global_ba(map_id)
        self._ref_kf = kf

    def _loop_pose(self, kf: Keyframe, cand: Keyframe, record: dict[str, Any]) -> F64 | None:
        """``cam_from_world`` of ``kf`` in ``cand``'s map: PnP on the candidate's points, then
        a guided search of the candidate's neighbourhood; None when it does not hold."""
        cam = self._camera_checked()
        has = np.flatnonzero(cand.point_ids >= 0)
        pairs = match_ratio(cand.descriptors[has], kf.descriptors, 0.75, TH_HIGH)
        if len(pairs) < 20:
            record["reason"] = f"{len(pairs)} appearance matches (need 20)"
            return None
        pids = cand.point_ids[has[pairs[:, 0]]]
        est = absolute_pose(
            cam,
            kf.keypoints[pairs[:, 1]],
            self.map.pos[pids],
            threshold_px=self.config.pnp_threshold_px,
            min_inliers=20,
            seed=self.config.seed,
        )
        if est is None:
            record["reason"] = "PnP found fewer than 20 inliers"
            return None
        return self._guided_loop_check(kf, cand, est.cam_from_world, record, scaled=True)

    def _guided_loop_check(
        self, kf: Keyframe, cand: Keyframe, pose: F64, record: dict[str, Any], *, scaled: bool
    ) -> F64 | None:
        """Search the points of ``cand`` and its neighbours in ``kf`` from ``pose`` (kf's
        ``cam_from_world`` in cand's map) and refine it; the refined pose when at least
        ``loop_min_inliers`` points agree, else None (the reason in ``record``). Without
        ``scaled`` (a monocular map of another scale) the points' distance ranges are not used."""
        cam = self._camera_checked()
        group = [cand] + [self.map.keyframes[k] for k, _ in self.map.covisible(cand)[:10]]
        ids = np.unique(np.concatenate([g.point_ids[g.point_ids >= 0] for g in group]))
        ids = ids[self.map.alive[ids] & (self.map.map_id[ids] == cand.map_id)]
        if scaled:
            visible, dist = self._in_view(pose, ids)
            ids, dist = ids[visible], dist[visible]
        else:
            z = self.map.pos[ids] @ pose[2, :3] + pose[2, 3]
            ids = ids[z > 0]
            dist = np.linalg.norm(self.map.pos[ids] - inverse(pose)[:3, 3], axis=1)
        octv = self.map.predict_octave(ids, dist)
        fake = _frame_of(kf)
        pairs = self._project_match(
            fake, pose, self.map.pos[ids], self.map.desc[ids], octv, 7.5, ratio=0.9
        )
        record["inliers"] = len(pairs)
        if len(pairs) < self.config.loop_min_inliers:
            record["reason"] = f"{len(pairs)} points matched by the guided search"
            return None
        ref = refine_pose(
            cam,
            pose,
            kf.keypoints[pairs[:, 1]],
            self.map.pos[ids[pairs[:, 0]]],
            sigma_px=self.map.sigma[kf.octaves[pairs[:, 1]]],
        )
        record["inliers"] = 0 if ref is None else ref.num_inliers
        if ref is None or ref.num_inliers < self.config.loop_min_inliers:
            record["reason"] = (
                f"{record['inliers']} inliers after refinement "
                f"(need {self.config.loop_min_inliers})"
            )
            return None
        return ref.cam_from_world

    def _merge_maps(self, kf: Keyframe, cand: Keyframe, corrected: F64, scale: float) -> None:
        """Bring the newer of the two keyframes' maps into the older one's frame (by the
        loop's rigid transform, or similarity for monocular maps) and relabel it."""
        self._settle_ba()
        old_id, new_id = cand.map_id, kf.map_id
        keep, gone = min(old_id, new_id), max(old_id, new_id)
        # A point of kf's map, in kf's camera, times scale, is where the candidate's map
        # sees it from the corrected pose.
        scaled = np.diag([scale, scale, scale, 1.0]) @ kf.cam_from_world
        w: F64 = inverse(corrected) @ scaled
        if keep == new_id:  # the candidate's map is the newer one: move it instead
            w = np.asarray(np.linalg.inv(w), dtype=np.float64)
        s = float(np.cbrt(np.linalg.det(w[:3, :3])))
        moved_kfs = {k.id for k in self.map.keyframes if k.map_id == gone}
        for k in self.map.keyframes:
            if k.map_id == gone:
                moved = w @ inverse(k.cam_from_world)
                moved[:3, :3] /= s
                k.cam_from_world = inverse(moved)
                k.map_id = keep
        ids = np.flatnonzero(self.map.map_id[: self.map.n] == gone)
        self.map.pos[ids] = self.map.pos[ids] @ w[:3, :3].T + w[:3, 3]
        self.map.map_id[ids] = keep
        if s != 1.0:
            # Frames hang from their keyframe in its units, which the similarity rescales.
            for rec in self._records:
                if rec.kf in moved_kfs:
                    rec.cam_from_kf[:3, 3] *= s
        for m in self._maps:
            if m["id"] == gone:
                m["merged_into"] = keep
        if self._map_id == gone:
            self._map_id = keep
        self._merges.append(
            {"maps": [keep, gone], "keyframes": [cand.id, kf.id], "scale": round(s, 5)}
        )

    def _close_loop(self, kf: Keyframe, cand: Keyframe, corrected: F64) -> None:
        """ORB-SLAM's CorrectLoop on SE(3): move kf and its neighbours to the loop's pose,
        fuse the duplicated points, optimise the essential graph and adjust globally."""
        from slamcli.graphs.pose_graph import Edge, optimize_se3

        self._settle_ba()
        map_id = cand.map_id
        connected = [kf] + [self.map.keyframes[k] for k, _ in self.map.covisible(kf)]
        connected = [k for k in connected if k.map_id == map_id]
        before = {k.id: k.cam_from_world.copy() for k in self.map.live(map_id)}
        delta = inverse(kf.cam_from_world) @ corrected  # applied on the world side
        moved: set[int] = set()
        for k in connected:
            new = k.cam_from_world @ delta
            pids = k.point_ids[k.point_ids >= 0]
            pids = np.array([p for p in pids.tolist() if p not in moved], np.int64)
            if pids.size:
                t = inverse(new) @ k.cam_from_world
                self.map.pos[pids] = self.map.pos[pids] @ t[:3, :3].T + t[:3, 3]
                moved.update(pids.tolist())
            k.cam_from_world = new
        # Fuse the loop's points into the corrected keyframes.
        group = [cand] + [self.map.keyframes[k] for k, _ in self.map.covisible(cand)[:10]]
        loop_ids = np.unique(np.concatenate([g.point_ids[g.point_ids >= 0] for g in group]))
        loop_ids = loop_ids[self.map.alive[loop_ids]]
        for k in connected:
            self._fuse_into(k, loop_ids, radius=4.0)
        kf.loop_edges.add(cand.id)
        cand.loop_edges.add(kf.id)
        # Essential graph: spanning tree, strong covisibility, loops.
        kfs = self.map.live(map_id)
        index = {k.id: i for i, k in enumerate(kfs)}
        init = {k.id: k.cam_from_world.copy() for k in kfs}
        old_or_new = {k: before.get(k, init[k]) for k in init}
        group_ids = {g.id for g in group}
        extra = [
            (k.id, nb, "loop")
            for k in connected
            for nb, _w in self.map.covisible(k)
            if nb in group_ids
        ]
        edges: list[Edge] = []
        for a, b, kind in self._graph_links(kfs, extra):
            # Loops are measured by the corrected poses, the rest by the poses before it.
            poses = init if kind == "loop" else old_or_new
            edges.append(Edge(index[a], index[b], poses[a] @ inverse(poses[b]), kind=kind))
        first = kfs[0].id
        world_from = np.stack([inverse(init[k.id]) for k in kfs])
        result = optimize_se3(world_from, edges, fixed=(index[first],))
        for k in kfs:
            k.cam_from_world = inverse(result.poses[index[k.id]])
        # Points follow the keyframe they were made in (or any that sees them).
        ids = np.flatnonzero(
            self.map.alive[: self.map.n] & (self.map.map_id[: self.map.n] == map_id)
        )
        for pid in ids.tolist():
            ref = int(self.map.ref_kf[pid])
            if ref not in index:
                views = self.map.obs[pid]
                ref = next((k for k in views if k in index), -1)
                if ref < 0:
                    continue
                self.map.ref_kf[pid] = ref
            t = inverse(self.map.keyframes[ref].cam_from_world) @ init[ref]
            self.map.pos[pid] = t[:3, :3] @ self.map.pos[pid] + t[:3, 3]
        self._counts["essential_graph_optimisations"] += 1
        if self.config.global_ba:
            self._global_ba(map_id)
        # Tracking continues from the corrected keyframe.
        self._ref_kf = kf

    def _global_ba(self, main: int | None) -> None:
        self._settle_ba()
        if main is None:
            return
        kfs = self.map.live(main)
        if len(kfs) < 2:
            return
        pids = np.unique(np.concatenate([k.point_ids[k.point_ids >= 0] for k in kfs]))
        pids = pids[self.map.alive[pids]]
        fixed = np.zeros(len(kfs), bool)
        fixed[0] = True
        self._bundle(kfs, fixed, pids, 20)
        self._counts["global_ba"] += 1

    # -- results -----------------------------------------------------------------------------

    def _trajectory(self, main: int | None) -> Trajectory:
        """Every frame of the main map, placed by its keyframe and, with
        ``final_pose_refinement``, re-estimated against the final map: with threads=2 the
        second half of the frames on the side process (each frame on its own, so the split
        changes nothing)."""
        stamps: list[int] = []
        poses: list[F64] = []
        jobs: list[tuple[F64, F64, F64, F64, F64]] = []
        refined: list[int] = []
        for rec in self._records:
            kf = self.map.keyframes[rec.kf]
            if kf.map_id != main:
                self._counts["frames_in_unmerged_maps"] += 1
                continue
            pose = rec.cam_from_kf @ self.map.world_pose(kf.id)
            if self.config.final_pose_refinement and len(rec.pids):
                alive = self.map.alive[rec.pids] & (self.map.map_id[rec.pids] == main)
                if np.count_nonzero(alive) >= 10:
                    refined.append(len(poses))
                    jobs.append(
                        (
                            pose,
                            rec.kp[alive].astype(np.float64),
                            self.map.pos[rec.pids[alive]],
                            rec.sigma[alive].astype(np.float64),
                            rec.depth[alive].astype(np.float64),
                        )
                    )
            stamps.append(rec.stamp_ns)
            poses.append(pose)
        if jobs:
            settings = (self._camera_checked(), self.mono, self.config.depth_baseline_m)
            half = len(jobs) // 2
            later = self._side.submit(refine_poses, *settings, jobs[half:])
            better = refine_poses(*settings, jobs[:half]) + later.result()
            for i, new in zip(refined, better, strict=True):
                if new is not None:
                    poses[i] = new
        return Trajectory(
            np.array(stamps, np.int64), np.stack([inverse(p) for p in poses]).reshape(-1, 4, 4)
        )

    def _result(self, main: int | None, trajectory: Trajectory) -> SlamResult:
        kfs = self.map.live(main)
        keyframes = Trajectory(
            np.array([k.stamp_ns for k in kfs], np.int64),
            np.stack([inverse(k.cam_from_world) for k in kfs]).reshape(-1, 4, 4),
        )
        alive = np.flatnonzero(
            self.map.alive[: self.map.n] & (self.map.map_id[: self.map.n] == main)
        )
        counts = dict(self._counts)
        for state in ("tracked", "relocalised", "lost", "initialising", "new_map"):
            counts.setdefault(f"frames_{state}", 0)
        counts["keyframes"] = len(kfs)
        counts["map_points"] = int(alive.size)
        counts["maps"] = len(self._maps)
        counts["map_merges"] = len(self._merges)
        counts["loop_closures_accepted"] = sum(1 for r in self._loops if r["accepted"])
        counts["loop_closures_rejected"] = sum(1 for r in self._loops if not r["accepted"])
        stages = {k: v / self._frames for k, v in sorted(self._ms.items())}
        return SlamResult(
            trajectory=trajectory,
            keyframes=keyframes,
            pose_graph=(keyframes.world_from_body, self._essential_graph(kfs)),
            points=self.map.pos[alive].copy(),
            point_colors=self.map.color[alive].copy(),
            metrics={
                "mode": "mono" if self.mono else "rgbd",
                "initialisation": self._init_info,
                "ms_per_frame": stages,
                "maps": self._maps,
                "merges": self._merges,
                "loop_closures": self._loops,
            },
            counts=counts,
        )

    def _essential_graph(self, kfs: list[Keyframe]) -> list[Any]:
        """The final essential graph of keyframes ``kfs`` (edges between their indices):
        spanning tree, strong covisibility (100 shared points) and loop edges, measured by
        the final poses."""
        from slamcli.graphs.pose_graph import Edge

        index = {k.id: i for i, k in enumerate(kfs)}
        edges: list[Edge] = []
        for a, b, kind in self._graph_links(kfs):
            rel = self.map.keyframes[a].cam_from_world @ inverse(
                self.map.keyframes[b].cam_from_world
            )
            edges.append(Edge(index[a], index[b], rel, kind=kind))
        return edges

    def _graph_links(
        self, kfs: list[Keyframe], extra: list[tuple[int, int, str]] | None = None
    ) -> list[tuple[int, int, str]]:
        """The essential graph's edges among ``kfs``, as (lower id, higher id, kind): the
        spanning tree, strong covisibility (100 shared points), loops, then ``extra``; each
        pair once, in a fixed order."""
        ids = {k.id for k in kfs}
        links: list[tuple[int, int, str]] = []
        seen: set[tuple[int, int]] = set()

        def add(a: int, b: int, kind: str) -> None:
            key = (min(a, b), max(a, b))
            if a in ids and b in ids and a != b and key not in seen:
                seen.add(key)
                links.append((*key, kind))

        for k in kfs:
            if k.parent is not None:
                add(k.parent, k.id, "tree")
            for nb, _w in self.map.covisible(k, min_weight=100):
                add(k.id, nb, "covisibility")
            for other in sorted(k.loop_edges):
                add(k.id, other, "loop")
        for a, b, kind in extra or []:
            add(a, b, kind)
        return links

    # -- helpers -----------------------------------------------------------------------------

    def _camera_checked(self) -> PinholeCamera:
        assert self._camera is not None
        return self._camera

    def _timed(self, stage: str) -> StageTimer:
        return StageTimer(self._ms, stage)

    def _initialise_mono(self, cur: _Frame) -> str:
        """Two-view initialisation: the first frame with enough features is the reference; a
        later one with enough matches and parallax makes the first two keyframes."""
        ref = self._init_ref
        if len(cur.features) < 100:
            return "initialising"
        if ref is None:
            self._init_ref = cur
            return "initialising"
        pairs = match_ratio(ref.features.descriptors, cur.features.descriptors, 0.9, TH_HIGH)
        if len(pairs):
            moved = np.linalg.norm(ref.keypoints[pairs[:, 0]] - cur.keypoints[pairs[:, 1]], axis=1)
            # ORB-SLAM searches a 100-pixel window around the reference keypoint.
            pairs = pairs[moved <= 100.0 * self._window_scale()]
        if len(pairs) < 100:
            self._counts["init_too_few_matches"] += 1
            self._init_ref = cur
            return "initialising"
        found = two_view_geometry(
            self._camera_checked(),
            ref.keypoints[pairs[:, 0]],
            cur.keypoints[pairs[:, 1]],
            self.map.sigma[ref.features.octaves[pairs[:, 0]]],
            min_parallax_deg=self.config.mono_min_parallax_deg,
            min_points=self.config.mono_min_points,
            seed=self.config.seed,
        )
        if found.points is None:
            self._counts[f"init_rejected_{found.reason}"] += 1
            return "initialising"
        good = found.good
        # Scale: median depth 1 in the reference.
        median = float(np.median(found.points[good, 2]))
        cur_from_ref = found.cur_from_ref.copy()
        cur_from_ref[:3, 3] /= median
        world = found.points[good] / median
        ref.cam_from_world = np.eye(4)
        cur.cam_from_world = cur_from_ref
        kf0 = self._new_keyframe(ref)
        kf1 = self._new_keyframe(cur)
        kf1.parent = kf0.id
        pids = self.map.add_points(kf0, pairs[good, 0], world)
        for kp, pid in zip(pairs[good, 1].tolist(), pids.tolist(), strict=True):
            self.map.observe(kf1, kp, pid)
        self.map.update_geometry(pids)
        self._bundle([kf0, kf1], np.array([True, False]), pids, 20)
        # Re-normalise after the adjustment.
        live = kf0.point_ids[kf0.point_ids >= 0]
        depths = self.map.pos[live, 2]
        if live.size < self.config.mono_min_points or not np.all(np.isfinite(depths)):
            self._counts["init_rejected_after_ba"] += 1
            self._discard_map(kf0.map_id)
            return "initialising"
        scale = 1.0 / float(np.median(depths))
        self.map.pos[live] *= scale
        kf1.cam_from_world[:3, 3] *= scale
        self._maps.append({"id": self._map_id, "first_frame": ref.index, "merged_into": None})
        self._counts["init_" + found.model] += 1
        self._init_info = {
            "model": found.model,
            "frames": [ref.index, cur.index],
            "points": int(live.size),
            "median_parallax_deg": round(found.parallax_deg, 3),
        }
        for k in (kf0, kf1):
            self._index_place(k)
        self._ref_kf = kf0
        ref.point_ids = kf0.point_ids.copy()
        self._record(ref, "tracked")
        self._ref_kf = kf1
        cur.point_ids = kf1.point_ids.copy()
        cur.cam_from_world = kf1.cam_from_world.copy()
        cur.inliers = int(np.count_nonzero(cur.point_ids >= 0))
        self._record(cur, "tracked")
        self._velocity = None
        self._set_last(cur)
        self._counts["keyframes_made"] += 2
        self._counts["frames_tracked"] += 1  # the reference, counted as initialising before
        self._counts["frames_initialising"] -= 1
        self._init_ref = None
        return "tracked"

    def _window_scale(self) -> float:
        cam = self._camera_checked()
        return max(1.0, cam.width / 640.0)

    def _discard_map(self, map_id: int) -> None:
        for k in self.map.keyframes:
            if k.map_id == map_id and not k.culled:
                for kp in np.flatnonzero(k.point_ids >= 0).tolist():
                    self.map.forget(k, kp)
                k.culled = True
                self.map.version += 1
                k.parent = None

    def _triangulate(self, kf: Keyframe) -> None:
        """New monocular points: unmatched keypoints of ``kf`` matched to those of its best
        covisible keyframes, checked against the epipolar line, triangulated, and kept when
        the rays have parallax, the point is in front of both cameras and reprojects well."""
        cam = self._camera_checked()
        neighbours = [self.map.keyframes[k] for k, _ in self.map.covisible(kf)[:20]]
        c1 = kf.center
        made = 0
        for nb in neighbours:
            free_kf = np.flatnonzero(kf.point_ids < 0)
            free_nb = np.flatnonzero(nb.point_ids < 0)
            if free_kf.size == 0 or free_nb.size == 0:
                break
            nb_depths = self._median_depth(nb)
            if not np.isfinite(nb_depths) or np.linalg.norm(nb.center - c1) / nb_depths < 0.01:
                continue
            pairs = match_ratio(
                nb.descriptors[free_nb], kf.descriptors[free_kf], 0.6 if self.mono else 0.8, TH_LOW
            )
            if len(pairs) == 0:
                continue
            i_nb, i_kf = free_nb[pairs[:, 0]], free_kf[pairs[:, 1]]
            world, ok = triangulate_checked(
                cam,
                kf.cam_from_world,
                nb.cam_from_world,
                kf.keypoints[i_kf],
                nb.keypoints[i_nb],
                self.map.sigma[kf.octaves[i_kf]],
                self.map.sigma[nb.octaves[i_nb]],
            )
            if not np.any(ok):
                continue
            i_kf, i_nb, world = i_kf[ok], i_nb[ok], world[ok]
            pids = self.map.add_points(kf, i_kf, world)
            for kp, pid in zip(i_nb.tolist(), pids.tolist(), strict=True):
                self.map.observe(nb, kp, pid)
            self.map.update_geometry(pids)
            made += int(pids.size)
        self._counts["points_triangulated"] += made

    def _median_depth(self, kf: Keyframe) -> float:
        pids = kf.point_ids[kf.point_ids >= 0]
        if pids.size == 0:
            return float("nan")
        z = self.map.pos[pids] @ kf.cam_from_world[2, :3] + kf.cam_from_world[2, 3]
        return float(np.median(z))


def _sim_matrix(pose: F64, scale: float) -> F64:
    """The 4x4 similarity [[scale R, t], [0, 1]] of a rigid pose and a scale."""
    m = pose.copy()
    m[:3, :3] = pose[:3, :3] * scale
    return m


def _frame_of(kf: Keyframe) -> _Frame:
    """A keyframe as a frame to search points in (its keypoints are already undistorted)."""
    features = Features(
        kf.keypoints.astype(np.float32),
        kf.octaves,
        kf.descriptors,
        np.zeros(len(kf.keypoints), np.float32),
    )
    return _Frame(kf.frame, kf.stamp_ns, "", features, kf.keypoints, kf.depth, kf.colors)
