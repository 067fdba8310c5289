"""Vocabulary files: one compressed ``.npz`` of the tree's arrays, written byte for byte the same
for the same vocabulary, and read back with every array checked before it is used."""

from __future__ import annotations

import functools
import io
import math
import zipfile
import zlib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import FormatError, InputError
from slamcli.formats.base import npy_header
from slamcli.vision.vocabulary.tree import (
    DESCRIPTOR_BYTES,
    FORMAT_TAG,
    FORMAT_VERSION,
    MAX_NODES,
    TRAIN_HINT,
    Vocabulary,
)

_DEFAULT_FILE = "orb_vocabulary.npz"


def _arrays(vocab: Vocabulary) -> dict[str, NDArray[Any]]:
    return {
        "format": np.array(FORMAT_TAG),
        "version": np.array(FORMAT_VERSION, np.int32),
        "branching": np.array(vocab.branching, np.int32),
        "levels": np.array(vocab.levels, np.int32),
        "centroids": vocab.centroids,
        "children": vocab.children,
        "idf": vocab.idf,
        "trained_images": np.array(vocab.trained_images, np.int64),
        "trained_descriptors": np.array(vocab.trained_descriptors, np.int64),
        "seed": np.array(vocab.seed, np.int64),
    }


def save_vocabulary(vocab: Vocabulary, path: str | Path) -> Path:
    """Write ``vocab`` as one compressed .npz, atomically; returns the path.

    The zip entries carry a fixed timestamp, so the same vocabulary gives the same bytes
    (``numpy.savez_compressed`` stamps the current time).
    """
    dest = Path(path)
    with atomic_path(dest) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, arr in _arrays(vocab).items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compresslevel=9)
    return dest


def load_vocabulary(path: str | Path) -> Vocabulary:
    """Read a vocabulary written by :func:`save_vocabulary`.

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


def default_vocabulary() -> Vocabulary:
    """The vocabulary shipped with slamcli, loaded once."""
    return _default_vocabulary()


@functools.cache
def _default_vocabulary() -> Vocabulary:
    return load_vocabulary(default_vocabulary_path())


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
        header = npy_header(npz, big)
        shape = header[0] if header is not None else None
        if shape is not None and math.prod(shape) > MAX_NODES * DESCRIPTOR_BYTES:
            raise _not_vocabulary(path, f"{big} declares shape {shape}")
    return {m: npz[m] for m in _MEMBERS}


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
