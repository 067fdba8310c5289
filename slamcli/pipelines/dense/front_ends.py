"""The dense pipeline's two front ends: what gives each frame's pose before the volume takes it.

- :class:`VisualFrontEnd` (``front_end=visual``, the default): the visual pipeline's tracker
  (:class:`~slamcli.pipelines.visual.VisualSlam`: motion model, local map, local bundle
  adjustment) poses the frame; the pose is refined against a ray cast of the TSDF volume and
  the frame's pose is ``model_weight`` of the way from the feature pose to the refined one.
  The two err differently (features are sharp in rotation, depth in translation), so the blend
  beats both. A refinement that throws, finds too few correspondences or strays from the
  feature pose is dropped. Frames the visual tracker cannot pose (no texture, lost) are tracked
  by the model tracker alone, which also places each new visual map in the volume's frame. At
  the end, its loop closure (place recognition, GTSAM pose graph) and final refinement give
  each frame its final feature pose, which takes the correction the model made when the frame
  was tracked.
- :class:`FramesFrontEnd` (``front_end=frames``): the model tracker
  (:class:`~slamcli.pipelines.dense.tracking.ModelTracker`) alone; earlier keyframes near a new
  one in pose and similar in ORB appearance are verified by PnP and RGB-D odometry as loops,
  and at the end the keyframe pose graph is optimised with Open3D's line-process global
  optimisation (which prunes false loops); every frame follows its keyframe.

Both sit behind :class:`FrontEnd`; the pipeline picks one at construction.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import PipelineError
from slamcli.geometry import blend_poses, compose, inverse, rotation_angle
from slamcli.pipelines.dense.config import DenseConfig
from slamcli.pipelines.dense.frames import Features, Frame, Keyframe, Rig
from slamcli.pipelines.dense.tracking import Model, ModelTracker, Track
from slamcli.pipelines.rgbd_odometry import rgbd_odometry_multi_scale
from slamcli.pipelines.timing import Stats
from slamcli.pipelines.visual import VisualConfig, VisualSlam
from slamcli.types import RgbdFrame, SlamResult
from slamcli.vision.matching import match_ratio
from slamcli.vision.pnp import pose_change, within

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

_NO_KEYPOINTS = np.zeros((0, 2), dtype=np.float32)
_NO_DESCRIPTORS = np.zeros((0, 32), dtype=np.uint8)


class FrontEnd(Protocol):
    """What gives each frame its pose, and its part in the keyframes and the final poses."""

    def features(self, frame: RgbdFrame, rgb: NDArray[np.uint8]) -> Features:
        """The features of a frame (``rgb``: its prepared colour image); may run on another
        thread."""
        ...

    def track(self, cur: Frame) -> tuple[F64 | None, str]:
        """World-from-camera pose of ``cur`` (or None when lost) and how it was found."""
        ...

    def allows_keyframe(self, cur: Frame, pose: F64) -> bool:
        """Whether a keyframe may be made of ``cur`` at ``pose``."""
        ...

    def link(self, kf: Keyframe, previous: Keyframe) -> None:
        """A keyframe follows ``previous``, whose images are still at hand."""
        ...

    def keyframe_added(self, kf: Keyframe) -> None:
        """``kf`` was added to the model's keyframes."""
        ...

    def final_poses(self, track: Track) -> F64 | None:
        """Give ``track`` its final poses; the keyframes' final poses (K, 4, 4) when they
        moved enough for the volume to be rebuilt, else None."""
        ...

    def loop_records(self) -> list[dict[str, Any]]:
        """One record per loop candidate verified."""
        ...

    def counts(self) -> dict[str, int]:
        """The front end's figures for the run's counts."""
        ...

    def close(self) -> None:
        """Release what it holds (after an error)."""
        ...


def moved_enough(keyframes: list[Keyframe], corrected: F64, config: DenseConfig) -> bool:
    """Whether the corrected keyframe poses (K, 4, 4) move a keyframe far enough from where it
    was fused for the volume to be rebuilt."""
    old = np.stack([k.world_from_cam for k in keyframes])
    shift = compose(inverse(old), corrected)
    moved_m = float(np.max(np.linalg.norm(shift[:, :3, 3], axis=1)))
    moved_deg = float(np.degrees(np.max(rotation_angle(shift))))
    log.info("the final poses move keyframes by up to %.4f m, %.3f deg", moved_m, moved_deg)
    return (
        moved_m >= config.reintegrate_min_shift_m or moved_deg >= config.reintegrate_min_shift_deg
    )


class _FrontEndParts:
    """What both front ends work with: the settings, the rig, the model, the model tracker,
    and the counts and stage times."""

    def __init__(
        self, config: DenseConfig, rig: Rig, model: Model, tracker: ModelTracker, stats: Stats
    ) -> None:
        self.config, self.rig, self.model, self.tracker, self.stats = (
            config,
            rig,
            model,
            tracker,
            stats,
        )


