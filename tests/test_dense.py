"""Dense RGB-D SLAM: accuracy on real and synthetic data, determinism, bad depth."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from dense_data import SYNTH_FRAMES, SYNTH_SIZE, cli_run, render_synth_loop

from slamcli.errors import PipelineError
from slamcli.evaluation import evaluate
from slamcli.formats import open_source
from slamcli.geometry import compose, interpolate_poses, inverse
from slamcli.pipelines import get_pipeline
from slamcli.pipelines.dense import DenseConfig, DenseSlam
from slamcli.types import RgbdFrame, SlamResult, Trajectory

log = logging.getLogger(__name__)

# Accuracy thresholds, shared with the perturbed runs of tests/robust.
TUM_ATE_M = 0.016
SYNTH_ATE_M = 0.01


def _run(path: Path, config: DenseConfig | None = None) -> tuple[SlamResult, Trajectory | None]:
    pipe = DenseSlam(config)
    with open_source(path) as source:
        for frame in source.frames(("rgbd",)):
            pipe.process(frame)
        result = pipe.finish()
        groundtruth = source.groundtruth()
    return result, groundtruth


@pytest.fixture(scope="module")
def synth_loop(shared_artefact: Any) -> Path:
    return shared_artefact("dense_synth_loop", render_synth_loop)


@dataclass
class _Processed:
    """The default pipeline over the synthetic loop: its frames, the pipeline after them (its
    keyframes as they were before ``finish``), and the result."""

    frames: list[RgbdFrame]
    pipe: DenseSlam
    keyframes: list[tuple[bool, int]]
    result: SlamResult
    groundtruth: Trajectory | None


@pytest.fixture(scope="module")
def processed(synth_loop: Path) -> _Processed:
    pipe = DenseSlam()
    with open_source(synth_loop) as source:
        frames = list(source.frames(("rgbd",)))
        groundtruth = source.groundtruth()
    for frame in frames:
        pipe.process(frame)
    # (packed, colour pixels kept) of every keyframe before the final rebuild.
    before = [(k.packed is not None, k.frame.rgb.size) for k in pipe.model.keyframes]
    return _Processed(frames, pipe, before, pipe.finish(), groundtruth)


@pytest.fixture(scope="module")
def synth_result(processed: _Processed) -> tuple[SlamResult, Trajectory | None]:
    return processed.result, processed.groundtruth


def test_registered() -> None:
    assert get_pipeline("dense") is DenseSlam
    assert DenseSlam.consumes == ("rgbd",)


def test_tum_rpy_excerpt(tum_excerpt: Path, reference_run: Any) -> None:
    """``slamcli run dense`` on the TUM excerpt (the reference run of the same command)."""
    from slamcli.formats.mesh import read_mesh
    from slamcli.formats.trajectory import read_trajectory

    run = reference_run("dense_tum")
    record = json.loads((run / "run.json").read_text())
    counts = record["counts"]
    with open_source(tum_excerpt) as source:
        groundtruth = source.groundtruth()
    trajectory = read_trajectory(run / "trajectory.tum")
    assert groundtruth is not None
    assert len(trajectory) == 150
    assert counts["frames_lost"] == 0
    ate = evaluate(groundtruth, trajectory, align="se3").ate.rmse
    log.info("TUM fr1/rpy excerpt: ATE %.4f m, %s", ate, record["metrics"]["ms_per_frame"])
    assert ate <= TUM_ATE_M
    assert record["metrics"]["evaluation"]["ate"]["rmse"] <= TUM_ATE_M
    assert counts["frames_placed_by_front_end"] == 150
    assert len(read_mesh(run / "mesh.ply").faces) > 10_000


def test_synthetic_loop(synth_loop: Path, synth_result: tuple[SlamResult, Trajectory]) -> None:
    from slamcli.backends import import_open3d
    from slamcli.synth.rgbd import build_rgbd_world

    result, groundtruth = synth_result
    assert result.trajectory is not None and len(result.trajectory) == SYNTH_FRAMES
    assert result.counts["frames_lost"] == 0
    ev = evaluate(groundtruth, result.trajectory, align="se3")
    log.info("synthetic loop: ATE %.4f m", ev.ate.rmse)
    assert ev.ate.rmse <= SYNTH_ATE_M
    assert result.keyframes is not None and len(result.keyframes) >= 5

    mesh = result.mesh
    assert mesh is not None and mesh.vertex_colors is not None
    assert mesh.vertex_colors.dtype == np.uint8 and mesh.vertex_colors.shape == mesh.vertices.shape
    assert result.points is not None and result.point_colors is not None
    assert len(result.points) == len(result.point_colors) > 1000

    o3d = import_open3d()
    vertices, faces = build_rgbd_world(SYNTH_FRAMES, SYNTH_SIZE, seed=3).scene.mesh()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(vertices.astype(np.float32), faces.astype(np.uint32))
    # Align by averaging gt_i @ inv(est_i) over all frames: the Umeyama fit of positions alone
    # leaves the rotation of a 0.2 m loop loose, and metres away that looks like mesh error.
    _, gt_poses = interpolate_poses(
        groundtruth.stamps_ns, groundtruth.world_from_body, result.trajectory.stamps_ns
    )
    gt_from_est = compose(gt_poses, inverse(result.trajectory.world_from_body))
    u, _, vt = np.linalg.svd(gt_from_est[:, :3, :3].sum(axis=0))
    rotation = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    in_world = mesh.vertices @ rotation.T + gt_from_est[:, :3, 3].mean(axis=0)
    distance = scene.compute_distance(in_world.astype(np.float32)).numpy()
    log.info("mesh: mean distance %.4f m over %d vertices", distance.mean(), len(distance))
    assert distance.mean() <= 0.01


def test_frames_front_end_closes_its_own_loops(synth_loop: Path) -> None:
    """With ``front_end=frames`` (PnP against the previous frame) the dense pipeline closes
    the loop itself, and the pose graph keeps the accuracy."""
    result, groundtruth = _run(synth_loop, DenseConfig(front_end="frames"))
    assert groundtruth is not None and result.trajectory is not None
    assert result.counts["frames_lost"] == 0
    assert "frames_placed_by_front_end" not in result.counts
    assert evaluate(groundtruth, result.trajectory, align="se3").ate.rmse <= 0.01
    loops = result.metrics["loop_closures"]
    accepted = [r for r in loops if r["accepted"]]
    assert accepted, loops
    assert all(r["frames"][1] - r["frames"][0] >= 45 for r in accepted)
    assert result.counts["loop_closures_accepted"] == len(accepted)
    assert result.counts["frames_reintegrated"] == result.counts["keyframes"]


def test_frames_without_texture_are_tracked_by_depth_alone(synth_loop: Path) -> None:
    """Blank colour for ten frames: the visual front end loses them and starts a new map after,
    the dense tracker carries those frames on depth alone and places the new map in the
    volume's frame, and the whole trajectory stays accurate."""
    frames = _frames(synth_loop, SYNTH_FRAMES)
    for i in range(30, 40):
        frames[i] = replace(frames[i], rgb=np.full_like(frames[i].rgb, 128))
    pipe = DenseSlam()
    for frame in frames:
        pipe.process(frame)
    result = pipe.finish()
    assert result.trajectory is not None and len(result.trajectory) == SYNTH_FRAMES
    assert result.counts["front_end_no_pose"] >= 10
    assert result.counts["front_end_maps"] >= 2
    assert result.counts["frames_placed_by_front_end"] < SYNTH_FRAMES
    with open_source(synth_loop) as source:
        groundtruth = source.groundtruth()
    assert groundtruth is not None
    assert evaluate(groundtruth, result.trajectory, align="se3").ate.rmse <= 0.02


