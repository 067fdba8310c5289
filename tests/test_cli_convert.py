"""``slamcli convert``: exit codes, files written and one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from click.testing import Result
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore
from test_tum_rgbd import write_tum_folder
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.formats.mcap import write as mw
from slamcli.formats.trajectory import write_tum
from slamcli.formats.tum_rgbd import TumRgbdSource
from slamcli.types import Trajectory

runner = CliRunner()


def invoke(*args: str | Path) -> Result:
    return runner.invoke(app, ["convert", *map(str, args)])


def one_line_error(res: Result, text: str) -> None:
    assert "Traceback" not in res.output
    lines = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and text in lines[0], res.stderr


def log_summary(path: Path) -> tuple[str, dict[str, tuple[str, int]]]:
    """(profile, {topic: (schema name, message count)}) from the file's summary."""
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        profile = reader.get_header().profile
    assert summary is not None and summary.statistics is not None
    counts = summary.statistics.channel_message_counts
    return profile, {
        c.topic: (summary.schemas[c.schema_id].name, counts[c.id])
        for c in summary.channels.values()
    }


@pytest.fixture
def tum(tmp_path: Path) -> Path:
    return write_tum_folder(tmp_path / "tum", 5)


def test_tum_to_ros2(tum: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    res = invoke(tum, out, "--flavor", "ros2")
    assert res.exit_code == 0, res.output
    profile, topics = log_summary(out)
    assert profile == "ros2"
    assert topics[mw.TOPIC_COLOR] == ("sensor_msgs/msg/Image", 5)
    assert topics[mw.TOPIC_DEPTH] == ("sensor_msgs/msg/Image", 5)
    assert topics[mw.TOPIC_CAMERA_INFO] == ("sensor_msgs/msg/CameraInfo", 5)
    assert topics[mw.TOPIC_GROUNDTRUTH][0] == "geometry_msgs/msg/PoseStamped"
    assert mw.TOPIC_COLOR in res.stdout and str(out.stat().st_size) in res.stdout


def test_tum_to_foxglove_compressed_with_max_frames(tum: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    res = invoke(tum, out, "--flavor", "foxglove", "--compress-images", "jpeg", "--max-frames", "2")
    assert res.exit_code == 0, res.output
    _, topics = log_summary(out)
    assert topics[mw.TOPIC_COLOR_COMPRESSED] == ("foxglove.CompressedImage", 2)
    assert topics[mw.TOPIC_DEPTH] == ("foxglove.RawImage", 2)
    assert topics[mw.TOPIC_TF][0] == "foxglove.FrameTransform"
    assert mw.TOPIC_COLOR not in topics


def test_source_options_reach_the_source(tum: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    res = invoke(tum, out, "--fx", "100", "--fy", "101", "--cx", "30", "--cy", "20")
    assert res.exit_code == 0, res.output
    store = get_typestore(Stores.ROS2_HUMBLE)
    with out.open("rb") as f:
        infos = [
            store.deserialize_cdr(m.data, s.name)
            for s, _, m in make_reader(f).iter_messages(topics=[mw.TOPIC_CAMERA_INFO])
        ]
    assert len(infos) == 5
    np.testing.assert_array_equal(infos[0].k, [100, 0, 30, 0, 101, 20, 0, 0, 1])


def test_existing_output_needs_force(tum: Path, tmp_path: Path) -> None:
    out = tmp_path / "out.mcap"
    out.write_bytes(b"precious")
    res = invoke(tum, out)
    assert res.exit_code == 1
    one_line_error(res, "already exists")
    assert "--force" in res.stderr
    assert out.read_bytes() == b"precious"
    res = invoke(tum, out, "--force")
    assert res.exit_code == 0, res.output
    assert out.read_bytes()[:8] == b"\x89MCAP0\r\n"


def test_unknown_flavour_is_a_usage_error(tum: Path, tmp_path: Path) -> None:
    res = invoke(tum, tmp_path / "out.mcap", "--flavor", "ros1")
    assert res.exit_code == 2
    assert "ros1" in res.stderr and "ros2" in res.stderr
    assert not (tmp_path / "out.mcap").exists()


def test_a_folder_that_is_neither_input_is_refused(tmp_path: Path) -> None:
    (tmp_path / "stuff").mkdir()
    (tmp_path / "stuff" / "notes.txt").write_text("hello")
    res = invoke(tmp_path / "stuff", tmp_path / "out.mcap")
    assert res.exit_code == 1
    one_line_error(res, "not a recognised input")
    assert not (tmp_path / "out.mcap").exists()


def test_run_folder_to_result_mcap(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}\n")
    stamps = 1_600_000_000_000_000_000 + np.arange(4, dtype=np.int64) * 50_000_000
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 0, 3] = np.arange(4)
    write_tum(run / "trajectory.tum", Trajectory(stamps, poses))
    res = invoke(run, run / "result.mcap")
    assert res.exit_code == 0, res.output
    _, topics = log_summary(run / "result.mcap")
    assert topics == {
        mw.TOPIC_RESULT_POSE: ("foxglove.PoseInFrame", 4),
        mw.TOPIC_TF: ("foxglove.FrameTransform", 4),
    }
    res = invoke(run, tmp_path / "other.mcap", "--flavor", "ros2")
    assert res.exit_code == 1
    one_line_error(res, "--flavor ros2 is for RGB-D inputs, not run folders")
    assert not (tmp_path / "other.mcap").exists()


@pytest.mark.parametrize("existing", [False, True])
def test_an_interrupted_convert_leaves_no_output(
    tum: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, existing: bool
) -> None:
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    out = out_dir / "out.mcap"
    if existing:
        out.write_bytes(b"earlier result")
    load_depth = TumRgbdSource._load_depth
    calls = []

    def interrupted(self: TumRgbdSource, k: int) -> object:
        calls.append(k)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return load_depth(self, k)

    monkeypatch.setattr(TumRgbdSource, "_load_depth", interrupted)
    res = invoke(tum, out, "--force")
    assert res.exit_code == 130
    assert "interrupted" in res.stderr
    assert len(calls) == 3
    if existing:
        assert [p.name for p in out_dir.iterdir()] == ["out.mcap"]
        assert out.read_bytes() == b"earlier result"
    else:
        assert list(out_dir.iterdir()) == []
