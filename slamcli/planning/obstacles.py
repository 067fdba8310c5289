"""Dynamic obstacles: discs that appear and vanish while the robot drives.

File format (CSV, UTF-8, ``#`` comment lines and blank lines ignored)::

    x,y,radius,appear_s,vanish_s
    1.5,0.0,0.3,0,
    -0.5,1.0,0.25,4.0,12.5

``x, y`` is the disc's centre in the map frame (m), ``radius`` its radius (m, > 0),
``appear_s`` when it appears (s after the start; empty = 0) and ``vanish_s`` when it goes
(empty or ``inf`` = it stays). It is present for ``appear_s <= t < vanish_s``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import FormatError

HEADER = ("x", "y", "radius", "appear_s", "vanish_s")


@dataclass(frozen=True)
class DynamicObstacle:
    """A disc (centre m, radius m) present for ``appear_s <= t < vanish_s`` (s)."""

    x: float
    y: float
    radius: float
    appear_s: float = 0.0
    vanish_s: float = math.inf
    name: str = ""
    """How messages name it, e.g. ``obstacles.csv:3``."""

    def present(self, t: float) -> bool:
        return self.appear_s <= t < self.vanish_s

    def label(self) -> str:
        where = f"({self.x:g}, {self.y:g}) m, radius {self.radius:g} m"
        return f"obstacle {self.name} at {where}" if self.name else f"obstacle at {where}"

    def as_dict(self) -> dict[str, object]:
        return {
            "name": self.name,
            "x": self.x,
            "y": self.y,
            "radius": self.radius,
            "appear_s": self.appear_s,
            "vanish_s": None if math.isinf(self.vanish_s) else self.vanish_s,
        }


def read_obstacles(path: str | Path) -> list[DynamicObstacle]:
    """Read an obstacles CSV (format in the module docstring); FormatError with file:line."""
    from slamcli.formats.text import iter_data_lines

    p = Path(path)
    out: list[DynamicObstacle] = []
    header_seen = False
    for line, fields in iter_data_lines(p, delimiter=","):
        if not header_seen:
            if tuple(f.lower() for f in fields) != HEADER:
                raise FormatError(
                    p, f"expected the header {','.join(HEADER)}, got {','.join(fields)}", line
                )
            header_seen = True
            continue
        fields = fields + [""] * (len(HEADER) - len(fields))
        if len(fields) != len(HEADER):
            raise FormatError(p, f"expected {len(HEADER)} fields, got {len(fields)}", line)
        values = []
        for name, text in zip(HEADER, fields, strict=True):
            if text == "" and name in ("appear_s", "vanish_s"):
                values.append(0.0 if name == "appear_s" else math.inf)
                continue
            try:
                values.append(float(text))
            except ValueError:
                raise FormatError(p, f"{name} {text!r} is not a number", line) from None
        x, y, radius, appear, vanish = values
        if not (math.isfinite(x) and math.isfinite(y)):
            raise FormatError(p, "x and y must be finite", line)
        if not (math.isfinite(radius) and radius > 0):
            raise FormatError(p, f"radius must be > 0 m, got {radius:g}", line)
        if not (math.isfinite(appear) and appear >= 0):
            raise FormatError(p, f"appear_s must be a finite time >= 0, got {appear:g}", line)
        if not vanish > appear:
            raise FormatError(p, f"vanish_s {vanish:g} must come after appear_s {appear:g}", line)
        out.append(DynamicObstacle(x, y, radius, appear, vanish, name=f"{p.name}:{line}"))
    if not header_seen:
        raise FormatError(p, f"empty file; expected the header {','.join(HEADER)}")
    return out


def first_hit(
    points: NDArray[np.float64], obstacles: Sequence[DynamicObstacle], inflate_m: float
) -> tuple[int, int] | None:
    """(point index, obstacle index) of the first of ``points`` (K, 2) within an obstacle
    grown by ``inflate_m``; None when no point is."""
    if not obstacles or len(points) == 0:
        return None
    centres = np.array([[o.x, o.y] for o in obstacles])
    reach = np.array([o.radius for o in obstacles]) + inflate_m
    d2 = ((points[:, None, :] - centres[None, :, :]) ** 2).sum(axis=2)
    inside = d2 <= reach[None, :] ** 2
    rows = np.flatnonzero(inside.any(axis=1))
    if len(rows) == 0:
        return None
    k = int(rows[0])
    return k, int(np.argmax(inside[k]))