@pytest.mark.slow
def test_a_fresh_process_writes_the_same_trajectory(
    synth_loop: Path, synth_result: tuple[SlamResult, Trajectory], tmp_path: Path
) -> None:
    """The in-process run above and ``slamcli run dense`` in a fresh process with another heap
    layout: one trajectory, to the byte, loop closures included."""
    from slamcli.formats.trajectory import write_tum

    assert synth_result[0].trajectory is not None
    write_tum(tmp_path / "in_process.tum", synth_result[0].trajectory)
    fresh = cli_run(synth_loop, tmp_path / "cli", 100_000)
    assert fresh == (tmp_path / "in_process.tum").read_bytes()


def _frames(path: Path, count: int) -> list[RgbdFrame]:
    with open_source(path) as source:
        return [f for _, f in zip(range(count), source.frames(("rgbd",)), strict=False)]


def test_mostly_invalid_depth_is_tracked_not_integrated(synth_loop: Path) -> None:
    frames = _frames(synth_loop, 20)
    depth = frames[10].depth_m.copy()
    depth[: int(0.95 * depth.shape[0])] = 0.0
    frames[10] = replace(frames[10], depth_m=depth)
    pipe = DenseSlam()
    for frame in frames:
        pipe.process(frame)
    result = pipe.finish()
    assert result.trajectory is not None and len(result.trajectory) == 20
    assert result.counts["frames_not_integrated_depth"] == 1
    assert result.counts["frames_integrated"] == 19
    assert result.counts["frames_lost"] == 0


