"""Stereo matching along rectified rows: a synthetic pair of known depth, the first KITTI and
EuRoC pairs (checked against OpenCV's semi-global matcher), the matcher's contracts, and the
compiled matcher against a brute-force reference written out below, on seeded random inputs full
of ties and on real ORB features."""

from __future__ import annotations

import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from conftest import shared_path
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.formats import open_source
from slamcli.types import PinholeCamera, StereoFrame, StereoRig
from slamcli.vision import stereo
from slamcli.vision.features import Features, OrbSettings, extract_orb
from slamcli.vision.stereo import StereoMatches, StereoSettings, match_stereo

SETTINGS = StereoSettings()


@dataclass(frozen=True)
class Matched:
    frame: StereoFrame
    left: Features
    right: Features
    matches: StereoMatches


def _first_pair(*parts: str, n_features: int) -> Matched:
    with open_source(shared_path(*parts)) as source:
        frame = next(f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame))
    orb = OrbSettings(n_features=n_features)
    left, right = extract_orb(frame.left, orb), extract_orb(frame.right, orb)
    return Matched(
        frame, left, right, match_stereo(left, right, frame.left, frame.right, frame.rig)
    )


@pytest.fixture(scope="module")
def kitti() -> Matched:
    return _first_pair("stereo", "kitti_excerpt_1", n_features=2000)


@pytest.fixture(scope="module")
def euroc() -> Matched:
    return _first_pair("stereo", "euroc_V1_01_micro", n_features=1000)


def _texture(h: int, w: int, seed: int) -> NDArray[np.float64]:
    """Seeded noise blurred at three scales, grey levels around 128."""
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w))
    for sigma, amp in ((1.0, 0.5), (3.0, 1.0), (8.0, 1.5)):
        img += amp * sigma * cv2.GaussianBlur(rng.standard_normal((h, w)), (0, 0), sigma)
    img = (img - img.mean()) / img.std()
    return np.clip(128.0 + 40.0 * img, 0.0, 255.0)


def _shifted(left: NDArray[np.float64], a: float, b: float) -> NDArray[np.uint8]:
    """The right image of a plane whose disparity at left column x is ``a + b * x``: the left
    pixel x shows at ``x - (a + b x)``, so right column r samples the left at
    ``(r + a) / (1 - b)``."""
    h, w = left.shape
    cols = ((np.arange(w, dtype=np.float64) + a) / (1.0 - b)).astype(np.float32)
    map_x = np.tile(cols, (h, 1))
    map_y = np.tile(np.arange(h, dtype=np.float32)[:, None], (1, w))
    right = cv2.remap(
        left.astype(np.float32), map_x, map_y, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT
    )
    return np.clip(np.rint(right), 0, 255).astype(np.uint8)


def _check_contract(m: StereoMatches, left: Features, right: Features) -> None:
    """Unmatched entries are NaN / -1, matched ones finite; no right keypoint used twice; the
    counts add up; matched rows lie within the band."""
    ok = m.matched
    assert m.u_right.shape == m.depth_m.shape == m.right_index.shape == (len(left),)
    assert m.u_right.dtype == m.depth_m.dtype == np.float64
    assert np.all(np.isnan(m.u_right[~ok])) and np.all(np.isnan(m.depth_m[~ok]))
    assert np.all(np.isfinite(m.u_right[ok])) and np.all(np.isfinite(m.depth_m[ok]))
    used = m.right_index[ok]
    assert np.unique(used).size == used.size
    assert m.n_matched == int(ok.sum()) <= m.n_refined <= m.n_descriptor
    rows_l = left.keypoints[ok, 1].astype(np.float64)
    rows_r = right.keypoints[used, 1].astype(np.float64)
    band = SETTINGS.band_px * SETTINGS.scale ** right.octaves[used].astype(np.float64)
    assert np.all(np.abs(rows_l - rows_r) <= band + 1e-6)
    assert np.all(np.abs(left.octaves[ok] - right.octaves[used]) <= 1)
    assert np.all(m.depth_m[ok] > 0)
    assert np.all(m.u_right[ok] < left.keypoints[ok, 0])


