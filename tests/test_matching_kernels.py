"""The compiled matchers of slamcli.vision.matching (match_ratio_grouped, match_by_projection)
against brute-force references written here: every candidate pair listed, ranked with Python
tuples, on seeded random descriptors drawn from small pools (so distances tie often) and on
real ORB features of the KITTI excerpt."""

from __future__ import annotations

import math
import subprocess
import sys
from typing import Any

import cv2
import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import ConfigError, InputError
from slamcli.vision.features import OrbSettings, extract_orb
from slamcli.vision.matching import match_by_projection, match_ratio_grouped
from slamcli.vision.vocabulary.files import default_vocabulary

Arr = np.ndarray[Any, Any]


def _bits(a: Arr, b: Arr) -> list[int]:
    """Hamming distances between the rows of ``a`` and the row ``b``, bit by bit."""
    x = np.bitwise_xor(a, b).astype(np.uint8)
    return np.unpackbits(x, axis=-1).reshape(len(a), -1).sum(axis=1).tolist()


def _pairs(rows: list[tuple[int, int]]) -> Arr:
    return np.array(sorted(rows, key=lambda r: r[1]), dtype=np.int64).reshape(-1, 2)


def _grouped_reference(
    da: Arr, ga: Arr, db: Arr, gb: Arr, ratio: float, max_distance: float
) -> Arr:
    """Each b: its group's a ranked by (distance, a); ratio test against the second (inf when
    alone); then each a keeps the b closest to it (lower b on a tie); rows (a, b) by b."""
    chosen: dict[int, tuple[int, int]] = {}
    for j in range(len(db)):
        cand = np.flatnonzero(ga == gb[j]).tolist()
        if not cand:
            continue
        ranked = sorted(zip(_bits(da[cand], db[j]), cand, strict=True))
        best_d, best_a = ranked[0]
        second = ranked[1][0] if len(ranked) > 1 else math.inf
        if best_d < ratio * second and best_d <= max_distance:
            chosen[j] = (best_a, best_d)
    keep: dict[int, tuple[int, int]] = {}
    for j, (a, d) in sorted(chosen.items()):
        if a not in keep or d < keep[a][1]:
            keep[a] = (j, d)
    return _pairs([(a, j) for a, (j, _d) in keep.items()])


def _projection_reference(
    pr: Arr,
    pdesc: Arr,
    radius: Arr,
    kp: Arr,
    kdesc: Arr,
    kp_oct: Arr | None,
    pred_oct: Arr | None,
    max_distance: float,
    ratio: float,
) -> Arr:
    """Each point: every keypoint within its radius (squared distances as numpy computes them
    for these dtypes) and, with both octave arrays, within one level; ranked by (distance,
    keypoint); kept within ``max_distance`` and, unless the second best is at another level,
    closer than ``ratio`` times it; then each keypoint keeps its closest point; rows (point,
    keypoint) by point. ``ratio`` > 0, so a lone candidate passes."""
    chosen: dict[int, tuple[int, int]] = {}
    for p in range(len(pr)):
        ok = np.sum((kp - pr[p]) ** 2, axis=1) <= radius[p] * radius[p]
        if kp_oct is not None and pred_oct is not None:
            ok &= np.abs(kp_oct.astype(np.int64) - pred_oct[p]) <= 1
        cand = np.flatnonzero(ok).tolist()
        if not cand:
            continue
        ranked = sorted(zip(_bits(kdesc[cand], pdesc[p]), cand, strict=True))
        best_d, best_k = ranked[0]
        if best_d > max_distance:
            continue
        if len(ranked) > 1:
            second_d, second_k = ranked[1]
            same_level = kp_oct is None or kp_oct[second_k] == kp_oct[best_k]
            if same_level and not best_d < ratio * second_d:
                continue
        chosen[p] = (best_k, best_d)
    keep: dict[int, tuple[int, int]] = {}
    for p, (k, d) in sorted(chosen.items()):
        if k not in keep or d < keep[k][1]:
            keep[k] = (p, d)
    return _pairs([(k, p) for k, (p, _d) in keep.items()])[:, ::-1]


def _pooled(rng: np.random.Generator, n: int, pool: Arr, flip: float) -> Arr:
    """``n`` descriptors copied from ``pool`` with a few bits flipped: many equal distances."""
    d = pool[rng.integers(0, len(pool), n)].copy()
    mask = rng.random(d.shape) < flip
    d[mask] ^= (np.uint8(1) << rng.integers(0, 8, int(mask.sum())).astype(np.uint8)).astype(
        np.uint8
    )
    return d


def _assert_same(got: Arr, want: Arr) -> None:
    assert got.dtype == np.int64
    assert got.shape == want.shape
    assert np.array_equal(got, want)


