"""Landmark observations in MCAP logs: the JSON schema, the reader, the writer and the CLI."""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import InputError, TopicNotFoundError
from slamcli.formats import open_source
from slamcli.formats.landmarks import LandmarkLog, read_landmark_log
from slamcli.formats.mcap import write as mw
from slamcli.formats.mcap.observations import SCHEMA_NAME, landmark_schema
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.trajectory import read_trajectory
from slamcli.geometry import se3_to_planar
from slamcli.types import LandmarkFrame, OdometryFrame

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "sample_data" / "landmarks"
DOC = ROOT / "docs" / "formats.md"
runner = CliRunner()


def _stamp_ns(text: str) -> int:
    whole, _, frac = text.partition(".")
    return int(whole) * 1_000_000_000 + int((frac + "0" * 9)[:9])


def _csv(name: str) -> list[dict[str, str]]:
    with (SAMPLE / name).open(newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    out = tmp_path_factory.mktemp("landmark_logs")
    return {
        flavor: mw.write_landmark_log(out / f"{flavor}.mcap", SAMPLE, flavor=flavor).path
        for flavor in ("ros2", "foxglove")
    }


def _read(path: Path, kinds: Sequence[str] = ("odometry", "landmarks"), **options: Any) -> Any:
    with open_source(path, **options) as source:
        assert isinstance(source, McapSource)
        frames = list(source.frames(kinds))
        return frames, source.groundtruth(), source.start_pose(), source.landmark_truth()


@pytest.mark.parametrize("flavor", ["ros2", "foxglove"])
def test_frames_equal_the_csv_files(logs: dict[str, Path], flavor: str) -> None:
    frames, _, _, truth = _read(logs[flavor])
    assert truth is None
    odometry = [f for f in frames if isinstance(f, OdometryFrame)]
    landmarks = [f for f in frames if isinstance(f, LandmarkFrame)]
    assert len(odometry) + len(landmarks) == len(frames)

    odo_rows = _csv("odometry.csv")
    assert [f.stamp_ns for f in odometry] == [_stamp_ns(r["t"]) for r in odo_rows]
    np.testing.assert_allclose([f.v for f in odometry], [float(r["v"]) for r in odo_rows], atol=0)
    np.testing.assert_allclose(
        [f.omega for f in odometry], [float(r["omega"]) for r in odo_rows], atol=0
    )
    # The pose is the dead reckoning of the controls, starting at the origin.
    assert all(f.world_from_body is not None for f in odometry)
    np.testing.assert_array_equal(odometry[0].world_from_body, np.eye(4))

    rows = _csv("measurements.csv")
    stamps = sorted({_stamp_ns(r["t"]) for r in rows})
    assert [f.stamp_ns for f in landmarks] == stamps
    got = [
        (f.stamp_ns, int(i), r, b)
        for f in landmarks
        for i, r, b in zip(
            f.ids.tolist(), f.ranges_m.tolist(), f.bearings_rad.tolist(), strict=True
        )
    ]
    want = [(_stamp_ns(r["t"]), int(r["id"]), float(r["range"]), float(r["bearing"])) for r in rows]
    assert [g[:2] for g in got] == [w[:2] for w in want]
    np.testing.assert_allclose([g[2:] for g in got], [w[2:] for w in want], atol=1e-9, rtol=0)
    assert all(f.ids.dtype == np.int64 for f in landmarks)

    # Time order, odometry first at equal stamps.
    keys = [(f.stamp_ns, 0 if isinstance(f, OdometryFrame) else 1) for f in frames]
    assert keys == sorted(keys)


@pytest.mark.parametrize("flavor", ["ros2", "foxglove"])
def test_ground_truth_and_start_pose(logs: dict[str, Path], flavor: str) -> None:
    want = read_trajectory(SAMPLE / "groundtruth.tum", "tum")
    with McapSource(logs[flavor]) as source:
        # Before reading frames: the poses as recorded.
        recorded = source.groundtruth()
        start = source.start_pose()
        assert source.landmark_truth() is None
    assert recorded is not None and start is not None
    np.testing.assert_array_equal(recorded.stamps_ns, want.stamps_ns)
    np.testing.assert_allclose(recorded.world_from_body, want.world_from_body, atol=1e-9)
    np.testing.assert_allclose(start, se3_to_planar(want.world_from_body[:1])[0], atol=1e-9)

    # After reading frames of a log without images: at the stamps of the frames read.
    frames, after, start_after, _ = _read(logs[flavor], ("landmarks",))
    assert after is not None and start_after == pytest.approx(start, abs=1e-12)
    np.testing.assert_array_equal(after.stamps_ns, [f.stamp_ns for f in frames])
    index = np.searchsorted(want.stamps_ns, after.stamps_ns)
    np.testing.assert_allclose(after.world_from_body, want.world_from_body[index], atol=1e-9)


def test_the_log_stores_the_shipped_schema_and_every_message_validates(
    logs: dict[str, Path],
) -> None:
    shipped = json.loads(landmark_schema())
    validator = jsonschema.Draft202012Validator(shipped)
    jsonschema.Draft202012Validator.check_schema(shipped)
    assert shipped == json.loads(
        (ROOT / "slamcli/formats/mcap/schemas/LandmarkObservations.json").read_text()
    )
    n = 0
    for path in logs.values():
        with path.open("rb") as fh:
            reader = make_reader(fh)
            for schema, channel, message in reader.iter_messages(topics=[mw.TOPIC_LANDMARKS]):
                assert schema is not None
                assert (schema.name, schema.encoding) == (SCHEMA_NAME, "jsonschema")
                assert channel.message_encoding == "json"
                assert json.loads(schema.data) == shipped
                msg = json.loads(message.data)
                validator.validate(msg)
                stamp = msg["timestamp"]["sec"] * 1_000_000_000 + msg["timestamp"]["nsec"]
                assert message.log_time == message.publish_time == stamp
                n += 1
    assert n == 2 * len({r["t"] for r in _csv("measurements.csv")})


# -- hand-made logs -------------------------------------------------------------------------


def _log(path: Path, messages: Sequence[tuple[str, int, Any]]) -> Path:
    """A log of (topic, log time ns, JSON message or raw bytes) on landmark channels."""
    with path.open("wb") as fh:
        writer = Writer(fh)
        writer.start()
        schema = writer.register_schema(SCHEMA_NAME, "jsonschema", landmark_schema())
        channels: dict[str, int] = {}
        sequence: dict[str, int] = {}
        for topic, log_time, msg in sorted(messages, key=lambda m: m[1]):
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "json", schema)
                sequence[topic] = 0
            data = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
            writer.add_message(channels[topic], log_time, data, log_time, sequence=sequence[topic])
            sequence[topic] += 1
        writer.finish()
    return path