@pytest.mark.parametrize(
    ("a", "b"),
    [(23.4, 0.0), (12.3, 0.05)],
    ids=["fronto-parallel", "slanted"],
)
def test_synthetic_plane_depths(a: float, b: float) -> None:
    h, w = 480, 640
    texture = _texture(h, w, seed=7)
    left_img = np.rint(texture).astype(np.uint8)
    right_img = _shifted(texture, a, b)
    rig = StereoRig(PinholeCamera(w, h, 500.0, 500.0, w / 2, h / 2), baseline_m=0.1)
    left, right = extract_orb(left_img), extract_orb(right_img)
    m = match_stereo(left, right, left_img, right_img, rig)
    _check_contract(m, left, right)
    assert m.n_matched > len(left) / 2
    ok = m.matched
    disparity = a + b * left.keypoints[ok, 0].astype(np.float64)
    truth = 500.0 * 0.1 / disparity
    rel = np.abs(m.depth_m[ok] / truth - 1.0)
    assert np.mean(rel < 0.02) >= 0.9
    assert np.median(rel) < 0.01


def test_kitti_first_pair(kitti: Matched) -> None:
    m, left = kitti.matches, kitti.left
    assert len(left) == 2000
    _check_contract(m, left, kitti.right)
    assert m.n_matched >= 0.4 * len(left)
    depth = m.depth_m[m.matched]
    # About 6 % of this road scene's matches are genuinely beyond 80 m (trees and buildings at
    # the end of the road: SGBM agrees, see below), so the band holds 90 %, not all.
    assert np.mean((depth > 0.5) & (depth < 80.0)) >= 0.9
    assert np.all(depth > 0.5)


def test_kitti_disparity_agrees_with_sgbm(kitti: Matched) -> None:
    frame, m = kitti.frame, kitti.matches
    block = 5
    sgbm = cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=192,
        blockSize=block,
        P1=8 * block * block,
        P2=32 * block * block,
        uniquenessRatio=10,
        speckleWindowSize=100,
        speckleRange=2,
        disp12MaxDiff=1,
    )
    dense = sgbm.compute(frame.left, frame.right).astype(np.float64) / 16.0
    kp = kitti.left.keypoints[m.matched].astype(np.float64)
    u, v = np.rint(kp[:, 0]).astype(np.int64), np.rint(kp[:, 1]).astype(np.int64)
    reference = dense[v, u]
    valid = reference > 0
    assert valid.mean() > 0.5
    ours = kp[:, 0] - m.u_right[m.matched]
    assert np.mean(np.abs(ours - reference)[valid] < 1.0) >= 0.8
    # The far matches are far for SGBM too: under 10 px of disparity (beyond 38 m).
    far = valid & (m.depth_m[m.matched] > 80.0)
    assert np.mean(reference[far] < 10.0) >= 0.9


def test_kitti_is_deterministic(kitti: Matched) -> None:
    f = kitti.frame
    again = match_stereo(kitti.left, kitti.right, f.left, f.right, f.rig)
    np.testing.assert_array_equal(again.right_index, kitti.matches.right_index)
    np.testing.assert_array_equal(again.u_right, kitti.matches.u_right)


def test_euroc_first_pair(euroc: Matched) -> None:
    m = euroc.matches
    _check_contract(m, euroc.left, euroc.right)
    assert m.n_matched >= 0.3 * len(euroc.left)
    depth = m.depth_m[m.matched]
    assert np.all((depth > 0.3) & (depth < 20.0))


def test_no_features_and_bad_input() -> None:
    img = np.zeros((60, 80), np.uint8)
    rig = StereoRig(PinholeCamera(80, 60, 50.0, 50.0, 40.0, 30.0), baseline_m=0.1)
    kp = Features(
        np.array([[40.0, 30.0]], np.float32),
        np.zeros(1, np.int16),
        np.zeros((1, 32), np.uint8),
        np.ones(1, np.float32),
    )
    m = match_stereo(kp, Features.empty(), img, img, rig)
    assert m.n_matched == 0 and np.isnan(m.depth_m).all() and m.right_index.tolist() == [-1]
    with pytest.raises(InputError, match="differ in size"):
        match_stereo(kp, kp, img, img[:50], rig)
    with pytest.raises(InputError, match="uint8"):
        match_stereo(kp, kp, img.astype(np.float32), img, rig)
    with pytest.raises(ConfigError, match=r"stereo\.band_px"):
        match_stereo(kp, kp, img, img, rig, StereoSettings(band_px=0.0))


