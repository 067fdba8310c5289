"""A bag-of-words vocabulary over ORB descriptors and a keyframe database for place recognition.

The vocabulary is a DBoW2-style hierarchical k-majority tree: the root's descriptors are split
into ``branching`` clusters (k-means++ seeding, then a fixed number of k-majority iterations with
Hamming distance and bitwise-majority centroids), each cluster again, down to ``levels`` levels.
The leaves are the words. Each word has an idf weight ``log(N_images / n_images_with_word)``,
so a word seen in every training image weighs nothing.

Node ids number the tree breadth first (0 is the root), and word ids number the leaves in the
same order, so a trained tree depends only on its input and seed: the saved file is
byte-identical for the same input and seed.

A node that holds ``branching`` descriptors or fewer is not clustered: as in DBoW2, each of its
distinct descriptors becomes a leaf child, so such a subtree ends above ``levels`` and leaves can
sit at different depths.

:class:`KeyframeDatabase` is the inverted index (word -> keyframes) that loop closure and
relocalisation query, with ORB-SLAM's candidate filter (keyframes sharing at least 0.8 x the
largest number of common words).
"""

from __future__ import annotations

import functools
import io
import itertools
import logging
import math
import zipfile
import zlib
from collections import deque
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError, InputError
from slamcli.vision.matching import hamming as _hamming

log = logging.getLogger(__name__)

U8 = NDArray[np.uint8]
I32 = NDArray[np.int32]
F32 = NDArray[np.float32]

ProgressFn = Callable[..., None]

FORMAT_TAG = "slamcli-orb-vocabulary"
"""The ``format`` entry of a saved vocabulary."""

FORMAT_VERSION = 1
"""The ``version`` entry this module writes and the newest it reads."""

DESCRIPTOR_BYTES = 32
"""ORB descriptors are 256 bits."""

DEFAULT_ITERATIONS = 10
"""k-majority iterations per node after k-means++ seeding (fewer if assignments settle)."""

MAX_NODES = 5_000_000
"""Largest tree a saved file may declare: far above any useful vocabulary (k=10, L=6 has 1.1 M
nodes), low enough that a damaged file cannot make the loader allocate gigabytes."""

TRAIN_HINT = "make one with 'slamcli vocab train IMAGES... --out FILE'"


_CHUNK = 65536
"""Descriptors per block in the distance computations, bounding the temporary arrays."""

_DEFAULT_FILE = "orb_vocabulary.npz"


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


