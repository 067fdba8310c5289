"""Shortest paths of a car with a minimum turning radius: Reeds-Shepp and Dubins curves.

A car at pose ``(x, y, yaw)`` (metres, metres, radians, in any fixed world frame) drives arcs
of radius ``R`` (the minimum turning radius) and straight lines. A *curve* is a word of at most
five segments, each a left arc ``L``, a straight line ``S`` or a right arc ``R``, with a signed
length in metres: negative means driving in reverse.

- **Reeds-Shepp** (forward and reverse): the shortest of the 48 words of Reeds & Shepp (1990),
  "Optimal paths for a car that goes both forwards and backwards". Eight base formulas (the
  paper's 8.1-8.4 and 8.7-8.11: CSC twice, CCC, CCCC twice, CCSC twice, CCSCC) are solved for
  the goal as given and under the paper's symmetries: *timeflip* (drive the word backwards in
  time: ``(x, y, phi) -> (-x, y, -phi)``, lengths negated), *reflect* (mirror in the x axis:
  ``(x, y, phi) -> (x, -y, -phi)``, L and R swapped) and, for CCC and CCSC, *backwards* (the
  word read from the goal: segments in reverse order).
- **Dubins** (forward only): the shortest of LSL, RSR, LSR, RSL, RLR and LRL (Dubins 1957).

Compiled kernels (numba, ``cache=True``; the first call in a fresh environment compiles them,
later processes load them from the on-disk cache). They take and return plain floats, so other
``@njit`` code (a lattice search's heuristic, for instance) calls them directly:

- :func:`rs_length` and :func:`dubins_length`: the length in metres of the shortest curve;
- :func:`rs_segments` and :func:`dubins_segments`: its segments as ``kinds`` (int8: ``+1`` left,
  ``0`` straight, ``-1`` right, the sign of the curvature) and signed ``lengths`` (metres).

The kernels do not validate their input (a radius <= 0 or a NaN gives a meaningless result);
the Python API (:func:`shortest_curve`, :func:`sample_curve`) checks it and raises
:class:`~slamcli.errors.ConfigError`.

Rounding noise is handled explicitly: segment signs are checked up to 1e-10 (radians, or
turning radii for straights), and segments shorter than 1e-10 turning radii are left out of a
word, so a curve never holds a sliver or a zero-length segment (nor the spurious gear change a
``-1e-14`` or a ``-0.0`` would imply). The same pose gives an empty word of length 0.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ConfigError

__all__ = [
    "LEFT",
    "RIGHT",
    "STRAIGHT",
    "Curve",
    "dubins_length",
    "dubins_segments",
    "rs_length",
    "rs_segments",
    "sample_curve",
    "shortest_curve",
]

LEFT = 1
"""Kind code of a left arc (curvature ``+1/R``)."""
STRAIGHT = 0
"""Kind code of a straight segment."""
RIGHT = -1
"""Kind code of a right arc (curvature ``-1/R``)."""

_KIND_NAMES = {LEFT: "L", STRAIGHT: "S", RIGHT: "R"}
_KIND_CODES = {name: code for code, name in _KIND_NAMES.items()}

_PI = math.pi
_TWO_PI = 2.0 * math.pi
_HALF_PI = 0.5 * math.pi
_TOL = 1e-10
"""Rounding-noise level of the kernels, in radians and turning radii.

