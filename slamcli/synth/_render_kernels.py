"""Compiled kernels of :mod:`slamcli.synth.rgbd`'s renderer: packing the rays Open3D casts and
shading their hits.

Rendered images (and the committed sample rendered from them) depend on the last bits of the
float32 shading, so its arithmetic is fixed operation by operation, as the numpy expressions it
stands for round it: float32 constants, dot products summed left to right from +0 as
``np.einsum`` sums them, norms as ``np.linalg.norm``, no fused multiply-add. The float64 ray
rotation (a BLAS product) and the log2 of the mip level selection stay numpy's, in the caller.

This module imports numba: import it only where a view is rendered.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]


@numba.njit(cache=True, nogil=True)
def pack_rays(origin: F64, dirs: F64, out: F32) -> None:
    """Fill rays ``out`` (H, W, 6) float32 with a centre (3,) and directions (H, W, 3),
    both float64."""
    for i in range(dirs.shape[0]):
        for j in range(dirs.shape[1]):
            for c in range(3):
                out[i, j, c] = np.float32(origin[c])
                out[i, j, 3 + c] = np.float32(dirs[i, j, c])


@numba.njit(cache=True, nogil=True)
def hit_geometry(
    rays: F32,
    t: F32,
    prim: NDArray[np.uint32],
    origin: F32,
    u_axis: F32,
    v_axis: F32,
    normal: F32,
    light: F32,
    two_fx: np.float32,
    texel: np.float32,
    sid: NDArray[np.int32],
    footprint: F32,
    a: F32,
    b: F32,
    shade: F32,
) -> None:
    """Per ray of rays (N, 6) (world frame) with hit parameter t (N,) on mesh triangle
    prim (N,): surface index ``sid`` (-1 for a miss), footprint in level-0 texels (at
    least 1e-6), hit position ``a``, ``b`` in metres along the surface's u and v axes from
    its origin, and the light factor ``shade``, given the per-surface tables (S, 3), the
    light position (3,), twice the focal length (pixels) and the level-0 texel (metres)."""
    zero = np.float32(0.0)
    min_cos = np.float32(0.2)
    min_footprint = np.float32(1e-6)
    ambient, diffuse, falloff = np.float32(0.45), np.float32(0.75), np.float32(0.12)
    one = np.float32(1.0)
    for i in range(t.shape[0]):
        hit = np.isfinite(t[i])
        s = np.int64(prim[i]) // 2 if hit else 0
        sid[i] = s if hit else -1
        tt = t[i] if hit else zero
        dx, dy, dz = rays[i, 3], rays[i, 4], rays[i, 5]
        px = rays[i, 0] + tt * dx
        py = rays[i, 1] + tt * dy
        pz = rays[i, 2] + tt * dz
        rx, ry, rz = px - origin[s, 0], py - origin[s, 1], pz - origin[s, 2]
        a[i] = zero + rx * u_axis[s, 0] + ry * u_axis[s, 1] + rz * u_axis[s, 2]
        b[i] = zero + rx * v_axis[s, 0] + ry * v_axis[s, 1] + rz * v_axis[s, 2]
        nx, ny, nz = normal[s, 0], normal[s, 1], normal[s, 2]
        d_norm = np.sqrt(dx * dx + dy * dy + dz * dz)
        cos_inc = abs(zero + dx * nx + dy * ny + dz * nz) / d_norm
        # A sub-pixel ray covers half a pixel; its footprint on the surface grows with
        # depth and with the slant of the surface.
        metres = tt * d_norm / (two_fx * (cos_inc if cos_inc >= min_cos else min_cos))
        texels = metres / texel
        footprint[i] = texels if texels >= min_footprint else min_footprint
        lx, ly, lz = light[0] - px, light[1] - py, light[2] - pz
        dist2 = zero + lx * lx + ly * ly + lz * lz
        lambert = abs(zero + lx * nx + ly * ny + lz * nz) / np.sqrt(dist2)
        shade[i] = ambient + diffuse * lambert / (one + falloff * dist2)


@numba.njit(cache=True, nogil=True)
def _mip_level(log2_footprint: np.float32, levels: int) -> int:
    """The mip level of a footprint: its log2 in level-0 texels (float32) rounded, clipped to
    the surface's ``levels`` levels."""
    level = np.floor(log2_footprint + np.float32(0.5))
    top = levels - 1
    return 0 if level < 0 else (top if level > top else int(level))


@numba.njit(cache=True, nogil=True)
def count_keys(
    sid: NDArray[np.int32],
    log2_footprint: F32,
    levels: NDArray[np.int64],
    mips: int,
    counts: NDArray[np.int64],
) -> None:
    """Add to ``counts`` the hit rays per key ``surface * mips + level``, the level being
    the rounded log2 footprint clipped to the surface's mip levels."""
    for i in range(sid.shape[0]):
        s = sid[i]
        if s >= 0:
            counts[s * mips + _mip_level(log2_footprint[i], levels[s])] += 1


@numba.njit(cache=True, nogil=True)
def place_samples(
    sid: NDArray[np.int32],
    log2_footprint: F32,
    a: F32,
    b: F32,
    size_v: F32,
    levels: NDArray[np.int64],
    texels: F32,
    starts: NDArray[np.int64],
    map_x: F32,
    map_y: F32,
    sample: NDArray[np.int32],
) -> None:
    """Write each hit ray's texture coordinates (columns along u, rows down from the edge
    at ``b = size_v``, in texels of its mip level) into ``map_x``, ``map_y`` at the next
    free place of its key's group, which starts at ``starts[key]``, and that place into
    ``sample`` (-1 for a miss)."""
    mips = texels.shape[0]
    half = np.float32(0.5)
    fill = starts.copy()
    for i in range(sid.shape[0]):
        s = sid[i]
        if s < 0:
            sample[i] = -1
            continue
        lv = _mip_level(log2_footprint[i], levels[s])
        k = s * mips + lv
        p = fill[k]
        fill[k] = p + 1
        map_x[p] = a[i] / texels[lv] - half
        map_y[p] = (size_v[s] - b[i]) / texels[lv] - half
        sample[i] = p


@numba.njit(cache=True, nogil=True)
def mean_colour(
    samples: NDArray[np.uint8],
    sample: NDArray[np.int32],
    shade: F32,
    views: int,
    out: F32,
) -> None:
    """Colour ``out`` (M, 3) float32: per pixel, the mean over ``views`` images of M rays
    each of the ray's texture sample (uint8 RGB) times its light factor; a ray without a
    sample is black."""
    m = out.shape[0]
    zero = np.float32(0.0)
    for j in range(m):
        for c in range(3):
            total = zero
            for v in range(views):
                i = v * m + j
                p = sample[i]
                colour = np.float32(samples[p, c]) if p >= 0 else zero
                total = colour * shade[i] if v == 0 else total + colour * shade[i]
            out[j, c] = np.float32(np.float64(total) / views)
