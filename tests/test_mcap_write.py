"""MCAP writers: TUM RGB-D to ROS 2 / Foxglove logs, and run folders to result.mcap.

Everything is read back without slamcli's own MCAP reader: ``mcap``'s reader, ROS 2 types
rebuilt from the schema text stored in the file (rosbags), the official Foxglove protobuf
package and a JSON-schema validator.
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import struct
from collections import deque
from collections.abc import Iterator
from decimal import Decimal
from pathlib import Path
from typing import Any

import cv2
import jsonschema
import numpy as np
import pytest
import trimesh
from foxglove_schemas_protobuf import (
    CameraCalibration_pb2,
    CompressedImage_pb2,
    FrameTransform_pb2,
    Grid_pb2,
    PointCloud_pb2,
    PoseInFrame_pb2,
    RawImage_pb2,
    SceneUpdate_pb2,
)
from google.protobuf import duration_pb2, json_format, timestamp_pb2
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from test_tum_rgbd import write_tum_folder

from slamcli.errors import ConfigError, ExportError, InputError
from slamcli.formats import open_source
from slamcli.formats.mcap import write as mw
from slamcli.formats.trajectory import write_tum
from slamcli.geometry import make_pose, quat_xyzw_to_matrix
from slamcli.types import OccupancyGrid, RgbdFrame, SlamResult, Trajectory

PROTOBUF = {
    "foxglove.RawImage": RawImage_pb2.RawImage,
    "foxglove.CompressedImage": CompressedImage_pb2.CompressedImage,
    "foxglove.CameraCalibration": CameraCalibration_pb2.CameraCalibration,
    "foxglove.PoseInFrame": PoseInFrame_pb2.PoseInFrame,
    "foxglove.FrameTransform": FrameTransform_pb2.FrameTransform,
    "foxglove.Grid": Grid_pb2.Grid,
    "foxglove.PointCloud": PointCloud_pb2.PointCloud,
    "foxglove.SceneUpdate": SceneUpdate_pb2.SceneUpdate,
}
FR1_K = [517.306408, 0.0, 318.643040, 0.0, 516.469215, 255.313989, 0.0, 0.0, 1.0]
FR1_D = [0.262383, -0.953104, -0.005358, 0.002628, 1.163314]


# --- reading logs back ---------------------------------------------------------------------------


def iter_topic(path: Path, topic: str) -> Iterator[tuple[Any, Any, Any]]:
    """(schema, channel, message) of one topic, in log-time order."""
    with path.open("rb") as f:
        yield from make_reader(f).iter_messages(topics=[topic], log_time_order=True)


def iter_zipped(path: Path, *topics: str) -> Iterator[tuple[tuple[Any, Any, Any], ...]]:
    """The k-th messages of several topics together, in one pass over the file."""
    queues: dict[str, deque[tuple[Any, Any, Any]]] = {t: deque() for t in topics}
    with path.open("rb") as f:
        for item in make_reader(f).iter_messages(topics=list(topics), log_time_order=True):
            queues[item[1].topic].append(item)
            if all(queues.values()):
                yield tuple(queues[t].popleft() for t in topics)
    assert not any(queues.values()), {t: len(q) for t, q in queues.items()}


def topic_counts(path: Path) -> dict[str, int]:
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    return {c.topic: counts.get(c.id, 0) for c in summary.channels.values()}


def assert_written_in_log_time_order(path: Path) -> None:
    """Messages in file order have non-decreasing log times, so chunks do not overlap."""
    with path.open("rb") as f:
        reader = make_reader(f)
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=False)]
        summary = reader.get_summary()
    assert times == sorted(times)
    assert summary is not None
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) > 1
    for a, b in itertools.pairwise(chunks):
        assert a.message_end_time <= b.message_start_time


class RosDecoder:
    """Deserialises CDR with types rebuilt from each schema's own ros2msg text."""

    def __init__(self) -> None:
        self.store = get_typestore(Stores.EMPTY)
        self.seen: set[str] = set()

    def __call__(self, schema: Any, channel: Any, message: Any) -> Any:
        assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
        if schema.name not in self.seen:
            self.store.register(get_types_from_msg(schema.data.decode(), schema.name))
            self.seen.add(schema.name)
        return self.store.deserialize_cdr(message.data, schema.name)


