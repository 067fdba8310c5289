"""McapLog: log-time order like mcap's own reader, bounded memory, and damaged logs."""

from __future__ import annotations

import json
import logging
import tracemalloc
from collections import Counter
from itertools import pairwise
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import shared_path
from mcap.data_stream import ReadDataStream
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, Message
from mcap.stream_reader import breakup_chunk
from mcap.writer import CompressionType, IndexType, Writer

from slamcli.errors import FormatError, InputError
from slamcli.formats.mcap.reader import MAGIC, McapLog

MS = 1_000_000
S = 1_000_000_000
T0 = 1_700_000_000 * S
NAV2_COUNTS = {"/tf": 5422, "/odom": 2639, "/amcl_pose": 135, "/tf_static": 1}

Msg = tuple[str, int, bytes]
"""(topic, log time ns, payload)."""


def write_log(
    path: Path,
    messages: list[Msg],
    *,
    compression: CompressionType = CompressionType.ZSTD,
    chunk_size: int = 2048,
    chunking: bool = True,
    summary: bool = True,
    index_types: IndexType = IndexType.ALL,
) -> Path:
    """Write ``messages`` in list order, one json channel per topic (registered on first use)."""
    with path.open("wb") as fh:
        writer = Writer(
            fh,
            chunk_size=chunk_size,
            compression=compression,
            use_chunking=chunking,
            # Without a summary only the message indexes stay, so the data section keeps the
            # same layout as the indexed file's.
            index_types=index_types if summary else index_types & IndexType.MESSAGE,
            repeat_channels=summary,
            repeat_schemas=summary,
            use_statistics=summary,
            use_summary_offsets=summary,
        )
        writer.start(profile="", library="slamcli-tests")
        schema = writer.register_schema("Sample", "jsonschema", b'{"type": "object"}')
        ids: dict[str, int] = {}
        for seq, (topic, t, data) in enumerate(messages):
            if topic not in ids:
                ids[topic] = writer.register_channel(topic, "json", schema)
            writer.add_message(ids[topic], log_time=t, data=data, publish_time=t + 7, sequence=seq)
        writer.finish()
    return path


def payload(topic: str, i: int) -> bytes:
    return json.dumps({"topic": topic, "i": i, "pad": "x" * (i % 37)}).encode()


def regular_messages(n: int = 300) -> list[Msg]:
    """Three topics at 100, 50 and 10 Hz, in log-time order, with some equal stamps."""
    out: list[Msg] = []
    for i in range(n):
        out.append(("/a", T0 + i * 10 * MS, payload("/a", i)))
        if i % 2 == 0:
            out.append(("/b", T0 + i * 10 * MS, payload("/b", i)))
        if i % 10 == 3:
            out.append(("/c", T0 + i * 10 * MS + 1, payload("/c", i)))
    return out


def ours(path: Path, **kwargs: object) -> list[tuple[str, int, int, int, bytes]]:
    with McapLog(path) as log:
        return [
            (m.channel.topic, m.log_time_ns, m.publish_time_ns, m.sequence, m.data)
            for m in log.messages(**kwargs)  # type: ignore[arg-type]
        ]


def reference(path: Path, **kwargs: object) -> list[tuple[str, int, int, int, bytes]]:
    with path.open("rb") as fh:
        return [
            (c.topic, m.log_time, m.publish_time, m.sequence, m.data)
            for _, c, m in make_reader(fh).iter_messages(**kwargs)  # type: ignore[arg-type]
        ]


def chunk_indexes(path: Path) -> list[ChunkIndex]:
    with path.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    return sorted(summary.chunk_indexes, key=lambda ci: ci.chunk_start_offset)


def chunk_messages(path: Path, ci: ChunkIndex) -> list[tuple[int, bytes]]:
    """(log time, payload) of every message inside one chunk, read with mcap's own parser."""
    with path.open("rb") as fh:
        fh.seek(ci.chunk_start_offset + 9)
        chunk = Chunk.read(ReadDataStream(fh))
    return [(r.log_time, r.data) for r in breakup_chunk(chunk) if isinstance(r, Message)]


