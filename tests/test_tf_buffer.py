"""TfBuffer: chain composition, interpolation, static/dynamic mixes, errors, and the real log."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import InputError
from slamcli.formats.mcap.records import PoseRecord, TransformRecord
from slamcli.formats.mcap.tf import TfBuffer
from slamcli.geometry import make_pose, so3_exp

S = 1_000_000_000


def _rz(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _pose(angle: float, t: tuple[float, float, float]) -> np.ndarray:
    return make_pose(_rz(angle), t)


def _tf(
    parent: str, child: str, stamp_ns: int, pose: np.ndarray, static: bool = False
) -> TransformRecord:
    return TransformRecord((PoseRecord(stamp_ns, parent, child, pose),), static)


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    return make_pose(so3_exp(rng.normal(size=3)), rng.normal(size=3))


def test_chain_through_common_ancestor_matches_hand_composition() -> None:
    rng = np.random.default_rng(3)
    world_from_a, a_from_b, world_from_c, c_from_d = (_random_pose(rng) for _ in range(4))
    buf = TfBuffer()
    buf.add(_tf("world", "a", 0, world_from_a, static=True))
    buf.add(_tf("c", "d", 0, c_from_d, static=True))
    for stamp in (1 * S, 2 * S):
        buf.add(_tf("a", "b", stamp, a_from_b))
        buf.add(_tf("world", "c", stamp, world_from_c))
    got = buf.lookup("d", "b", int(1.5 * S))
    world_from_d = world_from_c @ c_from_d
    expected = np.linalg.inv(world_from_d) @ world_from_a @ a_from_b
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # The reverse lookup is the inverse; a frame to itself is the identity.
    np.testing.assert_allclose(
        buf.lookup("b", "d", int(1.5 * S)), np.linalg.inv(expected), atol=1e-12
    )
    np.testing.assert_allclose(buf.lookup("b", "b", S), np.eye(4), atol=0)
    # Straight up the tree: parent_from_child composed in order.
    np.testing.assert_allclose(buf.lookup("world", "b", S), world_from_a @ a_from_b, atol=1e-12)


def test_interpolation_at_mid_time_is_slerp_and_linear() -> None:
    buf = TfBuffer()
    buf.add(_tf("odom", "base", 0, _pose(0.0, (0.0, 0.0, 0.0))))
    buf.add(_tf("odom", "base", 2 * S, _pose(np.pi / 2, (2.0, 4.0, 0.0))))
    mid = buf.lookup("odom", "base", S)
    np.testing.assert_allclose(mid, _pose(np.pi / 4, (1.0, 2.0, 0.0)), atol=1e-12)
    quarter = buf.lookup("odom", "base", S // 2)
    np.testing.assert_allclose(quarter, _pose(np.pi / 8, (0.5, 1.0, 0.0)), atol=1e-12)
    # Exactly on a sample: that sample.
    np.testing.assert_allclose(
        buf.lookup("odom", "base", 2 * S), _pose(np.pi / 2, (2, 4, 0)), atol=1e-12
    )
    # Inverse direction interpolates the same edge.
    np.testing.assert_allclose(buf.lookup("base", "odom", S), np.linalg.inv(mid), atol=1e-12)


def test_static_and_dynamic_mix() -> None:
    base_from_cam = _pose(-np.pi / 2, (0.1, 0.0, 0.3))
    buf = TfBuffer()
    buf.add(_tf("base", "cam", 0, base_from_cam, static=True))
    buf.add(_tf("map", "odom", 0, _pose(0.0, (10.0, 0.0, 0.0))))
    buf.add(_tf("map", "odom", 4 * S, _pose(0.0, (10.0, 0.0, 0.0))))
    buf.add(_tf("odom", "base", 1 * S, _pose(0.0, (0.0, 0.0, 0.0))))
    buf.add(_tf("odom", "base", 3 * S, _pose(0.0, (2.0, 0.0, 0.0))))
    got = buf.lookup("map", "cam", 2 * S)
    expected = _pose(0.0, (11.0, 0.0, 0.0)) @ base_from_cam
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # The static edge answers at any time; the dynamic one only inside its span.
    np.testing.assert_allclose(buf.lookup("base", "cam", 100 * S), base_from_cam)
    assert buf.frames() == {"base": "odom", "cam": "base", "map": None, "odom": "map"}
    edges = {(e.parent, e.child): e for e in buf.edges()}
    assert edges["base", "cam"].static and edges["base", "cam"].count == 1
    assert (edges["odom", "base"].first_ns, edges["odom", "base"].last_ns) == (S, 3 * S)


def test_lookup_many_matches_single_lookups() -> None:
    rng = np.random.default_rng(11)
    buf = TfBuffer()
    for stamp in range(0, 10 * S, S):
        buf.add(_tf("world", "body", stamp, _random_pose(rng)))
    buf.add(_tf("body", "cam", 0, _random_pose(rng), static=True))
    stamps = np.array([-S, 0, S // 3, 4 * S + 7, 9 * S, 9 * S + 10_000_000, 12 * S])
    valid, poses = buf.lookup_many("cam", "world", stamps)
    assert valid.tolist() == [False, True, True, True, True, True, False]
    assert poses.shape == (7, 4, 4)
    for ok, stamp, pose in zip(valid, stamps, poses, strict=True):
        assert buf.can_transform("cam", "world", int(stamp)) == ok
        if ok:
            np.testing.assert_allclose(pose, buf.lookup("cam", "world", int(stamp)), atol=1e-12)


def test_stamp_outside_range_raises_naming_frames_and_time() -> None:
    buf = TfBuffer()
    buf.add(_tf("odom", "base", 10 * S, np.eye(4)))
    buf.add(_tf("odom", "base", 20 * S, np.eye(4)))
    with pytest.raises(
        InputError, match=r"odom <- base at 25\.000 s.*odom -> base.*10\.000 s.*20\.000 s"
    ):
        buf.lookup("odom", "base", 25 * S)
    with pytest.raises(InputError, match=r"at 9\.000 s"):
        buf.lookup("odom", "base", 9 * S)
    # Within the allowed gap the end sample is held.
    np.testing.assert_allclose(buf.lookup("odom", "base", 20 * S + 40_000_000), np.eye(4))
    assert not buf.can_transform("odom", "base", 20 * S + 60_000_000)
    assert buf.can_transform("odom", "base", 25 * S, max_gap_ns=5 * S)


def test_single_sample_edge_needs_a_stamp_within_the_gap() -> None:
    buf = TfBuffer()
    buf.add(_tf("odom", "base", 5 * S, _pose(0.3, (1, 2, 3))))
    np.testing.assert_allclose(buf.lookup("odom", "base", 5 * S), _pose(0.3, (1, 2, 3)))
    with pytest.raises(InputError, match=r"odom <- base at 6\.000 s"):
        buf.lookup("odom", "base", 6 * S)


def test_unconnected_and_unknown_frames_raise() -> None:
    buf = TfBuffer()
    buf.add(_tf("map", "odom", 0, np.eye(4), static=True))
    buf.add(_tf("camera_link", "camera_optical", 0, np.eye(4), static=True))
    with pytest.raises(
        InputError, match=r"'odom' and 'camera_optical' are not connected.*'map'.*'camera_link'"
    ):
        buf.lookup("odom", "camera_optical", 0)
    with pytest.raises(InputError, match=r"'nowhere' is not in the transform tree") as err:
        buf.lookup("map", "nowhere", 0)
    assert err.value.hint is not None and "camera_link" in err.value.hint
    with pytest.raises(InputError, match="not connected"):
        buf.lookup_many("map", "camera_link", [0, 1])
    assert not buf.can_transform("map", "camera_link", 0)


def test_out_of_order_samples_are_sorted_and_duplicates_keep_the_last() -> None:
    buf = TfBuffer()
    for stamp, x in [(3, 3.0), (1, 1.0), (2, 99.0), (2, 2.0), (0, 0.0)]:
        buf.add(_tf("a", "b", stamp * S, _pose(0.0, (x, 0.0, 0.0))))
    for stamp in range(4):
        assert buf.lookup("a", "b", stamp * S)[0, 3] == pytest.approx(stamp)
    assert buf.lookup("a", "b", int(2.5 * S))[0, 3] == pytest.approx(2.5)
    assert buf.edges()[0].count == 4
    # Adding more samples after a lookup keeps working (growth beyond the initial capacity).
    for stamp in range(4, 200):
        buf.add(_tf("a", "b", stamp * S, _pose(0.0, (float(stamp), 0.0, 0.0))))
    assert buf.lookup("a", "b", int(150.25 * S))[0, 3] == pytest.approx(150.25)


def test_leading_slash_frames_match_and_reparenting_replaces_the_edge() -> None:
    buf = TfBuffer()
    buf.add(_tf("/odom", "/base", 0, _pose(0.0, (1, 0, 0)), static=True))
    np.testing.assert_allclose(buf.lookup("odom", "base", 0), _pose(0.0, (1, 0, 0)))
    buf.add(_tf("map", "base", 0, _pose(0.0, (2, 0, 0)), static=True))
    assert buf.frames()["base"] == "map"
    np.testing.assert_allclose(buf.lookup("map", "/base", 0), _pose(0.0, (2, 0, 0)))


def test_real_log_tree_resolves() -> None:
    from mcap.reader import make_reader

    from slamcli.formats.mcap.adapters import adapter_for
    from slamcli.formats.mcap.decode import decoder_for
    from slamcli.formats.mcap.records import ChannelInfo

    path = shared_path("mcap", "nav2_turtlebot.mcap")
    buf = TfBuffer()
    samples: list[tuple[int, np.ndarray]] = []
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=["/tf", "/tf_static"]):
            assert schema is not None
            info = ChannelInfo.from_records(channel, schema)
            adapter = adapter_for(schema.name)
            assert adapter is not None
            record = adapter(decoder_for(info)(message.data), message.log_time, channel.topic)
            assert isinstance(record, TransformRecord)
            assert record.static is (channel.topic == "/tf_static")
            buf.add(record)
            samples += [
                (p.stamp_ns, p.parent_from_child)
                for p in record.transforms
                if (p.frame_id, p.child_frame_id) == ("odom", "base_link")
            ]
    frames = buf.frames()
    assert frames["map"] is None
    assert frames["odom"] == "map"
    assert frames["base_link"] == "odom"
    assert frames["base_footprint"] == "base_link"
    assert frames["oakd_rgb_camera_optical_frame"] == "oakd_rgb_camera_frame"
    assert len(frames) == 34
    # On a recorded sample the lookup returns that sample, composed with the static footprint.
    stamp, odom_from_base = samples[len(samples) // 2]
    base_from_footprint = buf.lookup("base_link", "base_footprint", stamp)
    np.testing.assert_allclose(
        buf.lookup("odom", "base_footprint", stamp),
        odom_from_base @ base_from_footprint,
        atol=1e-12,
    )
    # Sim-time stamps: the log covers about 928.8 s to 1025.5 s.
    valid, poses = buf.lookup_many(
        "map", "oakd_rgb_camera_optical_frame", np.arange(930, 1025, 5) * S
    )
    assert valid.all()
    np.testing.assert_allclose(np.linalg.det(poses[:, :3, :3]), 1.0, atol=1e-9)
    with pytest.raises(InputError, match=r"map <- base_link at 1100\.000 s"):
        buf.lookup("map", "base_link", 1100 * S)
