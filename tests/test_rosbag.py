"""ROS 1 bags and ROS 2 bag folders as sources: the same frames, ground truth and info as the
MCAP log written from the same messages, and the real 2010 bag whose index rosbags cannot read."""

from __future__ import annotations

import itertools
import logging
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from bag_files import ros1_bag, ros2_bag
from conftest import shared_path

from slamcli.demo import default_sample
from slamcli.errors import FormatError, InputError, TopicNotFoundError
from slamcli.formats import open_source, sniff
from slamcli.formats.mcap.decode import decoder_for
from slamcli.formats.mcap.write.layer import open_log
from slamcli.formats.mcap.write.messages import Ros2Writer
from slamcli.formats.rosbag.ros1 import CHUNK, read_top_record
from slamcli.formats.rosbag.ros1_log import Ros1BagLog
from slamcli.formats.rosbag.source import Ros1BagSource, Ros2BagSource
from slamcli.geometry import se3_to_planar
from slamcli.types import ImuFrame, OdometryFrame, RgbdFrame

N_FRAMES = 12
KINDS = ("rgbd", "imu", "odometry")
CCNY = ("lidar", "rosbag1", "ccny_scan_matcher_demo.bag")


# -- the logs: one MCAP, and bags holding the same messages ------------------------------------


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A ROS 2 MCAP log of the sample's first frames: images, camera info, IMU, ground-truth
    poses and planar odometry made from them."""
    with open_source(default_sample()) as source:
        frames = []
        for frame in source.frames(("rgbd", "imu")):
            frames.append(frame)
            if sum(isinstance(f, RgbdFrame) for f in frames) == N_FRAMES:
                break
        truth = source.groundtruth()
    assert truth is not None
    path = tmp_path_factory.mktemp("room") / "room.mcap"
    with open_log(path, "ros2", force=False) as log:
        writer = Ros2Writer(log, "none", "16UC1", 90)
        for frame in frames:
            if isinstance(frame, RgbdFrame):
                writer.rgbd(frame)
            elif isinstance(frame, ImuFrame):
                writer.imu(frame)
        planar = se3_to_planar(truth.world_from_body)
        for i, (stamp, pose) in enumerate(zip(truth.stamps_ns, truth.world_from_body, strict=True)):
            writer.pose(int(stamp), pose)
            x, y, yaw = planar[i]
            writer.odometry(int(stamp), float(x), float(y), float(yaw), 0.1 * i, -0.02 * i)
    return path


@pytest.fixture(scope="module")
def bags(room: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("bags")
    return {
        "sqlite3": ros2_bag(room, out / "sqlite3", "sqlite3"),
        "mcap": ros2_bag(room, out / "mcap", "mcap"),
        "mcap_zstd": ros2_bag(room, out / "mcap_zstd", "mcap", compress=True),
        "ros1": ros1_bag(room, out / "room.bag", chunk=400_000),
        "ros1_bz2": ros1_bag(room, out / "room_bz2.bag", "bz2", chunk=400_000),
        "ros1_lz4": ros1_bag(room, out / "room_lz4.bag", "lz4", chunk=400_000),
    }


# -- comparing sources ---------------------------------------------------------------------------


def _read(path: Path, **options: Any) -> tuple[list[Any], Any, Any]:
    with open_source(path, **options) as source:
        frames = list(source.frames(KINDS))
        truth = source.groundtruth()
        info = source.info()
    return frames, truth, info


def _assert_same_frames(got: list[Any], want: list[Any]) -> None:
    assert [type(f).__name__ for f in got] == [type(f).__name__ for f in want]
    assert [f.stamp_ns for f in got] == [f.stamp_ns for f in want]
    for a, b in zip(got, want, strict=True):
        if isinstance(a, RgbdFrame):
            np.testing.assert_array_equal(a.rgb, b.rgb)
            np.testing.assert_array_equal(a.depth_m, b.depth_m)
            np.testing.assert_array_equal(a.camera.K, b.camera.K)
            assert a.depth_stamp_ns == b.depth_stamp_ns
        elif isinstance(a, OdometryFrame):
            assert (a.v, a.omega) == (b.v, b.omega)
            np.testing.assert_array_equal(a.world_from_body, b.world_from_body)
        elif isinstance(a, ImuFrame):
            np.testing.assert_array_equal(a.accel_mps2, b.accel_mps2)


def _streams(info: Any) -> list[tuple[str, str, int]]:
    return sorted((s.name, s.kind, s.count) for s in info.streams)


@pytest.mark.parametrize("name", ["sqlite3", "mcap", "mcap_zstd"])
def test_a_ros2_bag_gives_what_the_mcap_gives(room: Path, bags: dict[str, Path], name: str) -> None:
    want_frames, want_truth, want_info = _read(room)
    frames, truth, info = _read(bags[name])
    assert sum(isinstance(f, RgbdFrame) for f in frames) == N_FRAMES
    assert any(isinstance(f, OdometryFrame) for f in frames)
    assert any(isinstance(f, ImuFrame) for f in frames)
    _assert_same_frames(frames, want_frames)
    np.testing.assert_array_equal(truth.stamps_ns, want_truth.stamps_ns)
    np.testing.assert_allclose(truth.world_from_body, want_truth.world_from_body, atol=1e-12)
    assert info.format == "rosbag2" and want_info.format == "mcap"
    assert _streams(info) == _streams(want_info)
    assert (info.frames, info.groundtruth) == (want_info.frames, want_info.groundtruth)
    assert info.camera_source == want_info.camera_source
    assert info.problems == []
    assert info.details["bag"]["storage"] == ("sqlite3" if name == "sqlite3" else "mcap")
    assert info.details["bag"]["read_as"] == ("mcap" if name == "mcap" else "rosbags")
    assert info.details["bag"]["compression"] == ("message zstd" if name == "mcap_zstd" else "none")


@pytest.mark.parametrize("name", ["ros1", "ros1_bz2", "ros1_lz4"])
def test_a_ros1_bag_gives_what_the_mcap_gives(room: Path, bags: dict[str, Path], name: str) -> None:
    want_frames, want_truth, want_info = _read(room)
    frames, truth, info = _read(bags[name])
    _assert_same_frames(frames, want_frames)
    np.testing.assert_array_equal(truth.stamps_ns, want_truth.stamps_ns)
    np.testing.assert_allclose(truth.world_from_body, want_truth.world_from_body, atol=1e-12)
    assert info.format == "rosbag1"
    assert _streams(info) == _streams(want_info)
    assert (info.frames, info.groundtruth) == (want_info.frames, want_info.groundtruth)
    assert info.problems == []
    assert info.details["bag"]["index_used"] is True
    assert all(s.detail.endswith("(ros1)") for s in info.streams)


def test_open_source_sniffs_both_bag_kinds(bags: dict[str, Path], tmp_path: Path) -> None:
    with open_source(bags["ros1"]) as one:
        assert isinstance(one, Ros1BagSource)
    with open_source(bags["sqlite3"]) as two:
        assert isinstance(two, Ros2BagSource)
    db3 = next(bags["sqlite3"].glob("*.db3"))
    with open_source(db3) as lone:
        assert isinstance(lone, Ros2BagSource)
        assert sum(isinstance(f, RgbdFrame) for f in lone.frames(("rgbd",))) == N_FRAMES
    # A .bag.active (the recorder's name while recording) is known by its first line.
    active = tmp_path / "room.bag.active"
    shutil.copy(bags["ros1"], active)
    assert sniff.rosbag1(active)
    assert not sniff.rosbag2(tmp_path)
    assert not sniff.rosbag1(bags["sqlite3"] / "metadata.yaml")


def test_topic_options_apply_to_bags(room: Path, bags: dict[str, Path]) -> None:
    with open_source(room, gt_topic="/groundtruth") as log:
        want = log.groundtruth()
    with open_source(bags["ros1"], gt_topic="/groundtruth") as source:
        truth = source.groundtruth()
    assert truth is not None and want is not None and len(truth) == len(want) > N_FRAMES
    np.testing.assert_array_equal(truth.stamps_ns, want.stamps_ns)
    with (
        open_source(bags["sqlite3"], rgb_topic="/nope") as source,
        pytest.raises(TopicNotFoundError, match="no topic /nope"),
    ):
        list(source.frames(("rgbd",)))


def test_convert_writes_an_mcap_of_a_bag(bags: dict[str, Path], tmp_path: Path) -> None:
    from slamcli.convert import convert

    out = tmp_path / "from_bag.mcap"
    result = convert(bags["ros1_bz2"], out)
    assert result.summary is not None and result.summary.frames == N_FRAMES
    with open_source(bags["ros1_bz2"]) as bag, open_source(out) as log:
        want = [f for f in bag.frames(("rgbd",)) if isinstance(f, RgbdFrame)]
        got = [f for f in log.frames(("rgbd",)) if isinstance(f, RgbdFrame)]
    _assert_same_frames(got, want)


@pytest.mark.parametrize("name", ["ros1", "sqlite3"])
def test_convert_exports_a_pose_topic_of_a_bag_as_a_trajectory(
    room: Path, bags: dict[str, Path], tmp_path: Path, name: str
) -> None:
    from slamcli.convert import convert
    from slamcli.formats.trajectory import read_trajectory

    out = tmp_path / "groundtruth.tum"
    convert(bags[name], out, source_options={"gt_topic": "/groundtruth"})
    with open_source(room, gt_topic="/groundtruth") as log:
        want = log.groundtruth()
    got = read_trajectory(out)
    assert want is not None
    np.testing.assert_array_equal(got.stamps_ns, want.stamps_ns)
    np.testing.assert_allclose(got.world_from_body, want.world_from_body, atol=1e-6)


def test_ros1_bag_definitions_come_from_the_bag(tmp_path: Path) -> None:
    """A type no ROS distribution has decodes with the definition its connection stores."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    text = "uint32 count\nstring label\nfloat64[2] pair\n"
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(text, "odd_msgs/msg/Odd"))
    odd = store.types["odd_msgs/msg/Odd"]
    path = tmp_path / "odd.bag"
    with Writer(path) as writer:
        conn = writer.add_connection("/odd", "odd_msgs/msg/Odd", msgdef=text, md5sum="0" * 32)
        for i in range(3):
            msg = odd(count=i, label=f"n{i}", pair=np.array([i, -i], dtype=np.float64))
            writer.write(conn, 1_000_000_000 + i, store.serialize_ros1(msg, "odd_msgs/msg/Odd"))
    with Ros1BagLog(path) as log:
        msgs = list(log.messages(["/odd"]))
    assert [m.log_time_ns for m in msgs] == [1_000_000_000, 1_000_000_001, 1_000_000_002]
    assert msgs[0].channel.schema_name == "odd_msgs/Odd"
    decoded = [decoder_for(m.channel)(m.data) for m in msgs]
    assert [(d.count, d.label) for d in decoded] == [(0, "n0"), (1, "n1"), (2, "n2")]
    np.testing.assert_array_equal(decoded[2].pair, [2.0, -2.0])