def stamp_ns(header: Any) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


def fox_ns(t: dict[str, int]) -> int:
    return t["sec"] * 1_000_000_000 + t["nsec"]


def text_stamps(path: Path) -> tuple[list[int], np.ndarray]:
    """Exact ns stamps and the other columns of a TUM text file."""
    stamps, rows = [], []
    for line in path.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            fields = line.split()
            stamps.append(int(Decimal(fields[0]) * 1_000_000_000))
            rows.append([float(v) for v in fields[1:]])
    return stamps, np.asarray(rows)


def same_rotation(q_msg: list[float], q_file: np.ndarray) -> bool:
    q = np.asarray(q_msg)
    ref = q_file / np.linalg.norm(q_file)
    return min(np.abs(q - ref).max(), np.abs(q + ref).max()) < 1e-9


def protobuf_json(obj: Any, key: str = "") -> Any:
    """Foxglove JSON -> protobuf JSON: only the time fields are spelled differently."""
    if isinstance(obj, dict):
        if key in ("timestamp", "lifetime") and set(obj) == {"sec", "nsec"}:
            cls = timestamp_pb2.Timestamp if key == "timestamp" else duration_pb2.Duration
            return cls(seconds=obj["sec"], nanos=obj["nsec"]).ToJsonString()
        return {k: protobuf_json(v, k) for k, v in obj.items()}
    if isinstance(obj, list):
        return [protobuf_json(v, key) for v in obj]
    return obj


_VALIDATORS: dict[bytes, Any] = {}


def check_foxglove(schema: Any, channel: Any, message: Any) -> dict[str, Any]:
    """Decode one JSON message and check it against its schema and the protobuf package."""
    assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
    validator = _VALIDATORS.get(schema.data)
    if validator is None:
        schema_json = json.loads(schema.data)
        assert schema_json["title"] == schema.name
        assert schema.data == mw.foxglove_schema(schema.name.removeprefix("foxglove."))
        cls = jsonschema.validators.validator_for(schema_json)
        cls.check_schema(schema_json)
        validator = _VALIDATORS[schema.data] = cls(schema_json)
    msg = json.loads(message.data)
    validator.validate(msg)
    json_format.ParseDict(protobuf_json(msg), PROTOBUF[schema.name]())
    return msg


def rgb_psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0**2 / mse))


# --- the packaged schemas ------------------------------------------------------------------------


def _compare_fields(schema: dict[str, Any], descriptor: Any, where: str) -> None:
    props = schema["properties"]
    assert set(props) == {f.name for f in descriptor.fields}, where
    for f in descriptor.fields:
        sub = props[f.name]
        if f.message_type is None or f.message_type.full_name.startswith("google.protobuf"):
            continue
        _compare_fields(sub.get("items", sub), f.message_type, f"{where}.{f.name}")


@pytest.mark.parametrize("name", sorted(PROTOBUF))
def test_packaged_schemas_match_the_official_protobuf_fields(name: str) -> None:
    schema = json.loads(mw.foxglove_schema(name.removeprefix("foxglove.")))
    assert schema["title"] == name
    jsonschema.validators.validator_for(schema).check_schema(schema)
    _compare_fields(schema, PROTOBUF[name].DESCRIPTOR, name)


# --- TUM to ROS 2 --------------------------------------------------------------------------------


def _convert(src: Path, out: Path, **kwargs: Any) -> mw.McapWriteSummary:
    with open_source(src) as source:
        return mw.write_source_mcap(source, out, **kwargs)


