"""Scan matching on a likelihood field: branch-and-bound correlative search, then refinement.

:func:`search` is the correlative matcher of Olson (2009) and Cartographer: every pose of a
window, on a grid of angles and cell offsets, is scored by the mean likelihood of the scan's
points, and the best is found exactly by branch and bound over a pyramid of max-pooled fields
(a pooled value bounds every offset it covers, so a branch whose bound is below the best score
found is dropped). The same search serves the local matcher (a small window around the motion
prior) and loop closure (a wide window around a submap). :func:`refine` then moves the pose
continuously (Gauss-Newton on the bilinear field, Hector's and Cartographer's Ceres matcher's
cost), held near the search's answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry.planar import transform_points_planar
from slamcli.scans.grid import Field

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I64 = NDArray[np.int64]


class Pyramid:
    """Max-pooled copies of a field: level ``k`` holds at each cell the largest value of the
    ``2**k`` by ``2**k`` cells starting there (rows and columns up)."""

    def __init__(self, field: Field, depth: int) -> None:
        import cv2

        self.field = field
        self.levels: list[F32] = [field.values]
        for k in range(1, depth + 1):
            size = 1 << k
            kernel = np.ones((size, size), dtype=np.uint8)
            pooled = cv2.dilate(
                field.values,
                kernel,
                anchor=(0, 0),
                borderType=cv2.BORDER_CONSTANT,
                borderValue=0,
            )
            self.levels.append(np.asarray(pooled, dtype=np.float32))

    @property
    def depth(self) -> int:
        return len(self.levels) - 1


@dataclass(frozen=True)
class Match:
    """A scan's pose found by :func:`search` or :func:`refine`, and its score (mean likelihood
    of the scan's points, 0 to 1)."""

    pose: F64
    score: float


def angular_step(points: F64, resolution: float) -> float:
    """The angle step at which the scan's far points (95th percentile range) move one cell."""
    if not len(points):
        return 0.01
    reach = float(np.percentile(np.hypot(points[:, 0], points[:, 1]), 95))
    reach = max(reach, 4 * resolution)
    return math.acos(max(-1.0, 1.0 - resolution * resolution / (2.0 * reach * reach)))


def _cut(level: F32, r0: int, c0: int, rows: int, cols: int) -> F32:
    """``level[r0:r0+rows, c0:c0+cols]`` with zeros where that reaches past the array."""
    out = np.zeros((rows, cols), dtype=np.float32)
    h, w = level.shape
    a0, b0 = max(r0, 0), max(c0, 0)
    a1, b1 = min(r0 + rows, h), min(c0 + cols, w)
    if a1 > a0 and b1 > b0:
        out[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0] = level[a0:a1, b0:b1]
    return out


def _scores(flat: F32, base: I64, shift: I64) -> F64:
    """Mean of ``flat`` over each candidate's points: ``base`` (C, N) the flat cells of the
    points at the candidate's angle, ``shift`` (C,) the candidate's offset in flat cells."""
    return np.asarray(flat[base + shift[:, None]].mean(axis=1, dtype=np.float64))


def _children(a: I64, i: I64, j: I64, half: int, span: int) -> tuple[I64, I64, I64]:
    """The four sub-windows of each candidate (those starting inside the window)."""
    ca = np.repeat(a, 4)
    ci = (i[:, None] + np.array([0, 0, half, half])).ravel()
    cj = (j[:, None] + np.array([0, half, 0, half])).ravel()
    keep = (ci < span) & (cj < span)
    return ca[keep], ci[keep], cj[keep]