# -- damaged ROS 1 bags ----------------------------------------------------------------------------


def _copy(src: Path, dest: Path, edit: Any = None) -> Path:
    data = bytearray(src.read_bytes())
    if edit is not None:
        edit(data)
    dest.write_bytes(bytes(data))
    return dest


def _unindex(data: bytearray) -> None:
    """Set the bag header's index_pos to 0, as a recorder that did not finish leaves it."""
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = bytes(8)


def _chunk_offsets(path: Path) -> list[int]:
    with Ros1BagLog(path) as log:
        assert log.index is not None
        return sorted(log.index.chunk_times)


@pytest.mark.parametrize("name", ["ros1", "ros1_bz2", "ros1_lz4"])
def test_a_bag_without_index_is_walked_to_the_same_frames(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture, name: str
) -> None:
    path = _copy(bags[name], tmp_path / "unindexed.bag", _unindex)
    want_frames, _, want_info = _read(bags[name])
    with caplog.at_level(logging.WARNING):
        frames, _, info = _read(path)
    _assert_same_frames(frames, want_frames)
    assert _streams(info) == _streams(want_info)
    assert info.details["bag"]["records_walked"] is True
    assert any("not indexed" in p and "walked from the start" in p for p in info.problems)
    assert info.details["data_loss"] == []
    assert "reading its records from the start" in caplog.text


