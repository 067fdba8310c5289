"""The room's procedural textures: tiles, posters, checkerboards, stripes, shapes and text
painted over a noisy base colour per kind of surface, at :data:`TEXEL_M` metres per texel, so
feature detectors find corners at every scale from centimetres to half a metre. Everything is
drawn from the generator it is given (and OpenCV's RNG, seeded by the caller), so the same seed
paints the same texels."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

F32 = NDArray[np.float32]

TEXEL_M = 0.005
"""Edge of a texel at the finest mip level."""

_PALETTES: dict[str, tuple[tuple[int, int, int], ...]] = {
    "floor": ((150, 110, 75), (120, 95, 70), (165, 140, 110), (95, 85, 80)),
    "wall": ((215, 210, 195), (190, 205, 215), (220, 200, 180), (200, 215, 195)),
    "ceiling": ((225, 225, 220), (210, 212, 215)),
    "box": ((185, 150, 105), (160, 125, 85), (120, 140, 160), (175, 60, 50)),
}
# Decorations per square metre: (posters/rugs, medium shapes, small shapes, text lines).
_DENSITY: dict[str, tuple[float, float, float, float]] = {
    "floor": (0.5, 10.0, 45.0, 1.0),
    "wall": (1.4, 12.0, 55.0, 3.0),
    "ceiling": (0.3, 5.0, 25.0, 0.5),
    "box": (2.0, 14.0, 60.0, 6.0),
}


def paint_texture(rng: np.random.Generator, rows: int, cols: int, kind: str) -> NDArray[np.uint8]:
    """One surface texture: (rows, cols, 3) uint8 RGB at ``TEXEL_M`` metres per texel."""
    import cv2

    palette = _PALETTES[kind]
    base = np.array(palette[rng.integers(len(palette))], dtype=np.float32)
    coarse = rng.normal(0.0, 14.0, (rows // 48 + 2, cols // 48 + 2, 3)).astype(np.float32)
    img: F32 = base + cv2.resize(coarse, (cols, rows), interpolation=cv2.INTER_CUBIC)
    if kind in ("floor", "ceiling"):
        _tiles(rng, img, 0.6 if kind == "ceiling" else float(rng.uniform(0.3, 0.5)))
    area = rows * cols * TEXEL_M**2
    n_large, n_medium, n_small, n_text = (rng.poisson(d * area) for d in _DENSITY[kind])
    for _ in range(n_large):
        _poster(rng, img)
    for _ in range(n_medium):
        _shape(rng, img, rng.uniform(0.04, 0.15) / TEXEL_M)
    for _ in range(n_small):
        _shape(rng, img, rng.uniform(0.012, 0.04) / TEXEL_M)
    for _ in range(n_text):
        _text(rng, img)
    blurred = cv2.GaussianBlur(img, (0, 0), 0.6)
    return np.clip(np.rint(blurred), 0, 255).astype(np.uint8)


def _colour(rng: np.random.Generator) -> tuple[float, float, float]:
    c = rng.integers(0, 256, 3)
    return float(c[0]), float(c[1]), float(c[2])


def _tiles(rng: np.random.Generator, img: F32, tile_m: float) -> None:
    rows, cols = img.shape[:2]
    step = max(4, round(tile_m / TEXEL_M))
    ny, nx = rows // step + 1, cols // step + 1
    shade = rng.normal(0.0, 12.0, (ny, nx, 1)).astype(np.float32)
    img += np.repeat(np.repeat(shade, step, 0), step, 1)[:rows, :cols]
    grout = np.float32(0.55)
    img[::step] *= grout
    img[1::step] *= grout
    img[:, ::step] *= grout
    img[:, 1::step] *= grout


def _poster(rng: np.random.Generator, img: F32) -> None:
    rows, cols = img.shape[:2]
    h = min(rows - 2, round(rng.uniform(0.15, 0.7) / TEXEL_M))
    w = min(cols - 2, round(rng.uniform(0.15, 0.8) / TEXEL_M))
    if h < 4 or w < 4:
        return
    r0, c0 = int(rng.integers(0, rows - h)), int(rng.integers(0, cols - w))
    patch = img[r0 : r0 + h, c0 : c0 + w]
    style = rng.integers(3)
    if style == 0:
        cell = max(2, round(rng.uniform(0.015, 0.08) / TEXEL_M))
        ii, jj = np.indices((h, w))
        parity = ((ii // cell + jj // cell) % 2).astype(bool)
        patch[...] = _colour(rng)
        patch[parity] = _colour(rng)
    elif style == 1:
        width = max(2, round(rng.uniform(0.01, 0.05) / TEXEL_M))
        ii, jj = np.indices((h, w))
        diagonal = rng.integers(2) == 1
        band = ((ii + jj) if diagonal else jj) // width % 2 == 1
        patch[...] = _colour(rng)
        patch[band] = _colour(rng)
    else:
        patch[...] = _colour(rng)
        for _ in range(int(rng.integers(4, 12))):
            _shape(rng, patch, rng.uniform(0.2, 0.5) * min(h, w))
    frame = max(1, round(0.01 / TEXEL_M))
    dark = np.float32(0.3)
    img[r0 : r0 + frame, c0 : c0 + w] *= dark
    img[r0 + h - frame : r0 + h, c0 : c0 + w] *= dark
    img[r0 : r0 + h, c0 : c0 + frame] *= dark
    img[r0 : r0 + h, c0 + w - frame : c0 + w] *= dark


def _shape(rng: np.random.Generator, img: F32, size_px: float) -> None:
    import cv2

    rows, cols = img.shape[:2]
    size = max(2.0, float(size_px))
    cx, cy = rng.uniform(0, cols), rng.uniform(0, rows)
    colour = _colour(rng)
    kind = rng.integers(4)
    if kind == 0:
        angle = rng.uniform(0, np.pi)
        half = np.array([size, size * rng.uniform(0.3, 1.0)]) / 2
        c, s = math.cos(angle), math.sin(angle)
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        pts = local @ np.array([[c, s], [-s, c]]) + [cx, cy]
        cv2.fillPoly(img, [np.rint(pts).astype(np.int32)], colour, cv2.LINE_AA)
    elif kind == 1:
        n = int(rng.integers(3, 7))
        angles = np.sort(rng.uniform(0, 2 * np.pi, n))
        radii = size / 2 * rng.uniform(0.5, 1.0, n)
        pts = np.stack([cx + radii * np.cos(angles), cy + radii * np.sin(angles)], axis=1)
        cv2.fillPoly(img, [np.rint(pts).astype(np.int32)], colour, cv2.LINE_AA)
    elif kind == 2:
        radius = max(1, round(size / 2))
        cv2.circle(img, (round(cx), round(cy)), radius, colour, -1, cv2.LINE_AA)
    else:
        thick = max(1, round(size * rng.uniform(0.08, 0.2)))
        angle = rng.uniform(0, np.pi)
        dx, dy = size / 2 * math.cos(angle), size / 2 * math.sin(angle)
        p0, p1 = (round(cx - dx), round(cy - dy)), (round(cx + dx), round(cy + dy))
        cv2.line(img, p0, p1, colour, thick, cv2.LINE_AA)
        if rng.integers(2):
            p2, p3 = (round(cx + dy), round(cy - dx)), (round(cx - dy), round(cy + dx))
            cv2.line(img, p2, p3, colour, thick, cv2.LINE_AA)


_LETTERS = np.array(list("ABCDEFGHJKLMNPQRSTUVWXYZ0123456789#+="))


def _text(rng: np.random.Generator, img: F32) -> None:
    import cv2

    rows, cols = img.shape[:2]
    height_px = rng.uniform(0.025, 0.09) / TEXEL_M
    scale = height_px / 22.0
    text = "".join(rng.choice(_LETTERS, int(rng.integers(3, 9))))
    thickness = max(1, round(scale * 2))
    colour = np.array(_colour(rng), dtype=np.float32)
    (w, h), baseline = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thickness)
    h += baseline + thickness
    w += thickness
    if w >= cols or h >= rows:
        return
    r0, c0 = int(rng.integers(0, rows - h)), int(rng.integers(0, cols - w))
    # putText draws only on 8-bit images: render coverage, then blend the colour by it.
    alpha = np.zeros((h, w), dtype=np.uint8)
    org = (thickness // 2, h - baseline - thickness // 2)
    cv2.putText(alpha, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, 255, thickness, cv2.LINE_AA)
    a = (alpha.astype(np.float32) / 255.0)[..., None]
    patch = img[r0 : r0 + h, c0 : c0 + w]
    patch[...] = patch * (1.0 - a) + colour * a
