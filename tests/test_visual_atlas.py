"""Pieces of the visual pipeline that decide what a run reports and which depths it trusts:
the atlas's main map, and the stereo near/far split."""

from __future__ import annotations

import numpy as np
import pytest

from slamcli.pipelines.visual.atlas import Atlas, FrameRecord, Keyframe
from slamcli.pipelines.visual.frames import near_depths


def _keyframe(kid: int, map_id: int, culled: bool = False) -> Keyframe:
    return Keyframe(
        id=kid,
        frame=kid,
        stamp_ns=kid,
        map_id=map_id,
        cam_from_world=np.eye(4),
        keypoints=np.zeros((0, 2)),
        octaves=np.zeros(0, np.int16),
        descriptors=np.zeros((0, 32), np.uint8),
        depth=np.zeros(0),
        colors=np.zeros((0, 3), np.uint8),
        point_ids=np.zeros(0, np.int64),
        culled=culled,
    )


def _atlas(keyframe_maps: list[int], frames_per_keyframe: list[int]) -> Atlas:
    atlas = Atlas(1.2, 8)
    atlas.map.keyframes = [_keyframe(i, m) for i, m in enumerate(keyframe_maps)]
    empty = np.zeros(0, np.float32)
    for kid, count in enumerate(frames_per_keyframe):
        for _ in range(count):
            atlas.frames.append(
                FrameRecord(0, kid, np.eye(4), empty, empty, empty, np.zeros(0, np.int32), "ok")
            )
    return atlas


def test_the_main_map_is_the_one_with_the_most_frames() -> None:
    # Map 0 was lost after 3 frames; map 1 tracked 40 and was never merged.
    assert _atlas([0, 1, 1], [3, 25, 15]).main_map() == 1
    # A merge relabels the keyframes: their frames count for the map they joined.
    assert _atlas([0, 0, 0], [3, 25, 15]).main_map() == 0
    # A tie goes to the first map, and so does a run whose later map is shorter.
    assert _atlas([0, 1], [10, 10]).main_map() == 0
    assert _atlas([0, 1, 2], [20, 5, 19]).main_map() == 0
    assert Atlas(1.2, 8).main_map() is None


def test_a_map_without_live_keyframes_is_not_the_main_map() -> None:
    atlas = _atlas([0, 1], [2, 30])
    atlas.map.keyframes[1].culled = True
    assert atlas.main_map() == 0


def test_far_depths_are_dropped_unless_too_few_are_near() -> None:
    z = np.array([1.0, 30.0, np.nan, 5.0, 25.0, 25.0, 40.0])
    kept = near_depths(z, 20.0, 2)
    assert np.flatnonzero(np.isfinite(kept)).tolist() == [0, 3]
    # Only one near: the nearest far one keeps its depth (of two at 25 m, the first).
    kept = near_depths(np.where(np.arange(7) == 3, np.nan, z), 20.0, 2)
    np.testing.assert_array_equal(kept[[0, 4]], [1.0, 25.0])
    assert np.count_nonzero(np.isfinite(kept)) == 2
    # As many as there are, and never an unmatched keypoint; 0 keeps far points depthless.
    np.testing.assert_array_equal(np.isfinite(near_depths(z, 20.0, 100)), np.isfinite(z))
    assert np.count_nonzero(np.isfinite(near_depths(z, 0.5, 0))) == 0
    np.testing.assert_array_equal(z[np.isfinite(z)], near_depths(z, 1e9, 0)[np.isfinite(z)])


@pytest.mark.parametrize("n", [0, 1, 50, 400])
def test_near_depths_keep_the_nearest(n: int) -> None:
    rng = np.random.default_rng(n)
    z = rng.uniform(0.5, 60.0, 300)
    z[rng.random(300) < 0.2] = np.nan
    kept = near_depths(z, 10.0, n)
    finite = np.isfinite(kept)
    near = np.isfinite(z) & (z <= 10.0)
    assert np.all(finite[near])
    assert np.count_nonzero(finite) == max(np.count_nonzero(near), min(n, np.isfinite(z).sum()))
    dropped = np.isfinite(z) & ~finite
    if np.any(finite & ~near) and np.any(dropped):
        assert np.nanmax(kept) <= z[dropped].min()
    np.testing.assert_array_equal(kept[finite], z[finite])
