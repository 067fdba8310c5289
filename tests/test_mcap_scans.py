"""2-D laser scans in MCAP logs: LaserScan (ROS 2, ROS 1, Foxglove) in and out, bad scans skipped
and counted, topic choice, the mounting from tf, odometry from tf, and conversion."""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from conftest import shared_path
from mcap.reader import make_reader
from mcap.writer import Writer
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.convert import convert
from slamcli.demo import default_sample
from slamcli.errors import ConfigError, ExportError, TopicNotFoundError
from slamcli.formats import open_source
from slamcli.formats.mcap.adapters import adapter_for
from slamcli.formats.mcap.decode import DecodeError, decoder_for
from slamcli.formats.mcap.records import ChannelInfo
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.mcap.tf import TfBuffer
from slamcli.formats.mcap.write import foxglove_schema, laser_scan_message, write_scan_mcap
from slamcli.formats.mcap.write.foxglove import frame_transform
from slamcli.geometry import make_pose, matrix_to_quat_xyzw, planar_to_se3, se3_to_planar
from slamcli.source_options import SourceOptions
from slamcli.types import OdometryFrame, ScanFrame

runner = CliRunner()

T0 = 1_700_000_000_000_000_000
STEP = 100_000_000
MOUNT = (0.25, -0.125, 0.5)
N_BEAMS = 181


def f32(x: float) -> float:
    return float(np.float32(x))


def _scan(i: int, mount: tuple[float, float, float] = MOUNT) -> ScanFrame:
    """A sweep with float32-exact angles and limits; beams 5-8 are inf, NaN, too close, too
    far."""
    rng = np.random.default_rng(i)
    r = rng.uniform(0.2, 8.0, N_BEAMS).astype(np.float32)
    r[5], r[6], r[7], r[8] = np.inf, np.nan, 0.0625, 40.0
    return ScanFrame(
        T0 + i * STEP,
        r,
        f32(-math.pi / 2),
        f32(math.pi / (N_BEAMS - 1)),
        0.125,
        30.0,
        np.array(mount, dtype=np.float64),
    )


def _odom(i: int) -> OdometryFrame:
    pose = planar_to_se3([0.1 * i, 0.05 * i, 0.2 * i - 0.3])[0]
    return OdometryFrame(T0 + i * STEP - 5_000_000, v=0.25 * i, omega=-0.125, world_from_body=pose)


def _frames(n: int = 6) -> list[ScanFrame | OdometryFrame]:
    out: list[ScanFrame | OdometryFrame] = []
    for i in range(n):
        out += [_scan(i), _odom(i)]
    return out


def _in_stamp_order(frames: list[Any]) -> list[Any]:
    return sorted(frames, key=lambda f: (f.stamp_ns, isinstance(f, ScanFrame)))


def _assert_same_scan(got: Any, want: ScanFrame, mounting_atol: float = 1e-12) -> None:
    assert isinstance(got, ScanFrame)
    assert got.stamp_ns == want.stamp_ns
    np.testing.assert_array_equal(got.ranges_m, want.ranges_m)
    assert got.ranges_m.dtype == np.float32
    assert got.angle_min_rad == want.angle_min_rad
    assert got.angle_increment_rad == want.angle_increment_rad
    assert (got.range_min_m, got.range_max_m) == (want.range_min_m, want.range_max_m)
    np.testing.assert_allclose(
        got.body_from_sensor, want.body_from_sensor, rtol=0, atol=mounting_atol
    )


def _assert_same_odometry(got: Any, want: OdometryFrame) -> None:
    assert isinstance(got, OdometryFrame)
    assert got.stamp_ns == want.stamp_ns
    assert (got.v, got.omega) == (want.v, want.omega)
    assert got.world_from_body is not None and want.world_from_body is not None
    np.testing.assert_array_equal(got.world_from_body[:3, 3], want.world_from_body[:3, 3])
    np.testing.assert_allclose(got.world_from_body, want.world_from_body, rtol=0, atol=1e-12)