def search(
    pyramid: Pyramid,
    points: F64,
    guess: F64,
    linear_window_m: float,
    angular_window_rad: float,
    min_score: float = 0.0,
) -> Match | None:
    """The best pose of ``points`` (N, 2, body frame) within the window around ``guess``
    (x, y, yaw), or None when no pose scores above ``min_score``.

    Exact over the window's grid of poses (angles one far-point cell apart, offsets one cell
    apart): a greedy descent from the best top-level candidate gives a first score to beat,
    then each level keeps only the candidates whose bound beats it, evaluated together.
    """
    if not len(points):
        return None
    field = pyramid.field
    res = field.resolution
    step = angular_step(points, res)
    n_ang = math.ceil(angular_window_rad / step)
    angles = guess[2] + step * np.arange(-n_ang, n_ang + 1)
    n_lin = math.ceil(linear_window_m / res)
    c, s = np.cos(angles)[:, None], np.sin(angles)[:, None]
    wx = c * points[:, 0] - s * points[:, 1] + guess[0]
    wy = s * points[:, 0] + c * points[:, 1] + guess[1]
    # Cells of every point at every angle, for the window's lowest offset (-n_lin, -n_lin),
    # relative to a cut of the levels that holds every cell the search reads.
    cols = np.floor((wx - field.origin[0]) / res).astype(np.int64) - n_lin
    rows = np.floor((wy - field.origin[1]) / res).astype(np.int64) - n_lin
    span = 2 * n_lin + 1
    r0, c0 = int(rows.min()), int(cols.min())
    height = int(rows.max()) - r0 + span
    width = int(cols.max()) - c0 + span
    base = (rows - r0) * width + (cols - c0)
    flats = [_cut(level, r0, c0, height, width).ravel() for level in pyramid.levels]
    depth = pyramid.depth
    top = 1 << depth
    offsets = np.arange(0, span, top)
    ai, oi, oj = np.meshgrid(np.arange(len(angles)), offsets, offsets, indexing="ij")
    a, i, j = ai.ravel(), oi.ravel(), oj.ravel()
    bound = _scores(flats[depth], base[a], i * width + j)
    best_score = float(min_score)
    best: tuple[int, int, int] | None = None
    # A first answer: from the best top candidate, the best child at each level down.
    k = int(np.argmax(bound))
    da, di, dj = a[k : k + 1], i[k : k + 1], j[k : k + 1]
    for level in range(depth, 0, -1):
        da, di, dj = _children(da, di, dj, 1 << (level - 1), span)
        sc = _scores(flats[level - 1], base[da], di * width + dj)
        k = int(np.argmax(sc))
        da, di, dj = da[k : k + 1], di[k : k + 1], dj[k : k + 1]
        if level == 1 and sc[k] > best_score:
            best_score, best = float(sc[k]), (int(da[0]), int(di[0]), int(dj[0]))
    # Then every branch whose bound beats it, level by level.
    for level in range(depth, 0, -1):
        keep = bound > best_score
        a, i, j = _children(a[keep], i[keep], j[keep], 1 << (level - 1), span)
        if not len(a):
            break
        bound = _scores(flats[level - 1], base[a], i * width + j)
    else:
        if len(bound):
            k = int(np.argmax(bound))
            if bound[k] > best_score:
                best_score, best = float(bound[k]), (int(a[k]), int(i[k]), int(j[k]))
    if depth == 0 and len(bound):
        k = int(np.argmax(bound))
        if bound[k] > best_score:
            best_score, best = float(bound[k]), (int(a[k]), int(i[k]), int(j[k]))
    if best is None:
        return None
    ba, bi, bj = best
    pose = np.array([guess[0] + (bj - n_lin) * res, guess[1] + (bi - n_lin) * res, angles[ba]])
    return Match(pose, best_score)


def refine(
    field: Field,
    points: F64,
    start: F64,
    target: F64 | None = None,
    translation_weight: float = 1.0,
    rotation_weight: float = 1.0,
    iterations: int = 10,
) -> Match:
    """``start`` moved continuously to fit ``points`` (N, 2, body frame) to the field.

    Minimises ``sum (1 - F(T p))^2 / N + tw |t - t0|^2 + rw (yaw - yaw0)^2`` (metres,
    radians) by Gauss-Newton, ``T`` the pose, ``F`` the bilinear field and ``(t0, yaw0)`` the
    ``target`` (the motion prior; ``start`` when None). The prior terms decide where the field
    cannot (along a featureless corridor); elsewhere the points do.
    """
    pose = np.asarray(start, dtype=np.float64).copy()
    anchor = pose.copy() if target is None else np.asarray(target, dtype=np.float64)
    if not len(points):
        return Match(pose, 0.0)
    n = len(points)
    w_t = translation_weight
    for _ in range(iterations):
        world = transform_points_planar(pose, points)
        value, grad = field.sample(world)
        c, s = math.cos(pose[2]), math.sin(pose[2])
        # d(world)/d(yaw) = R' p
        dyaw = np.stack(
            [-s * points[:, 0] - c * points[:, 1], c * points[:, 0] - s * points[:, 1]], axis=1
        )
        jac = np.empty((n, 3))
        jac[:, :2] = -grad
        jac[:, 2] = -np.einsum("ij,ij->i", grad, dyaw)
        resid = 1.0 - value
        h = jac.T @ jac / n
        g = jac.T @ resid / n
        dt = pose - anchor
        dt[2] = (dt[2] + math.pi) % (2 * math.pi) - math.pi
        h[0, 0] += w_t
        h[1, 1] += w_t
        h[2, 2] += rotation_weight
        g[0] += w_t * dt[0]
        g[1] += w_t * dt[1]
        g[2] += rotation_weight * dt[2]
        try:
            delta = -np.linalg.solve(h, g)
        except np.linalg.LinAlgError:
            break
        pose = pose + delta
        if abs(delta[0]) < 1e-5 and abs(delta[1]) < 1e-5 and abs(delta[2]) < 1e-6:
            break
    value, _ = field.sample(transform_points_planar(pose, points))
    return Match(pose, float(value.mean()))


def fit_score(field: Field, points: F64, pose: F64) -> float:
    """The mean bilinear likelihood of the points at ``pose`` (what :func:`refine` scores)."""
    if not len(points):
        return 0.0
    value, _ = field.sample(transform_points_planar(pose, points))
    return float(value.mean())


def fit_fraction(field: Field, points: F64, pose: F64, threshold: float = 0.5) -> float:
    """The fraction of the points whose likelihood at ``pose`` is at least ``threshold``."""
    if not len(points):
        return 0.0
    value, _ = field.sample(transform_points_planar(pose, points))
    return float(np.mean(value >= threshold))
