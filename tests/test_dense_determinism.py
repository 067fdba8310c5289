"""Same input + same config = bit-identical dense trajectory, within a process and across runs.

Open3D's Gaussian pyramid filter rounds differently depending on the memory alignment of the
image buffer, which depends on the allocation history of the process; these tests feed the same
images at every alignment, and compare a CLI run with another heap layout's. (The closed loop's
fresh-process run is compared with its in-process run in test_dense.)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from dense_data import cli_run

ROOT = Path(__file__).resolve().parents[1]
ROOM = ROOT / "sample_data" / "rgbd_room"


def _at_alignment(a: np.ndarray, offset: int) -> np.ndarray:
    """A copy of ``a`` whose data starts ``offset`` bytes past a 64-byte boundary."""
    buf = np.empty(a.nbytes + 128, np.uint8)
    start = (-buf.ctypes.data) % 64 + offset
    out = buf[start : start + a.nbytes].view(a.dtype).reshape(a.shape)
    out[...] = a
    assert out.ctypes.data % 64 == offset
    return out


def _scene(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Two overlapping views of a smooth textured slanted plane: colours and depths."""
    rng = np.random.default_rng(seed)
    ys, xs = np.mgrid[0:120, 0:160].astype(np.float32)
    texture = rng.random((8, 8, 3)).astype(np.float32)
    import cv2

    big = cv2.resize(texture, (176, 120), interpolation=cv2.INTER_CUBIC).clip(0, 1)
    depth = (1.5 + 0.004 * xs + 0.002 * ys).astype(np.float32)
    return big[:, :160], big[:, 3:163], depth, depth + np.float32(0.01)


def test_pyramid_does_not_depend_on_buffer_alignment() -> None:
    from slamcli.pipelines.rgbd_odometry import pyr_down_depth, pyr_down_intensity

    rng = np.random.default_rng(0)
    intensity = rng.random((240, 320), dtype=np.float32)
    depth = np.where(rng.random((240, 320)) < 0.1, np.nan, 1 + rng.random((240, 320)))
    depth = depth.astype(np.float32)
    for shape in [(240, 320), (120, 160), (60, 80)]:
        i, d = intensity[: shape[0], : shape[1]], depth[: shape[0], : shape[1]]
        small_i = {pyr_down_intensity(_at_alignment(i, k)).tobytes() for k in (0, 16, 32, 48)}
        small_d = {pyr_down_depth(_at_alignment(d, k), 0.14).tobytes() for k in (0, 16, 32, 48)}
        assert len(small_i) == 1 and len(small_d) == 1, shape


def test_multi_scale_odometry_does_not_depend_on_buffer_alignment() -> None:
    from slamcli.backends import import_open3d
    from slamcli.pipelines.rgbd_odometry import rgbd_odometry_multi_scale

    o3d = import_open3d()
    odo = o3d.t.pipelines.odometry
    geometry = o3d.t.geometry
    src_rgb, tgt_rgb, src_depth, tgt_depth = _scene(1)
    K = np.array([[150.0, 0, 80], [0, 150.0, 60], [0, 0, 1]])
    results = set()
    # Blocks of assorted sizes kept alive between calls move where Open3D's own intermediate
    # images land, as a long run's allocation history does.
    heap = [np.empty(int(n), np.uint8) for n in np.random.default_rng(2).integers(1, 4000, 64)]
    for offset in [0, 16, 32, 48] * 4:
        heap.append(np.empty(int(heap[-1].size) % 997 + 8, np.uint8))

        def rgbd(rgb: np.ndarray, depth: np.ndarray, offset: int = offset) -> object:
            return geometry.RGBDImage(
                geometry.Image(_at_alignment(rgb, offset)),
                geometry.Image(_at_alignment(depth, offset)),
            )

        result = rgbd_odometry_multi_scale(
            o3d,
            rgbd(src_rgb, src_depth),
            rgbd(tgt_rgb, tgt_depth),
            o3d.core.Tensor(K),
            o3d.core.Tensor(np.eye(4)),
            1.0,
            4.0,
            [odo.OdometryConvergenceCriteria(n) for n in (6, 4, 2)],
            odo.Method.Hybrid,
            odo.OdometryLossParams(0.07),
        )
        assert result.fitness > 0.5
        results.add(result.transformation.numpy().tobytes())
    assert len(results) == 1


@pytest.mark.slow
def test_two_cli_runs_write_byte_identical_trajectories(tmp_path: Path, reference_run: Any) -> None:
    """A run in a fresh process and the same command's reference run, made in a test
    process: two heap layouts, one trajectory."""
    first = cli_run(ROOM, tmp_path / "a", 100_000)
    assert first == (reference_run("dense_room") / "trajectory.tum").read_bytes()