def _frames(src: Path, n: int | None = None) -> Iterator[RgbdFrame]:
    with open_source(src) as source:
        for k, frame in enumerate(source.frames(("rgbd",))):
            if n is not None and k >= n:
                return
            assert isinstance(frame, RgbdFrame)
            yield frame


@pytest.mark.slow
def test_ros2_raw_round_trip(tum_excerpt: Path, tmp_path: Path) -> None:
    out = tmp_path / "fr1.mcap"
    summary = _convert(tum_excerpt, out, flavor="ros2")
    assert summary.frames == 150 and summary.skipped == 0
    gt_stamps, gt_rows = text_stamps(tum_excerpt / "groundtruth.txt")
    imu_stamps, imu_rows = text_stamps(tum_excerpt / "accelerometer.txt")
    assert topic_counts(out) == {
        mw.TOPIC_COLOR: 150,
        mw.TOPIC_DEPTH: 150,
        mw.TOPIC_CAMERA_INFO: 150,
        mw.TOPIC_GROUNDTRUTH: len(gt_stamps),
        mw.TOPIC_IMU: len(imu_stamps),
    }
    with out.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary_rec = reader.get_summary()
        assert summary_rec is not None
        image_schema = next(s for s in summary_rec.schemas.values() if s.name.endswith("/Image"))
    # The full definition with its dependencies, as rosbag2 stores it.
    assert "MSG: std_msgs/Header" in image_schema.data.decode()
    assert "MSG: builtin_interfaces/Time" in image_schema.data.decode()

    decode = RosDecoder()
    streams = (
        (*msgs, frame)
        for msgs, frame in zip(
            iter_zipped(out, mw.TOPIC_COLOR, mw.TOPIC_DEPTH, mw.TOPIC_CAMERA_INFO),
            _frames(tum_excerpt),
            strict=True,
        )
    )
    max_depth_err = 0.0
    for color, depth, info, frame in streams:
        img, dimg, cinfo = decode(*color), decode(*depth), decode(*info)
        assert stamp_ns(img.header) == frame.stamp_ns == color[2].log_time == color[2].publish_time
        assert stamp_ns(dimg.header) == frame.depth_stamp_ns == depth[2].log_time
        assert stamp_ns(cinfo.header) == frame.stamp_ns
        assert img.header.frame_id == dimg.header.frame_id == "camera_color_optical_frame"
        assert (img.encoding, img.height, img.width, img.step) == ("rgb8", 480, 640, 640 * 3)
        np.testing.assert_array_equal(np.asarray(img.data).reshape(480, 640, 3), frame.rgb)
        assert (dimg.encoding, dimg.step, dimg.is_bigendian) == ("16UC1", 640 * 2, 0)
        mm = np.asarray(dimg.data).view("<u2").reshape(480, 640)
        np.testing.assert_array_equal(mm == 0, frame.depth_m == 0)
        max_depth_err = max(max_depth_err, float(np.abs(mm / 1000.0 - frame.depth_m).max()))
        assert (cinfo.width, cinfo.height, cinfo.distortion_model) == (640, 480, "plumb_bob")
        np.testing.assert_allclose(cinfo.k, FR1_K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(cinfo.d, FR1_D, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(np.asarray(cinfo.p).reshape(3, 4)[:, :3].ravel(), cinfo.k)
    # Equal to the millimetre: TUM's 0.2 mm steps round to at most 0.5 mm.
    assert 0.0001 < max_depth_err <= 0.0005 + 1e-6

    poses = [decode(*m) for m in iter_topic(out, mw.TOPIC_GROUNDTRUTH)]
    assert [stamp_ns(p.header) for p in poses] == gt_stamps
    for p, row in zip(poses, gt_rows, strict=True):
        assert p.header.frame_id == "world"
        assert [p.pose.position.x, p.pose.position.y, p.pose.position.z] == row[:3].tolist()
        o = p.pose.orientation
        assert same_rotation([o.x, o.y, o.z, o.w], row[3:])

    imus = [decode(*m) for m in iter_topic(out, mw.TOPIC_IMU)]
    assert [stamp_ns(m.header) for m in imus] == imu_stamps
    accel = np.array(
        [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imus]
    )
    np.testing.assert_array_equal(accel, imu_rows)
    assert all(m.orientation_covariance[0] == -1 for m in imus)
    assert all(m.angular_velocity_covariance[0] == -1 for m in imus)
    assert all(m.linear_acceleration_covariance[0] == 0 for m in imus)


def test_ros2_32fc1_depth_is_exact_and_max_frames_ends_the_log(
    tum_excerpt: Path, tmp_path: Path
) -> None:
    out = tmp_path / "fr1.mcap"
    summary = _convert(tum_excerpt, out, flavor="ros2", depth_encoding="32FC1", max_frames=12)
    assert summary.frames == 12
    assert_written_in_log_time_order(out)
    decode = RosDecoder()
    last = 0
    for depth, frame in zip(iter_topic(out, mw.TOPIC_DEPTH), _frames(tum_excerpt, 12), strict=True):
        dimg = decode(*depth)
        assert (dimg.encoding, dimg.step) == ("32FC1", 640 * 4)
        got = np.asarray(dimg.data).view("<f4").reshape(480, 640)
        assert got.tobytes() == frame.depth_m.astype("<f4").tobytes()
        last = frame.stamp_ns
    gt_stamps, _ = text_stamps(tum_excerpt / "groundtruth.txt")
    written = [stamp_ns(decode(*m).header) for m in iter_topic(out, mw.TOPIC_GROUNDTRUTH)]
    assert written == [t for t in gt_stamps if t <= last]
    imu = [m[2].log_time for m in iter_topic(out, mw.TOPIC_IMU)]
    assert imu and max(imu) <= last


@pytest.mark.parametrize("fmt", ["png", "jpeg"])
def test_ros2_compressed_round_trip(tum_excerpt: Path, tmp_path: Path, fmt: str) -> None:
    out = tmp_path / "fr1.mcap"
    _convert(tum_excerpt, out, flavor="ros2", compress_images=fmt, max_frames=10)
    counts = topic_counts(out)
    assert counts[mw.TOPIC_COLOR_COMPRESSED] == counts[mw.TOPIC_DEPTH_COMPRESSED] == 10
    assert mw.TOPIC_COLOR not in counts and mw.TOPIC_DEPTH not in counts
    decode = RosDecoder()
    streams = (
        (*msgs, frame)
        for msgs, frame in zip(
            iter_zipped(out, mw.TOPIC_COLOR_COMPRESSED, mw.TOPIC_DEPTH_COMPRESSED),
            _frames(tum_excerpt, 10),
            strict=True,
        )
    )
    for color, depth, frame in streams:
        cimg, dimg = decode(*color), decode(*depth)
        assert color[0].name == depth[0].name == "sensor_msgs/msg/CompressedImage"
        assert stamp_ns(cimg.header) == frame.stamp_ns
        assert stamp_ns(dimg.header) == frame.depth_stamp_ns
        assert cimg.format == fmt
        bgr = cv2.imdecode(np.asarray(cimg.data), cv2.IMREAD_COLOR)
        rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        if fmt == "png":
            np.testing.assert_array_equal(rgb, frame.rgb)
        else:
            assert not np.array_equal(rgb, frame.rgb)
            assert rgb_psnr(rgb, frame.rgb) > 30
        assert dimg.format == "16UC1; compressedDepth png"
        data = bytes(np.asarray(dimg.data))
        assert data[:12] == struct.pack("<iff", 0, 0.0, 0.0)
        assert data[12:20] == b"\x89PNG\r\n\x1a\n"
        mm = cv2.imdecode(np.frombuffer(data[12:], np.uint8), cv2.IMREAD_UNCHANGED)
        assert mm.dtype == np.uint16 and mm.shape == (480, 640)
        assert np.abs(mm / 1000.0 - frame.depth_m).max() <= 0.0005 + 1e-6
        np.testing.assert_array_equal(mm == 0, frame.depth_m == 0)


# --- TUM to Foxglove -----------------------------------------------------------------------------


@pytest.mark.slow
def test_foxglove_raw_round_trip(tum_excerpt: Path, tmp_path: Path) -> None:
    out = tmp_path / "fr1.mcap"
    summary = _convert(tum_excerpt, out, flavor="foxglove")
    assert summary.frames == 150
    gt_stamps, gt_rows = text_stamps(tum_excerpt / "groundtruth.txt")
    assert topic_counts(out) == {
        mw.TOPIC_COLOR: 150,
        mw.TOPIC_DEPTH: 150,
        mw.TOPIC_CAMERA_INFO: 150,
        mw.TOPIC_GROUNDTRUTH: len(gt_stamps),
        mw.TOPIC_TF: len(gt_stamps),
    }
    streams = (
        (*msgs, frame)
        for msgs, frame in zip(
            iter_zipped(out, mw.TOPIC_COLOR, mw.TOPIC_DEPTH, mw.TOPIC_CAMERA_INFO),
            _frames(tum_excerpt),
            strict=True,
        )
    )
    for k, (color, depth, info, frame) in enumerate(streams):
        if k % 25 == 0:
            img, dimg, cal = check_foxglove(*color), check_foxglove(*depth), check_foxglove(*info)
        else:
            img, dimg, cal = (json.loads(m[2].data) for m in (color, depth, info))
        assert fox_ns(img["timestamp"]) == frame.stamp_ns == color[2].log_time
        assert fox_ns(dimg["timestamp"]) == frame.depth_stamp_ns == depth[2].log_time
        assert fox_ns(cal["timestamp"]) == frame.stamp_ns
        assert img["frame_id"] == dimg["frame_id"] == cal["frame_id"]
        assert (img["encoding"], img["width"], img["height"], img["step"]) == (
            "rgb8",
            640,
            480,
            1920,
        )
        rgb = np.frombuffer(base64.b64decode(img["data"]), np.uint8).reshape(480, 640, 3)
        np.testing.assert_array_equal(rgb, frame.rgb)
        assert (dimg["encoding"], dimg["step"]) == ("16UC1", 1280)
        mm = np.frombuffer(base64.b64decode(dimg["data"]), "<u2").reshape(480, 640)
        assert np.abs(mm / 1000.0 - frame.depth_m).max() <= 0.0005 + 1e-6
        np.testing.assert_allclose(cal["K"], FR1_K, rtol=0, atol=1e-9)
        np.testing.assert_allclose(cal["D"], FR1_D, rtol=0, atol=1e-9)
        assert cal["distortion_model"] == "plumb_bob" and len(cal["P"]) == 12
    for topic in (mw.TOPIC_GROUNDTRUTH, mw.TOPIC_TF):
        msgs = [check_foxglove(*m) for m in iter_topic(out, topic)]
        assert [fox_ns(m["timestamp"]) for m in msgs] == gt_stamps
        for m, row in zip(msgs, gt_rows, strict=True):
            if topic == mw.TOPIC_TF:
                assert (m["parent_frame_id"], m["child_frame_id"]) == (
                    "world",
                    "camera_color_optical_frame",
                )
                p, q = m["translation"], m["rotation"]
            else:
                assert m["frame_id"] == "world"
                p, q = m["pose"]["position"], m["pose"]["orientation"]
            assert [p["x"], p["y"], p["z"]] == row[:3].tolist()
            assert same_rotation([q["x"], q["y"], q["z"], q["w"]], row[3:])


def test_foxglove_compressed_colour_and_exact_depth(tum_excerpt: Path, tmp_path: Path) -> None:
    out = tmp_path / "fr1.mcap"
    _convert(
        tum_excerpt,
        out,
        flavor="foxglove",
        compress_images="jpeg",
        depth_encoding="32FC1",
        max_frames=8,
    )
    counts = topic_counts(out)
    assert counts[mw.TOPIC_COLOR_COMPRESSED] == counts[mw.TOPIC_DEPTH] == 8
    streams = (
        (*msgs, frame)
        for msgs, frame in zip(
            iter_zipped(out, mw.TOPIC_COLOR_COMPRESSED, mw.TOPIC_DEPTH),
            _frames(tum_excerpt, 8),
            strict=True,
        )
    )
    for color, depth, frame in streams:
        cimg, dimg = check_foxglove(*color), check_foxglove(*depth)
        assert color[0].name == "foxglove.CompressedImage" and cimg["format"] == "jpeg"
        bgr = cv2.imdecode(np.frombuffer(base64.b64decode(cimg["data"]), np.uint8), 1)
        assert rgb_psnr(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), frame.rgb) > 30
        assert (dimg["encoding"], dimg["step"]) == ("32FC1", 640 * 4)
        assert base64.b64decode(dimg["data"]) == frame.depth_m.astype("<f4").tobytes()


# --- options, refusals and failures --------------------------------------------------------------


def test_bad_options_are_config_errors(tmp_path: Path) -> None:
    src = write_tum_folder(tmp_path / "tum", 2)
    for kwargs, text in (
        ({"flavor": "ros1"}, "flavor must be one of ros2, foxglove"),
        ({"compress_images": "webp"}, "compress_images must be one of"),
        ({"depth_encoding": "16UC2"}, "depth_encoding must be one of"),
        ({"jpeg_quality": 0}, "jpeg_quality"),
        ({"max_frames": 0}, "max_frames"),
    ):
        with pytest.raises(ConfigError, match=text):
            _convert(src, tmp_path / "out.mcap", **kwargs)
    assert not (tmp_path / "out.mcap").exists()


def test_existing_output_needs_force_and_a_folder_is_refused(tmp_path: Path) -> None:
    src = write_tum_folder(tmp_path / "tum", 3)
    out = tmp_path / "out.mcap"
    out.write_bytes(b"old")
    with pytest.raises(ExportError, match=r"out\.mcap: already exists") as err:
        _convert(src, out)
    assert err.value.hint is not None and "--force" in err.value.hint
    assert out.read_bytes() == b"old"
    summary = _convert(src, out, force=True)
    assert summary.frames == 3 and topic_counts(out)[mw.TOPIC_COLOR] == 3
    with pytest.raises(ExportError, match="is a folder"):
        _convert(src, tmp_path / "tum", force=True)


class _FailingSource:
    """A source whose frames stop with an error after ``n`` frames."""

    def __init__(self, inner: Any, n: int) -> None:
        self.inner, self.n = inner, n
        self.stats = inner.stats

    def info(self) -> Any:
        return self.inner.info()

    def groundtruth(self) -> Any:
        return self.inner.groundtruth()

    def frames(self, kinds: Any) -> Iterator[Any]:
        for k, frame in enumerate(self.inner.frames(kinds)):
            if k == self.n:
                raise InputError("disk went away")
            yield frame


def _failing(source: Any, n: int) -> Any:
    return _FailingSource(source, n)


def test_a_failed_write_leaves_no_file_and_keeps_the_old_one(tmp_path: Path) -> None:
    src = write_tum_folder(tmp_path / "tum", 6)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    with open_source(src) as source, pytest.raises(InputError, match="disk went away"):
        mw.write_source_mcap(_failing(source, 3), out_dir / "new.mcap")
    assert list(out_dir.iterdir()) == []
    (out_dir / "old.mcap").write_bytes(b"old")
    with open_source(src) as source, pytest.raises(InputError):
        mw.write_source_mcap(_failing(source, 3), out_dir / "old.mcap", force=True)
    assert [p.name for p in out_dir.iterdir()] == ["old.mcap"]
    assert (out_dir / "old.mcap").read_bytes() == b"old"


def test_depth_to_millimetres_rounds_and_drops_invalid() -> None:
    d = np.array([[0.0, np.nan, -1.0, 0.0004], [0.0015, 1.23449, 65.535, 65.6]], np.float32)
    np.testing.assert_array_equal(mw.depth_to_millimetres(d), [[0, 0, 0, 0], [2, 1234, 65535, 0]])


# --- result logs ---------------------------------------------------------------------------------

MAP_PIXELS = np.array(
    [[0, 254, 205, 254, 0], [254, 254, 254, 205, 205], [0, 0, 254, 254, 254]], np.uint8
)
"""Image rows top to bottom: 0 occupied, 254 free, 205 unknown (map_server trinary)."""


def _trajectory() -> Trajectory:
    n = 7
    stamps = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * 100_000_000
    yaw = np.linspace(0.0, 1.2, n)
    q = np.stack([np.zeros(n), np.zeros(n), np.sin(yaw / 2), np.cos(yaw / 2)], axis=1)
    t = np.stack([np.linspace(0, 1, n), np.linspace(0, -0.5, n), np.full(n, 0.3)], axis=1)
    return Trajectory(stamps, make_pose(quat_xyzw_to_matrix(q), t))


def _mesh() -> trimesh.Trimesh:
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], float)
    faces = np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3], [1, 2, 4]])
    colors = np.array(
        [[255, 0, 0, 255], [0, 255, 0, 255], [0, 0, 255, 255], [10, 20, 30, 255], [7, 8, 9, 255]],
        np.uint8,
    )
    return trimesh.Trimesh(vertices, faces, vertex_colors=colors, process=False)