# -- the real log ----------------------------------------------------------------------------


def test_nav2_log_reads_like_mcap() -> None:
    path = shared_path("mcap", "nav2_turtlebot.mcap")
    expected = reference(path)
    assert Counter(t for t, *_ in expected) == NAV2_COUNTS
    assert ours(path) == expected
    with McapLog(path) as log:
        stats = log.stats()
        channels = log.channels()
        assert {channels[cid].topic: st.count for cid, st in stats.items()} == NAV2_COUNTS
        odom = next(cid for cid, ch in channels.items() if ch.topic == "/odom")
        odom_times = [t for topic, t, *_ in expected if topic == "/odom"]
        assert (stats[odom].first_ns, stats[odom].last_ns) == (odom_times[0], odom_times[-1])
        assert channels[odom].schema_name == "nav_msgs/msg/Odometry"
        assert channels[odom].message_encoding == "cdr"
        assert log.indexed and log.health.summary_present and not log.health.data_lost
    mid = expected[len(expected) // 2][1]
    window = {"topics": ["/odom", "/amcl_pose"], "start_ns": mid, "end_ns": mid + 10 * S}
    got = ours(path, **window)
    assert got == reference(
        path, topics=window["topics"], starting_at=mid, ending_before=mid + 10 * S
    )
    assert {t for t, *_ in got} == {"/odom", "/amcl_pose"} and len(got) > 100


# -- generated logs ----------------------------------------------------------------------------


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
def test_chunked_log_matches_mcap_reader(tmp_path: Path, compression: CompressionType) -> None:
    path = write_log(tmp_path / "log.mcap", regular_messages(), compression=compression)
    assert len(chunk_indexes(path)) >= 10
    got = ours(path)
    assert got == reference(path)
    assert len(got) == 300 + 150 + 30
    with McapLog(path) as log:
        list(log.messages())
        assert log.health.crc_checked
        assert not log.health.chunk_overlap and not log.health.data_lost


def test_overlapping_chunks_are_merged_in_log_time_order(tmp_path: Path) -> None:
    # Writing each burst of messages 0.5 s behind the last makes neighbouring chunks overlap.
    msgs: list[Msg] = []
    for burst in range(12):
        base = T0 + burst * 500 * MS
        msgs += [("/a", base + k * 37 * MS, payload("/a", k)) for k in range(30)]
        msgs += [("/b", base + k * 53 * MS + 3, payload("/b", k)) for k in range(10)]
    path = write_log(tmp_path / "overlap.mcap", msgs, chunk_size=1500)
    idx = sorted(chunk_indexes(path), key=lambda ci: ci.message_start_time)
    assert any(b.message_start_time < a.message_end_time for a, b in pairwise(idx))
    got = ours(path)
    assert got == reference(path)
    times = [t for _, t, *_ in got]
    assert times == sorted(times) and len(got) == len(msgs)
    with McapLog(path) as log:
        assert log.health.chunk_overlap


def test_messages_within_a_chunk_are_sorted(tmp_path: Path) -> None:
    msgs = [("/a", T0 + t * MS, payload("/a", t)) for t in (5, 3, 9, 1, 7, 2)]
    path = write_log(tmp_path / "shuffled.mcap", msgs, chunk_size=1 << 20)
    got = ours(path)
    assert [t for _, t, *_ in got] == sorted(t for _, t, _ in msgs)
    assert got == reference(path)


def test_topic_filter_and_time_window(tmp_path: Path) -> None:
    path = write_log(tmp_path / "log.mcap", regular_messages())
    start, end = T0 + 500 * MS, T0 + 1500 * MS
    got = ours(path, topics=["/b", "/c"], start_ns=start, end_ns=end)
    assert got == reference(path, topics=["/b", "/c"], starting_at=start, ending_before=end)
    assert {t for t, *_ in got} == {"/b", "/c"}
    assert min(t for _, t, *_ in got) == start and max(t for _, t, *_ in got) < end
    assert len(got) == 50 + 10
    # A single topic given as a string means that topic, not its characters.
    assert [m[0] for m in ours(path, topics="/c")] == ["/c"] * 30


def test_chunks_without_a_wanted_channel_are_not_decompressed(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    msgs = [("/early", T0 + i * MS, payload("/early", i)) for i in range(200)]
    msgs += [("/late", T0 + (200 + i) * MS, payload("/late", i)) for i in range(200)]
    path = write_log(tmp_path / "split.mcap", msgs)
    chunks = chunk_indexes(path)
    with_late = [ci for ci in chunks if 2 in ci.message_index_offsets]
    opened: list[int] = []
    original = McapLog._inflate

    def counting(self: McapLog, body: memoryview, cache: dict[str, Any]) -> tuple[bytes, int]:
        opened.append(1)
        return original(self, body, cache)

    monkeypatch.setattr(McapLog, "_inflate", counting)
    got = ours(path, topics=["/late"])
    assert len(got) == 200
    assert len(opened) == len(with_late) < len(chunks) - 2


@pytest.mark.parametrize("compression", [CompressionType.ZSTD, CompressionType.NONE])
def test_log_without_summary_streams_and_counts(
    tmp_path: Path, compression: CompressionType
) -> None:
    msgs = regular_messages(200)
    path = write_log(tmp_path / "nosummary.mcap", msgs, summary=False, compression=compression)
    got = ours(path)
    assert [(t, ts, d) for t, ts, _, _, d in got] == sorted(msgs, key=lambda m: m[1])
    with McapLog(path) as log:
        assert not log.indexed
        assert not log.health.summary_present and not log.health.truncated
        stats = log.stats()
        by_topic = {log.channels()[cid].topic: st for cid, st in stats.items()}
    for topic in ("/a", "/b", "/c"):
        times = [t for tp, t, _ in msgs if tp == topic]
        st = by_topic[topic]
        assert (st.count, st.first_ns, st.last_ns) == (len(times), min(times), max(times))
    assert sum(st.count for st in by_topic.values()) == len(msgs)


def test_chunks_without_message_indexes_are_counted_by_a_pass(tmp_path: Path) -> None:
    msgs = regular_messages(100)
    path = write_log(tmp_path / "noidx.mcap", msgs, index_types=IndexType.CHUNK)
    with McapLog(path) as log:
        assert log.indexed
        counts = {log.channels()[cid].topic: st.count for cid, st in log.stats().items()}
    assert counts == dict(Counter(t for t, _, _ in msgs))
    assert ours(path) == reference(path)


# -- damaged logs ------------------------------------------------------------------------------


def cut_copy(src: Path, dst: Path, at: int) -> Path:
    dst.write_bytes(src.read_bytes()[:at])
    return dst


@pytest.fixture
def chunked_log(tmp_path: Path) -> Path:
    return write_log(tmp_path / "full.mcap", regular_messages(), chunk_size=4096)


def summary_start(path: Path) -> int:
    data = path.read_bytes()
    return int.from_bytes(data[-37 + 9 : -37 + 17], "little")


@pytest.mark.parametrize("where", ["magic", "header", "chunk", "before_footer", "after_data_end"])
def test_truncated_log_reads_everything_before_the_cut(
    chunked_log: Path, tmp_path: Path, where: str
) -> None:
    chunks = chunk_indexes(chunked_log)
    size = chunked_log.stat().st_size
    third = chunks[len(chunks) // 2]
    cut, stopped_at = {
        "magic": (4, 0),
        "header": (12, 8),
        "chunk": (third.chunk_start_offset + third.chunk_length // 2, third.chunk_start_offset),
        "before_footer": (size - 37, size - 37),
        "after_data_end": (summary_start(chunked_log) + 5, summary_start(chunked_log)),
    }[where]
    expected = sorted(
        m
        for ci in chunks
        if ci.chunk_start_offset + ci.chunk_length <= cut
        for m in chunk_messages(chunked_log, ci)
    )
    path = cut_copy(chunked_log, tmp_path / "cut.mcap", cut)
    with McapLog(path) as log:
        got = [(m.log_time_ns, m.data) for m in log.messages()]
        health = log.health
    assert sorted(got) == expected
    assert [t for t, _ in got] == sorted(t for t, _ in got)
    if where in ("chunk", "before_footer", "after_data_end"):
        assert len(got) > 0 and (len(got) < 480) == (where == "chunk")
    assert health.truncated and not health.summary_present and health.data_lost
    assert health.truncated_at_byte == stopped_at
    assert health.last_good_time_ns == (max(t for t, _ in expected) if expected else None)
    with (
        pytest.raises(InputError, match=f"byte {stopped_at} of {cut}") as exc,
        McapLog(path, strict=True) as strict_log,
    ):
        list(strict_log.messages())
    assert exc.value.hint is not None and "mcap recover" in exc.value.hint


def test_truncated_unchunked_log_keeps_whole_messages(tmp_path: Path) -> None:
    msgs = regular_messages(50)
    full = write_log(tmp_path / "flat.mcap", msgs, chunking=False)
    data = full.read_bytes()
    # Cut in the middle of the 41st message record: the first 40 are whole.
    first = data.index(b'{"topic"')
    cut = first
    for _ in range(40):
        cut = data.index(b'{"topic"', cut + 1)
    path = cut_copy(full, tmp_path / "cut.mcap", cut - 3)
    got = ours(path)
    assert [(t, ts, d) for t, ts, _, _, d in got] == sorted(msgs[:40], key=lambda m: m[1])
    with McapLog(path) as log:
        list(log.messages())
        assert log.health.truncated and log.health.truncated_at_byte is not None
        assert log.health.truncated_at_byte < cut - 3


def flip_inside_chunk(path: Path, dst: Path, ci: ChunkIndex) -> Path:
    data = bytearray(path.read_bytes())
    name_len = len(ci.compression.encode())
    data_start = ci.chunk_start_offset + 9 + 32 + name_len + 8
    data[data_start + ci.compressed_size // 2] ^= 0x5A
    dst.write_bytes(bytes(data))
    return dst


@pytest.mark.parametrize(
    "compression", [CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE]
)
@pytest.mark.parametrize("summary", [True, False], ids=["indexed", "streamed"])
def test_flipped_byte_skips_only_that_chunk(
    tmp_path: Path, compression: CompressionType, summary: bool
) -> None:
    msgs = regular_messages()
    indexed = write_log(tmp_path / "ok.mcap", msgs, compression=compression, chunk_size=4096)
    chunks = chunk_indexes(indexed)
    victim = chunks[2]
    lost = chunk_messages(indexed, victim)
    src = indexed
    if not summary:
        src = write_log(
            tmp_path / "flat.mcap", msgs, compression=compression, chunk_size=4096, summary=False
        )
        # Without a summary the chunk sits at the same offset: only the tail differs.
        assert (
            src.read_bytes()[: victim.chunk_start_offset + victim.chunk_length]
            == (indexed.read_bytes()[: victim.chunk_start_offset + victim.chunk_length])
        )
    path = flip_inside_chunk(src, tmp_path / "flipped.mcap", victim)
    with McapLog(path) as log:
        got = [(m.log_time_ns, m.data) for m in log.messages()]
        health = log.health
    everything = sorted((t, d) for _, t, d in msgs)
    assert sorted(got) == sorted(set(everything) - set(lost))
    assert len(got) == len(msgs) - len(lost) > 0
    assert health.bad_chunks == [
        (victim.message_start_time, victim.message_end_time, victim.chunk_start_offset)
    ]
    assert health.crc_checked and health.data_lost and not health.truncated
    assert any(f"byte {victim.chunk_start_offset}" in p for p in health.problems())
    with (
        pytest.raises(InputError, match=f"chunk at byte {victim.chunk_start_offset}"),
        McapLog(path, strict=True) as strict_log,
    ):
        list(strict_log.messages())


def test_late_messages_are_reordered_or_dropped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    msgs = [("/a", T0 + i * 100 * MS, payload("/a", i)) for i in range(40)]
    msgs.insert(21, ("/late", T0 + 1500 * MS, b"half a second late"))
    msgs.insert(31, ("/late", T0 + 50 * MS, b"far too late"))
    path = write_log(tmp_path / "late.mcap", msgs, chunking=False, summary=False)
    with (
        caplog.at_level(logging.DEBUG, logger="slamcli.formats.mcap.reader"),
        McapLog(path, reorder_window_ns=1 * S) as log,
    ):
        got = [(m.channel.topic, m.log_time_ns, m.data) for m in log.messages()]
        health = log.health
    assert [t for _, t, _ in got] == sorted(t for _, t, _ in got)
    assert ("/late", T0 + 1500 * MS, b"half a second late") in got
    assert ("/late", T0 + 50 * MS, b"far too late") not in got
    assert len(got) == 41
    assert health.dropped_late == 1 and health.reordered == 1 and health.data_lost
    assert any("/late" in r.getMessage() and "dropped" in r.getMessage() for r in caplog.records)
    # A window wide enough to cover the lag puts it back in order instead.
    with McapLog(path, reorder_window_ns=5 * S) as wide:
        assert len(list(wide.messages())) == 42 and wide.health.dropped_late == 0


def test_bad_magic_empty_and_missing_files(tmp_path: Path) -> None:
    bad = tmp_path / "bag.db3"
    bad.write_bytes(b"SQLite format 3\x00" + b"\x00" * 100)
    with pytest.raises(FormatError, match=r"bag\.db3: not an MCAP file"):
        McapLog(bad)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(InputError, match="empty file"):
        McapLog(empty)
    with pytest.raises(InputError, match="no such file"):
        McapLog(tmp_path / "missing.mcap")
    # Just the magic: a recorder that died at once; nothing to read, but no crash.
    stub = tmp_path / "stub.mcap"
    stub.write_bytes(MAGIC)
    with McapLog(stub) as log:
        assert list(log.messages()) == [] and log.health.truncated_at_byte == len(MAGIC)


# -- memory ------------------------------------------------------------------------------------


@pytest.mark.slow
def test_memory_stays_bounded_on_a_large_log(tmp_path: Path) -> None:
    rng = np.random.default_rng(7)
    path = tmp_path / "big.mcap"
    n_images = 200
    with path.open("wb") as fh:
        writer = Writer(fh, chunk_size=4 << 20, compression=CompressionType.ZSTD)
        writer.start()
        cam = writer.register_channel("/camera", "raw", 0)
        odom = writer.register_channel("/odom", "raw", 0)
        for i in range(n_images):
            t = T0 + i * 33 * MS
            writer.add_message(cam, t, i.to_bytes(4, "little") + rng.bytes((1 << 20) - 4), t)
            writer.add_message(odom, t + MS, b"odom", t + MS)
        writer.finish()
    size = path.stat().st_size
    assert size > 200 << 20
    tracemalloc.start()
    try:
        n = total = 0
        with McapLog(path) as log:
            for i, msg in enumerate(log.messages(topics=["/camera"])):
                assert msg.data[:4] == i.to_bytes(4, "little")
                n += 1
                total += len(msg.data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert (n, total) == (n_images, n_images << 20)
    assert peak < 30 << 20, f"peak {peak >> 20} MB while reading a {size >> 20} MB log"