def _assert_same_frames(got: list[Any], want: list[Any]) -> None:
    assert [type(f).__name__ for f in got] == [type(f).__name__ for f in want]
    for g, w in zip(got, want, strict=True):
        if isinstance(w, ScanFrame):
            _assert_same_scan(g, w)
        else:
            _assert_same_odometry(g, w)


# --- logs written by hand with rosbags messages (ROS 1 or ROS 2) --------------------------------


def _store(ros1: bool) -> Any:
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


class _Msgs:
    """rosbags messages of one ROS version."""

    def __init__(self, ros1: bool = False) -> None:
        from rosbags.typesys import get_types_from_msg

        self.ros1 = ros1
        self.store = _store(ros1)
        if ros1:
            # Noetic's store in rosbags has no tf2_msgs: a ROS 1 recorder stores this definition.
            text = "geometry_msgs/TransformStamped[] transforms"
            self.store.register(get_types_from_msg(text, "tf2_msgs/msg/TFMessage"))
        self.t = self.store.types

    def header(self, stamp_ns: int, frame: str) -> Any:
        sec, nsec = divmod(stamp_ns, 1_000_000_000)
        time = self.t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        extra = {"seq": 0} if self.ros1 else {}
        return self.t["std_msgs/msg/Header"](stamp=time, frame_id=frame, **extra)

    def scan(
        self,
        stamp_ns: int,
        frame: str,
        ranges: Any,
        angle_min: float,
        angle_max: float,
        increment: float,
        limits: tuple[float, float] = (0.125, 30.0),
    ) -> Any:
        return self.t["sensor_msgs/msg/LaserScan"](
            header=self.header(stamp_ns, frame),
            angle_min=angle_min,
            angle_max=angle_max,
            angle_increment=increment,
            time_increment=0.0,
            scan_time=0.0,
            range_min=limits[0],
            range_max=limits[1],
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )

    def scan_of(self, frame: ScanFrame, frame_id: str = "laser") -> Any:
        n = len(frame.ranges_m)
        end = frame.angle_min_rad + (n - 1) * frame.angle_increment_rad
        return self.scan(
            frame.stamp_ns,
            frame_id,
            frame.ranges_m,
            frame.angle_min_rad,
            end,
            frame.angle_increment_rad,
            (frame.range_min_m, frame.range_max_m),
        )

    def _pose(self, pose: np.ndarray) -> Any:
        t = pose[:3, 3]
        q = matrix_to_quat_xyzw(pose[:3, :3])
        return self.t["geometry_msgs/msg/Pose"](
            position=self.t["geometry_msgs/msg/Point"](x=t[0], y=t[1], z=t[2]),
            orientation=self.t["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )

    def odometry_of(self, frame: OdometryFrame, child: str = "base_link") -> Any:
        assert frame.world_from_body is not None
        vector3 = self.t["geometry_msgs/msg/Vector3"]
        twist = self.t["geometry_msgs/msg/Twist"](
            linear=vector3(x=frame.v or 0.0, y=0.0, z=0.0),
            angular=vector3(x=0.0, y=0.0, z=frame.omega or 0.0),
        )
        return self.t["nav_msgs/msg/Odometry"](
            header=self.header(frame.stamp_ns, "odom"),
            child_frame_id=child,
            pose=self.t["geometry_msgs/msg/PoseWithCovariance"](
                pose=self._pose(frame.world_from_body), covariance=np.zeros(36)
            ),
            twist=self.t["geometry_msgs/msg/TwistWithCovariance"](
                twist=twist, covariance=np.zeros(36)
            ),
        )

    def pose_stamped(self, stamp_ns: int, pose: np.ndarray) -> Any:
        return self.t["geometry_msgs/msg/PoseStamped"](
            header=self.header(stamp_ns, "map"), pose=self._pose(pose)
        )

    def tf(self, stamp_ns: int, edges: list[tuple[str, str, np.ndarray]]) -> Any:
        transforms = []
        for parent, child, pose in edges:
            t, q = pose[:3, 3], matrix_to_quat_xyzw(pose[:3, :3])
            transforms.append(
                self.t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(stamp_ns, parent),
                    child_frame_id=child,
                    transform=self.t["geometry_msgs/msg/Transform"](
                        translation=self.t["geometry_msgs/msg/Vector3"](x=t[0], y=t[1], z=t[2]),
                        rotation=self.t["geometry_msgs/msg/Quaternion"](
                            x=q[0], y=q[1], z=q[2], w=q[3]
                        ),
                    ),
                )
            )
        return self.t["tf2_msgs/msg/TFMessage"](transforms=transforms)


def _write_log(path: Path, msgs: _Msgs, rows: list[tuple[str, Any, int]]) -> Path:
    """An MCAP of (topic, rosbags message, log time) rows, with the definitions a recorder
    stores (ros1msg for ROS 1, ros2msg for ROS 2)."""
    ros1 = msgs.ros1
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros1" if ros1 else "ros2", library="test")
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, msg, log_ns in rows:
            typename = msg.__msgtype__
            if topic not in channels:
                if typename not in schemas:
                    text, _ = msgs.store.generate_msgdef(typename, ros_version=1 if ros1 else 2)
                    name = typename.replace("/msg/", "/") if ros1 else typename
                    encoding = "ros1msg" if ros1 else "ros2msg"
                    schemas[typename] = w.register_schema(name, encoding, text.encode())
                channels[topic] = w.register_channel(
                    topic, "ros1" if ros1 else "cdr", schemas[typename]
                )
            serialize = msgs.store.serialize_ros1 if ros1 else msgs.store.serialize_cdr
            data = bytes(serialize(msg, typename))
            w.add_message(channels[topic], log_time=log_ns, data=data, publish_time=log_ns)
        w.finish()
    return path


def _scan_log(
    path: Path,
    frames: list[Any],
    *,
    ros1: bool = False,
    mounting: np.ndarray | None = None,
    laser: str = "laser",
) -> Path:
    """Scans on /scan, odometry on /odom and, given a mounting, base_link -> laser on
    /tf_static."""
    msgs = _Msgs(ros1)
    rows: list[tuple[str, Any, int]] = []
    if mounting is not None:
        rows.append(("/tf_static", msgs.tf(T0 - STEP, [("base_link", laser, mounting)]), T0 - STEP))
    for f in frames:
        if isinstance(f, ScanFrame):
            rows.append(("/scan", msgs.scan_of(f, laser), f.stamp_ns))
        else:
            rows.append(("/odom", msgs.odometry_of(f), f.stamp_ns))
    return _write_log(path, msgs, rows)


def _read(path: Path, kinds: tuple[str, ...] = ("scan", "odometry"), **options: Any) -> list[Any]:
    with open_source(path, **options) as source:
        return list(source.frames(kinds))


# --- round trips ---------------------------------------------------------------------------------


def test_ros2_round_trip_gives_back_the_frames_written(tmp_path: Path) -> None:
    frames = _frames()
    summary = write_scan_mcap(tmp_path / "scans.mcap", frames)
    assert summary.frames == 6
    assert summary.topics == {
        "/tf_static": ("tf2_msgs/msg/TFMessage", 1),
        "/scan": ("sensor_msgs/msg/LaserScan", 6),
        "/odom": ("nav_msgs/msg/Odometry", 6),
    }
    with open_source(summary.path) as source:
        assert isinstance(source, McapSource)
        got = list(source.frames(("scan", "odometry")))
        assert source.stats.read == 12 and source.stats.skipped == 0
        info = source.info()
    _assert_same_frames(got, _in_stamp_order(frames))
    # The message's rules survive: inf is no return, NaN and 0.0625 m are no readings.
    scan = got[1]
    assert isinstance(scan, ScanFrame)
    assert scan.no_returns()[[5, 8]].all() and not scan.readings()[5:9].any()
    assert scan.name == f"/scan@{T0}"
    stream = next(s for s in info.streams if s.name == "/scan")
    assert (stream.kind, stream.count, stream.rate_hz) == ("scan", 6, pytest.approx(10.0))
    assert stream.detail.endswith(f", {N_BEAMS} beams")
    d = info.details
    assert (d["scan_topic"], d["scan_frame"], d["scan_beams"]) == ("/scan", "laser", N_BEAMS)
    assert d["scan_odometry"] == "/odom"
    assert d["scan_mounting"].startswith("x 0.250 m, y -0.125 m, yaw 28.6 deg from tf base_link")
    assert not [p for p in info.problems if "RGB-D" in p or "scan" in p]


def test_ros1_log_reads_like_the_ros2_one(tmp_path: Path) -> None:
    frames = _frames(4)
    log = _scan_log(tmp_path / "ros1.mcap", frames, ros1=True, mounting=planar_to_se3(MOUNT)[0])
    with log.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    schemas = {s.name for s in summary.schemas.values()}
    assert "sensor_msgs/LaserScan" in schemas and "tf2_msgs/TFMessage" in schemas
    _assert_same_frames(_read(log), _in_stamp_order(frames))


def test_foxglove_flavour_keeps_the_readings_and_drops_the_rest(tmp_path: Path) -> None:
    frames = _frames(3)
    summary = write_scan_mcap(tmp_path / "fox.mcap", frames, flavor="foxglove")
    assert summary.topics["/scan"] == ("foxglove.LaserScan", 3)
    assert summary.topics["/tf_static"] == ("foxglove.FrameTransform", 1)
    got = [f for f in _read(summary.path) if isinstance(f, ScanFrame)]
    want = [f for f in frames if isinstance(f, ScanFrame)]
    for g, w in zip(got, want, strict=True):
        assert g.stamp_ns == w.stamp_ns
        np.testing.assert_array_equal(g.readings(), w.readings())
        np.testing.assert_array_equal(g.ranges_m[w.readings()], w.ranges_m[w.readings()])
        np.testing.assert_array_equal(g.ranges_m[~w.readings()], 0.0)
        assert g.angle_min_rad == w.angle_min_rad
        assert g.angle_increment_rad == pytest.approx(w.angle_increment_rad, rel=1e-12)
        np.testing.assert_allclose(g.body_from_sensor, w.body_from_sensor, atol=1e-12)


def test_foxglove_messages_follow_the_official_schemas() -> None:
    scan_schema = json.loads(foxglove_schema("LaserScan"))
    msg = laser_scan_message(_scan(0), "laser")
    jsonschema.validate(msg, scan_schema)
    assert len(msg["ranges"]) == N_BEAMS and all(math.isfinite(r) for r in msg["ranges"])
    tf = frame_transform(T0, "base_link", "laser", planar_to_se3(MOUNT)[0])
    jsonschema.validate(tf, json.loads(foxglove_schema("FrameTransform")))


# --- bad scans -----------------------------------------------------------------------------------


def _bad_scan_log(path: Path) -> Path:
    msgs = _Msgs()
    inc = f32(0.01)
    ok = np.ones(11, dtype=np.float32)
    rows = [
        ("/scan", msgs.scan(T0, "laser", ok, 0.0, 10 * inc, inc), T0),
        # 11 ranges cannot end at 0.2 rad in steps of 0.01
        ("/scan", msgs.scan(T0 + STEP, "laser", ok, 0.0, 20 * inc, inc), T0 + STEP),
        ("/scan", msgs.scan(T0 + 2 * STEP, "laser", ok, 0.0, 10 * inc, 0.0), T0 + 2 * STEP),
        # one increment short: rounding a driver may do
        ("/scan", msgs.scan(T0 + 3 * STEP, "laser", ok, 0.0, 11 * inc, inc), T0 + 3 * STEP),
    ]
    return _write_log(path, msgs, rows)


def test_bad_scans_are_skipped_counted_and_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = _bad_scan_log(tmp_path / "bad.mcap")
    with caplog.at_level(logging.WARNING), McapSource(log) as source:
        got = list(source.frames(("scan",)))
        assert source.stats.skipped == 2
        assert source.stats.skipped_names == [f"/scan@{T0 + STEP}", f"/scan@{T0 + 2 * STEP}"]
        assert source.stats.read == 2
    assert [f.stamp_ns for f in got] == [T0, T0 + 3 * STEP]
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    length = next(w for w in warnings if "message 1 of /scan" in w)
    assert "channel /scan" in length and "11 ranges" in length and "angle_max" in length
    zero = next(w for w in warnings if "message 2 of /scan" in w)
    assert "angle_increment 0" in zero
    with (
        McapSource(log, strict=True) as source,
        pytest.raises(DecodeError, match="message 1 of /scan"),
    ):
        list(source.frames(("scan",)))


def test_info_deep_counts_bad_scans_and_exits_3(tmp_path: Path) -> None:
    log = _bad_scan_log(tmp_path / "bad.mcap")
    res = runner.invoke(app, ["info", str(log), "--deep", "--json"])
    assert res.exit_code == 3, res.output
    facts = json.loads(res.stdout)
    assert facts["details"]["unreadable"] == [f"/scan@{T0 + STEP}", f"/scan@{T0 + 2 * STEP}"]
    assert facts["details"]["scan_beams"] == 11


# --- topic choice --------------------------------------------------------------------------------


def test_a_log_without_scans_names_its_topics() -> None:
    log = shared_path("mcap", "nav2_turtlebot.mcap")
    with open_source(log) as source, pytest.raises(TopicNotFoundError) as err:
        next(iter(source.frames(("scan", "odometry"))))
    assert "no scan topics found; choose one with --scan-topic" in err.value.msg
    assert "the table lists the log's topics" in str(err.value.hint)
    rows = {row[0]: row[1] for row in err.value.candidates}
    assert rows["/odom"] == "nav_msgs/msg/Odometry"
    assert {"/amcl_pose", "/tf", "/tf_static"} <= set(rows)


def _two_scan_topics(path: Path) -> Path:
    msgs = _Msgs()
    inc = f32(0.5)
    rows = []
    for i, topic in enumerate(("/front/scan", "/rear/scan")):
        ranges = np.full(3, 1.0 + i, dtype=np.float32)
        rows.append((topic, msgs.scan(T0 + i, topic.split("/")[1], ranges, 0.0, 2 * inc, inc), T0))
    return _write_log(path, msgs, rows)


def test_two_scan_topics_need_a_choice(tmp_path: Path) -> None:
    log = _two_scan_topics(tmp_path / "two.mcap")
    with open_source(log) as source, pytest.raises(TopicNotFoundError) as err:
        list(source.frames(("scan",)))
    assert "2 scan topics found; choose one with --scan-topic" in err.value.msg
    assert [row[:2] for row in err.value.candidates] == [
        ["/front/scan", "sensor_msgs/msg/LaserScan"],
        ["/rear/scan", "sensor_msgs/msg/LaserScan"],
    ]
    got = _read(log, ("scan",), scan_topic="/rear/scan")
    assert len(got) == 1 and got[0].ranges_m.tolist() == [2.0, 2.0, 2.0]
    options = SourceOptions(scan_topic="/rear/scan")
    assert options.open_kwargs() == {"scan_topic": "/rear/scan"}
    res = runner.invoke(app, ["info", str(log), "--json", "--scan-topic", "/front/scan"])
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["details"]["scan_topic"] == "/front/scan"
    with pytest.raises(TopicNotFoundError, match="no topic /side/scan"):
        _read(log, ("scan",), scan_topic="/side/scan")


def test_scan_topic_is_no_option_of_other_formats() -> None:
    with pytest.raises(ConfigError, match="--scan-topic does not apply to tum"):
        open_source(default_sample(), scan_topic="/scan")


# --- mounting ------------------------------------------------------------------------------------


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _endpoints_in_body(scan: ScanFrame) -> np.ndarray:
    """(N, 2) beam end points on the body, from the planar scan as a pipeline uses it."""
    x, y, yaw = scan.body_from_sensor
    a = scan.angles() + yaw
    r = scan.ranges_m.astype(np.float64)
    return np.stack([x + r * np.cos(a), y + r * np.sin(a)], axis=1)


@pytest.mark.parametrize("upside_down", [False, True])
def test_mounting_follows_a_chain_of_static_transforms(tmp_path: Path, upside_down: bool) -> None:
    """base_link -> plate -> laser; an upside-down laser gets mirrored angles, and every beam
    ends where the 3-D transform puts it."""
    msgs = _Msgs()
    plate = make_pose(_rot_z(0.4), [0.1, 0.0, 0.2])
    laser = make_pose(_rot_z(-0.1) @ _rot_x(math.pi if upside_down else 0.0), [0.05, 0.02, 0.1])
    scan = _scan(1)
    rows = [
        ("/tf_static", msgs.tf(T0, [("base_link", "plate", plate)]), T0),
        ("/tf_static", msgs.tf(T0, [("plate", "laser", laser)]), T0),
        ("/odom", msgs.odometry_of(_odom(1)), T0 + STEP - 5_000_000),
        ("/scan", msgs.scan_of(scan), T0 + STEP),
    ]
    log = _write_log(tmp_path / "chain.mcap", msgs, rows)
    got = next(f for f in _read(log) if isinstance(f, ScanFrame))
    ok = np.isfinite(scan.ranges_m)
    r, a = scan.ranges_m[ok].astype(np.float64), scan.angles()[ok]
    sensor_pts = np.stack([r * np.cos(a), r * np.sin(a), np.zeros_like(r)], axis=1)
    body_from_laser = plate @ laser
    want = (sensor_pts @ body_from_laser[:3, :3].T + body_from_laser[:3, 3])[:, :2]
    np.testing.assert_allclose(_endpoints_in_body(got)[ok], want, atol=1e-6)
    assert (got.angle_increment_rad < 0) == upside_down


def test_a_tilted_scanner_is_warned_about(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    tilted = make_pose(_rot_x(math.radians(20)), [0.0, 0.0, 0.3])
    log = _scan_log(tmp_path / "tilt.mcap", [_scan(0), _odom(0)], mounting=tilted)
    with caplog.at_level(logging.WARNING):
        _read(log)
    assert any("tilted 20 deg" in r.getMessage() for r in caplog.records)


def test_without_tf_the_mounting_is_zero_and_info_says_so(tmp_path: Path) -> None:
    log = _scan_log(tmp_path / "notf.mcap", _frames(2))
    scans = [f for f in _read(log) if isinstance(f, ScanFrame)]
    assert len(scans) == 2
    np.testing.assert_array_equal(scans[0].body_from_sensor, np.zeros(3))
    with open_source(log) as source:
        info = source.info()
    assert "mounting taken as zero" in info.details["scan_mounting"]
    assert any(p.startswith("scans: no tf from laser to base_link") for p in info.problems)


# --- odometry from tf, on the real log -----------------------------------------------------------


def test_odometry_comes_from_tf_when_the_log_has_no_odometry_topic(tmp_path: Path) -> None:
    """The nav2 log's /tf and /tf_static with scans taken in its lidar frame, and no /odom: the
    odometry is tf odom -> base_link, which equals the log's own /odom messages."""
    nav2 = shared_path("mcap", "nav2_turtlebot.mcap")
    with open_source(nav2) as source:
        odom = [f for f in source.frames(("odometry",)) if isinstance(f, OdometryFrame)]
    out = tmp_path / "nav2_scans.mcap"
    msgs = _Msgs()
    with nav2.open("rb") as src, out.open("wb") as fh:
        w = Writer(fh)
        w.start(profile="ros2", library="test")
        channels: dict[int, int] = {}
        reader = make_reader(src)
        for schema, channel, message in reader.iter_messages(topics=["/tf", "/tf_static"]):
            if channel.id not in channels:
                sid = w.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = w.register_channel(channel.topic, "cdr", sid)
            w.add_message(
                channels[channel.id],
                log_time=message.log_time,
                data=message.data,
                publish_time=message.publish_time,
            )
        text, _ = msgs.store.generate_msgdef("sensor_msgs/msg/LaserScan")
        sid = w.register_schema("sensor_msgs/msg/LaserScan", "ros2msg", text.encode())
        scan_channel = w.register_channel("/scan", "cdr", sid)
        inc = f32(math.pi / 180)
        for f in odom[::100]:
            msg = msgs.scan(
                f.stamp_ns, "rplidar_link", np.ones(360, np.float32), 0.0, 359 * inc, inc
            )
            data = bytes(msgs.store.serialize_cdr(msg, "sensor_msgs/msg/LaserScan"))
            # the log's clock is wall time, the stamps simulation time: any log time will do
            w.add_message(scan_channel, log_time=T0 + f.stamp_ns, data=data, publish_time=T0)
        w.finish()
    with open_source(out) as source:
        frames = list(source.frames(("scan", "odometry")))
        info = source.info()
    from_tf = [f for f in frames if isinstance(f, OdometryFrame)]
    scans = [f for f in frames if isinstance(f, ScanFrame)]
    assert len(from_tf) == len(odom) == 2639 and len(scans) == len(odom[::100])
    assert [f.stamp_ns for f in from_tf] == [f.stamp_ns for f in odom]
    assert all(f.v is None and f.omega is None for f in from_tf)
    np.testing.assert_allclose(
        np.stack([f.world_from_body for f in from_tf]),
        np.stack([f.world_from_body for f in odom]),
        atol=1e-9,
    )
    assert info.details["scan_odometry"] == "tf odom -> base_link"
    # The mounting: the static chain base_link -> shell_link -> rplidar_link.
    tf = TfBuffer()
    with nav2.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=["/tf_static"]):
            decode = decoder_for(ChannelInfo.from_records(channel, schema))
            adapt = adapter_for(schema.name)
            assert adapt is not None
            tf.add(adapt(decode(message.data), message.log_time, channel.topic))
    want = se3_to_planar(tf.lookup("base_link", "rplidar_link", 0))[0]
    np.testing.assert_allclose(scans[0].body_from_sensor, want, atol=1e-12)
    assert abs(want[0]) > 0.01  # the lidar is not at the body's origin
    assert info.details["scan_mounting"].endswith("from tf base_link <- rplidar_link")


def test_a_log_of_scans_alone_has_the_scanner_for_its_body(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    log = _scan_log(tmp_path / "bare.mcap", [_scan(0), _scan(1)])
    with caplog.at_level(logging.WARNING):
        scans = _read(log, ("scan",))
    assert len(scans) == 2 and not caplog.records
    np.testing.assert_array_equal(scans[0].body_from_sensor, np.zeros(3))
    with open_source(log) as source:
        info = source.info()
    assert info.details["scan_mounting"].endswith(
        "from the scanner's own frame (the log has no odometry)"
    )
    assert info.details["scan_odometry"] is None and info.problems == []
    # Odometry asked for, and neither a topic nor tf has it.
    with pytest.raises(TopicNotFoundError, match="no odometry topics found"):
        _read(log)


# --- ground truth at the scans' stamps -----------------------------------------------------------


def test_groundtruth_is_interpolated_to_the_scans(tmp_path: Path) -> None:
    msgs = _Msgs()
    frames = _frames(4)
    rows: list[tuple[str, Any, int]] = [
        ("/tf_static", msgs.tf(T0, [("base_link", "laser", planar_to_se3(MOUNT)[0])]), T0)
    ]
    for f in frames:
        if isinstance(f, ScanFrame):
            rows.append(("/scan", msgs.scan_of(f), f.stamp_ns))
        else:
            rows.append(("/odom", msgs.odometry_of(f), f.stamp_ns))
    for k in range(-2, 40):
        stamp = T0 + k * STEP // 10
        pose = planar_to_se3([0.01 * k, 0.0, 0.0])[0]
        rows.append(("/ground_truth", msgs.pose_stamped(stamp, pose), stamp))
    log = _write_log(tmp_path / "gt.mcap", msgs, sorted(rows, key=lambda r: r[2]))
    with open_source(log, gt_topic="/ground_truth") as source:
        start = source.start_pose()
        list(source.frames(("scan", "odometry")))
        gt = source.groundtruth()
    assert gt is not None
    np.testing.assert_array_equal(gt.stamps_ns, [T0 + i * STEP for i in range(4)])
    np.testing.assert_allclose(gt.positions[:, 0], [0.0, 0.1, 0.2, 0.3], atol=1e-12)
    assert start is not None and start[0] == pytest.approx(-0.005)  # at the first odometry


# --- conversion and refusals ---------------------------------------------------------------------


@pytest.mark.parametrize("flavor", ["ros2", "foxglove"])
def test_convert_of_a_scan_log_reads_back_the_same(tmp_path: Path, flavor: str) -> None:
    frames = _frames(5)
    src = _scan_log(tmp_path / "in.mcap", frames, ros1=True, mounting=planar_to_se3(MOUNT)[0])
    result = convert(src, tmp_path / "out.mcap", flavor=flavor)
    assert result.kind == "source" and result.summary is not None
    assert result.summary.frames == 5
    assert result.summary.topics["/odom"] == ("nav_msgs/msg/Odometry", 5)
    got = _read(result.out)
    if flavor == "ros2":
        _assert_same_frames(got, _in_stamp_order(frames))
    else:
        assert [f.stamp_ns for f in got] == [f.stamp_ns for f in _in_stamp_order(frames)]
    res = runner.invoke(app, ["convert", str(src), str(tmp_path / "cli.mcap")])
    assert res.exit_code == 0, res.output
    _assert_same_frames(_read(tmp_path / "cli.mcap"), _in_stamp_order(frames))


def test_writer_refusals_leave_no_file(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    moved = [_scan(0), _scan(1, mount=(0.0, 0.0, 0.0))]
    with pytest.raises(ExportError, match="frame laser has one mounting"):
        write_scan_mcap(out, moved)
    with pytest.raises(ExportError, match="has no pose"):
        write_scan_mcap(out, [_scan(0), OdometryFrame(T0, v=1.0, omega=0.0)])
    with pytest.raises(ExportError, match="nothing to write"):
        write_scan_mcap(out, [])
    with pytest.raises(ConfigError, match="must differ"):
        write_scan_mcap(out, _frames(1), scan_topic="/odom")
    with pytest.raises(ConfigError, match="flavor must be one of"):
        write_scan_mcap(out, _frames(1), flavor="ros1")
    assert list(tmp_path.iterdir()) == []
    write_scan_mcap(out, _frames(1))
    with pytest.raises(ExportError, match="already exists"):
        write_scan_mcap(out, _frames(1))
    write_scan_mcap(out, _frames(2), force=True)
    assert len(_read(out)) == 4
