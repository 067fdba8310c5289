"""The ORB bag-of-words vocabulary, the keyframe database and ``slamcli vocab``.

Place recognition is checked on a rendered room the shipped vocabulary was not trained on
(texture seed 0; the vocabulary saw seeds 1-4): keyframes every 27 frames around one loop,
queries 6 frames after each keyframe.
"""

from __future__ import annotations

import time
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import InputError
from slamcli.synth.rgbd import build_rgbd_world
from slamcli.vision.vocabulary import (
    BowVector,
    KeyframeDatabase,
    Vocabulary,
    default_vocabulary,
    load_vocabulary,
    save_vocabulary,
    train_vocabulary,
)
from slamcli.vision.vocabulary import files as vocabulary_module

FRAMES = 540  # one loop around the room
KEYFRAMES = list(range(0, FRAMES, 27))
QUERY_OFFSET = 6


def _orb(gray: np.ndarray, features: int = 1000) -> np.ndarray:
    orb = cv2.ORB.create(nfeatures=features, nlevels=8, scaleFactor=1.2)
    _, desc = orb.detectAndCompute(gray, None)
    return desc


@pytest.fixture(scope="module")
def room() -> dict[int, np.ndarray]:
    """Grey 320x240 renders of the keyframes and the query frames (about 6 s)."""
    world = build_rgbd_world(FRAMES, (320, 240), seed=0)
    wanted = sorted({*KEYFRAMES, *(k + QUERY_OFFSET for k in KEYFRAMES)})
    return {
        i: cv2.cvtColor(world.render(world.trajectory.world_from_body[i])[0], cv2.COLOR_RGB2GRAY)
        for i in wanted
    }


@pytest.fixture(scope="module")
def descriptors(room: dict[int, np.ndarray]) -> dict[int, np.ndarray]:
    return {i: _orb(gray) for i, gray in room.items()}


@pytest.fixture(scope="module")
def small_vocab(descriptors: dict[int, np.ndarray]) -> Vocabulary:
    return train_vocabulary([descriptors[k] for k in KEYFRAMES[:6]], branching=8, levels=3)


def test_training_is_deterministic_to_the_byte(
    descriptors: dict[int, np.ndarray], tmp_path: Path
) -> None:
    images = [descriptors[k] for k in KEYFRAMES[:4]]
    save_vocabulary(train_vocabulary(images, branching=6, levels=3, seed=7), tmp_path / "a.npz")
    save_vocabulary(train_vocabulary(images, branching=6, levels=3, seed=7), tmp_path / "b.npz")
    save_vocabulary(train_vocabulary(images, branching=6, levels=3, seed=8), tmp_path / "c.npz")
    a, b, c = ((tmp_path / n).read_bytes() for n in ("a.npz", "b.npz", "c.npz"))
    assert a == b
    assert a != c  # the seed matters, so the equality above is not vacuous
    # A flat array with per-image counts is the same training input as the list.
    flat = train_vocabulary(
        np.concatenate(images),
        branching=6,
        levels=3,
        seed=7,
        per_image_counts=list(map(len, images)),
    )
    save_vocabulary(flat, tmp_path / "d.npz")
    assert (tmp_path / "d.npz").read_bytes() == a


def test_words_bow_and_direct_index(
    small_vocab: Vocabulary, descriptors: dict[int, np.ndarray]
) -> None:
    vocab = small_vocab
    desc = descriptors[KEYFRAMES[10]]
    words = vocab.words(desc)
    assert words.shape == (len(desc),) and words.dtype == np.int32
    assert words.min() >= 0 and words.max() < vocab.n_words
    assert vocab.n_words > 8**2  # the tree goes below the first two levels
    assert vocab.words(np.zeros((0, 32), np.uint8)).shape == (0,)
    assert len(vocab.bow(np.zeros((0, 32), np.uint8))) == 0

    bow = vocab.bow(desc)
    assert bow.words.dtype == np.int32 and bow.weights.dtype == np.float32
    assert np.all(np.diff(bow.words) > 0)
    assert np.all(bow.weights > 0)
    assert float(bow.weights.sum(dtype=np.float64)) == pytest.approx(1.0, abs=1e-5)

    # Same word implies same node at every level above: the direct index never separates them.
    level1, level2 = vocab.nodes(desc, 1), vocab.nodes(desc, 2)
    assert level1.shape == words.shape and len(np.unique(level1)) > 1
    for w in np.unique(words)[:50]:
        assert len(np.unique(level1[words == w])) == 1
        assert len(np.unique(level2[words == w])) == 1
    assert np.array_equal(vocab.nodes(desc, vocab.levels), vocab.word_node[words])