# --- match_ratio_grouped ---------------------------------------------------------------------


def test_grouped_matches_brute_force_on_tied_random_descriptors() -> None:
    rng = np.random.default_rng(20)
    matched = 0
    for trial in range(150):
        pool = rng.integers(0, 256, (int(rng.integers(1, 8)), 32), dtype=np.uint8)
        na, nb = int(rng.integers(1, 70)), int(rng.integers(1, 70))
        da = _pooled(rng, na, pool, 0.01)
        db = _pooled(rng, nb, pool, 0.01)
        ga = rng.integers(-2, 4, na)
        gb = rng.integers(-3, 5, nb)
        ratio = [0.6, 0.8, 1.0, 1.5][trial % 4]
        max_distance = [256, 50, 3][trial % 3]
        want = _grouped_reference(da, ga, db, gb, ratio, max_distance)
        _assert_same(match_ratio_grouped(da, ga, db, gb, ratio, max_distance), want)
        matched += len(want)
    assert matched > 500


def test_grouped_ties_go_to_the_lower_index() -> None:
    rng = np.random.default_rng(21)
    d = rng.integers(0, 256, (3, 32), dtype=np.uint8)
    # b0 is one bit from two equal a (0 and 2): the second is as close as the best, so the
    # ratio test fails below 1, and above 1 the lower a wins; b1 and b2 both pick a1 at
    # distance 0: the lower b keeps it.
    da = np.stack([d[0], d[1], d[0]])
    db = np.stack([d[0] ^ np.uint8(4), d[1], d[1]])
    ga = np.array([5, 7, 5])
    gb = np.array([5, 7, 7])
    assert match_ratio_grouped(da, ga, db, gb, 0.9).tolist() == [[1, 1]]
    assert match_ratio_grouped(da, ga, db, gb, 1.5).tolist() == [[0, 0], [1, 1]]


def test_grouped_does_not_depend_on_the_group_ids_values() -> None:
    """Small ids (bucketed) and ids spread over the whole int64 range (sorted) are one
    partition, so one result."""
    rng = np.random.default_rng(22)
    pool = rng.integers(0, 256, (120, 32), dtype=np.uint8)
    da, db = _pooled(rng, 300, pool, 0.02), _pooled(rng, 250, pool, 0.02)
    ga, gb = rng.integers(0, 6, 300), rng.integers(0, 7, 250)
    spread = np.array([-(2**62), -7, 0, 3, 2**40, 2**62, 2**63 - 1], dtype=np.int64)
    small = match_ratio_grouped(da, ga, db, gb, 0.9, 60)
    assert len(small) > 20
    _assert_same(match_ratio_grouped(da, spread[ga], db, spread[gb], 0.9, 60), small)
    _assert_same(match_ratio_grouped(da, ga.astype(np.int32), db, gb, 0.9, 60), small)


def test_grouped_descriptors_of_other_widths_and_empty_inputs() -> None:
    rng = np.random.default_rng(23)
    for width in (5, 8, 13, 64):
        pool = rng.integers(0, 256, (40, width), dtype=np.uint8)
        da, db = _pooled(rng, 60, pool, 0.05), _pooled(rng, 50, pool, 0.05)
        ga, gb = rng.integers(0, 3, 60), rng.integers(0, 3, 50)
        want = _grouped_reference(da, ga, db, gb, 0.9, 8 * width)
        assert len(want) > 0
        _assert_same(match_ratio_grouped(da, ga, db, gb, 0.9, 8 * width), want)
    empty = np.zeros((0, 32), np.uint8)
    one = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    none, g0, g1, g2 = (np.array(g, np.int64) for g in ([], [0], [1], [2]))
    for da, ga, db, gb in ((empty, none, one, g0), (one, g0, empty, none), (one, g1, one, g2)):
        _assert_same(match_ratio_grouped(da, ga, db, gb, 0.8), np.zeros((0, 2), np.int64))
    # A lone candidate passes the ratio test.
    assert match_ratio_grouped(one, g1, one, g1, 0.8).tolist() == [[0, 0]]


def test_grouped_rejects_malformed_input() -> None:
    d = np.zeros((4, 32), np.uint8)
    g = np.zeros(4, int)
    with pytest.raises(InputError, match="desc_b: expected"):
        match_ratio_grouped(d, g, d.astype(np.int16), g, 0.8)
    with pytest.raises(InputError, match="32 and 16 bytes"):
        match_ratio_grouped(d, g, d[:, :16], g, 0.8)
    with pytest.raises(InputError, match="group_a: expected 4 rows"):
        match_ratio_grouped(d, g[:3], d, g, 0.8)
    with pytest.raises(ConfigError, match="ratio"):
        match_ratio_grouped(d, g, d, g, 0.8j)  # type: ignore[arg-type]


