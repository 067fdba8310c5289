"""Laser logs with drifting odometry, made from the shared corrected CARMEN logs.

The shared Radish logs are *corrected*: their poses are a SLAM reference (PROVENANCE.md). A run
judged against them must not see them, so :func:`drifted_log` writes the same scans with
odometry made from the reference the way wheel odometry drifts: every step between consecutive
scans is 2.5 % too long, turns by an extra 0.015 rad per metre travelled (a heading bias), and
carries seeded Gaussian noise (1 cm + 1 % of the step in each direction, 0.005 rad + 0.2 % of
the step's turn in heading). The reference is written beside it as TUM.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np

from slamcli.formats.carmen import CarmenSource, write_carmen
from slamcli.formats.trajectory import write_tum
from slamcli.geometry.planar import between_planar, compose_planar, se3_to_planar
from slamcli.types import ScanFrame

SCALE = 1.025
HEADING_BIAS_RAD_PER_M = 0.015


def drift(reference: np.ndarray, seed: int = 0) -> np.ndarray:
    """(N, 3) odometry poses drifting from the (N, 3) reference poses as described above."""
    rng = np.random.default_rng(seed)
    out = [reference[0].copy()]
    for a, b in itertools.pairwise(reference):
        d = between_planar(a, b)
        dist = math.hypot(d[0], d[1])
        sigma = 0.01 + 0.01 * dist
        step = np.array(
            [
                SCALE * d[0] + rng.normal(0.0, sigma),
                SCALE * d[1] + rng.normal(0.0, sigma),
                d[2] + HEADING_BIAS_RAD_PER_M * dist + rng.normal(0.0, 0.005 + 0.002 * abs(d[2])),
            ]
        )
        out.append(compose_planar(out[-1], step))
    return np.array(out)


def drifted_log(log: Path, folder: Path, seed: int = 0) -> tuple[Path, Path]:
    """The scans of ``log`` with drifting odometry (``folder/drifted.log``) and the log's own
    poses as the reference (``folder/reference.tum``)."""
    with CarmenSource.open(log, odometry="none", groundtruth="log") as source:
        scans = [f for f in source.frames(("scan",)) if isinstance(f, ScanFrame)]
        reference = source.groundtruth()
    assert reference is not None and len(reference) == len(scans)
    odometry = drift(se3_to_planar(reference.world_from_body), seed)
    out = folder / "drifted.log"
    write_carmen(out, zip(scans, odometry, strict=True))
    write_tum(folder / "reference.tum", reference)
    return out, folder / "reference.tum"
