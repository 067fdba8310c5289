"""The renderer's compiled shading (``slamcli/synth/_render_kernels.py``) against the plain
numpy shading it replaced, written out here: the same float32 colour, bit for bit, so rendered
sequences (and the runs recorded on them) do not move."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
import pytest

from slamcli.synth import rgbd
from slamcli.synth.rgbd import LIGHT_POSITION, TEXEL_M, RgbdWorld, build_rgbd_world

OFFSETS = ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25))


def _numpy_shade(world: RgbdWorld, rays: np.ndarray, t: np.ndarray, prim: np.ndarray) -> Any:
    """Mean shaded colour (H, W, 3) float32 of rays (K, H, W, 6), as numpy expressions."""
    mips = 5
    table = world._surface_table()
    origin = rays[0, 0, 0, :3]
    d = rays[..., 3:].reshape(-1, 3)
    tt = t.reshape(-1)
    hit = np.isfinite(tt)
    s = np.where(hit, prim.reshape(-1).astype(np.int64) // 2, 0)
    points = origin + np.where(hit, tt, 0.0)[:, None] * d
    rel = points - table["origin"][s]
    a = np.einsum("ij,ij->i", rel, table["u"][s])
    b = np.einsum("ij,ij->i", rel, table["v"][s])
    normal = table["normal"][s]
    d_norm = np.linalg.norm(d, axis=1)
    cos_inc = np.abs(np.einsum("ij,ij->i", d, normal)) / d_norm
    ray_length = np.where(hit, tt, 0.0) * d_norm
    footprint = ray_length / (2.0 * world.camera.fx * np.maximum(cos_inc, 0.2))
    level = np.floor(np.log2(np.maximum(footprint / TEXEL_M, 1e-6)) + 0.5)
    level = np.clip(level, 0, table["levels"][s] - 1).astype(np.int64)
    colours = np.zeros((tt.size, 3), dtype=np.float32)
    for key in np.unique(s[hit] * mips + level[hit]):
        surface, lv = divmod(int(key), mips)
        idx = np.flatnonzero(hit & (s * mips + level == key))
        texel = TEXEL_M * 2.0**lv
        cols = (a[idx] / texel - 0.5).astype(np.float32)
        rows = ((table["size_v"][surface] - b[idx]) / texel - 0.5).astype(np.float32)
        sampled = cv2.remap(
            world.scene.textures[surface][lv],
            cols.reshape(1, -1),
            rows.reshape(1, -1),
            interpolation=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REFLECT_101,
        )
        colours[idx] = sampled.reshape(-1, 3)
    to_light = LIGHT_POSITION.astype(np.float32) - points
    dist2 = np.einsum("ij,ij->i", to_light, to_light)
    lambert = np.abs(np.einsum("ij,ij->i", to_light, normal)) / np.sqrt(dist2)
    shade = 0.45 + 0.75 * lambert / (1.0 + 0.12 * dist2)
    out = (colours * shade[:, None].astype(np.float32)).reshape(*t.shape, 3)
    return out.mean(axis=0)


@pytest.fixture(scope="module")
def world() -> RgbdWorld:
    return build_rgbd_world(540, (80, 60), seed=1)


def _poses(world: RgbdWorld) -> list[np.ndarray]:
    poses = list(world.trajectory.world_from_body[[0, 130, 270, 400]])
    # Close to a wall and looking along it: grazing rays, every mip level, steep footprints.
    grazing = poses[0].copy()
    grazing[:3, 3] = [2.7, -2.2, 0.3]
    grazing[:3, :3] = (
        np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]).T
        @ (cv2.Rodrigues(np.array([0.0, 0.35, 0.0]))[0])
    )
    return [*poses, grazing]


def test_compiled_shading_equals_the_numpy_shading_bit_for_bit(world: RgbdWorld) -> None:
    levels_seen: set[int] = set()
    for pose in _poses(world):
        rays = world._rays(pose, OFFSETS)
        t, prim = world._cast(rays)
        assert np.isfinite(t).mean() > 0.99  # inside the closed room
        want = _numpy_shade(world, rays, t, prim)
        got = world._shade(rays, t, prim)
        assert got.dtype == np.float32 and got.shape == (60, 80, 3)
        np.testing.assert_array_equal(got, want)
        assert np.array_equal(world.render_colour(pose), got)
        depth = t.reshape(-1)
        levels_seen |= set(np.unique(np.floor(np.log2(depth / (2 * world.camera.fx * TEXEL_M)))))
    assert len(levels_seen) >= 2


def test_rays_are_the_float32_camera_centre_and_rotated_pixel_rays(world: RgbdWorld) -> None:
    from slamcli.geometry.camera import unproject

    pose = world.trajectory.world_from_body[55]
    rays = world._rays(pose, OFFSETS)
    cam = world.camera
    uv = np.stack(np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height)), -1)
    for k, offset in enumerate(OFFSETS):
        want = (unproject(cam, uv + offset, 1.0) @ pose[:3, :3].T).astype(np.float32)
        np.testing.assert_array_equal(rays[k, ..., 3:], want)
        centre = np.broadcast_to(pose[:3, 3].astype(np.float32), want.shape)
        np.testing.assert_array_equal(rays[k, ..., :3], centre)
    assert rays.dtype == np.float32


def test_a_render_through_the_kernels_is_what_render_colour_and_cast_give(
    world: RgbdWorld,
) -> None:
    pose = world.trajectory.world_from_body[200]
    rgb, depth = world.render(pose)
    colour = world.render_colour(pose)
    np.testing.assert_array_equal(rgb, np.clip(np.rint(colour), 0, 255).astype(np.uint8))
    z, surface = world.cast(pose)
    inside = (z >= rgbd.MIN_RANGE_M) & (z <= rgbd.MAX_RANGE_M)
    np.testing.assert_array_equal(depth, np.where(inside, z, 0.0).astype(np.float32))
    assert surface.min() >= 0 and surface.max() < len(world.scene.surfaces)
