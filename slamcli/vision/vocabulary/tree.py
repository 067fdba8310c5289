"""The vocabulary tree: words of ORB descriptors, bag-of-words vectors and their score.

Node ids number the tree breadth first (0 is the root), and word ids number the leaves in the
same order. Each word has an idf weight ``log(N_images / n_images_with_word)``, so a word seen in
every training image weighs nothing. Training is in :mod:`~slamcli.vision.vocabulary.training`,
files in :mod:`~slamcli.vision.vocabulary.files`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.vision.matching import descriptor_words
from slamcli.vision.matching import hamming as _hamming

U8 = NDArray[np.uint8]
I32 = NDArray[np.int32]
F32 = NDArray[np.float32]

ProgressFn = Callable[..., None]

FORMAT_TAG = "slamcli-orb-vocabulary"
"""The ``format`` entry of a saved vocabulary."""

FORMAT_VERSION = 1
"""The ``version`` entry saved vocabularies carry, and the newest slamcli reads."""

DESCRIPTOR_BYTES = 32
"""ORB descriptors are 256 bits."""

DEFAULT_ITERATIONS = 10
"""k-majority iterations per node after k-means++ seeding (fewer if assignments settle)."""

MAX_NODES = 5_000_000
"""Largest tree a saved file may declare: far above any useful vocabulary (k=10, L=6 has 1.1 M
nodes), low enough that a damaged file cannot make the loader allocate gigabytes."""

TRAIN_HINT = "make one with 'slamcli vocab train IMAGES... --out FILE'"

CHUNK = 65536
"""Descriptors per block in the distance computations, bounding the temporary arrays."""


@dataclass(frozen=True)
class BowVector:
    """A bag-of-words vector: L1-normalised tf-idf weights of the words an image holds.

    Attributes:
        words: (M,) int32 word ids, sorted and unique.
        weights: (M,) float32 weights, all > 0, summing to 1 (or M = 0 for an image with no
            weighted word).
    """

    words: I32
    weights: F32

    def __len__(self) -> int:
        return int(self.words.shape[0])


def hamming(a: U8, b: U8) -> NDArray[np.int32]:
    """Hamming distances between broadcastable (..., 32) uint8 descriptor arrays -> (...) int32."""
    return _hamming(a, b, np.int32)


def check_descriptors(descriptors: Any, what: str = "descriptors") -> U8:
    """Descriptors as a contiguous (N, 32) uint8 array; ValueError for another shape or dtype."""
    arr = np.asarray(descriptors)
    if arr.ndim != 2 or arr.shape[1] != DESCRIPTOR_BYTES or arr.dtype != np.uint8:
        raise ValueError(
            f"{what}: expected an (N, {DESCRIPTOR_BYTES}) uint8 array of ORB descriptors, "
            f"got {arr.shape} {arr.dtype}"
        )
    return np.ascontiguousarray(arr)


class Vocabulary:
    """A hierarchical k-majority vocabulary tree over ORB descriptors, with idf word weights.

    Attributes:
        branching: children per node (k).
        levels: depth of the tree below the root (L); words are the leaves.
        centroids: (M, 32) uint8 descriptor of every node, breadth-first (row 0, the root, is
            unused).
        children: (M, k) int32 child node ids, -1 where a node has fewer children (or none).
        node_word: (M,) int32 word id of each leaf node, -1 for inner nodes.
        node_level: (M,) int32 depth of each node (root 0).
        idf: (W,) float32 idf weight of each word.
        trained_images: how many images the training descriptors came from.
        trained_descriptors: how many descriptors were clustered.
        seed: the seed it was trained with.
    """

    def __init__(
        self,
        *,
        branching: int,
        levels: int,
        centroids: U8,
        children: I32,
        idf: F32,
        trained_images: int = 0,
        trained_descriptors: int = 0,
        seed: int = 0,
    ) -> None:
        self.branching = int(branching)
        self.levels = int(levels)
        self.centroids = centroids
        self.children = children
        self.idf = idf
        self.trained_images = int(trained_images)
        self.trained_descriptors = int(trained_descriptors)
        self.seed = int(seed)
        self._centroid_words: NDArray[np.uint64] | None = None
        leaf = (children < 0).all(axis=1)
        self.node_word = np.full(children.shape[0], -1, np.int32)
        self.node_word[leaf] = np.arange(int(leaf.sum()), dtype=np.int32)
        self.word_node = np.flatnonzero(leaf).astype(np.int32)
        rows, cols = np.nonzero(children >= 0)
        parent = np.zeros(children.shape[0], np.int64)
        parent[children[rows, cols]] = rows
        # Each pass fixes one more level below the root; a tree of L levels settles in L passes.
        self.node_level = np.zeros(children.shape[0], np.int32)
        for _ in range(children.shape[0]):
            level = np.where(np.arange(parent.size) > 0, self.node_level[parent] + 1, 0)
            if np.array_equal(level, self.node_level):
                break
            self.node_level = level.astype(np.int32)

    @property
    def n_words(self) -> int:
        return int(self.word_node.shape[0])

    @property
    def n_nodes(self) -> int:
        return int(self.children.shape[0])

    def __repr__(self) -> str:
        return (
            f"Vocabulary(branching={self.branching}, levels={self.levels}, "
            f"words={self.n_words}, trained_images={self.trained_images})"
        )

    # -- lookups ----------------------------------------------------------------------------

    def _descend(self, descriptors: U8, stop_level: int) -> I32:
        """Node id reached at depth ``stop_level`` (or the leaf above it) per descriptor: at
        each level the child with the nearest centroid (ties: the first child), compiled
        (:func:`slamcli.vision._matching_kernels.descend`)."""
        desc = check_descriptors(descriptors)
        if desc.shape[0] == 0:
            return np.zeros(0, np.int32)
        from slamcli.vision import _matching_kernels as kernels

        if self._centroid_words is None:
            self._centroid_words = descriptor_words(self.centroids, "vocabulary centroids")
        words = descriptor_words(desc, "descriptors")
        nodes: I32 = kernels.descend(
            words, self._centroid_words, self.children, self.node_word, stop_level
        )
        return nodes

    def words(self, descriptors: U8) -> I32:
        """Word id of each descriptor: (N, 32) uint8 -> (N,) int32 (N may be 0)."""
        return self.node_word[self._descend(descriptors, self.levels)]

    def nodes(self, descriptors: U8, level: int) -> I32:
        """The direct index: node id at depth ``level`` (1..levels, 1 = the root's children)
        each descriptor passes through, (N,) int32; a leaf above that depth is its own node.

        Two descriptors can only be the same word when they share this node, so matching can be
        restricted to descriptors under the same node, as ORB-SLAM does.
        """
        if not 0 <= level <= self.levels:
            raise ValueError(f"level: expected 0..{self.levels}, got {level}")
        return self._descend(descriptors, level)

    def bow(self, descriptors: U8) -> BowVector:
        """The image's L1-normalised tf-idf vector; words with idf 0 are left out."""
        return self.bow_from_words(self.words(descriptors))

    def bow_from_words(self, words: I32) -> BowVector:
        """:meth:`bow` from word ids already looked up with :meth:`words`."""
        uniq, counts = np.unique(np.asarray(words, dtype=np.int32), return_counts=True)
        weights = counts * self.idf[uniq].astype(np.float64)
        keep = weights > 0
        uniq, weights = uniq[keep], weights[keep]
        total = weights.sum()
        if total > 0:
            weights = weights / total
        return BowVector(uniq.astype(np.int32), weights.astype(np.float32))

    @staticmethod
    def score(a: BowVector, b: BowVector) -> float:
        """DBoW2's L1 score ``1 - 0.5 * |a - b|_1`` of two L1-normalised vectors, in [0, 1].

        1 for identical vectors, 0 for vectors without a common word (or an empty one).
        """
        if len(a) == 0 or len(b) == 0:
            return 0.0
        _, ia, ib = np.intersect1d(a.words, b.words, assume_unique=True, return_indices=True)
        wa, wb = a.weights.astype(np.float64), b.weights.astype(np.float64)
        l1 = wa.sum() + wb.sum() + np.sum(np.abs(wa[ia] - wb[ib]) - wa[ia] - wb[ib])
        return float(np.clip(1.0 - 0.5 * l1, 0.0, 1.0))