def test_far_right_keypoints_are_not_candidates() -> None:
    """A right keypoint with the left one's descriptor, but beyond the disparity limit (or on
    another row), is not matched."""
    rig = StereoRig(PinholeCamera(400, 300, 100.0, 100.0, 200.0, 150.0), baseline_m=0.5)
    img = np.rint(_texture(300, 400, seed=3)).astype(np.uint8)
    desc = np.random.default_rng(1).integers(0, 256, (1, 32), dtype=np.uint8)

    def one(u: float, v: float) -> Features:
        pts = np.array([[u, v]], np.float32)
        return Features(pts, np.zeros(1, np.int16), desc.copy(), np.ones(1, np.float32))

    # Max disparity = fx * b / min depth = 100 * 0.5 / 0.5 = 100 px.
    settings = StereoSettings(min_depth_m=0.5)
    for right_kp in (one(80.0, 150.0), one(250.0, 150.0), one(180.0, 156.0)):
        m = match_stereo(one(200.0, 150.0), right_kp, img, img, rig, settings)
        assert m.n_descriptor == 0 and not m.matched.any()
    inside = match_stereo(one(200.0, 150.0), one(170.0, 151.0), img, img, rig, settings)
    assert inside.n_descriptor == 1


# The brute-force reference: every (left, right) pair is tested, one pair refined at a time.


def _np_lt(a: NDArray[np.float64], b: NDArray[np.float64] | float) -> NDArray[np.bool_]:
    """``a < b`` in numpy's sort order (NaN after every number): the order of the row band's
    two ``np.searchsorted`` calls on sorted rows, which the matcher's specification uses."""
    return (a < b) | (np.isnan(b) & ~np.isnan(a))


