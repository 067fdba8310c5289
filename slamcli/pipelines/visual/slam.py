"""Feature-based visual SLAM (ORB-SLAM-like), RGB-D, stereo or monocular, offline and
deterministic.

Per frame (:meth:`VisualSlam.process`), in the order of ORB-SLAM's threads of work:

- **Features** (:mod:`.frames`): ORB spread over the image and 8 pyramid levels; keypoints,
  not images, are undistorted. A stereo pair's left keypoints are matched along the rows of
  the right image, which gives near keypoints their depth. With ``threads = 2`` the next
  frame's features are extracted on the second core while the current one is tracked (the
  extraction is a pure function of the image, so the order of results never changes).
- **Tracking** (:mod:`.tracking`): motion model, reference keyframe or relocalisation, then the
  local map; a monocular map is first initialised from two views (:mod:`.initializer`), an
  RGB-D or stereo map from the first frame's depth, at metric scale.
- **Local mapping** (:mod:`.local_mapping`, :mod:`.bundle`) on each keyframe: new points,
  fusion, culling, local bundle adjustment.
- **Loop closing** (:mod:`.loop_closing`, :mod:`.places`): place recognition, verified loops
  close through the essential graph and a global bundle adjustment; a place recognised in
  another map merges the two maps (:mod:`.atlas`).
- **Lost tracking** never aborts the run: a lost frame is relocalised; when that fails for
  ``new_map_after_lost`` frames a new map is started, and merged when a place is recognised.

:meth:`VisualSlam.finish` runs a last global bundle adjustment and re-estimates every frame's
pose against the final map (an offline tool can afford it), then returns the trajectory of
every frame in the main map (the one holding the most frames, with all maps merged into it;
poses of the body the source's ground truth refers to, which for a stereo rig may differ from
the left camera, as EuRoC's IMU body does), the keyframes, the coloured points, the pose
graph, and counts of frames by tracking state, maps, merges and loop closures with their
scores and reasons.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, PipelineError
from slamcli.formats.base import Prefetch, SourceInfo
from slamcli.geometry import inverse
from slamcli.inertial.observability import ScaleInformation
from slamcli.kernels import load_numba
from slamcli.pipelines import Evaluation, PipelineBase
from slamcli.pipelines.timing import Stats
from slamcli.pipelines.visual.atlas import Atlas, Keyframe
from slamcli.pipelines.visual.bundle import BundleAdjuster
from slamcli.pipelines.visual.config import VisualConfig
from slamcli.pipelines.visual.frames import AnyFrame, Extracted, Frame, Rig, refine_poses
from slamcli.pipelines.visual.inertial import SCALE_DOUBT_STD, Inertial
from slamcli.pipelines.visual.initializer import MonoInitializer
from slamcli.pipelines.visual.local_mapping import LocalMapping
from slamcli.pipelines.visual.loop_closing import LoopClosing, essential_graph
from slamcli.pipelines.visual.parts import Shared
from slamcli.pipelines.visual.places import Places
from slamcli.pipelines.visual.tracking import Tracking
from slamcli.types import ImuFrame, SlamResult, Trajectory
from slamcli.worker import Background, SideProcess

F64 = NDArray[np.float64]

log = logging.getLogger(__name__)

_STATES = ("tracked", "relocalised", "inertial", "lost", "initialising", "new_map")


class VisualSlam(PipelineBase):
    """Pipeline ``visual``: consumes ``rgbd``, ``stereo`` or ``image`` (monocular) frames;
    produces poses, keyframes, coloured points and a pose graph."""

    name = "visual"
    consumes: tuple[str, ...] = ("rgbd",)
    config_class = VisualConfig

    def __init__(self, config: VisualConfig | None = None) -> None:
        self.config = cfg = config or VisualConfig()
        # With two threads, frames are decoded ahead on a reader thread (see run_pipeline).
        self.read_ahead = 2 if cfg.threads == 2 else 0
        self.rig = Rig(cfg)
        self.atlas = Atlas(cfg.scale_factor, cfg.levels)
        self.stats = Stats()
        # Local bundle adjustments run on this second process with threads=2, taken at points
        # fixed by the frame sequence. It is started once the adjustments run here have taken
        # ``side_process_after_s``, about what starting it costs (half a second of processor
        # time on a 2-core AMD EPYC: a short run never pays for it); it then imports its
        # modules and loads its kernels while the following frames are tracked, and an
        # adjustment due before it is ready runs here. Where an adjustment runs never changes
        # its result.
        self._side = SideProcess(
            parallel=cfg.threads == 2,
            preload=("slamcli.kernels:load_adjustment",),
            in_place_while_starting=True,
            start_after_s=cfg.side_process_after_s,
        )
        self.places = Places(cfg.vocabulary, self.atlas.map)
        shared = Shared(cfg, self.rig, self.atlas, self.places, self.stats)
        self.ba = BundleAdjuster(cfg, self.rig, self.atlas.map, self.stats, self._side)
        self.inertial = Inertial(shared)
        self.ba.inertial = self.inertial
        self.mapper = LocalMapping(shared, self.ba, self.inertial)
        self.initializer = MonoInitializer(shared, self.mapper)
        self.tracker = Tracking(shared)
        self.tracker.inertial = self.inertial
        self.initializer.inertial = self.inertial
        # Images wait here, in a visual-inertial run, until the IMU has a sample at or after
        # their stamp (so that the same samples are known whatever the threads).
        self._waiting: list[AnyFrame] = []
        self.imu_unused = ""
        """Why an input's IMU was not used, when it was not (``metrics.imu_unused``)."""
        self.loops = LoopClosing(shared, self.mapper, self.ba)
        self.loops.inertial = self.inertial
        # Two frames ahead: a keyframe's mapping takes several frames' tracking time, and the
        # features go on being extracted meanwhile.
        self._features = Prefetch(self.rig.extract, ahead=cfg.threads == 2, name="orb", depth=2)
        # numba's target, which every frame's matching needs, is built on another thread while
        # the source is opened and the first images decoded (which let go of the interpreter
        # lock): a short run's first frame then waits less for it.
        self._numba = Background(load_numba) if cfg.threads == 2 else None
        self._frames = 0
        self._textureless = 0

    # -- the pipeline -------------------------------------------------------------------------

    @property
    def evaluation(self) -> Evaluation:
        """``sim3`` for a monocular run (a map without metric scale), else ``se3``."""
        return self.rig.evaluation

    def seeds(self) -> dict[str, int]:
        """Seeds of the random choices: COLMAP's RANSAC (PnP) and OpenCV's (two-view geometry)
        both get ``config.seed``."""
        return {"ransac": self.config.seed, "opencv": self.config.seed}

    def frame_kinds(self, info: SourceInfo) -> tuple[str, ...]:
        """The frames to read from a source described by ``info``: stereo pairs from a stereo
        source, RGB-D when it has depth, colour images otherwise (or as the mode says).

        Raises:
            ConfigError: a mode the input cannot give (``rgbd`` without depth, ``stereo``
                without a stereo pair).
        """
        # A depth stream (TUM) or a depth topic paired with the colour one (MCAP).
        has_depth = any(s.kind == "depth" and s.count > 0 for s in info.streams) or bool(
            info.details.get("depth_topic") and info.frames > 0
        )
        has_pairs = any(s.kind == "stereo" and s.count > 0 for s in info.streams)
        mode = self.config.mode
        if mode == "auto":
            mode = "stereo" if has_pairs else "rgbd" if has_depth else "mono"
        if mode == "rgbd" and not has_depth:
            raise ConfigError(
                f"visual.mode=rgbd, but {info.path} has no depth stream",
                hint="use --set mode=mono (or mode=auto) for colour-only input",
            )
        if mode == "stereo" and not has_pairs:
            raise ConfigError(
                f"visual.mode=stereo, but {info.path} has no stereo pairs",
                hint="give a KITTI or EuRoC folder, or a log with left and right image topics",
            )
        self.rig.mono = mode == "mono"
        self.rig.stereo = mode == "stereo"
        kinds = {"mono": ("image",), "stereo": ("stereo",), "rgbd": ("rgbd",)}[mode]
        has_imu = any(s.kind == "imu" and s.count > 0 for s in info.streams)
        if not (self.config.imu and has_imu and mode != "rgbd"):
            return kinds
        from slamcli.inertial.preintegration import ImuNoise

        settings = info.details.get("imu")
        if not ImuNoise.has_settings(settings):
            # An accelerometer alone (TUM's), or an IMU whose noise is not given.
            if all(s.name == "accelerometer" for s in info.streams if s.kind == "imu"):
                return kinds
            self.imu_unused = (
                "the IMU's noise settings are unknown: the run is visual only (give the IMU's "
                "Kalibr imu.yaml with --calib)"
            )
            log.warning("%s: %s", info.path, self.imu_unused)
            return kinds
        assert isinstance(settings, dict)
        self.inertial.check(info.details.get("imu_check"), _frame_interval(info))
        self.inertial.noise = ImuNoise.from_details(settings)
        self.rig.inertial = True
        kinds = (*kinds, "imu")
        return kinds

    def process(self, frame: AnyFrame | ImuFrame) -> None:
        """Queue a frame; with two threads its features are extracted while the previous
        frame is tracked. An IMU sample is kept, and releases the images it covers."""
        if isinstance(frame, ImuFrame):
            self.inertial.add(frame)
            last = self.inertial.last_stamp_ns
            assert last is not None
            while self._waiting and self._waiting[0].stamp_ns <= last:
                self._push(self._waiting.pop(0))
            return
        if self.inertial.enabled:
            self.inertial.note_image(frame.stamp_ns)
            last = self.inertial.last_stamp_ns
            if last is None or frame.stamp_ns > last or self._waiting:
                self._waiting.append(frame)
                return
        self._push(frame)

    def _push(self, frame: AnyFrame) -> None:
        for ready, features in self._features.push(frame):
            self._track_frame(ready, features.result())

    def finish(self) -> SlamResult:
        """Track what is queued, adjust the final map, and return the result."""
        for frame in self._waiting:
            self._push(frame)
        self._waiting = []
        for ready, features in self._features.drain():
            self._track_frame(ready, features.result())
        self._features.close()
        self.ba.settle()
        try:
            if self._frames == 0:
                raise PipelineError("the visual pipeline received no frames")
            start = time.perf_counter()
            main = self.atlas.main_map()
            if main is None:
                self._no_map_error()
            if self.config.global_ba:
                with self.stats.timed("global_ba"):
                    self.ba.global_ba(main)
            with self.stats.timed("final_poses"):
                trajectory = self._trajectory(main)
        finally:
            self._side.close()
        self.stats.ms["total"] += (time.perf_counter() - start) * 1e3
        return self._result(main, trajectory)

    # -- as another pipeline's front end ------------------------------------------------------

    def extract(self, frame: AnyFrame) -> Extracted:
        """ORB features of ``frame`` for :meth:`track` (no state is changed: it may run on
        another thread)."""
        return self.rig.extract(frame)

    def track(self, frame: AnyFrame, features: Extracted) -> tuple[F64, int] | None:
        """Track ``frame`` now, without the queue of :meth:`process`: its world_from_camera
        pose as tracked (in the frame of its map) and that map's id, or None while the map is
        initialising or the frame is lost. :meth:`finish` still gives the final trajectory."""
        before = len(self.atlas.frames)
        self._track_frame(frame, features)
        if len(self.atlas.frames) == before:
            return None
        rec = self.atlas.frames[-1]
        kf = self.atlas.map.keyframes[rec.kf]
        return inverse(rec.cam_from_kf @ kf.cam_from_world), int(kf.map_id)

    def close(self) -> None:
        """Stop the side process and the feature thread (after an error; :meth:`finish` stops
        them itself)."""
        self._features.close()
        self._side.close()

    # -- frames ------------------------------------------------------------------------------

    def _track_frame(self, frame: AnyFrame, features: Extracted) -> None:
        start = time.perf_counter()
        cur = self.rig.prepare(frame, features, self._frames)
        self._frames += 1
        if len(cur.features) < 20:
            self._textureless += 1
        state = self._track(cur)
        self.stats.counts[f"frames_{state}"] += 1
        self.stats.ms["total"] += (time.perf_counter() - start) * 1e3

    def _track(self, cur: Frame) -> str:
        """Pose ``cur``; returns its tracking state (tracked, relocalised, initialising,
        new_map, lost)."""
        if not self.tracker.has_map():
            return self._start_map(cur)
        state = self.tracker.locate(cur)
        if state is None:
            if self.tracker.lost_too_long():
                self._start_new_map()
            return "lost"
        if state == "inertial":
            return state
        self.tracker.accept(cur, state)
        if self.tracker.wants_keyframe(cur):
            with self.stats.timed("mapping"):
                self._keyframe(cur)
        self.tracker.set_last(cur)
        return state

    def _start_map(self, cur: Frame) -> str:
        """A map's first keyframes: from two views (monocular) or from ``cur``'s depth."""
        counts = self.stats.counts
        if self.rig.mono:
            made = self.initializer.initialise(cur)
            if made is None:
                return "initialising"
            ref, kf0, kf1 = made
            self.places.index(kf0)
            self.places.index(kf1)
            self.tracker.begin([(ref, kf0), (cur, kf1)])
            counts["keyframes_made"] += 2
            counts["frames_tracked"] += 1  # the reference, counted as initialising before
            counts["frames_initialising"] -= 1
            return "tracked"
        first = self.mapper.start_map(cur)
        if first is None:
            return "initialising"
        self.places.index(first)
        self.tracker.begin([(cur, first)])
        counts["keyframes_made"] += 1
        return "new_map" if len(self.atlas.maps) > 1 else "tracked"

    def _keyframe(self, cur: Frame) -> None:
        """Make a keyframe of the tracked frame ``cur``: local mapping, then loop closing."""
        assert self.tracker.reference is not None
        kf = self.mapper.insert_keyframe(cur, self.tracker.reference)
        self.places.index(kf)
        if self.inertial.enabled:
            self._inertial_steps(kf)
        if self.config.loop_closure:
            with self.stats.timed("loop"):
                self.loops.detect(kf)
        self.tracker.follow(cur, kf)
        self.stats.counts["keyframes_made"] += 1

    def _inertial_steps(self, kf: Keyframe) -> None:
        """After keyframe ``kf``: initialise its map's IMU when due (then move the map into
        the metric, gravity-aligned world and adjust it whole with its inertial terms), or
        refine it ``imu_refine_s`` later."""
        map_id = kf.map_id
        if not self.inertial.active(map_id):
            kfs = self.atlas.map.live(map_id)
            if (kfs[-1].stamp_ns - kfs[0].stamp_ns) * 1e-9 < self.config.imu_init_s:
                return
            # The adjustment running apart works in the map's old frame.
            self.ba.settle()
            with self.stats.timed("imu_init"):
                init = self.inertial.try_initialise(map_id)
                if init is None:
                    return
                self.atlas.transform_map(map_id, self.inertial.gravity_aligned(init))
                first = self.atlas.map.keyframes[self.inertial.chain(map_id)[0].id]
                placed = self.inertial.place_head(map_id, first)
                self.stats.counts["imu_placed_keyframes"] += placed
                self.tracker.velocity = None
                self.ba.global_ba(map_id)
            return
        if self.inertial.due_refinement(map_id):
            with self.stats.timed("imu_init"):
                self.ba.global_ba(map_id)
                self.inertial.refined(map_id)

    def _start_new_map(self) -> None:
        """Tracking was lost for too long: the next frames start a map of their own."""
        self.ba.settle()
        self.atlas.start_new_map()
        self.tracker.reset()
        self.initializer.reset()
        self.stats.counts["maps_started"] += 1

    def _no_map_error(self) -> None:
        """Raise the PipelineError that says why no map came out of the frames."""
        if self._textureless >= self._frames * 0.9:
            raise PipelineError(
                f"no map could be made: {self._textureless} of {self._frames} frames had fewer "
                "than 20 ORB features (images without texture?)",
                hint="check the images; visual SLAM needs textured scenes",
            )
        if self.rig.mono:
            raise PipelineError(
                f"monocular initialisation never succeeded over {self._frames} frames (it needs "
                f"{self.config.mono_min_points} points triangulated with at least "
                f"{self.config.mono_min_parallax_deg} deg of parallax: the camera must translate)",
                hint="give a sequence that moves sideways, or use RGB-D input",
            )
        if self.rig.stereo:
            raise PipelineError(
                f"no map could be made from {self._frames} stereo pairs: none had 100 keypoints "
                f"matched in the right image with a depth kept (nearer than "
                f"{self.rig.depth_max_m:.1f} m, or among the {self.config.stereo_min_near} "
                "nearest)",
                hint="check that the pairs are rectified and the baseline is right "
                "('slamcli info'), or raise visual.stereo_far_baselines or "
                "visual.stereo_min_near",
            )
        raise PipelineError(
            f"no map could be made from {self._frames} frames: none had 100 keypoints with depth "
            f"between {self.config.depth_min_m} and {self.config.depth_max_m} m",
            hint="check the depth stream and its depth scale, or widen visual.depth_max_m",
        )

    # -- results -----------------------------------------------------------------------------

    def _trajectory(self, main: int | None) -> Trajectory:
        """Every frame of the main map, placed by its keyframe and, with
        ``final_pose_refinement``, re-estimated against the final map (compiled, a tenth of a
        millisecond a frame: here, as handing them to the side process would cost more)."""
        smap = self.atlas.map
        stamps: list[int] = []
        poses: list[F64] = []
        jobs: list[tuple[F64, F64, F64, F64, F64]] = []
        refined: list[int] = []
        for rec in self.atlas.frames:
            kf = smap.keyframes[rec.kf]
            if kf.map_id != main:
                self.stats.counts["frames_in_unmerged_maps"] += 1
                continue
            pose = rec.cam_from_kf @ smap.world_pose(kf.id)
            if rec.state == "inertial" and main is not None:
                # Posed on the IMU while vision failed: bridged between the final keyframes
                # on either side of the gap.
                bridged = self.inertial.bridge(main, rec.stamp_ns)
                if bridged is not None:
                    pose = bridged
            if self.config.final_pose_refinement and len(rec.pids):
                alive = smap.alive[rec.pids] & (smap.map_id[rec.pids] == main)
                if np.count_nonzero(alive) >= 10:
                    refined.append(len(poses))
                    jobs.append(
                        (
                            pose,
                            rec.kp[alive].astype(np.float64),
                            smap.pos[rec.pids[alive]],
                            rec.sigma[alive].astype(np.float64),
                            rec.depth[alive].astype(np.float64),
                        )
                    )
            stamps.append(rec.stamp_ns)
            poses.append(pose)
        if jobs:
            better = refine_poses(*self.rig.refine_jobs(), jobs)
            for i, new in zip(refined, better, strict=True):
                if new is not None:
                    poses[i] = new
        return Trajectory(np.array(stamps, np.int64), self._bodies(poses))

    def _bodies(self, cam_from_world: list[F64]) -> F64:
        """(N, 4, 4) world_from_body of cameras at ``cam_from_world``."""
        body = self.rig.trajectory_from_camera
        if np.array_equal(body, np.eye(4)):
            # The camera is the body: no product, so the poses keep their exact bits.
            return np.stack([inverse(p) for p in cam_from_world]).reshape(-1, 4, 4)
        camera_from_body = inverse(body)
        return np.stack([inverse(p) @ camera_from_body for p in cam_from_world]).reshape(-1, 4, 4)

    def _inertial_record(
        self, main: int | None, scale_info: ScaleInformation | None
    ) -> dict[str, Any]:
        """The IMU's part of ``run.json``: whether the main map was initialised, the
        initialisations and refinements (when, scale, gravity, biases), and the last
        keyframe's bias estimate, how well the motion determined a monocular run's scale,
        and the IMU clock's offset when a refusal estimated it."""
        chain = self.inertial.chain(main) if main is not None else []
        last = self.inertial.states[chain[-1].id] if chain else None
        clock = self.inertial.clock
        return {
            "initialised": main is not None and self.inertial.active(main),
            "attempts": self.inertial.attempts,
            "last_refusal": self.inertial.last_refusal or None,
            "events": self.inertial.records,
            "final_gyro_bias": None if last is None else [round(float(x), 7) for x in last[3:6]],
            "final_accel_bias": None if last is None else [round(float(x), 6) for x in last[6:9]],
            "scale_determination": None
            if scale_info is None
            else {
                "std": round(scale_info.std, 5),
                "imu_scale": round(scale_info.scale, 5),
                "keyframes": scale_info.keyframes,
                "seconds": round(scale_info.duration_s, 3),
            },
            "clock_offset": None if clock is None else dataclasses.asdict(clock),
        }

    def _doubts(
        self,
        counts: dict[str, int],
        main: int | None = None,
        scale_info: ScaleInformation | None = None,
    ) -> list[str]:
        """Why the result may be wrong, in words: loops refused as implausible (the first
        few, then how many more), maps lost and joined again by a merge, an IMU never
        initialised, a monocular scale the motion leaves loose, frames left in maps never
        merged into the main one."""
        loops = self.loops.doubts
        doubts = loops[:3]
        if len(loops) > 3:
            doubts.append(f"{len(loops) - 3} more loops were refused as implausible")
        for r in self.loops.records:
            if r["type"] == "merge" and r["accepted"]:
                scale = f", scale {r['scale']:.3g}" if "scale" in r else ""
                doubts.append(
                    f"tracking was lost and a new map started; it was joined to the older map "
                    f"where frames {r['frames'][0]} and {r['frames'][1]} see one place"
                    f"{scale}: the poses on either side of the gap are only as good as that match"
                )
        if self.inertial.enabled and (main is None or not self.inertial.active(main)):
            why = (
                f"; the last refusal: {self.inertial.last_refusal}"
                if self.inertial.last_refusal
                else ""
            )
            doubts.append(
                f"the IMU was never initialised ({self.inertial.attempts} attempt(s) refused"
                f"{why}): the trajectory is not gravity-aligned"
                + (" and has the map's arbitrary scale" if self.rig.mono else "")
            )
        if scale_info is not None and scale_info.std > SCALE_DOUBT_STD:
            doubts.append(
                f"the motion determines the metric scale only to {100 * scale_info.std:.1f} % "
                f"(one standard deviation, at best, over {scale_info.duration_s:.1f} s): the "
                "camera accelerates too little for the IMU to tell its size"
            )
        inertial_frames = counts.get("frames_inertial", 0)
        if inertial_frames:
            doubts.append(
                f"{inertial_frames} frames were posed on the IMU alone (vision failed on them)"
            )
        apart = counts.get("frames_in_unmerged_maps", 0)
        if apart:
            doubts.append(
                f"{apart} frames were tracked in maps never merged into the main one: tracking "
                "was lost and the place not recognised again, so they have no pose"
            )
        return doubts

    def _result(self, main: int | None, trajectory: Trajectory) -> SlamResult:
        """The result of the run: ``trajectory``, the keyframes, points and essential graph of
        map ``main``, the counts and the records of maps, merges and loop closures."""
        smap = self.atlas.map
        kfs = smap.live(main)
        scale_info = self.inertial.scale_determination(main) if main is not None else None
        keyframes = Trajectory(
            np.array([k.stamp_ns for k in kfs], np.int64),
            self._bodies([k.cam_from_world for k in kfs]),
        )
        alive = np.flatnonzero(smap.alive[: smap.n] & (smap.map_id[: smap.n] == main))
        counts = dict(self.stats.counts)
        for state in _STATES:
            counts.setdefault(f"frames_{state}", 0)
        counts["keyframes"] = len(kfs)
        counts["map_points"] = int(alive.size)
        counts["maps"] = len(self.atlas.maps)
        counts["map_merges"] = len(self.atlas.merges)
        counts["loop_closures_accepted"] = sum(1 for r in self.loops.records if r["accepted"])
        counts["loop_closures_rejected"] = sum(1 for r in self.loops.records if not r["accepted"])
        stages = self.stats.per_frame(self._frames)
        return SlamResult(
            trajectory=trajectory,
            keyframes=keyframes,
            pose_graph=(
                keyframes.world_from_body,
                essential_graph(smap, kfs, self.rig.trajectory_from_camera),
            ),
            points=smap.pos[alive].copy(),
            point_colors=smap.color[alive].copy(),
            metrics={
                "mode": self.rig.mode,
                "initialisation": self.initializer.info,
                "ms_per_frame": stages,
                "maps": [m.to_dict() for m in self.atlas.maps],
                "merges": self.atlas.merges,
                "loop_closures": self.loops.records,
                "doubts": self._doubts(counts, main, scale_info),
                **(
                    {"inertial": self._inertial_record(main, scale_info)}
                    if self.inertial.enabled
                    else {}
                ),
                **({"imu_unused": self.imu_unused} if self.imu_unused else {}),
            },
            counts=counts,
            imu_states=self.inertial.table(main),
            data_loss=self._imu_loss(),
            truth_to_estimate=self.rig.truth_to_trajectory,
        )

    def _imu_loss(self) -> list[str]:
        """The IMU data the run could not use: what the source's checks found lost, and the
        samples dropped for stamps that did not follow the one before."""
        lines = list(self.inertial.data_loss)
        if self.inertial.dropped:
            lines.append(
                f"{self.inertial.dropped} IMU sample(s) dropped: their stamps repeat or go back "
                "on the sample before"
            )
        return lines


def _frame_interval(info: SourceInfo) -> float | None:
    """The mean interval between the images of ``info``'s camera stream, seconds."""
    for s in info.streams:
        if s.kind in ("image", "stereo", "rgbd") and s.rate_hz:
            return 1.0 / float(s.rate_hz)
    return None
