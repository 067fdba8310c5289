"""Submaps: probability grids of a run of consecutive nodes, in the local frame.

As in Cartographer, two submaps are active: each node is inserted into both, scans are
matched against the older (fuller) one, and when it holds ``scans_per_submap`` nodes it is
finished and a new one starts, so that the newer one is half full. A finished submap never
changes; loop closure searches it. Its place in the world follows its first node (its anchor):
``world_from_local = G(anchor) L(anchor)^-1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from slamcli.scans.grid import Field, ProbabilityGrid
from slamcli.scans.matching import Pyramid

F64 = NDArray[np.float64]

_KEPT_PYRAMIDS = 2
"""Finished submaps whose loop-search pyramids are kept between searches."""


@dataclass
class Submap:
    """A grid and the nodes inserted into it (indices of the graph's nodes)."""

    index: int
    grid: ProbabilityGrid
    nodes: list[int] = field(default_factory=list)
    finished: bool = False
    _pyramid: Pyramid | None = field(default=None, repr=False)
    _field_at: int = -1

    @property
    def anchor(self) -> int:
        return self.nodes[0]

    def pyramid(self, sigma_m: float, depth: int, box: F64 | None = None) -> Pyramid:
        """The max-pooled likelihood field of the grid as it is now, over ``box`` (xmin, ymin,
        xmax, ymax) when given; the whole grid's is kept until the grid changes."""
        if box is not None:
            return Pyramid(self.grid.likelihood_field(sigma_m, box), depth)
        if (
            self._pyramid is None
            or self._field_at != self.grid.insertions
            or (self._pyramid.depth < depth)
        ):
            field_: Field = self.grid.likelihood_field(sigma_m)
            self._pyramid = Pyramid(field_, depth)
            self._field_at = self.grid.insertions
        return self._pyramid

    def drop_pyramid(self) -> None:
        """Free the cached pyramid (finished submaps keep only their grid)."""
        self._pyramid = None


class SubmapSet:
    """Every submap of a run; the active ones take new nodes."""

    def __init__(self, resolution_m: float, scans_per_submap: int) -> None:
        self.resolution = resolution_m
        self.size = scans_per_submap
        self.all: list[Submap] = []
        self.active: list[Submap] = []
        self._searched: list[Submap] = []

    def loop_pyramid(self, sub: Submap, sigma_m: float, depth: int) -> Pyramid:
        """A finished submap's pyramid for loop search; the last few searched keep theirs,
        so that memory stays bounded however long the run."""
        if sub in self._searched:
            self._searched.remove(sub)
        self._searched.append(sub)
        while len(self._searched) > _KEPT_PYRAMIDS:
            self._searched.pop(0).drop_pyramid()
        return sub.pyramid(sigma_m, depth)

    def matching(self) -> Submap | None:
        """The submap scans are matched against: the oldest active one."""
        return self.active[0] if self.active else None

    def insert(self, node: int, points_local: F64, sensor_local: F64, misses: F64) -> list[int]:
        """Insert a node's scan into the active submaps, starting and finishing submaps as
        they fill; returns the indices of the submaps finished now."""
        if not self.active or len(self.active[-1].nodes) >= max(1, self.size // 2):
            sub = Submap(len(self.all), ProbabilityGrid(self.resolution))
            self.all.append(sub)
            self.active.append(sub)
        for sub in self.active:
            sub.grid.insert(points_local, sensor_local, misses)
            sub.nodes.append(node)
        done = []
        while self.active and len(self.active[0].nodes) >= self.size:
            sub = self.active.pop(0)
            sub.finished = True
            sub.grid.shrink()
            sub.drop_pyramid()
            done.append(sub.index)
        return done
