"""The keyframe database: an inverted index (word -> keyframes) that loop closure and
relocalisation query, with ORB-SLAM's candidate filter (keyframes sharing at least 0.8 x the
largest number of common words)."""

from __future__ import annotations

import itertools
from collections.abc import Collection

import numpy as np

from slamcli.vision.vocabulary.tree import BowVector, Vocabulary


class KeyframeDatabase:
    """Inverted index word -> keyframes, for loop closure and relocalisation queries.

    Keyframes are scored against a query only when they share a word with it, and of those only
    the ones sharing at least ``min_common_ratio`` x the largest number of common words (ORB-SLAM
    keeps 0.8) are scored with :meth:`Vocabulary.score`.
    """

    def __init__(self, vocabulary: Vocabulary) -> None:
        self.vocabulary = vocabulary
        self._bows: dict[int, BowVector] = {}
        self._index: list[list[int]] = [[] for _ in range(vocabulary.n_words)]

    def __len__(self) -> int:
        return len(self._bows)

    def __contains__(self, kf_id: object) -> bool:
        return kf_id in self._bows

    def add(self, kf_id: int, bow: BowVector) -> None:
        """Index keyframe ``kf_id`` (replacing an earlier entry of the same id)."""
        kf_id = int(kf_id)
        if kf_id in self._bows:
            self.remove(kf_id)
        if len(bow) and int(bow.words[-1]) >= len(self._index):
            raise ValueError(f"bow: word {int(bow.words[-1])} is not in the vocabulary")
        self._bows[kf_id] = bow
        for w in bow.words.tolist():
            self._index[w].append(kf_id)

    def remove(self, kf_id: int) -> None:
        """Forget keyframe ``kf_id``; unknown ids are ignored."""
        bow = self._bows.pop(int(kf_id), None)
        if bow is None:
            return
        for w in bow.words.tolist():
            self._index[w].remove(int(kf_id))

    def query(
        self,
        bow: BowVector,
        *,
        exclude: Collection[int] = frozenset(),
        max_results: int | None = None,
        min_common_ratio: float = 0.8,
    ) -> list[tuple[int, float]]:
        """Keyframes most like ``bow``: ``[(kf_id, score), ...]``, best first.

        Args:
            bow: the query image's vector.
            exclude: keyframe ids never returned (the query's own, its covisible neighbours);
                they are left out before the common-word filter, as in ORB-SLAM.
            max_results: at most this many results (None: all candidates).
            min_common_ratio: keep keyframes sharing at least this fraction of the largest
                number of words any keyframe shares with the query.

        Returns:
            Sorted by score descending, then keyframe id ascending.
        """
        if len(bow) == 0 or not self._bows:
            return []
        lists = [self._index[w] for w in bow.words.tolist() if w < len(self._index)]
        hits = np.fromiter(
            itertools.chain.from_iterable(lists), dtype=np.int64, count=sum(map(len, lists))
        )
        if exclude and hits.size:
            hits = hits[~np.isin(hits, np.fromiter(exclude, dtype=np.int64))]
        if hits.size == 0:
            return []
        ids, common = np.unique(hits, return_counts=True)
        keep = common >= min_common_ratio * common.max()
        dense = np.zeros(len(self._index), np.float64)
        dense[bow.words] = bow.weights
        scored = []
        for kf in ids[keep].tolist():
            other = self._bows[kf]
            # For two L1-normalised vectors, 1 - 0.5 |a - b|_1 is the sum of the common minima.
            s = float(np.minimum(dense[other.words], other.weights).sum())
            scored.append((kf, min(max(s, 0.0), 1.0)))
        scored.sort(key=lambda r: (-r[1], r[0]))
        return scored if max_results is None else scored[:max_results]
