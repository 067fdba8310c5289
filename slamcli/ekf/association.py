"""Data association for observations without landmark ids.

Both methods compare an observation with a landmark by the squared Mahalanobis distance of the
innovation under its full covariance ``S = H P Hᵀ + R`` (robot, landmark and cross terms), never a
Euclidean distance mixing metres and radians, and accept a pairing only inside the χ² gate.

- :func:`nearest_neighbour`: each observation takes its nearest compatible landmark; a landmark
  goes to at most one observation of a scan (the closer pairings are decided first).
- :func:`jcbb`: joint compatibility branch and bound (Neira and Tardós 2001): the largest set of
  pairings whose *stacked* innovation passes the joint χ² gate, ties broken by the smaller joint
  distance. It rejects pairings that are each plausible but together imply inconsistent robot
  poses, at a cost exponential in the worst case; the search stops after ``max_nodes``.

Observations of a landmark with an id not yet mapped are first collected, and mapped once they
agree with each other (:func:`agree_with_mean`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from slamcli.ekf.filter import LandmarkEkf
from slamcli.geometry.planar import wrap_angle

F64 = NDArray[np.float64]

UNMATCHED = -1


@dataclass(frozen=True)
class Candidates:
    """Individual compatibility of a scan: ``d2[i, j]`` for observation i and landmark slot j."""

    d2: F64

    @classmethod
    def of(cls, ekf: LandmarkEkf, zs: F64, r_covs: F64) -> Candidates:
        d2 = np.full((len(zs), ekf.count), np.inf)
        for i, (z, r) in enumerate(zip(zs, r_covs, strict=True)):
            if ekf.count:
                d2[i] = ekf.innovations_all(z, r)[2]
        return cls(d2)

    def best(self) -> tuple[NDArray[np.int64], F64]:
        """Each observation's nearest landmark and its distance (inf without landmarks)."""
        if self.d2.shape[1] == 0:
            n = self.d2.shape[0]
            return np.full(n, UNMATCHED, dtype=np.int64), np.full(n, np.inf)
        j = np.argmin(self.d2, axis=1)
        return j.astype(np.int64), self.d2[np.arange(len(j)), j]


def agree_with_mean(points: F64, covs: F64, gate: float) -> bool:
    """Whether every one of several positions of one landmark, (K, 2) ``points`` with (K, 2, 2)
    covariances ``covs``, lies within the χ² ``gate`` of their mean (squared Mahalanobis
    distance under its own covariance)."""
    d = points - points.mean(axis=0)
    d2 = np.einsum("ni,ni->n", d, np.linalg.solve(covs, d[:, :, None])[..., 0])
    return not np.any(d2 > gate)


def nearest_neighbour(cands: Candidates, gate: float) -> NDArray[np.int64]:
    """Slots paired with each observation (``UNMATCHED`` = none inside the gate)."""
    d2 = cands.d2
    out = np.full(d2.shape[0], UNMATCHED, dtype=np.int64)
    if d2.size == 0:
        return out
    obs, lms = np.nonzero(d2 < gate)
    order = np.argsort(d2[obs, lms], kind="stable")
    taken: set[int] = set()
    for k in order:
        i, j = int(obs[k]), int(lms[k])
        if out[i] == UNMATCHED and j not in taken:
            out[i] = j
            taken.add(j)
    return out


def joint_distance(
    ekf: LandmarkEkf,
    zs: F64,
    r_covs: F64,
    pairs: list[tuple[int, int]],
    predicted: dict[int, tuple[F64, F64]] | None = None,
) -> float:
    """Squared Mahalanobis distance of the stacked innovation of ``(observation, slot)`` pairs.

    ``predicted`` keeps each slot's predicted observation and Jacobian between calls made at
    one filter state (a search tries many pairings of the same slots).
    """
    m = len(pairs)
    nu = np.empty(2 * m)
    h = np.zeros((2 * m, ekf.dim))
    r = np.zeros((2 * m, 2 * m))
    cache = {} if predicted is None else predicted
    for k, (i, j) in enumerate(pairs):
        if j not in cache:
            cache[j] = ekf.predicted(j)
        zhat, hj = cache[j]
        nu[2 * k] = zs[i][0] - zhat[0]
        nu[2 * k + 1] = wrap_angle(zs[i][1] - zhat[1])
        h[2 * k : 2 * k + 2, :3] = hj[:, :3]
        c = 3 + 2 * j
        h[2 * k : 2 * k + 2, c : c + 2] = hj[:, 3:]
        r[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = r_covs[i]
    cols = np.unique(np.concatenate([[0, 1, 2], *[[3 + 2 * j, 4 + 2 * j] for _, j in pairs]]))
    hs = h[:, cols]
    s = hs @ ekf.P[np.ix_(cols, cols)] @ hs.T + r
    return float(nu @ np.linalg.solve(0.5 * (s + s.T), nu))


def jcbb(
    ekf: LandmarkEkf,
    zs: F64,
    r_covs: F64,
    cands: Candidates,
    gate: float,
    joint_gate: Callable[[int], float],
    max_nodes: int = 2000,
) -> NDArray[np.int64]:
    """The jointly compatible pairing with the most pairs (``UNMATCHED`` for the rest).

    ``joint_gate(k)`` is the χ² threshold for ``k`` pairings (2k degrees of freedom).
    """
    m = cands.d2.shape[0]
    options = [[int(j) for j in np.argsort(cands.d2[i]) if cands.d2[i, j] < gate] for i in range(m)]
    best: list[int] = [UNMATCHED] * m
    best_score = (0, 0.0)
    nodes = 0
    pairs: list[tuple[int, int]] = []
    current = [UNMATCHED] * m
    predicted: dict[int, tuple[F64, F64]] = {}

    def search(i: int, used: frozenset[int], paired: int) -> None:
        nonlocal best, best_score, nodes
        if nodes >= max_nodes:
            return
        nodes += 1
        if i == m:
            dist = joint_distance(ekf, zs, r_covs, pairs, predicted) if pairs else 0.0
            score = (paired, -dist)
            if paired > best_score[0] or (paired == best_score[0] and -dist > best_score[1]):
                best, best_score = list(current), score
            return
        for j in options[i]:
            if j in used:
                continue
            pairs.append((i, j))
            if joint_distance(ekf, zs, r_covs, pairs, predicted) < joint_gate(len(pairs)):
                current[i] = j
                search(i + 1, used | {j}, paired + 1)
                current[i] = UNMATCHED
            pairs.pop()
        # Leave observation i unpaired only if the rest could still beat the best.
        if paired + (m - i - 1) > best_score[0] or best_score[0] == 0:
            search(i + 1, used, paired)

    search(0, frozenset(), 0)
    return np.asarray(best, dtype=np.int64)