def _run_folder(root: Path, *, extras: bool = True) -> Path:
    root.mkdir()
    (root / "run.json").write_text("{}\n")
    write_tum(root / "trajectory.tum", _trajectory())
    if extras:
        _mesh().export(root / "mesh.ply")
        pts = np.random.default_rng(0).uniform(-2, 2, (50, 3))
        cols = np.random.default_rng(1).integers(0, 256, (50, 4), dtype=np.uint8)
        cols[:, 3] = 255
        trimesh.PointCloud(pts, colors=cols).export(root / "points.ply")
        cv2.imwrite(str(root / "map.pgm"), MAP_PIXELS)
        (root / "map.yaml").write_text(
            "image: map.pgm\nresolution: 0.05\norigin: [-1.0, 2.0, 0.0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
        )
    return root


def test_result_mcap_messages_validate_and_hold_the_run(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run")
    path = mw.write_result_mcap(run)
    assert path == run / "result.mcap"
    traj = _trajectory()
    assert topic_counts(path) == {
        mw.TOPIC_RESULT_MAP: 1,
        mw.TOPIC_RESULT_POINTS: 1,
        mw.TOPIC_RESULT_MESH: 1,
        mw.TOPIC_RESULT_POSE: len(traj),
        mw.TOPIC_TF: len(traj),
    }
    decoded: dict[str, list[dict[str, Any]]] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            decoded.setdefault(channel.topic, []).append(check_foxglove(schema, channel, message))

    poses = decoded[mw.TOPIC_RESULT_POSE]
    assert [fox_ns(p["timestamp"]) for p in poses] == traj.stamps_ns.tolist()
    for p, tf, pose in zip(poses, decoded[mw.TOPIC_TF], traj.world_from_body, strict=True):
        pos = p["pose"]["position"]
        np.testing.assert_allclose([pos["x"], pos["y"], pos["z"]], pose[:3, 3], atol=1e-9)
        assert tf["translation"] == pos and tf["rotation"] == p["pose"]["orientation"]
        assert (tf["parent_frame_id"], tf["child_frame_id"]) == ("world", "camera")

    grid = decoded[mw.TOPIC_RESULT_MAP][0]
    cells = np.frombuffer(base64.b64decode(grid["data"]), np.uint8).reshape(-1, 5, 5)
    occupancy = cells[..., 0].view(np.int8)
    expected = np.select([MAP_PIXELS == 0, MAP_PIXELS == 254], [100, 0], -1)[::-1]
    np.testing.assert_array_equal(occupancy, expected)
    assert grid["column_count"] == 5 and grid["cell_size"] == {"x": 0.05, "y": 0.05}
    assert grid["pose"]["position"] == {"x": -1.0, "y": 2.0, "z": 0.0}

    cloud = decoded[mw.TOPIC_RESULT_POINTS][0]
    assert cloud["point_stride"] == 16
    layout = np.dtype(
        [("xyz", "<f4", 3), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
    )
    packed = np.frombuffer(base64.b64decode(cloud["data"]), layout)
    pts = np.random.default_rng(0).uniform(-2, 2, (50, 3))
    cols = np.random.default_rng(1).integers(0, 256, (50, 4), dtype=np.uint8)
    np.testing.assert_array_equal(packed["xyz"], pts.astype(np.float32))
    np.testing.assert_array_equal(packed["red"], cols[:, 0])
    np.testing.assert_array_equal(packed["blue"], cols[:, 2])

    update = decoded[mw.TOPIC_RESULT_MESH][0]
    (model,) = update["entities"][0]["models"]
    assert model["media_type"] == "model/gltf-binary"
    glb = base64.b64decode(model["data"])
    assert glb[:4] == b"glTF"
    scene = trimesh.load(io.BytesIO(glb), file_type="glb", process=False)
    (loaded,) = scene.geometry.values()
    mesh = _mesh()
    assert len(loaded.vertices) == len(mesh.vertices) and len(loaded.faces) == len(mesh.faces)
    np.testing.assert_allclose(loaded.vertices, mesh.vertices, atol=1e-6)
    np.testing.assert_array_equal(loaded.visual.vertex_colors, mesh.visual.vertex_colors)


def test_result_mcap_with_a_trajectory_only(tmp_path: Path) -> None:
    run = _run_folder(tmp_path / "run", extras=False)
    out = tmp_path / "elsewhere.mcap"
    assert mw.write_result_mcap(run, out) == out
    assert set(topic_counts(out)) == {mw.TOPIC_RESULT_POSE, mw.TOPIC_TF}
    with pytest.raises(ExportError, match="already exists"):
        mw.write_result_mcap(run, out)


def test_result_log_refusals(tmp_path: Path) -> None:
    (tmp_path / "plain").mkdir()
    with pytest.raises(InputError, match="not a run folder"):
        mw.write_result_mcap(tmp_path / "plain")
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "run.json").write_text("{}")
    with pytest.raises(ExportError, match="nothing to write"):
        mw.write_result_mcap(empty)
    assert not (empty / "result.mcap").exists()


def test_result_log_from_memory_takes_a_grid(tmp_path: Path) -> None:
    prob = np.array([[0.0, 1.0, np.nan], [0.25, 0.5, 0.0]], np.float32)
    grid = OccupancyGrid(prob, 0.1, (0.5, -0.5, np.pi / 2))
    summary = mw.write_result_log(tmp_path / "g.mcap", SlamResult(grid=grid))
    assert summary.topics == {mw.TOPIC_RESULT_MAP: ("foxglove.Grid", 1)}
    ((schema, channel, message),) = iter_topic(tmp_path / "g.mcap", mw.TOPIC_RESULT_MAP)
    msg = check_foxglove(schema, channel, message)
    cells = np.frombuffer(base64.b64decode(msg["data"]), np.uint8).reshape(2, 3, 5)
    np.testing.assert_array_equal(cells[..., 0].view(np.int8), [[0, 100, -1], [25, 50, 0]])
    np.testing.assert_array_equal(cells[..., 1], [[255, 0, 205], [191, 128, 255]])
    q = msg["pose"]["orientation"]
    np.testing.assert_allclose([q["z"], q["w"]], [np.sqrt(0.5), np.sqrt(0.5)])
