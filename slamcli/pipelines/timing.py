"""Per-stage timing of a pipeline's frames."""

from __future__ import annotations

import time


class StageTimer:
    """Adds the milliseconds spent in a ``with`` block to ``totals[stage]``."""

    def __init__(self, totals: dict[str, float], stage: str) -> None:
        self._totals, self._stage = totals, stage

    def __enter__(self) -> None:
        self._start = time.perf_counter()

    def __exit__(self, *exc: object) -> None:
        self._totals[self._stage] += (time.perf_counter() - self._start) * 1e3