def _msg(stamp_ns: int, observations: list[dict[str, Any]]) -> dict[str, Any]:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    return {
        "timestamp": {"sec": sec, "nsec": nsec},
        "frame_id": "base_link",
        "observations": observations,
    }


T0 = 1_700_000_000_000_000_000
GOOD = [{"id": 1, "range": 2.0, "bearing": 0.5}, {"range": 3.0, "bearing": -0.25}]


@pytest.mark.parametrize(
    ("bad", "what"),
    [
        ({"id": 1, "bearing": 0.5}, "has no 'range'"),
        ({"id": 1, "range": "2.0", "bearing": 0.5}, "not a finite number"),
        ({"id": 1.5, "range": 2.0, "bearing": 0.5}, "not an integer"),
        ({"range": 2.0, "bearing": None}, "not a finite number"),
    ],
)
def test_a_message_breaking_the_schema_names_topic_log_time_and_sequence(
    tmp_path: Path, bad: dict[str, Any], what: str
) -> None:
    log = _log(
        tmp_path / "bad.mcap",
        [
            ("/landmarks", T0 + 5, _msg(T0, GOOD)),
            ("/landmarks", T0 + 100_000_005, _msg(T0 + 100_000_000, [GOOD[0], bad])),
            ("/landmarks", T0 + 200_000_005, _msg(T0 + 200_000_000, GOOD)),
        ],
    )
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(_msg(T0, [bad]), json.loads(landmark_schema()))
    with McapSource(log, strict=True) as source, pytest.raises(InputError) as err:
        list(source.frames(("landmarks",)))
    text = err.value.msg
    assert "/landmarks" in text and what in text and "observations[1]" in text
    assert "log time 1700000000.100000005 s" in text and "sequence 1" in text
    # Without --strict the message is skipped, counted and named, like any undecodable one.
    with McapSource(log) as source:
        frames = list(source.frames(("landmarks",)))
        assert source.stats.skipped == 1
        assert source.stats.skipped_names == [f"/landmarks@{T0 + 100_000_005}"]
    assert [f.stamp_ns for f in frames] == [T0, T0 + 200_000_000]
    np.testing.assert_array_equal(frames[0].ids, [1, -1])