class VisualFrontEnd(_FrontEndParts):
    """``front_end=visual`` (see the module's description)."""

    def __init__(
        self, config: DenseConfig, rig: Rig, model: Model, tracker: ModelTracker, stats: Stats
    ) -> None:
        super().__init__(config, rig, model, tracker, stats)
        self.visual = VisualSlam(VisualConfig(threads=config.threads, seed=config.seed))
        # The volume-from-map transform of each of the visual tracker's maps, and each pose's
        # tracker pose and map (None where the model tracker alone placed the frame).
        self._map_offsets: dict[int, F64] = {}
        self._seed: tuple[F64, int] | None = None
        self._seed_of_pose: list[tuple[F64, int] | None] = []
        self._front_end_result: SlamResult | None = None

    def features(self, frame: RgbdFrame, rgb: NDArray[np.uint8]) -> Features:
        # The visual tracker finds its own features (on the raw image); the frame's ORB
        # keypoints are not used.
        return _NO_KEYPOINTS, _NO_DESCRIPTORS, (frame, self.visual.extract(frame))

    def track(self, cur: Frame) -> tuple[F64 | None, str]:
        self._seed = None
        pose, status = self._track_visual(cur)
        if pose is not None:
            self._seed_of_pose.append(self._seed)
        return pose, status

    def allows_keyframe(self, cur: Frame, pose: F64) -> bool:
        # Keyframes only feed the final rebuild here: a view kept on an earlier pass adds
        # nothing, so revisiting a mapped room adds no keyframes.
        return not self._near_keyframe(cur, pose)

    def link(self, kf: Keyframe, previous: Keyframe) -> None:
        pass

    def keyframe_added(self, kf: Keyframe) -> None:
        pass

    def loop_records(self) -> list[dict[str, Any]]:
        if self._front_end_result is None:
            return []
        return list(self._front_end_result.metrics.get("loop_closures", []))

    def counts(self) -> dict[str, int]:
        front = self._front_end_result
        if front is None:
            return {}
        return {
            f"front_end_{key}": int(front.counts.get(key, 0))
            for key in ("keyframes", "maps", "map_merges", "map_points")
        }

    def close(self) -> None:
        self.visual.close()

    def _track_visual(self, cur: Frame) -> tuple[F64 | None, str]:
        """Pose ``cur`` with the visual tracker, refined against the model and blended by
        ``model_weight``; the dense tracker alone when the visual one has no pose, and for the
        first frame of each of its maps (which places that map in the volume's frame)."""
        cfg = self.config
        source, features = cur.front
        with self.stats.timed("front_end"):
            tracked = self.visual.track(source, features)
        cur.front = None
        if tracked is None:
            self.stats.counts["front_end_no_pose"] += 1
            return self.tracker.track(cur)
        online, map_id = tracked
        offset = self._map_offsets.get(map_id)
        if offset is None:
            pose, status = self.tracker.track(cur)
            if pose is not None:
                self._map_offsets[map_id] = compose(pose, inverse(online))
                self._seed = (online, map_id)
            return pose, status
        self._seed = (online, map_id)
        seed = compose(offset, online)
        depth_ok = cur.valid_fraction >= cfg.min_valid_depth_fraction
        if not (depth_ok and self.model.volume is not None and cfg.model_weight > 0):
            return seed, "tracked_visual"
        with self.stats.timed("track_model"):
            refined = self.tracker.refine_model(cur, seed)
        if refined is None:
            return seed, "tracked_visual"
        if not within(seed, refined, cfg.max_seed_disagreement_m, cfg.max_seed_disagreement_deg):
            self.stats.counts["rejected_seed_disagreement"] += 1
            return seed, "tracked_visual"
        return blend_poses(seed, refined, cfg.model_weight), "tracked_model"

    def final_poses(self, track: Track) -> F64 | None:
        """Final poses with the visual front end: each frame the visual tracker placed gets
        its final visual pose (after loop closure, the pose graph and the last refinement)
        times the correction the model refinement made to it when it was tracked; the other
        frames follow the nearest such frame by their tracked motion. The first placed frame
        keeps its pose. Returns the keyframes' final poses when they moved enough for the
        volume to be rebuilt, else None."""
        try:
            self._front_end_result = front = self.visual.finish()
        except PipelineError as exc:
            # No map came out of the visual tracker: the tracked poses stand.
            log.info("the visual front end made no map (%s); keeping the tracked poses", exc)
            self.visual.close()
            self.stats.counts["front_end_no_map"] += 1
            return None
        assert front.trajectory is not None
        final_of = {
            int(s): p
            for s, p in zip(
                front.trajectory.stamps_ns, front.trajectory.world_from_body, strict=True
            )
        }
        tracked = track.poses
        final: list[F64 | None] = [None] * len(tracked)
        for i, (stamp, seed) in enumerate(zip(track.stamps, self._seed_of_pose, strict=True)):
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
        self.stats.counts["frames_placed_by_front_end"] = len(placed)
        track.poses = [p for p in out if p is not None]
        if not self.model.keyframes:
            return None
        index_of = {f: k for k, f in enumerate(track.frames)}
        corrected = np.stack([track.poses[index_of[kf.frame.index]] for kf in self.model.keyframes])
        if not moved_enough(self.model.keyframes, corrected, self.config):
            return None
        return corrected

    def _near_keyframe(self, cur: Frame, pose: F64) -> bool:
        """Whether a keyframe of an earlier pass (``loop_min_frames`` or more before ``cur``)
        lies within ``keyframe_min_m`` and ``keyframe_min_deg`` of ``pose``."""
        cfg = self.config
        earlier = [
            k for k in self.model.keyframes if cur.index - k.frame.index >= cfg.loop_min_frames
        ]
        if not earlier:
            return False
        poses = np.stack([k.world_from_cam for k in earlier])
        near = np.linalg.norm(poses[:, :3, 3] - pose[:3, 3], axis=1) < cfg.keyframe_min_m
        if not near.any():
            return False
        turned = np.degrees(rotation_angle(compose(inverse(poses[near]), pose)))
        return bool(np.any(turned < cfg.keyframe_min_deg))


