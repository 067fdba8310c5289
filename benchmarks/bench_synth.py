"""ms per rendered image of `slamcli synth` beside Open3D's bare ray cast of the same rays.

The reference is `RaycastingScene.cast_rays` alone on the rays one image needs (one per pixel
for each of the 2x2 sub-pixel offsets; RGB-D adds the pixel centre's depth ray), on the same
room, in the same process and with the same (single-threaded) Open3D: the floor any renderer of
this scene pays. Ours is a whole view: the rays, the cast, texture sampling and shading, and for
RGB-D the depth image; stereo renders both cameras of a pair (reported per image). Medians over
``--repeat`` views spread over the loop, after a warm-up view that loads the compiled kernels.

Usage: python benchmarks/bench_synth.py [--repeat 15]
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from slamcli.synth.rgbd import RgbdWorld


def _median_ms(work: Callable[[int], object], views: list[int]) -> float:
    work(views[0])
    times = []
    for i in views:
        start = time.perf_counter()
        work(i)
        times.append(time.perf_counter() - start)
    return 1000.0 * statistics.median(times)


def _bare_cast_ms(world: RgbdWorld, rays_per_pixel: int, views: list[int]) -> float:
    """Open3D's cast_rays alone on one image's rays (origins and directions made beforehand)."""
    from slamcli.backends import import_open3d

    o3d = import_open3d()
    vertices, faces = world.scene.mesh()
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(vertices, dtype=np.float32)),
        o3d.core.Tensor.from_numpy(np.ascontiguousarray(faces, dtype=np.uint32)),
    )
    cam = world.camera
    poses = world.trajectory.world_from_body
    rays: dict[int, Any] = {}
    for i in views:
        pose = poses[i]
        u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
        d = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones(u.shape)], -1)
        d = np.repeat((d @ pose[:3, :3].T)[None], rays_per_pixel, axis=0)
        origin = np.broadcast_to(pose[:3, 3], d.shape)
        packed = np.ascontiguousarray(np.concatenate([origin, d], -1), dtype=np.float32)
        rays[i] = o3d.core.Tensor.from_numpy(packed)
    return _median_ms(lambda i: scene.cast_rays(rays[i]), views)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15, help="views timed per row")
    args = parser.parse_args()

    from slamcli.synth.rgbd import build_rgbd_world
    from slamcli.synth.stereo import build_stereo_world

    rows = []
    for size in ((320, 240), (640, 480)):
        world = build_rgbd_world(540, size, seed=0)
        views = np.linspace(0, 539, args.repeat + 1).astype(int).tolist()
        rng = np.random.default_rng(0)

        def view(i: int, w: RgbdWorld = world, g: np.random.Generator = rng) -> object:
            return w.render(w.trajectory.world_from_body[i], g)

        ours = _median_ms(view, views)
        bare = _bare_cast_ms(world, 5, views)
        rows.append((f"synth rgbd {size[0]}x{size[1]}, noise", ours, bare))
    stereo = build_stereo_world(360, (320, 240), seed=0)
    views = np.linspace(0, 359, args.repeat + 1).astype(int).tolist()
    rngs = (np.random.default_rng(1), np.random.default_rng(2))
    ours = _median_ms(lambda i: stereo.render_pair(i, *rngs), views) / 2
    bare = _bare_cast_ms(stereo.room, 4, views)
    rows.append(("synth stereo 320x240, noise (per image)", ours, bare))

    print(f"{'view':42} {'ours ms':>9} {'bare cast ms':>13} {'ratio':>7}")
    for name, ours_ms, bare_ms in rows:
        print(f"{name:42} {ours_ms:9.1f} {bare_ms:13.1f} {ours_ms / bare_ms:7.2f}")


if __name__ == "__main__":
    main()