A word whose segments have the right signs up to ``_TOL`` is valid (the local frame's rounding
alone can tilt a straight-ahead goal by ~1e-14 / distance radians, which a tighter test would
reject, leaving a longer word as the "shortest"); segments shorter than ``_TOL`` are dropped
from the result (so no gear change of that size appears); a Dubins arc within ``_TOL`` of a
full turn is a zero arc that rounding wrapped. The end of a curve can so move by a few
``_TOL`` turning radii.
"""

# Reeds-Shepp base formulas, in the order they are tried.
_RS_LSL = 0  # 8.1   L+ S+ L+
_RS_LSR = 1  # 8.2   L+ S+ R+
_RS_LRL = 2  # 8.3   L+ R- L (C|C|C and C|CC; CC|C by reading it backwards)
_RS_LRLR_A = 3  # 8.7   L+ R+u L-u R-
_RS_LRLR_B = 4  # 8.8   L+ R-u L-u R+
_RS_LRSL = 5  # 8.9   L+ R-(pi/2) S- L-
_RS_LRSR = 6  # 8.10  L+ R-(pi/2) S- R-
_RS_LRSLR = 7  # 8.11  L+ R-(pi/2) S- L-(pi/2) R+

# Each base word in its left-first, forward-in-time form (0-padded to five segments).
_RS_KINDS = np.array(
    [
        [LEFT, STRAIGHT, LEFT, 0, 0],
        [LEFT, STRAIGHT, RIGHT, 0, 0],
        [LEFT, RIGHT, LEFT, 0, 0],
        [LEFT, RIGHT, LEFT, RIGHT, 0],
        [LEFT, RIGHT, LEFT, RIGHT, 0],
        [LEFT, RIGHT, STRAIGHT, LEFT, 0],
        [LEFT, RIGHT, STRAIGHT, RIGHT, 0],
        [LEFT, RIGHT, STRAIGHT, LEFT, RIGHT],
    ],
    dtype=np.int8,
)
_RS_SIZES = np.array([3, 3, 3, 4, 4, 4, 4, 5], dtype=np.int64)

# Dubins words.
_DUBINS_KINDS = np.array(
    [
        [LEFT, STRAIGHT, LEFT],
        [RIGHT, STRAIGHT, RIGHT],
        [LEFT, STRAIGHT, RIGHT],
        [RIGHT, STRAIGHT, LEFT],
        [RIGHT, LEFT, RIGHT],
        [LEFT, RIGHT, LEFT],
    ],
    dtype=np.int8,
)


# ----------------------------------------------------------------------------- shared helpers


@numba.njit(cache=True, nogil=True)
def _wrap(a: float) -> float:
    """``a`` wrapped to [-pi, pi] (radians)."""
    v = a
    if v > _PI or v < -_PI:
        # The kernels wrap sums of a few angles; only a far-off input needs the division.
        if abs(v) > 4.0 * _TWO_PI:
            v = np.fmod(v, _TWO_PI)
        while v > _PI:
            v -= _TWO_PI
        while v < -_PI:
            v += _TWO_PI
    return v


@numba.njit(cache=True, nogil=True)
def _wrap_positive(a: float) -> float:
    """``a`` wrapped to [0, 2 pi) (radians); a value a rounding error short of 2 pi is 0."""
    v = a - _TWO_PI * math.floor(a / _TWO_PI)
    if v >= _TWO_PI - _TOL:
        v = 0.0
    return v


@numba.njit(cache=True, nogil=True)
def _to_local(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> tuple[float, float, float]:
    """The goal in the start's body frame, in turning radii; heading change wrapped to [-pi, pi]."""
    dx = x1 - x0
    dy = y1 - y0
    c = math.cos(yaw0)
    s = math.sin(yaw0)
    return (c * dx + s * dy) / radius, (-s * dx + c * dy) / radius, _wrap(yaw1 - yaw0)


# ----------------------------------------------------------------------------- Reeds-Shepp


@numba.njit(cache=True, nogil=True)
def _tau_omega(u: float, v: float, xi: float, eta: float, phi: float) -> tuple[float, float]:
    """First and last arc of the CCCC words given the middle arcs ``u``, ``v`` (paper, 8.6)."""
    delta = _wrap(u - v)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = _wrap(t1 + _PI) if t2 < 0.0 else _wrap(t1)
    return tau, _wrap(tau - u + v - phi)


@numba.njit(cache=True, nogil=True)
def _centre_same(x: float, y: float, sphi: float, cphi: float) -> tuple[float, float]:
    """Goal's left-circle centre seen from the start's left-circle centre (turning radii)."""
    return x - sphi, y - 1.0 + cphi