def _descend_by_hand(vocab: Vocabulary, desc: np.ndarray, level: int) -> list[int]:
    """The node each descriptor reaches at ``level``: the nearest child centroid per level,
    the first child on a tie, a leaf above ``level`` kept (one descriptor at a time)."""
    bits = np.unpackbits(vocab.centroids, axis=1)
    out = []
    for d in np.unpackbits(desc, axis=1):
        node = 0
        for _ in range(level):
            kids = [int(c) for c in vocab.children[node] if c >= 0]
            if not kids:
                break
            dist = [int(np.count_nonzero(bits[c] != d)) for c in kids]
            node = kids[dist.index(min(dist))]
        out.append(node)
    return out


def test_descent_takes_the_nearest_child_and_the_first_on_a_tie(
    small_vocab: Vocabulary, descriptors: dict[int, np.ndarray]
) -> None:
    rng = np.random.default_rng(3)
    kids = small_vocab.children[0][small_vocab.children[0] >= 0]
    between = small_vocab.centroids[kids[:4]].copy()
    between[:, :4] = 0  # near, and often equally near, several first-level centroids
    desc = np.concatenate(
        [
            descriptors[KEYFRAMES[7]][:300],
            rng.integers(0, 256, (200, 32), dtype=np.uint8),
            small_vocab.centroids[1:60],  # exactly on a node: distance 0 there
            between,
        ]
    )
    for level in range(small_vocab.levels + 1):
        got = small_vocab.nodes(desc, level)
        assert got.dtype == np.int32
        assert got.tolist() == _descend_by_hand(small_vocab, desc, level)