def test_two_landmark_topics_need_a_choice(tmp_path: Path) -> None:
    log = _log(
        tmp_path / "two.mcap",
        [("/front/landmarks", T0, _msg(T0, GOOD)), ("/rear/landmarks", T0, _msg(T0, GOOD[:1]))],
    )
    with McapSource(log) as source, pytest.raises(TopicNotFoundError) as err:
        list(source.frames(("landmarks",)))
    assert "--landmark-topic" in err.value.msg
    assert sorted(row[0] for row in err.value.candidates) == ["/front/landmarks", "/rear/landmarks"]
    with open_source(log, landmark_topic="/rear/landmarks") as source:
        (frame,) = source.frames(("landmarks",))
    assert isinstance(frame, LandmarkFrame) and frame.ids.tolist() == [1]
    with (
        McapSource(log, landmark_topic="/nope") as source,
        pytest.raises(TopicNotFoundError, match="no topic /nope"),
    ):
        list(source.frames(("landmarks",)))


def test_late_observations_come_back_in_stamp_order(tmp_path: Path) -> None:
    """A detector logs its observations 250 ms after they were taken; odometry is prompt."""
    run = read_landmark_log(SAMPLE)
    keep = run.odometry_stamps_ns < run.odometry_stamps_ns[0] + 3_000_000_000
    meas = run.measurement_stamps_ns < run.odometry_stamps_ns[0] + 3_000_000_000
    short = LandmarkLog(
        run.odometry_stamps_ns[keep],
        run.odometry[keep],
        run.measurement_stamps_ns[meas],
        run.measurement_ids[meas],
        run.measurement_ranges[meas],
        run.measurement_bearings[meas],
    )
    prompt = mw.write_landmark_log(tmp_path / "prompt.mcap", short).path
    late = tmp_path / "late.mcap"
    with prompt.open("rb") as src, late.open("wb") as dst:
        reader = make_reader(src)
        writer = Writer(dst)
        writer.start()
        ids: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            if channel.id not in ids:
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid
                )
            delay = 250_000_000 if channel.topic == mw.TOPIC_LANDMARKS else 0
            t = message.log_time + delay
            writer.add_message(ids[channel.id], t, message.data, t, message.sequence)
        writer.finish()
    want, _, _, _ = _read(prompt)
    got, _, _, _ = _read(late)
    assert [(type(f), f.stamp_ns) for f in got] == [(type(f), f.stamp_ns) for f in want]
    assert sum(isinstance(f, LandmarkFrame) for f in got) == len(set(short.measurement_stamps_ns))


# -- CLI and the README example ---------------------------------------------------------------