# --- match_by_projection ---------------------------------------------------------------------


def _projection_case(
    rng: np.random.Generator, lattice: bool
) -> tuple[Arr, Arr, Arr, Arr, Arr, Arr, Arr]:
    n, p = int(rng.integers(1, 90)), int(rng.integers(1, 70))
    pool = rng.integers(0, 256, (int(rng.integers(1, 6)), 32), dtype=np.uint8)
    kdesc, pdesc = _pooled(rng, n, pool, 0.01), _pooled(rng, p, pool, 0.01)
    if lattice:
        # Pixels and radii on a lattice: distances exactly equal to the radius, points on cell
        # borders.
        step = float(rng.choice([1.0, 0.5, 0.25]))
        kp = rng.integers(0, 40, (n, 2)) * step
        pr = rng.integers(-2, 42, (p, 2)) * step
        radius = rng.choice([0.0, 1.0, 2.0, 3.0, 5.0], p) * step
    else:
        kp = rng.uniform(0, 80, (n, 2))
        pr = kp[rng.integers(0, n, p)] + rng.normal(0, 3, (p, 2))
        radius = rng.choice([1.5, 4.0, 9.0]) * 1.2 ** rng.integers(0, 4, p)
    kp_oct = rng.integers(0, 4, n).astype(np.int16)
    pred_oct = rng.integers(0, 4, p).astype(np.int64)
    return pr, pdesc, radius, kp, kdesc, kp_oct, pred_oct


def test_projection_matches_brute_force_on_tied_random_inputs() -> None:
    rng = np.random.default_rng(30)
    matched = 0
    for trial in range(160):
        pr, pdesc, radius, kp, kdesc, kp_oct, pred_oct = _projection_case(rng, trial % 2 == 0)
        if trial % 5 == 1:
            kp = kp.astype(np.float32)
        if trial % 7 == 2:
            pr = pr.astype(np.float32)
        if trial % 4 == 3:
            radius = radius.astype(np.float32)
        levels = trial % 3  # none, keypoint levels only, both
        ratio = [0.9, 0.75, 1.0, 1.3][trial % 4]
        max_distance = [100, 256, 40][trial % 3]
        got = match_by_projection(
            pr,
            pdesc,
            radius,
            kp,
            kdesc,
            kp_octaves=kp_oct if levels else None,
            predicted_octaves=pred_oct if levels == 2 else None,
            max_distance=max_distance,
            ratio=ratio,
        )
        want = _projection_reference(
            pr,
            pdesc,
            radius,
            kp,
            kdesc,
            kp_oct if levels else None,
            pred_oct if levels == 2 else None,
            max_distance,
            ratio,
        )
        _assert_same(got, want)
        matched += len(want)
    assert matched > 1000


def test_projection_ties_go_to_the_lower_index() -> None:
    rng = np.random.default_rng(31)
    d = rng.integers(0, 256, (1, 32), dtype=np.uint8)
    kp = np.array([[10.0, 10.0], [12.0, 10.0], [30.0, 30.0]])
    kdesc = np.repeat(d, 3, axis=0)
    # Point 0 sees keypoints 0 and 1 at distance 0 (ratio test fails unless they differ in
    # level); points 1 and 2 both want keypoint 2 at distance 0: point 1 keeps it.
    pr = np.array([[11.0, 10.0], [30.0, 31.0], [31.0, 30.0]])
    pdesc = np.repeat(d, 3, axis=0)
    radius = np.full(3, 3.0)
    same = np.zeros(3, np.int16)
    assert match_by_projection(pr, pdesc, radius, kp, kdesc, kp_octaves=same).tolist() == [[1, 2]]
    other = np.array([0, 1, 0], np.int16)
    assert match_by_projection(pr, pdesc, radius, kp, kdesc, kp_octaves=other).tolist() == [
        [0, 0],
        [1, 2],
    ]


def test_projection_skips_points_off_the_grid() -> None:
    """A point whose pixel is NaN, infinite or beyond int64 cells matches nothing and changes
    nothing for the others."""
    rng = np.random.default_rng(32)
    kp = rng.uniform(0, 100, (200, 2))
    kdesc = rng.integers(0, 256, (200, 32), dtype=np.uint8)
    src = rng.integers(0, 200, 60)
    pr = kp[src] + rng.normal(0, 1, (60, 2))
    pdesc = kdesc[src] ^ (rng.random((60, 32)) < 0.05).astype(np.uint8)
    radius = np.full(60, 5.0)
    base = match_by_projection(pr, pdesc, radius, kp, kdesc, ratio=0.95)
    assert len(base) > 30
    row = int(base[0, 0])
    for bad in (np.nan, np.inf, -np.inf, 1e300):
        moved = pr.copy()
        moved[row, 1] = bad
        got = match_by_projection(moved, pdesc, radius, kp, kdesc, ratio=0.95)
        with np.errstate(over="ignore", invalid="ignore"):
            want = _projection_reference(moved, pdesc, radius, kp, kdesc, None, None, 100, 0.95)
        _assert_same(got, want)
        assert row not in got[:, 0]