def _reference_pairs(
    left: Features, right: Features, max_disp: float, s: StereoSettings
) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(left, right) descriptor matches, in increasing left index, by testing every pair."""
    ul, vl = (left.keypoints[:, c].astype(np.float64) for c in (0, 1))
    ur, vr = (right.keypoints[:, c].astype(np.float64) for c in (0, 1))
    ol, orr = left.octaves.astype(np.int64), right.octaves.astype(np.int64)
    band = np.array([s.band_px * s.scale ** float(o) for o in orr], np.float64)
    bits_l = np.unpackbits(left.descriptors, axis=1)
    bits_r = np.unpackbits(right.descriptors, axis=1)
    chosen: dict[int, tuple[int, int]] = {}
    for i in range(len(left)):
        disp = ul[i] - ur
        near = (
            (np.abs(orr - ol[i]) <= 1)
            & ~_np_lt(vr, vl[i] - band)
            & ~_np_lt(vl[i] + band, vr)
            & (disp >= 0.0)
            & (disp <= max_disp)
        )
        js = np.flatnonzero(near)
        if js.size:
            dist = (bits_r[js] != bits_l[i]).sum(axis=1)
            k = int(np.lexsort((js, dist))[0])
            if dist[k] < s.max_hamming:
                chosen[i] = (int(dist[k]), int(js[k]))
    owner: dict[int, tuple[int, int]] = {}
    for i in sorted(chosen):
        d, j = chosen[i]
        if j not in owner or d < owner[j][0]:
            owner[j] = (d, i)
    pairs = sorted((i, j) for j, (_, i) in owner.items())
    out = np.array(pairs, np.int64).reshape(-1, 2)
    return out[:, 0].copy(), out[:, 1].copy()


def _reference_pyramid(image: NDArray[np.uint8], levels: int, scale: float) -> list[NDArray]:
    h, w = image.shape
    out = [image]
    for level in range(1, levels):
        f = scale**level
        out.append(cv2.resize(image, (max(1, round(w / f)), max(1, round(h / f)))))
    return out


def _reference(
    left: Features,
    right: Features,
    img_l: NDArray[np.uint8],
    img_r: NDArray[np.uint8],
    rig: StereoRig,
    s: StereoSettings = SETTINGS,
) -> StereoMatches:
    """:func:`match_stereo` written out: brute-force pairs, then each pair's SAD costs in
    float32 over explicit patches, the parabola, the disparity and median rules."""
    n = len(left)
    if n == 0 or len(right) == 0:
        return StereoMatches.unmatched(n)
    fx_b = rig.camera.fx * rig.baseline_m
    max_disp = fx_b / (rig.baseline_m if s.min_depth_m is None else s.min_depth_m)
    il, ir = _reference_pairs(left, right, max_disp, s)
    m = il.size
    w, reach = s.patch_radius_px, s.search_radius_px
    span = 2 * reach + 1
    octave = left.octaves[il].astype(np.int64)
    factor = s.scale ** octave.astype(np.float64)  # numpy's power, as the specification has it
    levels = int(octave.max()) + 1 if m else 1
    pyr_l = _reference_pyramid(img_l, levels, s.scale)
    pyr_r = _reference_pyramid(img_r, levels, s.scale)
    u_r, sad, ok = np.zeros(m), np.zeros(m), np.zeros(m, bool)
    for k in range(m):
        f = factor[k]
        lvl_l, lvl_r = pyr_l[octave[k]], pyr_r[octave[k]]
        h, wd = lvl_l.shape
        u = int(np.rint(left.keypoints[il[k], 0] / f))
        v = int(np.rint(left.keypoints[il[k], 1] / f))
        r = int(np.rint(right.keypoints[ir[k], 0] / f))
        inside = w <= v < h - w and w <= u < wd - w and w + reach <= r < wd - w - reach
        cost = np.zeros(span, np.float32)
        if inside:
            patch = lvl_l[v - w : v + w + 1, u - w : u + w + 1].astype(np.float32)
            patch -= patch[w, w]
            for i in range(span):
                c = r - reach + i
                window = lvl_r[v - w : v + w + 1, c - w : c + w + 1].astype(np.float32)
                cost[i] = np.abs(patch - (window - window[w, w])).sum()
        else:
            r = 0
        best = int(np.argmin(cost))
        b = min(max(best, 1), span - 2)
        d1, d2, d3 = (float(cost[b + j]) for j in (-1, 0, 1))
        denom = 2.0 * (d1 + d3 - 2.0 * d2)
        delta = 0.0 if denom <= 0.0 else (d1 - d3) / denom
        ok[k] = inside and 0 < best < span - 1 and denom > 0.0 and abs(delta) <= s.max_offset_px
        u_r[k] = f * ((r + (best - reach)) + delta)
        sad[k] = float(cost[best])
    disparity = left.keypoints[il, 0].astype(np.float64) - u_r
    ok &= (disparity > 0.0) & (disparity < max_disp)
    il, ir, u_r, sad, disparity = il[ok], ir[ok], u_r[ok], sad[ok], disparity[ok]
    n_refined = int(il.size)
    if il.size:
        keep = sad <= s.outlier_factor * np.sort(sad)[il.size // 2]
        il, ir, u_r, disparity = il[keep], ir[keep], u_r[keep], disparity[keep]
    out = StereoMatches.unmatched(n)
    out.u_right[il] = u_r
    out.depth_m[il] = fx_b / disparity
    out.right_index[il] = ir
    return StereoMatches(out.u_right, out.depth_m, out.right_index, m, n_refined, int(il.size))


def _assert_same(got: StereoMatches, want: StereoMatches) -> None:
    """Bit for bit: values (NaN where NaN), dtypes and counts."""
    for name in ("u_right", "depth_m", "right_index"):
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        np.testing.assert_array_equal(a, b, err_msg=name, strict=True)
    assert (got.n_descriptor, got.n_refined, got.n_matched) == (
        want.n_descriptor,
        want.n_refined,
        want.n_matched,
    )


def _features(
    pts: NDArray[np.float64], octaves: NDArray[np.int64], desc: NDArray[np.uint8]
) -> Features:
    return Features(
        pts.astype(np.float32), octaves.astype(np.int16), desc, np.ones(len(pts), np.float32)
    )


def _random_pair(
    rng: np.random.Generator, n_words: int = 32
) -> tuple[Features, Features, NDArray[np.uint8], NDArray[np.uint8]]:
    """A small pair of images (often of few grey levels or in flat blocks, so SAD costs tie)
    and features whose rows, columns and disparities sit on half pixels (so rows land exactly
    on band edges and disparities on the limits) and whose descriptors come from a pool of four
    with a few bits flipped (so Hamming distances tie)."""
    h, w = int(rng.integers(30, 90)), int(rng.integers(60, 160))
    levels = int(rng.choice([2, 4, 256]))
    block = int(rng.choice([1, 1, 3, 4]))  # flat blocks: neighbouring shifts cost the same
    cells = rng.integers(0, levels, (h // block + 1, w // block + 1))
    img_l = (np.kron(cells, np.ones((block, block)))[:h, :w] * (255 // (levels - 1))).astype(
        np.uint8
    )
    if rng.random() < 0.3:
        img_l = cv2.GaussianBlur(img_l, (0, 0), float(rng.uniform(0.5, 2.0)))
    shift = int(rng.integers(0, 12))
    img_r = np.roll(img_l, -shift, axis=1)
    if rng.random() < 0.5:
        img_r = np.clip(img_r.astype(np.int64) + rng.integers(-8, 9, img_r.shape), 0, 255)
    img_r = img_r.astype(np.uint8)
    pool = rng.integers(0, 256, (4, n_words), dtype=np.uint8)

    def descriptors(n: int) -> NDArray[np.uint8]:
        d = pool[rng.integers(0, 4, n)]
        flip = rng.random((n, n_words)) < 0.02
        d[flip] ^= (1 << rng.integers(0, 8, int(flip.sum()))).astype(np.uint8)
        return d

    n_l = int(rng.integers(1, 60))
    pts_l = np.stack([rng.integers(0, 2 * w, n_l) / 2, rng.integers(0, 2 * h, n_l) / 2], axis=1)
    oct_l = rng.integers(0, 4, n_l)
    desc_l = descriptors(n_l)
    # Half the right keypoints copy a left one, moved by a chosen disparity and row offset.
    n_copy = int(rng.integers(0, 2 * n_l))
    src = rng.integers(0, n_l, n_copy)
    disp = rng.choice([0.0, 0.5, 1.0, float(shift), 5.5, 20.0, 20.5, -1.0], n_copy)
    dv = rng.choice([0.0, 0.5, -0.5, 2.0, -2.0, 2.5, 2.4, -2.4], n_copy)
    pts_c = pts_l[src] - np.stack([disp, -dv], axis=1)
    oct_c = np.clip(oct_l[src] + rng.integers(-2, 3, n_copy), 0, 4)
    desc_c = np.where(rng.random((n_copy, 1)) < 0.7, desc_l[src], descriptors(n_copy))
    n_new = int(rng.integers(1, 40))
    pts_n = np.stack([rng.integers(0, 2 * w, n_new) / 2, rng.integers(0, 2 * h, n_new) / 2], 1)
    pts_r = np.concatenate([pts_c, pts_n])
    oct_r = np.concatenate([oct_c, rng.integers(0, 4, n_new)])
    desc_r = np.concatenate([desc_c, descriptors(n_new)])
    perm = rng.permutation(len(pts_r))
    left = _features(pts_l, oct_l, desc_l)
    right = _features(pts_r[perm], oct_r[perm], desc_r[perm])
    return left, right, img_l, img_r


def test_matches_reference_on_random_pairs_with_ties() -> None:
    # fx * baseline / min depth = 50 * 0.2 / 0.5 = 20 px exactly: disparities land on the limit.
    rig = StereoRig(PinholeCamera(160, 90, 50.0, 50.0, 80.0, 45.0), baseline_m=0.2)
    variants = [
        StereoSettings(min_depth_m=0.5),
        StereoSettings(min_depth_m=0.5, band_px=1.0, max_hamming=30, max_offset_px=0.5),
        StereoSettings(min_depth_m=0.5, patch_radius_px=2, search_radius_px=3, scale=1.5),
        StereoSettings(band_px=2.5, search_radius_px=9, max_offset_px=0.5, outlier_factor=1.0),
    ]
    matched = 0
    for seed in range(240):
        rng = np.random.default_rng(seed)
        left, right, img_l, img_r = _random_pair(rng)
        s = variants[seed % len(variants)]
        got = match_stereo(left, right, img_l, img_r, rig, s)
        _assert_same(got, _reference(left, right, img_l, img_r, rig, s))
        matched += got.n_matched
    assert matched > 500  # the refinement and outlier rules were exercised, not just skipped


def test_tied_neighbouring_shifts_give_half_a_pixel() -> None:
    """The left image is a ramp over the 12 columns around the keypoint (kinks either side), the
    right one the same shifted by 7 px: the patch fits the right keypoint and the shift after it
    equally well (SAD 0) and the one before worse, so the parabola's offset is exactly +0.5,
    which ``max_offset_px=0.5`` keeps."""
    h, w, u0, shift = 41, 80, 40, 7
    row = np.zeros(w, np.int64)
    row[u0 - 5 : u0 + 7] = 100 + 3 * np.arange(-5, 7)
    row[u0 - 6], row[u0 + 7] = 200, 10
    img_l = np.tile(row, (h, 1)).astype(np.uint8)
    img_r = np.roll(img_l, -shift, axis=1)
    rig = StereoRig(PinholeCamera(w, h, 50.0, 50.0, w / 2, h / 2), baseline_m=0.2)
    desc = np.random.default_rng(5).integers(0, 256, (1, 32), dtype=np.uint8)
    left = _features(np.array([[u0, 20.0]]), np.zeros(1, np.int64), desc)
    right = _features(np.array([[u0 - shift, 20.0]]), np.zeros(1, np.int64), desc)
    s = StereoSettings(max_offset_px=0.5)
    got = match_stereo(left, right, img_l, img_r, rig, s)
    assert got.n_matched == 1 and got.u_right[0] == u0 - shift + 0.5
    _assert_same(got, _reference(left, right, img_l, img_r, rig, s))


def test_pairs_match_reference_for_odd_rows_octaves_and_descriptor_lengths() -> None:
    """The descriptor pairing alone, where the refinement could not follow: rows spread over
    far more whole rows than the matcher tabulates, rows too large for every whole row to be a
    float64, rows that are infinite or NaN, octaves that are negative or skip levels, and
    descriptors whose length is not a multiple of 8 bytes."""
    s = StereoSettings(band_px=1.5)
    for seed in range(120):
        rng = np.random.default_rng(1000 + seed)
        n_words = int(rng.choice([32, 13, 8, 1]))
        left, right, _, _ = _random_pair(rng, n_words)
        spread = float(rng.choice([1.0, 1e3, 1e6, 1e17]))
        # Large rows, where whole rows are no longer all representable in float64.
        offset = float(rng.choice([0.0, 0.0, 2.0**52, 2.0**54, -(2.0**60)]))
        odd = rng.choice(
            [0.0, np.inf, -np.inf, np.nan], size=len(right), p=[0.85, 0.05, 0.05, 0.05]
        )
        k_r, k_l = right.keypoints.astype(np.float64), left.keypoints.astype(np.float64)
        k_r[:, 1] = k_r[:, 1] * spread + offset + odd
        k_l[:, 1] = k_l[:, 1] * spread + offset
        k_l[: len(left) // 4, 1] = rng.choice([np.inf, -np.inf, np.nan], len(left) // 4)
        octaves = rng.choice([-3, -1, 0, 2, 5, 6], size=len(right)).astype(np.int16)
        left = Features(k_l, left.octaves - 1, left.descriptors, left.responses)
        right = Features(k_r, octaves, right.descriptors, right.responses)
        max_disp = float(rng.choice([0.0, 20.0, np.inf]))
        got = stereo._descriptor_pairs(left, right, max_disp, s)
        want = _reference_pairs(left, right, max_disp, s)
        np.testing.assert_array_equal(got[0], want[0], strict=True)
        np.testing.assert_array_equal(got[1], want[1], strict=True)


@pytest.mark.parametrize("which", ["kitti", "euroc"])
def test_matches_reference_on_real_orb_features(which: str, request: pytest.FixtureRequest) -> None:
    pair: Matched = request.getfixturevalue(which)
    f = pair.frame
    want = _reference(pair.left, pair.right, f.left, f.right, f.rig)
    assert want.n_matched > 300
    _assert_same(pair.matches, want)


def test_same_results_from_concurrent_threads(kitti: Matched, euroc: Matched) -> None:
    jobs = [kitti, euroc] * 4

    def run(p: Matched) -> StereoMatches:
        return match_stereo(p.left, p.right, p.frame.left, p.frame.right, p.frame.rig)

    with ThreadPoolExecutor(max_workers=2) as pool:
        results = list(pool.map(run, jobs))
    for p, got in zip(jobs, results, strict=True):
        _assert_same(got, p.matches)


def test_importing_stereo_leaves_numba_unimported() -> None:
    code = "import sys, slamcli.vision.stereo; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_inconsistent_features_are_rejected() -> None:
    img = np.zeros((60, 80), np.uint8)
    rig = StereoRig(PinholeCamera(80, 60, 50.0, 50.0, 40.0, 30.0), baseline_m=0.1)
    pts = np.array([[40.0, 30.0], [50.0, 30.0]])
    good = _features(pts, np.zeros(2, np.int64), np.zeros((2, 32), np.uint8))
    short = _features(pts, np.zeros(2, np.int64), np.zeros((2, 16), np.uint8))
    with pytest.raises(InputError, match="descriptors differ in length"):
        match_stereo(good, short, img, img, rig)
    torn = Features(good.keypoints, good.octaves[:1], good.descriptors, good.responses)
    with pytest.raises(InputError, match="right stereo features"):
        match_stereo(good, torn, img, img, rig)