def test_convert_then_info_lists_the_landmark_topic(tmp_path: Path) -> None:
    out = tmp_path / "x.mcap"
    res = runner.invoke(app, ["convert", str(SAMPLE), str(out)])
    assert res.exit_code == 0, res.output
    assert mw.TOPIC_LANDMARKS in res.stdout and mw.TOPIC_ODOM in res.stdout
    res = runner.invoke(app, ["info", str(out)])
    assert res.exit_code == 0, res.output
    assert "/landmarks" in res.stdout and "slamcli.LandmarkObservations" in res.stdout
    n_stamps = len({r["t"] for r in _csv("measurements.csv")})
    assert f"{n_stamps} messages on /landmarks" in res.stdout
    assert "paired RGB-D" not in res.stdout
    res = runner.invoke(app, ["info", str(out), "--json"])
    data = json.loads(res.stdout)
    streams = {s["name"]: s for s in data["streams"]}
    n_messages = len({r["t"] for r in _csv("measurements.csv")})
    assert streams["/landmarks"]["count"] == n_messages
    assert streams["/landmarks"]["kind"] == "landmarks"
    assert data["details"]["landmark_topic"] == "/landmarks"
    assert data["details"]["landmark_messages"] == n_messages
    assert data["groundtruth"] == len(_csv("odometry.csv")) + 1
    assert data["problems"] == []
    # Written atomically: nothing but the log is left in the folder; a second write needs --force.
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]
    res = runner.invoke(app, ["convert", str(SAMPLE), str(out)])
    assert res.exit_code == 1 and "already exists" in res.stderr
    res = runner.invoke(app, ["convert", str(SAMPLE), str(out), "--max-frames", "3", "--force"])
    assert res.exit_code == 1 and "not landmark folders" in res.stderr


def test_the_documented_python_example_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    section = DOC.read_text(encoding="utf-8").split("## Landmark observations in MCAP")[1]
    blocks = re.findall(r"```python\n(.*?)```", section.split("\n## ")[0], re.S)
    assert len(blocks) == 1
    code = blocks[0]
    assert len([line for line in code.splitlines() if line.strip()]) <= 16
    monkeypatch.chdir(tmp_path)
    exec(compile(code, str(DOC), "exec"), {"__name__": "__doc_example__"})
    with open_source(tmp_path / "observations.mcap") as source:
        (frame,) = source.frames(("landmarks",))
    assert isinstance(frame, LandmarkFrame)
    assert frame.stamp_ns == 1_700_000_000_100_000_000
    assert frame.ids.tolist() == [2, -1]
    np.testing.assert_allclose(frame.ranges_m, [3.553, 4.979])
    np.testing.assert_allclose(frame.bearings_rad, [-0.890, 1.391])
    # The documented example message is valid too.
    example = json.loads(re.findall(r"```json\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)[0])
    jsonschema.validate(example, json.loads(landmark_schema()))


@pytest.mark.parametrize(("late_s", "expect"), [(1.0, "first"), (40.0, None)])
def test_start_pose_when_ground_truth_starts_late(
    tmp_path: Path, late_s: float, expect: str | None
) -> None:
    run = read_landmark_log(SAMPLE)
    assert run.groundtruth is not None
    stamps = run.groundtruth.stamps_ns
    gt = run.groundtruth.subset(stamps >= stamps[0] + round(late_s * 1e9))
    late = LandmarkLog(
        run.odometry_stamps_ns,
        run.odometry,
        run.measurement_stamps_ns,
        run.measurement_ids,
        run.measurement_ranges,
        run.measurement_bearings,
        gt,
    )
    path = mw.write_landmark_log(tmp_path / "late_gt.mcap", late).path
    with McapSource(path) as source:
        start = source.start_pose()
    if expect is None:
        assert start is None
    else:
        assert start is not None
        np.testing.assert_allclose(start, se3_to_planar(gt.world_from_body[:1])[0], atol=1e-12)
