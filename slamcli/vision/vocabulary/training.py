"""Training a vocabulary tree: DBoW2-style hierarchical k-majority clustering of ORB descriptors.

The root's descriptors are split into ``branching`` clusters (k-means++ seeding, then a fixed
number of k-majority iterations with Hamming distance and bitwise-majority centroids), each
cluster again, down to ``levels`` levels; the leaves are the words. A trained tree depends only
on its input and seed: the saved file is byte-identical for the same input and seed.

A node that holds ``branching`` descriptors or fewer is not clustered: as in DBoW2, each of its
distinct descriptors becomes a leaf child, so such a subtree ends above ``levels`` and leaves can
sit at different depths.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.vision.vocabulary.tree import (
    CHUNK,
    DEFAULT_ITERATIONS,
    DESCRIPTOR_BYTES,
    I32,
    MAX_NODES,
    U8,
    ProgressFn,
    Vocabulary,
    check_descriptors,
    hamming,
)

log = logging.getLogger(__name__)


def _nearest(descriptors: U8, centres: U8) -> tuple[I32, NDArray[np.int32]]:
    """Index of the nearest of ``centres`` (K, 32) for each descriptor (N, 32), and the distance.

    Ties go to the lowest index (``argmin``), so the result is deterministic.
    """
    n = descriptors.shape[0]
    labels = np.empty(n, np.int32)
    dists = np.empty(n, np.int32)
    for start in range(0, n, CHUNK):
        block = hamming(descriptors[start : start + CHUNK, None, :], centres[None, :, :])
        labels[start : start + CHUNK] = block.argmin(axis=1)
        dists[start : start + CHUNK] = block.min(axis=1)
    return labels, dists


def _majority(bits: U8, labels: I32, k: int) -> tuple[U8, NDArray[np.int64]]:
    """Bitwise-majority centroids of the clusters ``labels`` in [0, k) -> ((k, 32), sizes (k,)).

    ``bits`` is (N, 256) unpacked descriptors. A bit is set when more than half of the
    cluster's descriptors have it set (ties give 0). Empty clusters get zero centroids.
    """
    order = np.argsort(labels, kind="stable")
    sizes = np.bincount(labels, minlength=k)
    counts = np.zeros((k, bits.shape[1]), np.int64)
    nonempty = np.flatnonzero(sizes)
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]])[nonempty]
    counts[nonempty] = np.add.reduceat(bits[order], starts, axis=0, dtype=np.int64)
    return np.packbits(2 * counts > sizes[:, None], axis=1), sizes


def _majority_one(descriptors: U8) -> U8:
    """Bitwise-majority descriptor (32,) of (N, 32) descriptors (ties give 0)."""
    votes = np.unpackbits(descriptors, axis=1).sum(axis=0, dtype=np.int64)
    return np.packbits(2 * votes > descriptors.shape[0])


def _kmeanspp(descriptors: U8, k: int, rng: np.random.Generator) -> U8:
    """k-means++ seeds (at most k, fewer when the descriptors have fewer distinct values)."""
    n = descriptors.shape[0]
    chosen = [int(rng.integers(n))]
    mind = hamming(descriptors, descriptors[chosen[0]]).astype(np.float64)
    while len(chosen) < k:
        weights = mind * mind
        total = weights.sum()
        if total <= 0:
            break
        nxt = int(np.searchsorted(np.cumsum(weights), rng.random() * total, side="right"))
        nxt = min(nxt, n - 1)
        chosen.append(nxt)
        mind = np.minimum(mind, hamming(descriptors, descriptors[nxt]))
    return descriptors[chosen]


def _kmajority(
    descriptors: U8, k: int, rng: np.random.Generator, iterations: int
) -> list[NDArray[np.int64]]:
    """Cluster descriptors (N > k) into at most k groups; returns each group's row indices.

    Groups come in centroid order; empty groups are dropped.
    """
    centres = _kmeanspp(descriptors, k, rng)
    bits = np.unpackbits(descriptors, axis=1)
    labels, _ = _nearest(descriptors, centres)
    for _ in range(iterations):
        centres, sizes = _majority(bits, labels, centres.shape[0])
        centres = centres[sizes > 0]
        new_labels, _ = _nearest(descriptors, centres)
        if np.array_equal(new_labels, labels) and bool((sizes > 0).all()):
            break
        labels = new_labels
    order = np.argsort(labels, kind="stable")
    bounds = np.cumsum(np.bincount(labels, minlength=centres.shape[0]))
    return [g for g in np.split(order, bounds[:-1]) if g.size]


def _flatten_training_input(
    descriptors: U8 | Sequence[U8], per_image_counts: Sequence[int] | NDArray[Any] | None
) -> tuple[U8, I32]:
    """(all descriptors (N, 32), image index of each (N,)) from either accepted input form."""
    if isinstance(descriptors, np.ndarray):
        flat = check_descriptors(descriptors)
        if per_image_counts is None:
            return flat, np.arange(flat.shape[0], dtype=np.int32)
        counts = np.asarray(per_image_counts, dtype=np.int64)
        if counts.ndim != 1 or (counts < 0).any() or int(counts.sum()) != flat.shape[0]:
            raise ValueError(
                f"per_image_counts: expected non-negative counts summing to {flat.shape[0]}"
            )
    else:
        if per_image_counts is not None:
            raise ValueError("per_image_counts: give it only with a single descriptor array")
        arrays = [check_descriptors(d, f"descriptors[{i}]") for i, d in enumerate(descriptors)]
        counts = np.array([a.shape[0] for a in arrays], dtype=np.int64)
        flat = np.concatenate(arrays) if arrays else np.zeros((0, DESCRIPTOR_BYTES), np.uint8)
    return flat, np.repeat(np.arange(counts.size, dtype=np.int32), counts)


def train_vocabulary(
    descriptors: U8 | Sequence[U8],
    *,
    branching: int = 10,
    levels: int = 4,
    seed: int = 0,
    per_image_counts: Sequence[int] | NDArray[Any] | None = None,
    iterations: int = DEFAULT_ITERATIONS,
    progress: ProgressFn | None = None,
) -> Vocabulary:
    """Train a vocabulary tree.

    Args:
        descriptors: either a list with one (N_i, 32) uint8 array per training image, or one
            (N, 32) uint8 array of all images' descriptors one image after the other, with
            ``per_image_counts`` giving N_i. Which image each descriptor comes from sets the
            idf weights; a single array without counts counts every descriptor as an image
            of its own (idf by descriptor frequency).
        branching: children per node (k >= 2).
        levels: tree depth (L >= 1); up to k**L words.
        seed: seeds the k-means++ seeding; same input and seed give the same tree.
        per_image_counts: see ``descriptors``.
        iterations: k-majority iterations per node after seeding.
        progress: called as ``progress(done, total)`` with the levels finished.

    Raises:
        ValueError: bad shapes or parameters, or no descriptors at all.
    """

    if branching < 2 or levels < 1 or iterations < 0:
        raise ValueError(
            f"expected branching >= 2, levels >= 1 and iterations >= 0, "
            f"got {branching}, {levels}, {iterations}"
        )
    if branching**levels > MAX_NODES:
        raise ValueError(
            f"branching {branching} and levels {levels} give up to {branching**levels} "
            f"words, more than the limit of {MAX_NODES}"
        )
    flat, image_of = _flatten_training_input(descriptors, per_image_counts)
    n_images = int(image_of.max()) + 1 if image_of.size else 0
    if flat.shape[0] == 0:
        raise ValueError("no descriptors to train a vocabulary on")
    rng = np.random.default_rng(seed)
    centroids: list[U8] = [np.zeros(DESCRIPTOR_BYTES, np.uint8)]
    children: list[list[int]] = [[]]
    # Breadth first: (node, depth, its descriptors' rows); node ids follow the queue order.
    queue: deque[tuple[int, int, NDArray[np.int64]]] = deque([(0, 0, np.arange(flat.shape[0]))])
    while queue:
        node, depth, rows = queue.popleft()
        if progress is not None:
            progress(depth, levels)
        if depth >= levels:
            continue
        desc = flat[rows]
        split = rows.size > branching
        if split:
            groups = _kmajority(desc, branching, rng, iterations)
            child_rows = [rows[g] for g in groups]
            child_centres = [_majority_one(desc[g]) for g in groups]
        else:
            # As in DBoW2: a node with k descriptors or fewer gets one leaf per distinct one.
            uniq, inverse = np.unique(desc, axis=0, return_inverse=True)
            inverse = inverse.reshape(-1)
            child_rows = [rows[inverse == j] for j in range(uniq.shape[0])]
            child_centres = list(uniq)
        if len(child_rows) < 2:
            continue
        for crow, centre in zip(child_rows, child_centres, strict=True):
            children[node].append(len(centroids))
            centroids.append(centre)
            children.append([])
            if split:
                queue.append((len(centroids) - 1, depth + 1, crow))
    if progress is not None:
        progress(levels, levels)
    child_table = np.full((len(children), branching), -1, np.int32)
    for node, kids in enumerate(children):
        child_table[node, : len(kids)] = kids
    vocab = Vocabulary(
        branching=branching,
        levels=levels,
        centroids=np.stack(centroids).astype(np.uint8),
        children=child_table,
        idf=np.zeros(0, np.float32),
        trained_images=n_images,
        trained_descriptors=int(flat.shape[0]),
        seed=seed,
    )
    words = vocab.words(flat)
    pairs = np.unique(words.astype(np.int64) * max(n_images, 1) + image_of)
    images_with_word = np.bincount(pairs // max(n_images, 1), minlength=vocab.n_words)
    with np.errstate(divide="ignore"):
        idf = np.log(n_images / np.maximum(images_with_word, 1))
    vocab.idf = idf.astype(np.float32)
    log.info(
        "trained a vocabulary of %d words on %d descriptors from %d images",
        vocab.n_words,
        flat.shape[0],
        n_images,
    )
    return vocab
