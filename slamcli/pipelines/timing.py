"""What a pipeline counts and times while it works: events by name, milliseconds by stage."""

from __future__ import annotations

import time
from collections import defaultdict


class StageTimer:
    """Adds the milliseconds spent in a ``with`` block to ``totals[stage]``."""

    def __init__(self, totals: dict[str, float], stage: str) -> None:
        self._totals, self._stage = totals, stage

    def __enter__(self) -> None:
        self._start = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self._totals[self._stage] += (time.perf_counter() - self._start) * 1e3


class Stats:
    """A pipeline's counts (``counts[name] += 1``) and stage times in milliseconds (``with
    stats.timed(stage): ...``), shared by the parts of one pipeline."""

    def __init__(self) -> None:
        self.counts: defaultdict[str, int] = defaultdict(int)
        self.ms: defaultdict[str, float] = defaultdict(float)

    def timed(self, stage: str) -> StageTimer:
        return StageTimer(self.ms, stage)

    def per_frame(self, frames: int) -> dict[str, float]:
        """Each stage's milliseconds per frame, by stage name."""
        return {k: v / frames for k, v in sorted(self.ms.items())}