def test_projection_rejects_malformed_input() -> None:
    pr = np.zeros((3, 2))
    kp = np.ones((4, 2))
    pd, kd = np.zeros((3, 32), np.uint8), np.zeros((4, 32), np.uint8)
    r = np.ones(3)
    for radius in (np.array([1.0, -1.0, 2.0]), np.array([1.0, np.inf, 2.0]), np.full(3, np.nan)):
        with pytest.raises(InputError, match="radius_px: expected finite radii"):
            match_by_projection(pr, pd, radius, kp, kd)
    for bad in (np.nan, -np.inf):
        k = kp.copy()
        k[2, 0] = bad
        with pytest.raises(InputError, match="keypoints: expected finite pixels"):
            match_by_projection(pr, pd, r, k, kd)
    with pytest.raises(InputError, match="kp_desc: expected 4 rows"):
        match_by_projection(pr, pd, r, kp, kd[:3])
    with pytest.raises(InputError, match="predicted_octaves: expected 3 rows"):
        match_by_projection(
            pr,
            pd,
            r,
            kp,
            kd,
            kp_octaves=np.zeros(4, np.int16),
            predicted_octaves=np.zeros(2, np.int64),
        )
    with pytest.raises(InputError, match=r"projected: expected \(M, 2\)"):
        match_by_projection(np.zeros((3, 3)), pd, r, kp, kd)
    with pytest.raises(ConfigError, match="max_distance"):
        match_by_projection(pr, pd, r, kp, kd, max_distance=1j)  # type: ignore[arg-type]
    empty = match_by_projection(np.zeros((0, 2)), pd[:0], r[:0], kp, kd)
    _assert_same(empty, np.zeros((0, 2), np.int64))


# --- real ORB features -----------------------------------------------------------------------


@pytest.fixture(scope="module")
def kitti_features() -> list[Any]:
    """ORB features (2000 per image) of the left and right images of the first three KITTI
    pairs and of the fourth left image."""
    root = shared_path("stereo", "kitti_excerpt_1")
    names = sorted(p.name for p in (root / "image_l").glob("*.png"))[:4]
    feats = []
    for i, name in enumerate(names):
        sides = ("image_l", "image_r") if i < 3 else ("image_l",)
        for side in sides:
            grey = np.asarray(cv2.imread(str(root / side / name), cv2.IMREAD_GRAYSCALE), np.uint8)
            feats.append(extract_orb(grey, OrbSettings(n_features=2000)))
    return feats


def test_grouped_matches_brute_force_on_kitti_orb(kitti_features: list[Any]) -> None:
    vocabulary = default_vocabulary()
    for i in range(3):
        left, right = kitti_features[2 * i], kitti_features[2 * i + 1]
        for level, ratio, max_distance in ((3, 0.8, 50), (2, 0.6, 256)):
            ga = vocabulary.nodes(right.descriptors, level)
            gb = vocabulary.nodes(left.descriptors, level)
            args = (right.descriptors, ga, left.descriptors, gb, ratio, max_distance)
            want = _grouped_reference(*args)
            assert len(want) > 200
            _assert_same(match_ratio_grouped(*args), want)


def test_projection_matches_brute_force_on_kitti_orb(kitti_features: list[Any]) -> None:
    rng = np.random.default_rng(33)
    for i in range(3):
        now, later = kitti_features[2 * i], kitti_features[2 * i + 2]
        pr = now.keypoints.astype(np.float64) + rng.normal(0, 1.5, now.keypoints.shape)
        pred = now.octaves.astype(np.int64)
        for scale, keypoints in ((4.0, later.keypoints), (15.0, later.keypoints.astype(float))):
            radius = scale * 1.2**pred
            args = (pr, now.descriptors, radius, keypoints, later.descriptors)
            got = match_by_projection(
                *args, kp_octaves=later.octaves, predicted_octaves=pred, ratio=0.9
            )
            want = _projection_reference(*args, later.octaves, pred, 100, 0.9)
            assert len(want) > 300
            _assert_same(got, want)


def test_importing_matching_leaves_numba_unimported() -> None:
    code = "import sys, slamcli.vision.matching; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