def test_a_truncated_bag_is_read_to_its_last_whole_message(
    bags: dict[str, Path], tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    full = bags["ros1"].read_bytes()
    path = tmp_path / "cut.bag"
    path.write_bytes(full[: int(len(full) * 0.6)])
    want, _, _ = _read(bags["ros1"])
    with caplog.at_level(logging.WARNING), open_source(path) as source:
        frames = list(source.frames(KINDS))
        lost = list(source.stats.data_loss)
    rgbd = [f for f in frames if isinstance(f, RgbdFrame)]
    assert 0 < len(rgbd) < N_FRAMES
    want_rgbd = [f for f in want if isinstance(f, RgbdFrame)]
    _assert_same_frames(rgbd, want_rgbd[: len(rgbd)])
    assert any(line.startswith("truncated: the bag ends inside a record at byte") for line in lost)
    assert "truncated inside the record at byte" in caplog.text
    with pytest.raises(InputError, match="truncated"), open_source(path, strict=True) as source:
        list(source.frames(("rgbd",)))


def test_garbage_after_the_magic_is_a_format_error(tmp_path: Path) -> None:
    path = tmp_path / "junk.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + b"this is not a bag record at all" * 8)
    with pytest.raises(FormatError, match=r"junk\.bag: the bytes at byte 13 are not a bag record"):
        open_source(path)
    zeros = tmp_path / "zeros.bag"
    zeros.write_bytes(b"#ROSBAG V2.0\n" + bytes(40) + b"\x01" * 40)
    with pytest.raises(FormatError, match="at byte 13"):
        open_source(zeros)
    other = tmp_path / "other.bag"
    other.write_bytes(b"not a bag at all")
    with pytest.raises(FormatError, match="not a ROS 1 bag"):
        open_source(other)


def test_an_unknown_compression_names_the_chunk(bags: dict[str, Path], tmp_path: Path) -> None:
    def rename(data: bytearray) -> None:
        at = data.index(b"compression=none")
        data[at : at + 16] = b"compression=zzzz"

    path = _copy(bags["ros1"], tmp_path / "odd.bag", rename)
    wanted = r"the chunk at byte \d+ has compression 'zzzz'"
    with pytest.raises(FormatError, match=wanted) as err, open_source(path) as source:
        list(source.frames(("rgbd",)))
    offset = int(str(err.value).split("the chunk at byte ")[1].split()[0])
    with path.open("rb") as fh:
        rec = read_top_record(fh, offset, path.stat().st_size, path)
    assert rec is not None and rec.op == CHUNK


def test_a_chunk_that_does_not_decompress_is_skipped(bags: dict[str, Path], tmp_path: Path) -> None:
    src = bags["ros1_bz2"]
    second = _chunk_offsets(src)[1]

    def spoil(data: bytearray) -> None:
        at = second + 200
        data[at : at + 64] = b"\xff" * 64

    path = _copy(src, tmp_path / "spoilt.bag", spoil)
    with open_source(path) as source:
        frames = [f for f in source.frames(("rgbd",)) if isinstance(f, RgbdFrame)]
        lost = list(source.stats.data_loss)
    assert 0 < len(frames) < N_FRAMES
    assert any(f"bad chunk at byte {second} skipped" in line for line in lost)
    with (
        pytest.raises(InputError, match=f"the chunk at byte {second}"),
        open_source(path, strict=True) as source,
    ):
        list(source.frames(("rgbd",)))


def test_lz4_chunks_without_the_lz4_package_name_the_chunk(
    bags: dict[str, Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    with open_source(bags["ros1_lz4"]) as source:
        monkeypatch.setitem(sys.modules, "lz4.frame", None)
        with pytest.raises(InputError, match=r"the chunk at byte \d+ is lz4-compressed"):
            list(source.frames(("rgbd",)))


def test_ros2_bag_metadata_errors(bags: dict[str, Path], tmp_path: Path) -> None:
    broken = tmp_path / "broken"
    shutil.copytree(bags["sqlite3"], broken)
    (broken / "metadata.yaml").write_text("rosbag2_bagfile_information:\n  version: 9\n")
    with pytest.raises(FormatError, match=r"metadata\.yaml: is not rosbag2 metadata"):
        open_source(broken)
    missing = tmp_path / "missing"
    shutil.copytree(bags["sqlite3"], missing)
    next(missing.glob("*.db3")).unlink()
    with pytest.raises(InputError, match="storage files that are missing"):
        open_source(missing)


# -- the real 2010 bag ----------------------------------------------------------------------------


def test_rosbags_alone_cannot_read_the_ccny_bag() -> None:
    from rosbags.rosbag1 import Reader

    with pytest.raises(AssertionError):
        Reader(shared_path(*CCNY)).open()


def test_the_ccny_bag_is_read_by_walking_its_records() -> None:
    with open_source(shared_path(*CCNY)) as source:
        assert isinstance(source, Ros1BagSource)
        info = source.info()
        msgs = list(source.log.messages(["/scan"]))
    assert [s.name for s in info.streams] == ["/scan"]
    (scan,) = info.streams
    assert scan.count == 360 and scan.detail.startswith("sensor_msgs/LaserScan (ros1)")
    assert scan.start_s is not None and scan.end_s is not None
    assert scan.end_s - scan.start_s == pytest.approx(35.8, abs=0.05)
    assert scan.rate_hz == pytest.approx(10.0, abs=0.1)
    bag = info.details["bag"]
    assert bag["records_walked"] is True and "read_index_data" in bag["index_problem"]
    assert bag["notes"] == [
        "index data records declare 20 bytes per entry but hold 12 (the first at byte 792650)"
    ]
    assert any("walked from the start" in p for p in info.problems)
    assert info.details["data_loss"] == []
    times = [m.log_time_ns for m in msgs]
    assert len(times) == 360 and all(b > a for a, b in itertools.pairwise(times))


def test_the_ccny_scans_decode_with_the_bags_own_definition() -> None:
    with Ros1BagLog(shared_path(*CCNY)) as log:
        msgs = list(log.messages())
    # The 2010 definition names its header roslib/Header; it is read as std_msgs/Header.
    assert b"MSG: std_msgs/Header" in msgs[0].channel.schema_data
    decode = decoder_for(msgs[0].channel)
    scans = [decode(m.data) for m in msgs]
    first = scans[0]
    assert first.header.frame_id == "/laser"
    assert len(first.ranges) == 681
    assert first.angle_min == pytest.approx(-2.086, abs=1e-3)
    assert first.angle_max == pytest.approx(2.086, abs=1e-3)
    assert (first.range_min, first.range_max) == pytest.approx((0.02, 5.6), abs=1e-6)
    assert first.angle_min + 680 * first.angle_increment == pytest.approx(first.angle_max, abs=1e-5)
    stamps = [s.header.stamp.sec * 10**9 + s.header.stamp.nanosec for s in scans]
    assert all(b > a for a, b in itertools.pairwise(stamps))
    assert (stamps[-1] - stamps[0]) * 1e-9 == pytest.approx(35.8, abs=0.1)
    seqs = [s.header.seq for s in scans]
    assert seqs == list(range(seqs[0], seqs[0] + 360))
    # Header stamps (acquisition) precede the log times (receipt) by under a second.
    lag = np.array([m.log_time_ns for m in msgs]) - np.array(stamps)
    assert (lag > 0).all() and lag.max() < 1e9


def test_the_ccny_bag_walks_the_same_in_a_truncated_copy(tmp_path: Path) -> None:
    data = shared_path(*CCNY).read_bytes()
    cut = tmp_path / "ccny_cut.bag"
    # Inside the second chunk: the first chunk's 278 messages and part of the second's remain.
    cut.write_bytes(data[:900_000])
    with Ros1BagLog(cut) as log:
        msgs = list(log.messages())
        health = log.health
    assert 278 < len(msgs) < 360
    assert health.truncated and health.truncated_at_byte == 796041
    with Ros1BagLog(shared_path(*CCNY)) as whole:
        full = list(whole.messages())
    assert [m.data for m in msgs] == [m.data for m in full[: len(msgs)]]
    with cut.open("rb") as fh:
        rec = read_top_record(fh, 796041, cut.stat().st_size, cut)
    assert rec is not None and rec.op == CHUNK and not rec.complete
