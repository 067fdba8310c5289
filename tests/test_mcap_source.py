"""MCAP logs as sources: topic selection, colour/depth pairing, camera and ground truth."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.demo import default_sample
from slamcli.errors import ConfigError, InputError, TopicNotFoundError
from slamcli.formats import open_source
from slamcli.formats.mcap.records import ImageRecord
from slamcli.formats.mcap.source import McapSource, _StreamPairer
from slamcli.formats.mcap.write import write_source_mcap
from slamcli.formats.pairing import associate_stamps
from slamcli.types import RgbdFrame

runner = CliRunner()


@pytest.fixture(scope="module")
def room_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("logs")
    logs = {}
    for name, flavor, compress in (
        ("ros2", "ros2", "none"),
        ("foxglove", "foxglove", "none"),
        ("ros2_png", "ros2", "png"),
        ("foxglove_jpeg", "foxglove", "jpeg"),
    ):
        with open_source(default_sample()) as source:
            written = write_source_mcap(
                source, out / f"room_{name}.mcap", flavor=flavor, compress_images=compress
            )
        logs[name] = written.path
    return logs


def _tum_frames() -> list[RgbdFrame]:
    with open_source(default_sample()) as source:
        return [f for f in source.frames(("rgbd",)) if isinstance(f, RgbdFrame)]


@pytest.mark.parametrize("flavor", ["ros2", "foxglove", "ros2_png", "foxglove_jpeg"])
def test_frames_equal_the_tum_folder_they_came_from(
    room_logs: dict[str, Path], flavor: str
) -> None:
    expected = _tum_frames()
    with open_source(room_logs[flavor]) as source:
        assert isinstance(source, McapSource)
        frames = [f for f in source.frames(("rgbd",)) if isinstance(f, RgbdFrame)]
        camera, origin = source.camera()
    assert len(frames) == len(expected) == 30
    assert [f.stamp_ns for f in frames] == [f.stamp_ns for f in expected]
    for got, want in zip(frames, expected, strict=True):
        if flavor.endswith("jpeg"):
            mse = np.mean((got.rgb.astype(float) - want.rgb.astype(float)) ** 2)
            assert 10 * np.log10(255.0**2 / mse) > 30.0
        else:
            np.testing.assert_array_equal(got.rgb, want.rgb)
        # 16UC1 holds millimetres: equal to the millimetre.
        assert np.abs(got.depth_m - want.depth_m).max() <= 0.0005 + 1e-6
    np.testing.assert_array_equal(camera.K, expected[0].camera.K)
    assert (camera.width, camera.height) == (320, 240)
    assert not camera.is_distorted
    assert origin.startswith("topic /camera/color/camera_info")


def test_groundtruth_is_interpolated_to_the_frames_after_reading(
    room_logs: dict[str, Path],
) -> None:
    with open_source(default_sample()) as tum:
        want = tum.groundtruth()
    assert want is not None
    with open_source(room_logs["ros2"]) as source:
        before = source.groundtruth()
        frames = list(source.frames(("rgbd",)))
        after = source.groundtruth()
    assert before is not None and after is not None
    assert len(before) == len(after) == len(frames) == 30
    np.testing.assert_array_equal(after.stamps_ns, want.stamps_ns)
    np.testing.assert_allclose(after.world_from_body, want.world_from_body, atol=1e-9)


def test_run_over_a_log_scores_like_the_folder(room_logs: dict[str, Path], tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["run", "odometry", str(room_logs["ros2"]), "--out", str(tmp_path / "r")]
    )
    assert res.exit_code == 0, res.output
    assert "ATE (m)" in res.stdout


def _image_log(path: Path, topics: dict[str, str], n: int = 3) -> Path:
    """A ROS 2 log with one Image topic per entry (topic -> encoding)."""
    from mcap.writer import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    image = ts.types["sensor_msgs/msg/Image"]
    header = ts.types["std_msgs/msg/Header"]
    time = ts.types["builtin_interfaces/msg/Time"]
    schema_text = ts.generate_msgdef("sensor_msgs/msg/Image")[0].encode()
    with path.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("sensor_msgs/msg/Image", "ros2msg", schema_text)
        channels = {t: w.register_channel(t, "cdr", sid) for t in topics}
        for i in range(n):
            for t, enc in topics.items():
                bpp = {"rgb8": 3, "16UC1": 2, "32FC1": 4}[enc]
                msg = image(
                    header=header(stamp=time(sec=100, nanosec=i * 33_000_000), frame_id="cam"),
                    height=2,
                    width=2,
                    encoding=enc,
                    is_bigendian=0,
                    step=2 * bpp,
                    data=np.zeros(4 * bpp, dtype=np.uint8),
                )
                stamp = 100_000_000_000 + i * 33_000_000
                w.add_message(channels[t], stamp, ts.serialize_cdr(msg, image.__msgtype__), stamp)
        w.finish()
    return path


def test_two_colour_topics_need_a_choice_and_list_the_candidates(tmp_path: Path) -> None:
    log = _image_log(tmp_path / "two.mcap", {"/a/image": "rgb8", "/b/image": "rgb8", "/d": "16UC1"})
    with McapSource(log) as source, pytest.raises(TopicNotFoundError, match="2 rgb topics") as err:
        source.topic("rgb")
    assert [row[0] for row in err.value.candidates] == ["/a/image", "/b/image"]
    assert err.value.candidates[0][1:4] == ["sensor_msgs/msg/Image", "rgb8", "3"]
    with McapSource(log, rgb_topic="/b/image") as source:
        assert source.topic("rgb") == "/b/image"
        assert source.topic("depth") == "/d"
    res = runner.invoke(app, ["run", "odometry", str(log), "--out", str(tmp_path / "o")])
    assert res.exit_code == 1
    assert "choose one with --rgb-topic" in res.output
    assert "/a/image" in res.output and "/b/image" in res.output
    assert not (tmp_path / "o").exists()


def test_a_missing_or_mistyped_topic_is_named(tmp_path: Path) -> None:
    log = _image_log(tmp_path / "one.mcap", {"/c": "rgb8", "/d": "32FC1"})
    with (
        McapSource(log, rgb_topic="/nope") as source,
        pytest.raises(TopicNotFoundError, match="no topic /nope"),
    ):
        source.topic("rgb")
    with (
        McapSource(log, gt_topic="/c") as source,
        pytest.raises(TopicNotFoundError, match="has type sensor_msgs/msg/Image"),
    ):
        source.groundtruth()
    with McapSource(log) as source:
        assert source.topic("depth") == "/d"
        with pytest.raises(TopicNotFoundError, match=r"no camera topic.*--camera-info-topic"):
            source.topic("camera")


def test_without_calibration_the_camera_comes_from_options(tmp_path: Path) -> None:
    log = _image_log(tmp_path / "nocal.mcap", {"/c": "rgb8", "/d": "16UC1"})
    with McapSource(log, camera="fr1") as source:
        camera, origin = source.camera()
        frames = list(source.frames(("rgbd",)))
    assert camera.fx == pytest.approx(517.306408)
    assert "fr1" in origin
    assert len(frames) == 3
    with pytest.raises(ConfigError, match="--gt-topic or --gt-frame"):
        McapSource(log, gt_topic="/x", gt_frame="y")


def test_nav2_log_ground_truth_from_pose_topic_and_tf() -> None:
    from tests.conftest import shared_path

    log = shared_path("mcap", "nav2_turtlebot.mcap")
    with McapSource(log) as source:
        amcl = source.groundtruth()
        odometry = list(source.frames(("odometry",)))
    assert amcl is not None and len(amcl) == 135
    assert len(odometry) == 2639
    assert all(f.v is not None and f.world_from_body is not None for f in odometry)
    with McapSource(log, gt_frame="base_footprint") as source:
        tf_gt = source.groundtruth()
    assert tf_gt is not None and len(tf_gt) > 1000
    # The tf chain map -> odom -> base_footprint is a rigid-body pose at every stamp.
    r = tf_gt.world_from_body[:, :3, :3]
    np.testing.assert_allclose(
        r @ np.swapaxes(r, 1, 2), np.broadcast_to(np.eye(3), r.shape), atol=1e-9
    )
    with (
        McapSource(log, gt_frame="no_such_frame") as source,
        pytest.raises(InputError, match="no frame 'no_such_frame'"),
    ):
        source.groundtruth()


def test_info_on_the_nav2_log_lists_topics_types_and_counts() -> None:
    import json

    from tests.conftest import shared_path

    log = shared_path("mcap", "nav2_turtlebot.mcap")
    res = runner.invoke(app, ["info", str(log), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    streams = {s["name"]: s for s in data["streams"]}
    assert {k: v["count"] for k, v in streams.items()} == {
        "/amcl_pose": 135,
        "/odom": 2639,
        "/tf": 5422,
        "/tf_static": 1,
    }
    assert streams["/odom"]["detail"].startswith("nav_msgs/msg/Odometry")
    assert data["format"] == "mcap" and data["frames"] == 0 and data["groundtruth"] == 135
    assert any("no RGB-D frames" in p for p in data["problems"])


def _record(stamp: int) -> ImageRecord:
    return ImageRecord(stamp, "f", "rgb", np.zeros((1, 1, 3), np.uint8), "rgb8")


@settings(max_examples=150, deadline=None)
@given(
    st.lists(st.integers(0, 12_000_000), min_size=1, max_size=40),
    st.lists(st.integers(0, 12_000_000), min_size=1, max_size=40),
    st.integers(-8_000_000, 8_000_000),
)
# The colour stream stops after one image while depth goes on: the buffer stays bounded.
@example(rgb_jitter=[0], depth_jitter=[0] * 40, offset=0)
@example(rgb_jitter=[0] * 40, depth_jitter=[7_000_000], offset=-3_000_000)
def test_streamed_pairing_equals_the_global_associate_rule(
    rgb_jitter: list[int], depth_jitter: list[int], offset: int
) -> None:
    period, max_dt = 33_333_333, 20_000_000
    rgb = [i * period + j for i, j in enumerate(rgb_jitter)]
    depth = [i * period + 5_000_000 + j for i, j in enumerate(depth_jitter)]
    want_i, want_j = associate_stamps(np.array(rgb), np.array(depth), max_dt, offset)
    want = sorted(zip((rgb[i] for i in want_i), (depth[j] for j in want_j), strict=True))
    pairer = _StreamPairer(max_dt, offset)
    got = []
    events = sorted([(s, "rgb") for s in rgb] + [(s, "depth") for s in depth])
    for stamp, role in events:
        pairer.add(role, _record(stamp))
        got += [(a.stamp_ns, b.stamp_ns) for a, b in pairer.ready()]
        assert len(pairer.buf["rgb"]) + len(pairer.buf["depth"]) <= 40
    got += [(a.stamp_ns, b.stamp_ns) for a, b in pairer.ready(final=True)]
    assert sorted(got) == want


def test_odom_exported_as_tum_matches_the_decoded_messages(tmp_path: Path) -> None:
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    from slamcli.formats.trajectory import read_trajectory
    from tests.conftest import shared_path

    log = shared_path("mcap", "nav2_turtlebot.mcap")
    out = tmp_path / "odom.tum"
    res = runner.invoke(app, ["convert", str(log), str(out), "--gt-topic", "/odom"])
    assert res.exit_code == 0, res.output
    ts = get_typestore(Stores.ROS2_HUMBLE)
    stamps, xyz, quats = [], [], []
    with log.open("rb") as fh:
        for _, _, message in make_reader(fh).iter_messages(topics=["/odom"]):
            msg = ts.deserialize_cdr(message.data, "nav_msgs/msg/Odometry")
            stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
            p, q = msg.pose.pose.position, msg.pose.pose.orientation
            xyz.append([p.x, p.y, p.z])
            quats.append([q.x, q.y, q.z, q.w])
    order = np.argsort(stamps, kind="stable")
    stamps_sorted = np.asarray(stamps)[order]
    keep = np.concatenate([[True], np.diff(stamps_sorted) > 0])
    traj = read_trajectory(out)
    np.testing.assert_array_equal(traj.stamps_ns, stamps_sorted[keep])
    np.testing.assert_allclose(traj.positions, np.asarray(xyz)[order][keep], atol=1e-9)
    from slamcli.geometry import matrix_to_quat_xyzw

    got = matrix_to_quat_xyzw(traj.world_from_body[:, :3, :3])
    want = np.asarray(quats)[order][keep]
    want = want / np.linalg.norm(want, axis=1, keepdims=True)
    sign = np.sign(np.sum(got * want, axis=1, keepdims=True))
    np.testing.assert_allclose(got, want * sign, atol=1e-8)
    res = runner.invoke(app, ["convert", str(log), str(out), "--gt-topic", "/odom"])
    assert res.exit_code == 1 and "--force" in res.output