@numba.njit(cache=True, nogil=True)
def _centre_opposite(x: float, y: float, sphi: float, cphi: float) -> tuple[float, float]:
    """Goal's right-circle centre seen from the start's left-circle centre (turning radii)."""
    return x + sphi, y - 1.0 - cphi


# Each base formula solves its word for the goal (x, y, phi) in the start's frame in turning
# radii (phi in [-pi, pi]), given sin(phi) and cos(phi), and returns (valid, t, u, v), the
# word's free parameters. A word that cannot be shorter than ``bound`` (turning radii) is
# reported invalid as soon as its middle segments show it, before the costly trigonometry: its
# first and last arcs t, v together turn at least |phi - (turn of the middle)| wrapped to
# [-pi, pi], so the middle segments plus that are a lower bound on its length.

_INVALID = (False, 0.0, 0.0, 0.0)


@numba.njit(cache=True, nogil=True)
def _rs_lsl(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.1, L+ S+ L+."""
    xi, eta = _centre_same(x, y, sphi, cphi)
    u = math.sqrt(xi * xi + eta * eta)
    if u + abs(phi) >= bound:
        return _INVALID
    t = math.atan2(eta, xi)
    v = _wrap(phi - t)
    return t >= -_TOL and v >= -_TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lsr(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.2, L+ S+ R+."""
    xi, eta = _centre_opposite(x, y, sphi, cphi)
    r2 = xi * xi + eta * eta
    if r2 < 4.0:
        return _INVALID
    u = math.sqrt(r2 - 4.0)
    if u + abs(phi) >= bound:
        return _INVALID
    t = _wrap(math.atan2(eta, xi) + math.atan2(2.0, u))
    v = _wrap(t - phi)
    return t >= -_TOL and v >= -_TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrl(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formulas 8.3/8.4, L+ R- L (the paper's typo corrected)."""
    xi, eta = _centre_same(x, y, sphi, cphi)
    r = math.sqrt(xi * xi + eta * eta)
    if r > 4.0:
        return _INVALID
    u = -2.0 * math.asin(0.25 * r)
    if -u + abs(_wrap(phi + u)) >= bound:
        return _INVALID
    t = _wrap(math.atan2(eta, xi) + 0.5 * u + _PI)
    v = _wrap(phi - t + u)
    return t >= -_TOL and u <= _TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrlr_a(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.7, L+ R+u L-u R-."""
    xi, eta = _centre_opposite(x, y, sphi, cphi)
    rho = 0.25 * (2.0 + math.sqrt(xi * xi + eta * eta))
    if rho > 1.0:
        return _INVALID
    u = math.acos(rho)
    if 2.0 * u + abs(_wrap(phi + 2.0 * u)) >= bound:
        return _INVALID
    t, v = _tau_omega(u, -u, xi, eta, phi)
    return t >= -_TOL and v <= _TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrlr_b(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.8, L+ R-u L-u R+."""
    xi, eta = _centre_opposite(x, y, sphi, cphi)
    rho = (20.0 - xi * xi - eta * eta) / 16.0
    if rho < 0.0 or rho > 1.0:
        return _INVALID
    u = -math.acos(rho)
    if u < -_HALF_PI or -2.0 * u + abs(phi) >= bound:
        return _INVALID
    t, v = _tau_omega(u, u, xi, eta, phi)
    return t >= -_TOL and v >= -_TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrsl(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.9, L+ R-(pi/2) S- L-."""
    xi, eta = _centre_same(x, y, sphi, cphi)
    rho = math.sqrt(xi * xi + eta * eta)
    if rho < 2.0:
        return _INVALID
    r = math.sqrt(rho * rho - 4.0)
    u = 2.0 - r
    if abs(u) + _HALF_PI + abs(_wrap(phi - _HALF_PI)) >= bound:
        return _INVALID
    t = _wrap(math.atan2(eta, xi) + math.atan2(r, -2.0))
    v = _wrap(phi - _HALF_PI - t)
    return t >= -_TOL and u <= _TOL and v <= _TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrsr(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.10, L+ R-(pi/2) S- R-."""
    xi, eta = _centre_opposite(x, y, sphi, cphi)
    rho = math.sqrt(eta * eta + xi * xi)
    if rho < 2.0:
        return _INVALID
    u = 2.0 - rho
    if abs(u) + _HALF_PI + abs(_wrap(phi - _HALF_PI)) >= bound:
        return _INVALID
    t = math.atan2(xi, -eta)
    v = _wrap(t + _HALF_PI - phi)
    return t >= -_TOL and u <= _TOL and v <= _TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_lrslr(
    x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Formula 8.11, L+ R-(pi/2) S- L-(pi/2) R+ (the paper's typo corrected)."""
    xi, eta = _centre_opposite(x, y, sphi, cphi)
    rho = math.sqrt(xi * xi + eta * eta)
    if rho < 2.0:
        return _INVALID
    u = 4.0 - math.sqrt(rho * rho - 4.0)
    if u > _TOL or abs(u) + _PI + abs(phi) >= bound:
        return _INVALID
    t = _wrap(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta))
    v = _wrap(t - phi)
    return t >= -_TOL and v >= -_TOL, t, u, v


@numba.njit(cache=True, nogil=True)
def _rs_word_length(f: int, t: float, u: float, v: float) -> float:
    """Total length (turning radii) of base word ``f`` with parameters ``t``, ``u``, ``v``."""
    if f in (_RS_LRLR_A, _RS_LRLR_B):
        return abs(t) + 2.0 * abs(u) + abs(v)
    base = abs(t) + abs(u) + abs(v)
    if f in (_RS_LRSL, _RS_LRSR):
        return base + _HALF_PI
    if f == _RS_LRSLR:
        return base + _PI
    return base


_Best = tuple[float, int, int, float, float, float]


@numba.njit(cache=True, nogil=True, inline="always")
def _rs_formula(
    f: int, x: float, y: float, phi: float, sphi: float, cphi: float, bound: float
) -> tuple[bool, float, float, float]:
    """Base formula ``f`` (``_RS_*``); inlined where ``f`` is a constant, so it folds away."""
    if f == _RS_LSL:
        return _rs_lsl(x, y, phi, sphi, cphi, bound)
    if f == _RS_LSR:
        return _rs_lsr(x, y, phi, sphi, cphi, bound)
    if f == _RS_LRL:
        return _rs_lrl(x, y, phi, sphi, cphi, bound)
    if f == _RS_LRLR_A:
        return _rs_lrlr_a(x, y, phi, sphi, cphi, bound)
    if f == _RS_LRLR_B:
        return _rs_lrlr_b(x, y, phi, sphi, cphi, bound)
    if f == _RS_LRSL:
        return _rs_lrsl(x, y, phi, sphi, cphi, bound)
    if f == _RS_LRSR:
        return _rs_lrsr(x, y, phi, sphi, cphi, bound)
    return _rs_lrslr(x, y, phi, sphi, cphi, bound)


@numba.njit(cache=True, nogil=True, inline="always")
def _rs_try(
    f: int,
    backwards: int,
    x: float,
    y: float,
    phi: float,
    sphi: float,
    cphi: float,
    best: _Best,
) -> _Best:
    """``best`` improved by base formula ``f`` under timeflip and reflection; ``backwards``
    (0 or 1) is recorded in the variant bits."""
    for sym in range(4):
        timeflip = sym & 1
        reflect = sym >> 1
        flip = timeflip != reflect
        ok, t, u, v = _rs_formula(
            f,
            -x if timeflip else x,
            -y if reflect else y,
            -phi if flip else phi,
            -sphi if flip else sphi,
            cphi,
            best[0],
        )
        if ok:
            length = _rs_word_length(f, t, u, v)
            if length < best[0]:
                best = (length, f, sym + 4 * backwards, t, u, v)
    return best


@numba.njit(cache=True, nogil=True)
def _rs_solve(x: float, y: float, phi: float) -> _Best:
    """Shortest Reeds-Shepp word to ``(x, y, phi)`` (start at the origin, unit radius).

    Returns ``(length, formula, variant, t, u, v)``; ``variant`` bits: 1 timeflip,
    2 reflect, 4 backwards (the word read from the goal, for CCC and CCSC).
    """
    s = math.sin(phi)
    c = math.cos(phi)
    xb = x * c + y * s
    yb = x * s - y * c
    best = (np.inf, -1, 0, 0.0, 0.0, 0.0)
    best = _rs_try(_RS_LSL, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LSR, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRL, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRL, 1, xb, yb, phi, s, c, best)
    best = _rs_try(_RS_LRLR_A, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRLR_B, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRSL, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRSL, 1, xb, yb, phi, s, c, best)
    best = _rs_try(_RS_LRSR, 0, x, y, phi, s, c, best)
    best = _rs_try(_RS_LRSR, 1, xb, yb, phi, s, c, best)
    return _rs_try(_RS_LRSLR, 0, x, y, phi, s, c, best)


@numba.njit(cache=True, nogil=True)
def rs_length(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> float:
    """Length (m) of the shortest Reeds-Shepp curve from pose 0 to pose 1.

    Poses are ``(x, y, yaw)`` in metres and radians in one world frame; ``radius`` is the
    minimum turning radius in metres (> 0, unchecked). Compiled with numba: callable from
    other ``@njit`` functions (and, more slowly, from Python).
    """
    x, y, phi = _to_local(x0, y0, yaw0, x1, y1, yaw1, radius)
    return _rs_solve(x, y, phi)[0] * radius


@numba.njit(cache=True, nogil=True)
def rs_segments(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> tuple[NDArray[np.int8], NDArray[np.float64]]:
    """Segments of the shortest Reeds-Shepp curve from pose 0 to pose 1 (see :func:`rs_length`).

    Returns ``kinds`` (n,) int8 (``+1`` left, ``0`` straight, ``-1`` right) and ``lengths``
    (n,) float64, signed metres (negative = reverse), ``n <= 5``, in driving order. Their
    absolute lengths add up to :func:`rs_length` but for the segments shorter than
    ``1e-10 * radius``, which are left out (the same pose gives ``n = 0``).
    """
    x, y, phi = _to_local(x0, y0, yaw0, x1, y1, yaw1, radius)
    _, f, variant, t, u, v = _rs_solve(x, y, phi)
    if f < 0:  # no word: only a NaN input gets here
        return np.empty(0, dtype=np.int8), np.empty(0, dtype=np.float64)
    n = _RS_SIZES[f]
    word = np.empty(5, dtype=np.float64)
    word[0] = t
    if f == _RS_LRLR_A:
        word[1] = u
        word[2] = -u
        word[3] = v
    elif f == _RS_LRLR_B:
        word[1] = u
        word[2] = u
        word[3] = v
    elif f in (_RS_LRSL, _RS_LRSR):
        word[1] = -_HALF_PI
        word[2] = u
        word[3] = v
    elif f == _RS_LRSLR:
        word[1] = -_HALF_PI
        word[2] = u
        word[3] = -_HALF_PI
        word[4] = v
    else:
        word[1] = u
        word[2] = v
    sign = -1.0 if variant & 1 else 1.0
    mirror = -1 if variant & 2 else 1
    kinds = np.empty(5, dtype=np.int8)
    lengths = np.empty(5, dtype=np.float64)
    m = 0
    for i in range(n):
        j = n - 1 - i if variant & 4 else i
        if abs(word[j]) > _TOL:
            kinds[m] = mirror * _RS_KINDS[f, j]
            lengths[m] = sign * word[j] * radius
            m += 1
    return kinds[:m].copy(), lengths[:m].copy()


# ----------------------------------------------------------------------------- Dubins
# The goal frame of Dubins' formulas: start at the origin, goal at (d, 0), unit radius;
# ``a`` and ``b`` are the start and goal headings relative to the line from start to goal.


@numba.njit(cache=True, nogil=True)
def _dubins_word(
    w: int, d: float, a: float, b: float, sa: float, ca: float, sb: float, cb: float
) -> tuple[bool, float, float, float]:
    """Word ``w`` (row of ``_DUBINS_KINDS``) to the goal; ``(valid, t, p, q)``, all >= 0.

    ``sa, ca, sb, cb`` are the sines and cosines of ``a`` and ``b``.
    """
    if w == 0 or w == 1:
        # Same-side circles: the outer tangent, parallel to the line between the centres.
        if w == 0:
            vx = d + sa - sb
            vy = cb - ca
        else:
            vx = d - sa + sb
            vy = ca - cb
        p = math.sqrt(vx * vx + vy * vy)
        # Coincident circles: the heading of the straight is arbitrary; take the start's.
        theta = math.atan2(vy, vx) if p > _TOL else a
        if w == 0:
            return True, _wrap_positive(theta - a), p, _wrap_positive(b - theta)
        return True, _wrap_positive(a - theta), p, _wrap_positive(theta - b)
    if w == 2 or w == 3:
        # Opposite-side circles: the inner tangent, which needs the centres >= 2 apart.
        if w == 2:
            vx = d + sa + sb
            vy = -ca - cb
        else:
            vx = d - sa - sb
            vy = ca + cb
        p2 = vx * vx + vy * vy - 4.0
        if p2 < 0.0:
            return False, 0.0, 0.0, 0.0
        p = math.sqrt(p2)
        if w == 2:
            theta = math.atan2(vy, vx) - math.atan2(-2.0, p)
            return True, _wrap_positive(theta - a), p, _wrap_positive(theta - b)
        theta = math.atan2(vy, vx) - math.atan2(2.0, p)
        return True, _wrap_positive(a - theta), p, _wrap_positive(b - theta)
    # CCC: a middle circle touching both end circles, whose centres must be <= 4 apart.
    if w == 4:
        vx = d - sa + sb
        vy = ca - cb
    else:
        vx = d + sa - sb
        vy = cb - ca
    c = 1.0 - (vx * vx + vy * vy) / 8.0
    if c < -1.0:
        return False, 0.0, 0.0, 0.0
    p = _TWO_PI - math.acos(min(c, 1.0))
    theta = math.atan2(vy, vx)
    if w == 4:
        t = _wrap_positive(a - theta + 0.5 * p)
        return True, t, p, _wrap_positive(a - b - t + p)
    t = _wrap_positive(theta - a + 0.5 * p)
    return True, t, p, _wrap_positive(b - a - t + p)


@numba.njit(cache=True, nogil=True)
def _dubins_solve(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> tuple[float, int, float, float, float]:
    """Shortest Dubins word: ``(length in radii, word, t, p, q)``."""
    dx = (x1 - x0) / radius
    dy = (y1 - y0) / radius
    d = math.sqrt(dx * dx + dy * dy)
    # With d == 0 any reference direction is valid; the start's heading keeps a exact.
    theta = math.atan2(dy, dx) if d > 0.0 else yaw0
    a = _wrap_positive(yaw0 - theta)
    b = _wrap_positive(yaw1 - theta)
    sa = math.sin(a)
    ca = math.cos(a)
    sb = math.sin(b)
    cb = math.cos(b)
    best = np.inf
    best_w = -1
    bt = 0.0
    bp = 0.0
    bq = 0.0
    for w in range(6):
        ok, t, p, q = _dubins_word(w, d, a, b, sa, ca, sb, cb)
        if ok and t + p + q < best:
            best = t + p + q
            best_w = w
            bt = t
            bp = p
            bq = q
    return best, best_w, bt, bp, bq


@numba.njit(cache=True, nogil=True)
def dubins_length(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> float:
    """Length (m) of the shortest forward-only (Dubins) curve from pose 0 to pose 1.

    Same conventions as :func:`rs_length`; callable from other ``@njit`` functions.
    """
    return _dubins_solve(x0, y0, yaw0, x1, y1, yaw1, radius)[0] * radius


@numba.njit(cache=True, nogil=True)
def dubins_segments(
    x0: float, y0: float, yaw0: float, x1: float, y1: float, yaw1: float, radius: float
) -> tuple[NDArray[np.int8], NDArray[np.float64]]:
    """Segments of the shortest Dubins curve, as :func:`rs_segments` (all lengths >= 0)."""
    _, w, t, p, q = _dubins_solve(x0, y0, yaw0, x1, y1, yaw1, radius)
    word = (t, p, q)
    kinds = np.empty(3, dtype=np.int8)
    lengths = np.empty(3, dtype=np.float64)
    m = 0
    for i in range(3):
        if word[i] > _TOL:
            kinds[m] = _DUBINS_KINDS[w, i]
            lengths[m] = word[i] * radius
            m += 1
    return kinds[:m].copy(), lengths[:m].copy()


# ----------------------------------------------------------------------------- Python API


@dataclass(frozen=True)
class Curve:
    """A curve of a car with turning radius ``radius_m``: segments driven one after another.

    Attributes:
        kinds: ``'L'`` (left arc), ``'S'`` (straight) or ``'R'`` (right arc) per segment.
        lengths: signed length of each segment, metres; < 0 means driving in reverse.
        radius_m: the radius of the arcs, metres.
    """

    kinds: tuple[str, ...]
    lengths: tuple[float, ...]
    radius_m: float

    def __post_init__(self) -> None:
        _check_radius(self.radius_m)
        if len(self.kinds) != len(self.lengths):
            raise ConfigError(
                f"curve: {len(self.kinds)} kinds but {len(self.lengths)} lengths",
                hint="give one signed length per segment kind",
            )
        bad = [k for k in self.kinds if k not in _KIND_CODES]
        if bad:
            raise ConfigError(f"curve: unknown segment kind {bad[0]!r}", hint="use 'L', 'S' or 'R'")
        if not all(math.isfinite(v) for v in self.lengths):
            raise ConfigError(
                f"curve: segment lengths must be finite, got {self.lengths!r}",
                hint="give lengths in metres, negative for reverse",
            )

    @property
    def length_m(self) -> float:
        """Total distance driven, metres (forward and reverse alike)."""
        return float(sum(abs(v) for v in self.lengths))

    @property
    def reversals(self) -> int:
        """Number of gear changes (forward <-> reverse) between consecutive segments."""
        signs = [v > 0 for v in self.lengths if v != 0.0]
        return sum(1 for a, b in itertools.pairwise(signs) if a != b)


def shortest_curve(
    q0: Sequence[float] | ArrayLike,
    q1: Sequence[float] | ArrayLike,
    radius_m: float,
    *,
    reverse: bool = True,
) -> Curve:
    """The shortest curve from pose ``q0`` to pose ``q1`` for turning radius ``radius_m``.

    Poses are ``(x, y, yaw)`` in metres and radians. With ``reverse`` (default) the car may
    reverse (Reeds-Shepp); without, it drives forward only (Dubins). Raises ConfigError on a
    radius <= 0 or a non-finite pose.
    """
    radius = _check_radius(radius_m)
    x0, y0, yaw0 = _check_pose("q0", q0)
    x1, y1, yaw1 = _check_pose("q1", q1)
    kernel = rs_segments if reverse else dubins_segments
    kinds, lengths = kernel(x0, y0, yaw0, x1, y1, yaw1, radius)
    return Curve(
        kinds=tuple(_KIND_NAMES[int(k)] for k in kinds),
        lengths=tuple(float(v) for v in lengths),
        radius_m=radius,
    )


def sample_curve(
    curve: Curve, q0: Sequence[float] | ArrayLike, step_m: float
) -> tuple[NDArray[np.float64], NDArray[np.int8], NDArray[np.float64]]:
    """Poses along ``curve`` driven from pose ``q0``, on the exact arcs and lines.

    Every segment is cut into equal pieces no longer than ``step_m`` (metres, along the path),
    so there is a sample at each segment boundary (a gear change is where ``direction``
    changes sign) and consecutive samples are at most ``step_m`` apart. No pose repeats: an
    empty curve gives the single pose ``q0``.

    Returns:
        poses: (N, 3) float64 ``x, y, yaw`` (m, m, rad); ``poses[0]`` is ``q0`` and
            ``poses[-1]`` the end of the curve. ``yaw`` is continuous (not wrapped): it starts at
            ``q0``'s yaw and ends at the goal's yaw plus a multiple of 2 pi.
        direction: (N,) int8, the gear of the motion leaving each pose: +1 forward, -1 reverse
            (the last pose repeats the one before it).
        curvature: (N,) float64, signed 1/m, of the segment leaving each pose: ``+1/R`` on a
            left arc, ``-1/R`` on a right arc, 0 on a straight, whatever the gear (it is
            ``d yaw / ds`` with ``s`` the signed distance driven). The last repeats.
    """
    x, y, yaw = _check_pose("q0", q0)
    step = _check_step(step_m)
    radius = curve.radius_m
    poses = [np.array([[x, y, yaw]])]
    gears: list[NDArray[np.int8]] = []
    curvatures: list[NDArray[np.float64]] = []
    for name, length in zip(curve.kinds, curve.lengths, strict=True):
        if length == 0.0:
            continue
        k = _KIND_CODES[name]
        n = max(1, math.ceil(abs(length) / step))
        if abs(length) / n > step:
            n += 1
        s = np.arange(1, n + 1, dtype=np.float64) * (length / n)
        s[-1] = length
        if k == STRAIGHT:
            xs = x + s * math.cos(yaw)
            ys = y + s * math.sin(yaw)
            yaws = np.full(n, yaw)
        else:
            # Chord of an arc turning by dth: 2 R sin(dth / 2) along the mean heading (exact,
            # and free of the cancellation in sin(yaw + dth) - sin(yaw) for small dth).
            dth = k * s / radius
            mid = yaw + 0.5 * dth
            chord = 2.0 * k * radius * np.sin(0.5 * dth)
            xs = x + chord * np.cos(mid)
            ys = y + chord * np.sin(mid)
            yaws = yaw + dth
        poses.append(np.column_stack((xs, ys, yaws)))
        gears.append(np.full(n, 1 if length > 0 else -1, dtype=np.int8))
        curvatures.append(np.full(n, k / radius))
        x, y, yaw = float(xs[-1]), float(ys[-1]), float(yaws[-1])
    out = np.concatenate(poses)
    if not gears:
        return out, np.ones(1, dtype=np.int8), np.zeros(1)
    direction = np.concatenate([*gears, gears[-1][-1:]])
    curvature = np.concatenate([*curvatures, curvatures[-1][-1:]])
    return out, direction, curvature


def _check_radius(radius_m: float) -> float:
    """``radius_m`` as a finite float > 0, else ConfigError."""
    try:
        r = float(radius_m)
    except (TypeError, ValueError):
        r = math.nan
    if not math.isfinite(r) or r <= 0.0:
        raise ConfigError(
            f"radius_m: the turning radius must be a finite number > 0 m, got {radius_m!r}",
            hint="give the car's minimum turning radius in metres, e.g. 1.5",
        )
    return r


def _check_step(step_m: float) -> float:
    """``step_m`` as a finite float > 0, else ConfigError."""
    try:
        step = float(step_m)
    except (TypeError, ValueError):
        step = math.nan
    if not math.isfinite(step) or step <= 0.0:
        raise ConfigError(
            f"step_m: the sample spacing must be a finite number > 0 m, got {step_m!r}",
            hint="give the largest distance between samples in metres, e.g. 0.05",
        )
    return step


def _check_pose(name: str, q: Sequence[float] | ArrayLike) -> tuple[float, float, float]:
    """``q`` as three finite floats ``(x, y, yaw)``, else ConfigError naming ``name``."""
    try:
        arr = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        arr = np.full(0, np.nan)
    if arr.shape != (3,) or not np.isfinite(arr).all():
        raise ConfigError(
            f"{name}: expected a pose (x, y, yaw) of three finite numbers, got {q!r}",
            hint="give x and y in metres and yaw in radians",
        )
    return float(arr[0]), float(arr[1]), float(arr[2])