def test_all_zero_depth_is_an_error(synth_loop: Path) -> None:
    pipe = DenseSlam()
    for frame in _frames(synth_loop, 5):
        pipe.process(replace(frame, depth_m=np.zeros_like(frame.depth_m)))
    with pytest.raises(PipelineError, match="none of the 5 frames had usable depth"):
        pipe.finish()


def test_no_frames_is_an_error() -> None:
    with pytest.raises(PipelineError, match="received no RGB-D frames"):
        DenseSlam().finish()


def test_camera_mismatch_is_an_error(synth_loop: Path) -> None:
    frame = _frames(synth_loop, 1)[0]
    wrong = replace(frame.camera, width=frame.camera.width * 2)
    with pytest.raises(PipelineError, match="must agree"):
        DenseSlam().process(replace(frame, camera=wrong))


def test_config_is_checked() -> None:
    from slamcli.errors import ConfigError

    with pytest.raises(ConfigError, match=r"dense\.depth_min_m"):
        DenseConfig(depth_min_m=5.0, depth_max_m=3.0)


def test_volume_starts_at_the_first_frame_and_grows_with_the_scene() -> None:
    from slamcli.pipelines.dense.volume import Volume, open3d
    from slamcli.types import PinholeCamera

    cam = PinholeCamera(320, 240, 256.0, 256.0, 159.5, 119.5)
    cfg = DenseConfig()
    volume = Volume(open3d(), cfg, cam, cfg.block_count)
    wall = np.full((240, 320), 1.5, dtype=np.float32)
    rgb = np.full((240, 320, 3), 128, dtype=np.uint8)
    volume.integrate(wall, rgb, np.eye(4))
    first = volume.size
    # Sized to the data: the frame's blocks plus the growth margin, where a budget sized for
    # the camera's whole depth range (24 views of a wall at 3 m) held 19776 blocks (1.6 GB).
    assert volume.capacity == int(np.ceil(cfg.block_growth * first))
    assert volume.capacity < 1000
    assert volume.growths == 1

    moved = np.eye(4)
    moved[0, 3] = 3.0
    volume.integrate(wall, rgb, moved)
    assert volume.size > 1.8 * first
    assert volume.capacity >= volume.size
    assert volume.growths == 2
    # Growing keeps what was fused before: the mesh spans both walls.
    mesh, _, _ = volume.extract(0.5)
    assert mesh.vertices[:, 0].min() < 0.0 and mesh.vertices[:, 0].max() > 3.0


def test_volume_budget_follows_the_scene(
    synth_result: tuple[SlamResult, Trajectory | None],
) -> None:
    counts = synth_result[0].counts
    # Capacity stays within the growth margin of what the scene uses (plus one frame's blocks).
    assert counts["voxel_blocks"] <= counts["voxel_block_budget"] <= 3 * counts["voxel_blocks"]


def test_only_keyframes_keep_images_packed_and_a_rebuild_fuses_them(
    processed: _Processed,
) -> None:
    """Memory follows the keyframes: every keyframe but the newest keeps its images only
    packed (a lossless 16-bit depth PNG and a JPEG), they decode to the depth it had, and
    the rebuild after loop closure fuses exactly the keyframes."""
    pipe, frames, before = processed.pipe, processed.frames, processed.keyframes
    kfs = pipe.model.keyframes
    assert len(kfs) == len(before) >= 5
    assert all(packed and pixels == 0 for packed, pixels in before[:-1])
    assert not before[-1][0] and before[-1][1] > 0
    # Packed bytes stay far below the arrays they replace.
    packed = sum(len(d) + len(c) for k in kfs[:-1] for d, c in [k.packed])  # type: ignore[misc]
    raw = sum(f.rgb.nbytes + f.depth_m.nbytes for f in frames[: len(kfs) - 1])
    assert packed < 0.5 * raw
    # The depth comes back as it was, to the 1/5000 m step it was stored in.
    first = pipe.rig.images(kfs[0])
    original = pipe._prepare(frames[kfs[0].frame.index])
    assert np.abs(first.depth - original.depth).max() <= 1.0 / 5000
    assert first.small is not None and first.rgb.shape == original.rgb.shape
    result = processed.result
    # The final poses (the visual front end's, after its last refinement) moved the
    # keyframes, so the volume was rebuilt from them.
    assert result.counts["frames_reintegrated"] == len(kfs)