def _nearest(descriptors: U8, centres: U8) -> tuple[I32, NDArray[np.int32]]:
    """Index of the nearest of ``centres`` (K, 32) for each descriptor (N, 32), and the distance.

    Ties go to the lowest index (``argmin``), so the result is deterministic.
    """
    n = descriptors.shape[0]
    labels = np.empty(n, np.int32)
    dists = np.empty(n, np.int32)
    for start in range(0, n, _CHUNK):
        block = hamming(descriptors[start : start + _CHUNK, None, :], centres[None, :, :])
        labels[start : start + _CHUNK] = block.argmin(axis=1)
        dists[start : start + _CHUNK] = block.min(axis=1)
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
        # Padding rows of -1 point at the leaf itself during descent, so a descriptor that has
        # reached a leaf above the bottom level stays there.
        self._next = np.where(children >= 0, children, np.arange(children.shape[0])[:, None])
        self._next = self._next.astype(np.int32)

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

    # -- training ---------------------------------------------------------------------------

    @classmethod
    def train(
        cls,
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
        vocab = cls(
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

    # -- lookups ----------------------------------------------------------------------------

    def _descend(self, descriptors: U8, stop_level: int) -> I32:
        """Node id reached at depth ``stop_level`` (or the leaf above it) per descriptor."""
        desc = check_descriptors(descriptors)
        node = np.zeros(desc.shape[0], np.int32)
        if desc.shape[0] == 0:
            return node
        for _ in range(stop_level):
            kids = self._next[node]  # (N, k)
            d = np.empty(kids.shape, np.int32)
            for start in range(0, desc.shape[0], _CHUNK):
                sl = slice(start, start + _CHUNK)
                d[sl] = hamming(desc[sl, None, :], self.centroids[kids[sl]])
            d[self.children[node] < 0] = DESCRIPTOR_BYTES * 8 + 1
            at_leaf = self.node_word[node] >= 0
            step = kids[np.arange(kids.shape[0]), d.argmin(axis=1)]
            node = np.where(at_leaf, node, step).astype(np.int32)
        return node

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

    # -- files ------------------------------------------------------------------------------

    def _arrays(self) -> dict[str, NDArray[Any]]:
        return {
            "format": np.array(FORMAT_TAG),
            "version": np.array(FORMAT_VERSION, np.int32),
            "branching": np.array(self.branching, np.int32),
            "levels": np.array(self.levels, np.int32),
            "centroids": self.centroids,
            "children": self.children,
            "idf": self.idf,
            "trained_images": np.array(self.trained_images, np.int64),
            "trained_descriptors": np.array(self.trained_descriptors, np.int64),
            "seed": np.array(self.seed, np.int64),
        }

    def save(self, path: str | Path) -> Path:
        """Write the vocabulary as one compressed .npz, atomically; returns the path.

        The zip entries carry a fixed timestamp, so the same vocabulary gives the same bytes
        (``numpy.savez_compressed`` stamps the current time).
        """
        dest = Path(path)
        with atomic_path(dest) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for name, arr in self._arrays().items():
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
                info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
                info.compress_type = zipfile.ZIP_DEFLATED
                info.external_attr = 0o644 << 16
                zf.writestr(info, buf.getvalue(), compresslevel=9)
        return dest

    @classmethod
    def load(cls, path: str | Path) -> Vocabulary:
        """Read a vocabulary written by :meth:`save`.

        Raises:
            InputError: the file is missing or unreadable, or is not a slamcli vocabulary
                (another .npz, text, a truncated or damaged file); the message names the file.
        """
        p = Path(path)
        if not p.exists():
            raise InputError(f"{p}: no such vocabulary file", hint=TRAIN_HINT)
        if not p.is_file():
            raise InputError(f"{p}: is not a file; expected a slamcli vocabulary (.npz)")
        try:
            with p.open("rb") as fh:
                head = fh.read(4)
            if head != b"PK\x03\x04":
                raise _not_vocabulary(p, _not_zip_reason(head))
            with np.load(p, allow_pickle=False) as npz:
                arrays = _read_members(p, npz)
        except InputError:
            raise
        except OSError as exc:
            if isinstance(exc, PermissionError):
                raise InputError(f"{p}: cannot be read ({exc.strerror})") from None
            raise _not_vocabulary(p, "not a zip/.npz file") from None
        except (zipfile.BadZipFile, zlib.error, EOFError, ValueError, KeyError) as exc:
            detail = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
            raise _not_vocabulary(p, f"damaged or truncated: {detail}") from None
        except (NotImplementedError, RuntimeError) as exc:
            raise _not_vocabulary(p, f"unreadable zip entry: {exc}") from None
        return _from_arrays(p, arrays)

    @classmethod
    def default(cls) -> Vocabulary:
        """The vocabulary shipped with slamcli (``slamcli/data/orb_vocabulary.npz``), cached."""
        return _default_vocabulary()


@functools.cache
def _default_vocabulary() -> Vocabulary:
    return Vocabulary.load(default_vocabulary_path())


def default_vocabulary_path() -> Path:
    """Where the shipped vocabulary is installed."""
    return Path(str(resources.files("slamcli") / "data" / _DEFAULT_FILE))


def _not_zip_reason(head: bytes) -> str:
    if not head:
        return "the file is empty"
    try:
        head.decode("ascii")
    except UnicodeDecodeError:
        return "not an .npz (zip) file"
    return "it holds text, not an .npz (zip) file"


def _not_vocabulary(path: Path, why: str) -> FormatError:
    return FormatError(path, f"not a slamcli ORB vocabulary ({why})", hint=TRAIN_HINT)


_MEMBERS = (
    "format",
    "version",
    "branching",
    "levels",
    "centroids",
    "children",
    "idf",
    "trained_images",
    "trained_descriptors",
    "seed",
)


def _read_members(path: Path, npz: Any) -> dict[str, NDArray[Any]]:
    names = set(npz.files)
    if "format" not in names:
        raise _not_vocabulary(path, "an .npz without the vocabulary's format tag")
    tag = npz["format"]
    if tag.shape != () or str(tag) != FORMAT_TAG:
        raise _not_vocabulary(path, f"format tag {str(tag)[:60]!r}, expected {FORMAT_TAG!r}")
    version = npz["version"] if "version" in names else None
    if version is None or version.shape != () or version.dtype.kind not in "iu":
        raise _not_vocabulary(path, "no format version")
    if int(version) > FORMAT_VERSION:
        raise InputError(
            f"{path}: vocabulary format version {int(version)} is newer than this slamcli "
            f"reads ({FORMAT_VERSION})",
            hint="upgrade slamcli, or retrain it with 'slamcli vocab train'",
        )
    missing = [m for m in _MEMBERS if m not in names]
    if missing:
        raise _not_vocabulary(path, f"missing {', '.join(missing)}")
    for big in ("centroids", "children", "idf"):
        # The header states the shape; refuse a huge one before numpy allocates it.
        shape = _member_shape(npz, big)
        if shape is not None and math.prod(shape) > MAX_NODES * DESCRIPTOR_BYTES:
            raise _not_vocabulary(path, f"{big} declares shape {shape}")
    return {m: npz[m] for m in _MEMBERS}


def _member_shape(npz: Any, name: str) -> tuple[int, ...] | None:
    with npz.zip.open(f"{name}.npy") as fh:
        version = np.lib.format.read_magic(fh)
        if version == (1, 0):
            shape, _, _ = np.lib.format.read_array_header_1_0(fh)
        elif version == (2, 0):
            shape, _, _ = np.lib.format.read_array_header_2_0(fh)
        else:
            return None
    return tuple(int(s) for s in shape)


def _scalar(path: Path, arrays: dict[str, NDArray[Any]], name: str) -> int:
    a = arrays[name]
    if a.shape != () or a.dtype.kind not in "iu":
        raise _not_vocabulary(path, f"{name} is not an integer")
    return int(a)


def _from_arrays(path: Path, arrays: dict[str, NDArray[Any]]) -> Vocabulary:
    k = _scalar(path, arrays, "branching")
    levels = _scalar(path, arrays, "levels")
    centroids, children, idf = arrays["centroids"], arrays["children"], arrays["idf"]
    m = centroids.shape[0] if centroids.ndim == 2 else -1
    problem = ""
    if not (2 <= k <= 1024 and 1 <= levels <= 32):
        problem = f"branching {k} and levels {levels} out of range"
    elif centroids.dtype != np.uint8 or centroids.shape[1:] != (DESCRIPTOR_BYTES,) or m < 1:
        problem = f"centroids are {centroids.shape} {centroids.dtype}, expected (M, 32) uint8"
    elif children.dtype != np.int32 or children.shape != (m, k):
        problem = f"children are {children.shape} {children.dtype}, expected ({m}, {k}) int32"
    elif ((children < -1) | (children >= m)).any():
        problem = "children name nodes that do not exist"
    else:
        ids = children[children >= 0]
        # Breadth-first numbering: every node except the root is the child of one earlier node.
        parent_of = np.repeat(np.arange(m), (children >= 0).sum(axis=1))
        if not (np.array_equal(np.sort(ids), np.arange(1, m)) and bool((parent_of < ids).all())):
            problem = "the tree's nodes are not numbered breadth first from the root"
    leaves = int((children < 0).all(axis=1).sum()) if not problem else 0
    if not problem and (idf.dtype != np.float32 or idf.shape != (leaves,)):
        problem = f"idf is {idf.shape} {idf.dtype}, expected ({leaves},) float32"
    if not problem and not bool(np.isfinite(idf).all()):
        problem = "idf holds values that are not finite"
    if problem:
        raise _not_vocabulary(path, problem)
    vocab = Vocabulary(
        branching=k,
        levels=levels,
        centroids=np.ascontiguousarray(centroids),
        children=np.ascontiguousarray(children),
        idf=idf,
        trained_images=_scalar(path, arrays, "trained_images"),
        trained_descriptors=_scalar(path, arrays, "trained_descriptors"),
        seed=_scalar(path, arrays, "seed"),
    )
    if int(vocab.node_level.max()) > levels:
        raise _not_vocabulary(path, f"the tree is deeper than its {levels} levels")
    return vocab


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


# -- training data from images and logs -----------------------------------------------------

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
"""Files a folder input is searched for (recursively); a file named directly may also be PNM,
BMP or WebP."""

INPUT_KINDS = "an image, a folder of PNG/JPEG images, a TUM RGB-D folder or an MCAP log"


@dataclass
class TrainingImages:
    """ORB descriptors of the training images, one array per image, and what was left out.

    Attributes:
        descriptors: one (N_i, 32) uint8 array per image used.
        names: the image each array came from (path, or ``log:frame name``).
        unreadable: images that could not be read or decoded, as ``"name: reason"``.
        not_8bit: images left out because they are not 8-bit (depth maps).
    """

    descriptors: list[U8]
    names: list[str]
    unreadable: list[str]
    not_8bit: list[str]

    @property
    def n_descriptors(self) -> int:
        return sum(int(d.shape[0]) for d in self.descriptors)


def _image_files(folder: Path) -> list[Path]:
    return sorted(
        p for p in folder.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file()
    )


def _plan_input(path: Path) -> list[Path] | None:
    """The image files of a file or folder input, or None for a log read through a source."""
    from slamcli.formats import sniff

    if not path.exists():
        raise InputError(f"{path}: no such file or folder", hint=f"give {INPUT_KINDS}")
    if path.is_dir():
        if sniff.tum_rgbd(path):
            return None
        files = _image_files(path)
        if not files:
            raise InputError(
                f"{path}: folder holds no {'/'.join(s[1:] for s in IMAGE_SUFFIXES)} images",
                hint=f"give {INPUT_KINDS}",
            )
        return files
    if sniff.mcap(path):
        return None
    return [path]


def _select(index: int, used: int, every: int, max_frames: int | None) -> bool:
    return index % every == 0 and (max_frames is None or used < max_frames)


def extract_training_descriptors(
    inputs: Sequence[str | Path],
    *,
    features: int = 1000,
    every: int = 1,
    max_frames: int | None = None,
    rgb_topic: str | None = None,
    progress: ProgressFn | None = None,
) -> TrainingImages:
    """ORB descriptors of every ``every``-th image of each input, for :meth:`Vocabulary.train`.

    Args:
        inputs: image files, folders of PNG/JPEG images (searched recursively, in sorted path
            order), TUM RGB-D folders (their colour images) or MCAP logs (their image topic).
        features: ORB features per image (``cv2.ORB`` with 8 levels, scale 1.2, on grey).
        every: use every K-th image of each input (the first is always used).
        max_frames: at most this many images from each input.
        rgb_topic: the image topic of MCAP inputs (default: the one image topic they have).
        progress: called as ``progress(done, total)`` per image used; ``total`` is None when an
            input is a log whose length is not known up front.

    Raises:
        InputError: an input is missing, not a kind listed above, or a file named directly is
            not a readable image; a folder's unreadable images are skipped and listed instead.
    """
    from slamcli.backends import import_cv2

    cv2 = import_cv2()
    if features < 1 or every < 1 or (max_frames is not None and max_frames < 1):
        raise ValueError("features, every and max_frames must be positive")
    plans = [(Path(p), _plan_input(Path(p))) for p in inputs]
    total: int | None = 0
    for _, files in plans:
        if files is None or total is None:
            total = None
        else:
            total += len(files[::every][:max_frames])
    orb = cv2.ORB.create(nfeatures=features, nlevels=8, scaleFactor=1.2)
    result = TrainingImages([], [], [], [])

    def use(name: str, gray: U8) -> None:
        _, desc = orb.detectAndCompute(gray, None)
        result.descriptors.append(
            np.zeros((0, DESCRIPTOR_BYTES), np.uint8) if desc is None else desc
        )
        result.names.append(name)
        if progress is not None:
            progress(len(result.names), total)

    for path, files in plans:
        used = 0
        if files is None:
            used = _from_source(
                path, every, max_frames, rgb_topic, cv2, use, result.not_8bit.append
            )
        else:
            named = len(files) == 1 and files[0] == path
            for i, file in enumerate(files):
                if not _select(i, used, every, max_frames):
                    continue
                gray, reason = _read_grey(file, cv2)
                if gray is None:
                    if named:
                        raise InputError(f"{file}: {reason}", hint=f"give {INPUT_KINDS}")
                    if reason == "not 8-bit":
                        result.not_8bit.append(str(file))
                    else:
                        result.unreadable.append(f"{file}: {reason}")
                    continue
                use(str(file), gray)
                used += 1
    return result


def _read_grey(path: Path, cv2: Any) -> tuple[U8 | None, str]:
    from slamcli.formats.images import decode_image, read_image_file

    data, reason = read_image_file(path)
    if data is None:
        return None, reason
    img, reason = decode_image(data)
    if img is None:
        return None, reason
    if img.dtype != np.uint8:
        return None, "not 8-bit"
    gray = _grey(img, cv2, rgb=False)
    return (gray, "") if gray is not None else (None, f"has an unsupported layout {img.shape}")


def _grey(img: NDArray[Any], cv2: Any, *, rgb: bool) -> U8 | None:
    """(H, W) uint8 grey from a grey, RGB/BGR or RGBA/BGRA uint8 image; None for other shapes."""
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return np.ascontiguousarray(img)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        codes = {
            (3, True): cv2.COLOR_RGB2GRAY,
            (4, True): cv2.COLOR_RGBA2GRAY,
            (3, False): cv2.COLOR_BGR2GRAY,
            (4, False): cv2.COLOR_BGRA2GRAY,
        }
        return np.asarray(cv2.cvtColor(img, codes[img.shape[2], rgb]), dtype=np.uint8)
    return None


def _from_source(
    path: Path,
    every: int,
    max_frames: int | None,
    rgb_topic: str | None,
    cv2: Any,
    use: Callable[[str, U8], None],
    not_8bit: Callable[[str], None],
) -> int:
    from slamcli.formats import open_source, sniff
    from slamcli.types import ImageFrame

    used = 0
    options = {"rgb_topic": rgb_topic} if rgb_topic and sniff.mcap(path) else {}
    with open_source(path, **options) as source:
        for i, frame in enumerate(source.frames(("image",))):
            if max_frames is not None and used >= max_frames:
                break
            if i % every or not isinstance(frame, ImageFrame):
                continue
            img, name = frame.image, f"{path}:{frame.name or frame.stamp_ns}"
            if img.dtype != np.uint8:
                not_8bit(name)
                continue
            gray = _grey(img, cv2, rgb=True)
            if gray is None:
                continue
            use(name, gray)
            used += 1
    return used
