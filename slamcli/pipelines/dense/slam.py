"""Dense RGB-D SLAM: frame-to-model tracking seeded by a front end, TSDF fusion, a mesh.

Each frame goes through these stages (:meth:`DenseSlam.process`):

- **prepare** (:mod:`.frames`): depth cleaned and cut to the depth range, the front end's
  features, the tracking image; with ``threads = 2`` on a second core, a frame ahead.
- **track** (:mod:`.front_ends`, :mod:`.tracking`): the front end gives the frame's pose,
  refined against a ray cast of the volume.
- **integrate** (:mod:`.volume`): frames with a trusted pose and enough valid depth are fused
  into an Open3D ``VoxelBlockGrid`` (TSDF, weight, colour).
- **keyframes**: every few frames (or after enough motion) a keyframe keeps its images, packed,
  for the final rebuild (and, with ``front_end=frames``, for loop verification).

:meth:`DenseSlam.finish` takes the front end's final poses, rebuilds the volume from the
keyframes at their final poses when they moved, and extracts the mesh and points.

Every frame with a pose goes into the trajectory; every skipped or recovered frame is counted
by reason in ``SlamResult.counts``. Open3D objects never leave the package.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import PipelineError
from slamcli.formats.base import Prefetch
from slamcli.pipelines import PipelineBase
from slamcli.pipelines.dense.config import DenseConfig
from slamcli.pipelines.dense.frames import Frame, Keyframe, Rig
from slamcli.pipelines.dense.front_ends import FramesFrontEnd, FrontEnd, VisualFrontEnd
from slamcli.pipelines.dense.tracking import Model, ModelTracker, Track
from slamcli.pipelines.dense.volume import Volume
from slamcli.pipelines.timing import Stats
from slamcli.types import RgbdFrame, SlamResult, Trajectory
from slamcli.vision.pnp import pose_change

F64 = NDArray[np.float64]

# Tracking outcomes whose frames are fused into the volume.
_TRUSTED = ("tracked_first", "tracked_model", "tracked_visual", "recovered_f2f")


class DenseSlam(PipelineBase):
    """Pipeline ``dense``: consumes ``rgbd`` frames, produces poses, a mesh and points."""

    name = "dense"
    consumes = ("rgbd",)
    config_class = DenseConfig

    def __init__(self, config: DenseConfig | None = None) -> None:
        self.config = cfg = config or DenseConfig()
        # With two threads, frames are decoded ahead on a reader thread (see run_pipeline).
        self.read_ahead = 2 if cfg.threads == 2 else 0
        self.stats = Stats()
        self.rig = Rig(cfg)
        # The volume and the keyframes. Only keyframes keep their images (packed, about 0.3 MB
        # each at 640x480), so memory follows the keyframes, not the log: a rebuild after loop
        # closure fuses the keyframes.
        self.model = Model()
        self.tracker = ModelTracker(cfg, self.rig, self.model, self.stats)
        front = VisualFrontEnd if cfg.front_end == "visual" else FramesFrontEnd
        self.front_end: FrontEnd = front(cfg, self.rig, self.model, self.tracker, self.stats)
        self.track = Track()
        self._prefetch = Prefetch(self._prepare, ahead=cfg.threads == 2, name="prepare")
        self._frames = 0
        self._integrated = 0
        self._best_valid_fraction = 0.0

    # -- the pipeline -------------------------------------------------------------------------

    def seeds(self) -> dict[str, int]:
        """Seeds of the random number generators a run uses, by generator: OpenCV's (PnP
        RANSAC) gets ``config.seed`` before every PnP."""
        return {"opencv": self.config.seed}

    def close(self) -> None:
        """Stop the preparing thread and the front end's helpers (after an error;
        :meth:`finish` stops them itself)."""
        self._prefetch.close()
        self.front_end.close()

    def process(self, frame: RgbdFrame) -> None:
        """Track, integrate and maybe keyframe one RGB-D frame. With two threads, the next
        frame's images are prepared (depth cleaned, ORB features, tracking image) on a second
        core while this one is tracked; frames are still tracked in order."""
        # Stage timers nest (the ray cast is part of tracking), so the total is timed on its own.
        with self.stats.timed("total"):
            self.rig.check(frame)
            for _, prepared in self._prefetch.push(frame):
                self._process(prepared)

    def finish(self) -> SlamResult:
        """Take the front end's final poses, rebuild the volume and extract the mesh and points.

        Raises:
            PipelineError: no frame was read, or none had enough valid depth to build a map.
        """
        with self.stats.timed("total"):
            for _, prepared in self._prefetch.drain():
                self._process(prepared)
        self._prefetch.close()
        volume = self.model.volume
        if self._frames == 0 or volume is None:
            self.front_end.close()
            raise self._no_map_error()
        finish_start = time.perf_counter()
        with self.stats.timed("optimise"):
            corrections = self.front_end.final_poses(self.track)
        if corrections is not None:
            with self.stats.timed("reintegrate"):
                volume = self._rebuild(corrections)
        with self.stats.timed("extract"):
            mesh, points, colors = volume.extract(self._weight_threshold(corrections))
        self.stats.ms["total"] += (time.perf_counter() - finish_start) * 1e3
        keyframes = self.model.keyframes
        return SlamResult(
            trajectory=Trajectory(
                np.array(self.track.stamps, dtype=np.int64), np.stack(self.track.poses)
            ),
            keyframes=Trajectory(
                np.array([k.frame.stamp_ns for k in keyframes], dtype=np.int64),
                np.stack([k.world_from_cam for k in keyframes]).reshape(-1, 4, 4),
            ),
            points=points,
            point_colors=colors,
            mesh=mesh,
            metrics={
                "ms_per_frame": self.stats.per_frame(self._frames),
                "loop_closures": self.front_end.loop_records(),
            },
            counts=self._counts(volume),
        )

    # -- stages -------------------------------------------------------------------------------

    def _prepare(self, frame: RgbdFrame) -> Frame:
        return self.rig.prepare(frame, self.front_end.features)

    def _process(self, prepared: Any) -> None:
        """Track a prepared frame (``prepared.result()``), then fuse and keyframe it."""
        with self.stats.timed("prepare"):
            cur: Frame = prepared.result()
        cur.index = self._frames
        self._best_valid_fraction = max(self._best_valid_fraction, cur.valid_fraction)
        self._frames += 1
        counts = self.stats.counts
        pose, status = self.front_end.track(cur)
        counts[status] += 1
        if pose is None:
            counts["frames_lost"] += 1
            self.tracker.lost()
            return
        self.tracker.moved(pose)
        self.track.stamps.append(cur.stamp_ns)
        self.track.poses.append(pose)
        self.track.frames.append(cur.index)
        counts["frames_tracked"] += 1
        trusted = status in _TRUSTED
        depth_ok = cur.valid_fraction >= self.config.min_valid_depth_fraction
        if not depth_ok:
            counts["frames_not_integrated_depth"] += 1
        elif not trusted:
            counts["frames_not_integrated_untrusted"] += 1
        if trusted and depth_ok:
            with self.stats.timed("integrate"):
                self._integrate(cur, pose)
            self.tracker.reference, self.tracker.reference_pose = cur, pose
            if self._wants_keyframe(cur, pose):
                with self.stats.timed("loop"):
                    self._add_keyframe(cur, pose)

    def _integrate(self, cur: Frame, pose: F64) -> None:
        """Fuse a trusted frame into the volume."""
        if self.model.volume is None:
            self.model.volume = Volume(
                self.rig.o3d, self.config, self.rig.camera, self.config.block_count
            )
        self.model.volume.integrate(cur.depth, cur.rgb, pose)
        self._integrated += 1

    def _wants_keyframe(self, cur: Frame, pose: F64) -> bool:
        keyframes = self.model.keyframes
        if not keyframes:
            return True
        if not self.front_end.allows_keyframe(cur, pose):
            return False
        last = keyframes[-1]
        if cur.index - last.frame.index >= self.config.keyframe_every:
            return True
        moved_m, turned_deg = pose_change(last.world_from_cam, pose)
        return moved_m >= self.config.keyframe_min_m or turned_deg >= self.config.keyframe_min_deg

    def _add_keyframe(self, cur: Frame, pose: F64) -> None:
        keyframes = self.model.keyframes
        kf = Keyframe(len(keyframes), cur, pose.copy())
        if keyframes:
            prev = keyframes[-1]
            self.front_end.link(kf, prev)
            self.rig.pack(prev)
        keyframes.append(kf)
        self.front_end.keyframe_added(kf)

    def _rebuild(self, corrected: F64) -> Volume:
        """Rebuild the volume from the keyframes at their corrected poses (K, 4, 4)."""
        keyframes = self.model.keyframes
        for kf, pose in zip(keyframes, corrected, strict=True):
            kf.world_from_cam = pose
        # The rebuilt volume covers about the same blocks: it starts with that room, and the
        # old one is released first so the two never hold memory at once.
        assert self.model.volume is not None
        capacity = math.ceil(self.config.block_growth * self.model.volume.size)
        self.model.volume = None
        volume = Volume(self.rig.o3d, self.config, self.rig.camera, capacity)
        for kf in keyframes:
            frame = self.rig.images(kf)
            volume.integrate(frame.depth, frame.rgb, kf.world_from_cam)
        self.model.volume = volume
        self.stats.counts["frames_reintegrated"] = len(keyframes)
        return volume

    # -- results ------------------------------------------------------------------------------

    def _weight_threshold(self, rebuilt: F64 | None) -> float:
        """The least voxel weight in the mesh: ``mesh_weight_threshold`` for a volume of every
        integrated frame; a volume rebuilt from the keyframes alone saw each surface fewer
        times, so the threshold shrinks with the keyframes' share of the frames (never below
        one observation)."""
        threshold = self.config.mesh_weight_threshold
        if rebuilt is None or self._integrated == 0:
            return threshold
        share = len(self.model.keyframes) / self._integrated
        return min(threshold, max(1.0, threshold * share))

    def _counts(self, volume: Volume) -> dict[str, int]:
        counts = dict(self.stats.counts)
        counts.setdefault("frames_lost", 0)
        counts["keyframes"] = len(self.model.keyframes)
        counts["frames_integrated"] = self._integrated
        counts.update(self.front_end.counts())
        loop_records = self.front_end.loop_records()
        counts["loop_closures_accepted"] = sum(bool(r["accepted"]) for r in loop_records)
        counts["loop_closures_rejected"] = sum(not r["accepted"] for r in loop_records)
        counts["voxel_blocks"] = volume.size
        counts["voxel_block_budget"] = volume.capacity
        counts["voxel_block_growths"] = volume.growths
        return counts

    def _no_map_error(self) -> PipelineError:
        if self._frames == 0:
            return PipelineError("the dense pipeline received no RGB-D frames")
        return PipelineError(
            f"none of the {self._frames} frames had usable depth: at best "
            f"{100 * self._best_valid_fraction:.1f}% of the pixels read between "
            f"{self.config.depth_min_m} and {self.config.depth_max_m} m (need "
            f"{100 * self.config.min_valid_depth_fraction:.0f}%)",
            hint="check the depth stream and its depth factor (TUM: 5000 units per metre), "
            "or widen dense.depth_min_m / dense.depth_max_m",
        )