def test_score_identical_neighbour_and_unrelated(descriptors: dict[int, np.ndarray]) -> None:
    vocab = default_vocabulary()
    bows = {i: vocab.bow(d) for i, d in descriptors.items()}
    first = bows[KEYFRAMES[0]]
    assert Vocabulary.score(first, first) == pytest.approx(1.0, abs=1e-9)
    assert Vocabulary.score(first, BowVector(np.zeros(0, np.int32), np.zeros(0, np.float32))) == 0
    for n, k in enumerate(KEYFRAMES):
        far = KEYFRAMES[(n + len(KEYFRAMES) // 2) % len(KEYFRAMES)]  # the other side of the room
        near = Vocabulary.score(bows[k], bows[k + QUERY_OFFSET])
        unrelated = Vocabulary.score(bows[far], bows[k + QUERY_OFFSET])
        assert 0 <= unrelated < near <= 1, (k, near, unrelated)


def test_database_ranks_the_neighbouring_keyframe_first(
    descriptors: dict[int, np.ndarray],
) -> None:
    vocab = default_vocabulary()
    db = KeyframeDatabase(vocab)
    for k in KEYFRAMES:
        db.add(k, vocab.bow(descriptors[k]))
    assert len(db) == len(KEYFRAMES)
    for k in KEYFRAMES:
        query = vocab.bow(descriptors[k + QUERY_OFFSET])
        results = db.query(query)
        assert results[0][0] == k, (k, results[:3])
        scores = [s for _, s in results]
        assert scores == sorted(scores, reverse=True)
        assert results[0][1] == pytest.approx(Vocabulary.score(query, db._bows[k]), abs=1e-6)
        # Excluding the true match (as loop closure excludes covisible keyframes) drops it.
        assert k not in [kf for kf, _ in db.query(query, exclude={k})]
    # A removed keyframe is no longer found; max_results bounds the answer.
    db.remove(KEYFRAMES[3])
    query = vocab.bow(descriptors[KEYFRAMES[3] + QUERY_OFFSET])
    assert KEYFRAMES[3] not in [kf for kf, _ in db.query(query, min_common_ratio=0.0)]
    assert len(db.query(query, min_common_ratio=0.0, max_results=2)) == 2


def _bad_files(tmp_path: Path, good: Path) -> dict[str, Path]:
    text = tmp_path / "text.npz"
    text.write_text("not a vocabulary\n")
    other = tmp_path / "other.npz"
    np.savez_compressed(other, a=np.arange(5))
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    # Right tag, but the tree arrays are inconsistent.
    broken = tmp_path / "broken.npz"
    with np.load(good) as npz:
        arrays = {name: npz[name] for name in npz.files}
    arrays["children"] = arrays["children"][:-3]
    np.savez_compressed(broken, **arrays)
    # A zip whose member is damaged.
    damaged = tmp_path / "damaged.npz"
    with zipfile.ZipFile(good) as zf, zipfile.ZipFile(damaged, "w") as out:
        for info in zf.infolist():
            data = zf.read(info)
            out.writestr(info, data[: len(data) // 2] if info.filename == "centroids.npy" else data)
    return {
        "missing": tmp_path / "missing.npz",
        "folder": tmp_path,
        "text": text,
        "other npz": other,
        "truncated": truncated,
        "empty": empty,
        "broken tree": broken,
        "damaged member": damaged,
    }


def test_load_errors_are_one_line_input_errors(small_vocab: Vocabulary, tmp_path: Path) -> None:
    good = save_vocabulary(small_vocab, tmp_path / "good.npz")
    assert load_vocabulary(good).n_words == small_vocab.n_words
    runner = CliRunner()
    for kind, path in _bad_files(tmp_path, good).items():
        with pytest.raises(InputError) as info:
            load_vocabulary(path)
        assert str(path) in info.value.msg, kind
        assert "\n" not in info.value.msg, kind
        if kind != "folder":
            assert "slamcli vocab train" in (info.value.hint or ""), kind
        result = runner.invoke(app, ["vocab", "info", str(path)])
        output = result.stdout + result.stderr
        assert result.exit_code == 1, (kind, output)
        assert "Traceback" not in output and "error:" in output, kind


def test_default_vocabulary_is_small_and_loads_fast() -> None:
    path = vocabulary_module.default_vocabulary_path()
    assert path.stat().st_size <= 10 * 2**20
    vocabulary_module._default_vocabulary.cache_clear()
    started = time.process_time()
    vocab = default_vocabulary()
    assert time.process_time() - started < 0.5
    assert default_vocabulary() is vocab  # cached
    assert vocab.n_words >= 5000 and vocab.trained_images >= 100
    assert np.all(vocab.idf >= 0)


def test_vocab_train_cli_end_to_end(room: dict[int, np.ndarray], tmp_path: Path) -> None:
    images = tmp_path / "images" / "sub"
    images.mkdir(parents=True)
    for k in KEYFRAMES[:4]:
        cv2.imwrite(str(images / f"{k:04d}.png"), room[k])
    (images / "notes.txt").write_text("not an image, ignored")
    out = tmp_path / "vocab.npz"
    args = ["vocab", "train", str(tmp_path / "images"), "--out", str(out), "--levels", "2"]
    runner = CliRunner()
    result = runner.invoke(app, [*args, "--features", "500", "--every", "2"])
    assert result.exit_code == 0, result.output
    assert "images" in result.stdout and "words" in result.stdout
    vocab = load_vocabulary(out)
    assert vocab.trained_images == 2 and vocab.levels == 2
    # The command trains exactly what the library trains on the same images.
    expected = train_vocabulary([_orb(room[k], 500) for k in KEYFRAMES[:4:2]], levels=2)
    assert np.array_equal(vocab.centroids, expected.centroids)
    assert np.array_equal(vocab.idf, expected.idf)

    again = runner.invoke(app, args)
    assert again.exit_code == 1 and "already exists" in again.stderr
    assert load_vocabulary(out).trained_images == 2  # untouched

    missing = runner.invoke(
        app, ["vocab", "train", str(tmp_path / "nope"), "--out", str(tmp_path / "new.npz")]
    )
    assert missing.exit_code == 1 and str(tmp_path / "nope") in missing.stderr
    assert "Traceback" not in missing.stdout + missing.stderr

    info = runner.invoke(app, ["vocab", "info", str(out)])
    assert info.exit_code == 0 and "2 images" in info.stdout