@dataclass
class Loop:
    """A verified loop: ``cand_from_cur`` (4, 4) maps keyframe ``cur`` into keyframe ``cand``."""

    cand: int
    cur: int
    cand_from_cur: F64
    information: F64
    record: dict[str, Any] = field(default_factory=dict)


class FramesFrontEnd(_FrontEndParts):
    """``front_end=frames`` (see the module's description)."""

    def __init__(
        self, config: DenseConfig, rig: Rig, model: Model, tracker: ModelTracker, stats: Stats
    ) -> None:
        super().__init__(config, rig, model, tracker, stats)
        self._loops: list[Loop] = []
        self._records: list[dict[str, Any]] = []

    def features(self, frame: RgbdFrame, rgb: NDArray[np.uint8]) -> Features:
        import cv2

        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        orb = cv2.ORB.create(nfeatures=self.config.orb_features)
        kps, found = orb.detectAndCompute(gray, None)
        keypoints = np.array([k.pt for k in kps], dtype=np.float32).reshape(-1, 2)
        desc = np.zeros((0, 32), np.uint8) if found is None else np.asarray(found, np.uint8)
        return keypoints, desc, None

    def track(self, cur: Frame) -> tuple[F64 | None, str]:
        return self.tracker.track(cur)

    def allows_keyframe(self, cur: Frame, pose: F64) -> bool:
        return True

    def link(self, kf: Keyframe, previous: Keyframe) -> None:
        # The odometry edge of the keyframe pose graph.
        prev_from_kf = compose(inverse(previous.world_from_cam), kf.world_from_cam)
        kf.info_to_previous = self.tracker.information(kf.frame, previous.frame, prev_from_kf)

    def final_poses(self, track: Track) -> F64 | None:
        corrected = self._optimise()
        if corrected is None:
            return None
        # Each pose follows the latest keyframe at or before it.
        keyframes = self.model.keyframes
        old = np.stack([k.world_from_cam for k in keyframes])
        kf_frames = np.array([k.frame.index for k in keyframes])
        owner = np.clip(np.searchsorted(kf_frames, track.frames, side="right") - 1, 0, None)
        delta = compose(corrected, inverse(old))
        track.poses = list(compose(delta[owner], np.stack(track.poses)))
        return corrected

    def loop_records(self) -> list[dict[str, Any]]:
        return self._records

    def counts(self) -> dict[str, int]:
        return {}

    def close(self) -> None:
        pass

    def keyframe_added(self, kf: Keyframe) -> None:
        """Find, verify and record loop closures between ``kf`` and earlier keyframes."""
        cfg = self.config
        candidates = []
        for old in self.model.keyframes[:-1]:
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
            self._records.append(record)
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
        o3d = self.rig.o3d
        reg = o3d.pipelines.registration
        graph = reg.PoseGraph()
        for kf in self.model.keyframes:
            graph.nodes.append(reg.PoseGraphNode(kf.world_from_cam))
        for a, b in zip(self.model.keyframes[:-1], self.model.keyframes[1:], strict=True):
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
        return corrected if moved_enough(self.model.keyframes, corrected, self.config) else None

    def _verify_loop(self, old: Keyframe, kf: Keyframe, ratio: float) -> dict[str, Any]:
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
        old_from_cur, record["inliers"] = self.tracker.pnp(
            old.frame, kf.frame, cfg.loop_min_inliers
        )
        if old_from_cur is None:
            record["reason"] = f"fewer than {cfg.loop_min_inliers} PnP inliers"
            return record
        kf_frame, old_frame = self.rig.images(kf), self.rig.images(old)
        odo = self.rig.o3d.t.pipelines.odometry
        try:
            result = rgbd_odometry_multi_scale(
                self.rig.o3d,
                self.rig.full_image(kf_frame),
                self.rig.full_image(old_frame),
                self.rig.o3d.core.Tensor(self.rig.camera.K),
                self.rig.o3d.core.Tensor(old_from_cur),
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
            info = self.tracker.information(kf_frame, old_frame, refined)
            self._loops.append(Loop(old.id, kf.id, refined, info, record))
        return record
