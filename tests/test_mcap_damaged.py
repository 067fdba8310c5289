"""Damaged MCAP logs end to end: what a run salvages, what it says, and its exit codes."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.demo import default_sample
from slamcli.formats import open_source
from slamcli.formats.mcap.write import write_source_mcap

runner = CliRunner()


@pytest.fixture(scope="module")
def log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled sample as a ROS 2 log (30 RGB-D frames in several chunks)."""
    out = tmp_path_factory.mktemp("damaged") / "room.mcap"
    with open_source(default_sample()) as source:
        write_source_mcap(source, out, flavor="ros2")
    return out


def _run(path: Path, out: Path, *extra: str) -> Any:
    return runner.invoke(app, ["run", "odometry", str(path), "--out", str(out), *extra])


def _record(out: Path) -> dict[str, Any]:
    return dict(json.loads((out / "run.json").read_text()))


def _chunks(path: Path) -> list[Any]:
    from mcap.reader import make_reader

    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)


def test_the_intact_log_is_clean(log: Path, tmp_path: Path) -> None:
    assert len(_chunks(log)) >= 4
    res = _run(log, tmp_path / "ok")
    assert res.exit_code == 0, res.output
    assert _record(tmp_path / "ok")["counts"]["frames_processed"] == 30


def _summary_start(data: bytes) -> int:
    # Footer record (opcode, u64 length, u64 summary_start, u64 summary_offset_start, u32 crc)
    # followed by the 8-byte magic.
    return int.from_bytes(data[-37 + 9 : -37 + 17], "little")


@pytest.mark.parametrize("fraction", [0.35, 0.7, 1.0])
def test_a_truncated_log_is_salvaged_with_exit_3(
    log: Path, tmp_path: Path, fraction: float
) -> None:
    data = log.read_bytes()
    cut = tmp_path / "cut.mcap"
    # 1.0 cuts inside the summary: every message is there, only the index and footer are lost.
    end = _summary_start(data) + 20 if fraction == 1.0 else int(len(data) * fraction)
    cut.write_bytes(data[:end])
    res = _run(cut, tmp_path / "run")
    assert res.exit_code == 3, res.output
    assert "truncated" in res.output and "mcap recover" in res.output
    record = _record(tmp_path / "run")
    processed = record["counts"]["frames_processed"]
    # Everything before the cut is used: a cut near the end keeps (nearly) every frame.
    assert 0 < processed <= 30
    if fraction == 1.0:
        assert processed == 30
    else:
        assert processed < 30
    assert any("truncated" in line for line in record["data_loss"])
    strict = _run(cut, tmp_path / "strict", "--strict")
    assert strict.exit_code == 1
    assert "mcap recover" in strict.output
    assert "Traceback" not in strict.output
    info = runner.invoke(app, ["info", str(cut)])
    assert info.exit_code == 3
    assert "truncated" in info.output


def test_a_chunk_with_a_flipped_byte_is_skipped_with_its_time_range(
    log: Path, tmp_path: Path
) -> None:
    chunk = _chunks(log)[1]
    data = bytearray(log.read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0xFF
    bad = tmp_path / "flipped.mcap"
    bad.write_bytes(bytes(data))
    res = _run(bad, tmp_path / "run")
    assert res.exit_code == 3, res.output
    assert f"bad chunk at byte {chunk.chunk_start_offset}" in res.output
    start_s = f"{chunk.message_start_time * 1e-9:.3f} s"
    assert start_s in res.output
    record = _record(tmp_path / "run")
    assert 0 < record["counts"]["frames_processed"] < 30
    strict = _run(bad, tmp_path / "strict", "--strict")
    assert strict.exit_code == 1
    assert str(chunk.chunk_start_offset) in strict.output


def _rewrite(
    src: Path,
    dst: Path,
    add: Callable[[Any, list[tuple[int, int, bytes]]], None],
    chunked: bool = True,
) -> None:
    """Copy a log message by message; ``add(writer, messages)`` may add channels/messages."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with src.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        messages = []
        channel_ids: dict[int, int] = {}
        with dst.open("wb") as out:
            writer = Writer(out, use_chunking=chunked)
            writer.start(profile="ros2")
            schema_ids = {
                sid: writer.register_schema(s.name, s.encoding, s.data)
                for sid, s in summary.schemas.items()
            }
            for cid, ch in summary.channels.items():
                channel_ids[cid] = writer.register_channel(
                    ch.topic, ch.message_encoding, schema_ids[ch.schema_id]
                )
            for _, channel, message in reader.iter_messages():
                messages.append((channel_ids[channel.id], message.log_time, message.data))
            add(writer, messages)
            for cid, t, payload in messages:
                writer.add_message(cid, t, payload, t)
            writer.finish()


def test_an_undecodable_extra_channel_is_ignored_unless_asked_for(
    log: Path, tmp_path: Path
) -> None:
    def extra(writer: Any, messages: list[tuple[int, int, bytes]]) -> None:
        sid = writer.register_schema("acme/Blob", "acme-idl", b"opaque")
        cid = writer.register_channel("/acme/blob", "acme", sid)
        messages.append((cid, messages[0][1], b"\x00\x01"))
        messages.sort(key=lambda m: m[1])

    mixed = tmp_path / "extra.mcap"
    _rewrite(log, mixed, extra)
    res = _run(mixed, tmp_path / "run")
    assert res.exit_code == 0, res.output
    assert _record(tmp_path / "run")["counts"]["frames_processed"] == 30
    info = runner.invoke(app, ["info", str(mixed), "--json"])
    assert info.exit_code == 0
    problems = json.loads(info.stdout)["problems"]
    assert any("/acme/blob" in p and "cannot be read" in p for p in problems)
    asked = _run(mixed, tmp_path / "asked", "--gt-topic", "/acme/blob")
    assert asked.exit_code in (1, 2)
    assert "/acme/blob" in asked.output
    assert "Traceback" not in asked.output


def test_a_late_message_is_dropped_counted_and_exits_3(log: Path, tmp_path: Path) -> None:
    def late(writer: Any, messages: list[tuple[int, int, bytes]]) -> None:
        # Spread the log times over 3 s (header stamps, which pairing uses, stay), then log a
        # copy of an early depth image at the very end, with its early log time: more than
        # the 1 s reorder window behind, so it cannot be put back in order.
        messages.sort(key=lambda m: m[1])
        t0 = messages[0][1]
        messages[:] = [(c, t0 + 3 * (t - t0), d) for c, t, d in messages]
        cid, t, payload = messages[10]
        messages.append((cid, t, payload))

    unchunked = tmp_path / "late.mcap"
    _rewrite(log, unchunked, late, chunked=False)
    res = _run(unchunked, tmp_path / "run")
    assert res.exit_code == 3, res.output
    assert "1 message(s) came too late" in res.output
    assert _record(tmp_path / "run")["counts"]["frames_processed"] == 30
