"""Hostile MCAP input: size limits on chunks and messages, bounded decompression, and damaged
payloads that must end as skipped messages or one-line errors, never as tracebacks.

The hostile files are built here: a few hundred kB that declare or decompress to gigabytes.
Commands run as subprocesses so their wall time and peak RSS can be measured.
"""

from __future__ import annotations

import io
import os
import random
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.data_stream import RecordBuilder
from mcap.reader import make_reader
from mcap.records import Chunk, ChunkIndex, DataEnd, Footer
from mcap.writer import CompressionType, Writer
from measured import run_measured
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.demo import default_sample
from slamcli.errors import ConfigError, InputError, SlamcliError
from slamcli.formats import open_source
from slamcli.formats.mcap.adapters import adapter_for
from slamcli.formats.mcap.decode import decoder_for
from slamcli.formats.mcap.reader import MAGIC, McapLog
from slamcli.formats.mcap.records import ChannelInfo
from slamcli.formats.mcap.source import McapSource
from slamcli.formats.mcap.write import write_source_mcap

GIB = 2**30
MB = 2**20
SLAMCLI = str(Path(sys.executable).with_name("slamcli"))
MAX_SECONDS = 10.0
MAX_RSS_MB = 500.0

runner = CliRunner()


@pytest.fixture(scope="module")
def room(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The bundled sample as a ROS 2 log: 30 RGB-D frames in chunks of about 1.1 MB."""
    out = tmp_path_factory.mktemp("limits") / "room.mcap"
    with open_source(default_sample()) as source:
        write_source_mcap(source, out, flavor="ros2")
    return out


def _zeros_in_steps(comp: Any, n: int) -> bytes:
    """``n`` zero bytes through a streaming compressor, fed 64 MB at a time."""
    out = io.BytesIO()
    block = bytes(64 * MB)
    left = n
    while left:
        k = min(len(block), left)
        out.write(comp.compress(block if k == len(block) else block[:k]))
        left -= k
    out.write(comp.flush())
    return out.getvalue()


def zeros_zstd(n: int, *, content_size: bool = True) -> bytes:
    """``n`` zero bytes as one zstd frame, compressed in 64 MB steps (a few hundred kB)."""
    import zstandard

    cctx = zstandard.ZstdCompressor(level=1, write_content_size=content_size)
    return _zeros_in_steps(cctx.compressobj(size=n if content_size else -1), n)


def zeros_lz4(n: int) -> bytes:
    """``n`` zero bytes as one lz4 frame, compressed in 64 MB steps."""
    import lz4.frame

    comp = lz4.frame.LZ4FrameCompressor()
    return comp.begin(source_size=n) + _zeros_in_steps(comp, n)


def with_chunk(
    src: Path,
    dst: Path,
    data: bytes,
    *,
    compression: str,
    declared: int,
    indexed: bool = True,
    record_length: int | None = None,
) -> int:
    """Copy ``src`` with a chunk of ``data`` inserted before its first chunk.

    ``indexed`` rewrites the summary with a chunk index for every chunk (the hostile one
    declaring ``declared`` bytes like its header); otherwise the footer points at no summary
    and the log is read front to back. ``record_length`` overwrites the chunk record's length
    field. Returns the inserted chunk's byte offset.
    """
    raw = src.read_bytes()
    with src.open("rb") as fh:
        summary = make_reader(fh).get_summary()
    assert summary is not None
    indexes = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    first = indexes[0]
    at = first.chunk_start_offset
    builder = RecordBuilder()
    Chunk(
        compression=compression,
        data=data,
        message_start_time=first.message_start_time,
        message_end_time=first.message_start_time,
        uncompressed_crc=0,
        uncompressed_size=declared,
    ).write(builder)
    hostile = bytearray(builder.end())
    if record_length is not None:
        hostile[1:9] = record_length.to_bytes(8, "little")
    shift = len(hostile)
    data_end = max(c.chunk_start_offset + c.chunk_length + c.message_index_length for c in indexes)
    body = raw[:at] + bytes(hostile) + raw[at:data_end]
    tail = RecordBuilder()
    DataEnd(data_section_crc=0).write(tail)
    summary_start = 0
    if indexed:
        summary_start = len(body) + tail.count
        for schema in summary.schemas.values():
            schema.write(tail)
        for channel in summary.channels.values():
            channel.write(tail)
        ChunkIndex(
            message_start_time=first.message_start_time,
            message_end_time=first.message_start_time,
            chunk_start_offset=at,
            chunk_length=shift,
            message_index_offsets={},
            message_index_length=0,
            compression=compression,
            compressed_size=len(data),
            uncompressed_size=declared,
        ).write(tail)
        for c in indexes:
            ChunkIndex(
                message_start_time=c.message_start_time,
                message_end_time=c.message_end_time,
                chunk_start_offset=c.chunk_start_offset + shift,
                chunk_length=c.chunk_length,
                message_index_offsets={k: v + shift for k, v in c.message_index_offsets.items()},
                message_index_length=c.message_index_length,
                compression=c.compression,
                compressed_size=c.compressed_size,
                uncompressed_size=c.uncompressed_size,
            ).write(tail)
    Footer(summary_start=summary_start, summary_offset_start=0, summary_crc=0).write(tail)
    dst.write_bytes(body + tail.end() + MAGIC)
    return at


def measured(*args: str) -> tuple[int, str, float, float]:
    """Run the CLI: (exit code, stdout + stderr, CPU seconds, peak RSS in MB).

    The time is the child's user + system CPU time: what the input cost, whatever else the
    machine (a CI runner with two test workers) is doing at the time. The RSS is the
    command's own (see ``measured.py``), not the test worker's.
    """
    return run_measured([SLAMCLI, *args], env={**os.environ, "COLUMNS": "250", "NO_COLOR": "1"})


def check_refused(args: list[str], path: Path, at: int, codes: tuple[int, ...] = (3,)) -> str:
    code, output, seconds, rss_mb = measured(*args)
    assert code in codes, output
    assert "Traceback" not in output, output
    assert any(str(path) in line and f"byte {at}" in line for line in output.splitlines()), output
    assert seconds < MAX_SECONDS, (seconds, output)
    assert rss_mb < MAX_RSS_MB, (rss_mb, output)
    return output


def commands(path: Path, out: Path) -> list[list[str]]:
    return [["info", "--deep", str(path)], ["run", "odometry", str(path), "--out", str(out)]]


@pytest.fixture(scope="module")
def zstd_3gib() -> bytes:
    return zeros_zstd(3 * GIB)


@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "streamed"])
def test_a_chunk_declaring_3_gib_of_zstd_zeros_is_refused_fast(
    room: Path, tmp_path: Path, zstd_3gib: bytes, indexed: bool
) -> None:
    assert len(zstd_3gib) < 1 * MB
    bomb = tmp_path / "bomb.mcap"
    at = with_chunk(room, bomb, zstd_3gib, compression="zstd", declared=3 * GIB, indexed=indexed)
    for args in commands(bomb, tmp_path / "run"):
        output = check_refused(args, bomb, at)
        assert "3221225472 bytes" in output and "256 MB limit" in output
        assert "--max-chunk-mb" in output
        assert "unpack" not in output
    strict = check_refused([*commands(bomb, tmp_path / "strict")[1], "--strict"], bomb, at, (1,))
    assert "--max-chunk-mb" in strict


def test_a_chunk_declaring_3_gib_of_lz4_zeros_is_refused_fast(room: Path, tmp_path: Path) -> None:
    bomb = tmp_path / "bomb.mcap"
    at = with_chunk(room, bomb, zeros_lz4(3 * GIB), compression="lz4", declared=3 * GIB)
    for args in commands(bomb, tmp_path / "run"):
        check_refused(args, bomb, at)


@pytest.mark.parametrize(
    ("compression", "make"),
    [
        ("zstd", lambda n: zeros_zstd(n)),
        ("zstd", lambda n: zeros_zstd(n, content_size=False)),
        ("lz4", zeros_lz4),
    ],
    ids=["zstd", "zstd-no-content-size", "lz4"],
)
@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "streamed"])
def test_a_chunk_lying_about_its_size_stops_decompressing_at_the_declared_size(
    room: Path, tmp_path: Path, compression: str, make: Callable[[int], bytes], indexed: bool
) -> None:
    # 1 GiB of zeros in a chunk that claims 1 MB: within the limit, so it is decompressed,
    # and decompression must stop one step past 1 MB.
    bomb = tmp_path / "liar.mcap"
    at = with_chunk(room, bomb, make(GIB), compression=compression, declared=MB, indexed=indexed)
    output = check_refused(commands(bomb, tmp_path / "run")[0], bomb, at)
    assert f"more than the {MB} bytes it declares" in output


def test_a_refused_chunk_is_freed_before_the_next_pass(room: Path, tmp_path: Path) -> None:
    # 200 MB is read before the lie shows; info --deep reads the log in several passes, and
    # each must free that buffer, or the peak grows by 200 MB a pass.
    bomb = tmp_path / "liar.mcap"
    data = zeros_zstd(GIB, content_size=False)
    at = with_chunk(room, bomb, data, compression="zstd", declared=200 * MB)
    check_refused(commands(bomb, tmp_path / "run")[0], bomb, at)


def test_a_record_length_of_2_to_the_62_is_a_truncation(room: Path, tmp_path: Path) -> None:
    bomb = tmp_path / "long.mcap"
    at = with_chunk(room, bomb, b"", compression="", declared=0, indexed=False, record_length=2**62)
    for args in commands(bomb, tmp_path / "run"):
        # Nothing before the break defines a channel, so a run stops for want of topics.
        output = check_refused(args, bomb, at, (1, 3))
        assert "truncated" in output


def test_a_chunk_declaring_1_tib_is_refused(room: Path, tmp_path: Path) -> None:
    bomb = tmp_path / "tib.mcap"
    at = with_chunk(room, bomb, zeros_zstd(MB), compression="zstd", declared=2**40)
    for args in commands(bomb, tmp_path / "run"):
        output = check_refused(args, bomb, at)
        assert f"{2**40} bytes" in output


@pytest.fixture(scope="module")
def big_chunk(room: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """The sample plus a genuine 2 MB chunk (one message on a channel nothing reads)."""
    import zstandard
    from mcap.records import Message

    builder = RecordBuilder()
    Message(channel_id=999, log_time=0, data=bytes(2 * MB), publish_time=0, sequence=0).write(
        builder
    )
    records = builder.end()
    path = tmp_path_factory.mktemp("big") / "big.mcap"
    data = zstandard.ZstdCompressor().compress(records)
    at = with_chunk(room, path, data, compression="zstd", declared=len(records))
    return path, at


def test_max_chunk_mb_sets_the_limit(big_chunk: tuple[Path, int], tmp_path: Path) -> None:
    path, at = big_chunk
    fine = runner.invoke(app, ["info", "--deep", str(path)])
    assert fine.exit_code == 0, fine.output
    small = runner.invoke(app, ["info", "--deep", str(path), "--max-chunk-mb", "2"])
    assert small.exit_code == 3, small.output
    assert f"byte {at}" in small.output and "over the 2 MB limit" in small.output
    strict = runner.invoke(app, ["info", "--deep", str(path), "--max-chunk-mb", "2", "--strict"])
    assert strict.exit_code == 1
    assert "--max-chunk-mb" in strict.output
    ran = runner.invoke(
        app,
        ["run", "odometry", str(path), "--out", str(tmp_path / "o"), "--max-chunk-mb", "2"],
    )
    assert ran.exit_code == 3, ran.output
    assert (tmp_path / "o" / "run.json").exists()
    bad = runner.invoke(app, ["info", str(path), "--max-chunk-mb", "0"])
    assert bad.exit_code == 2


def test_max_chunk_mb_reaches_convert(room: Path, tmp_path: Path) -> None:
    out = tmp_path / "gt.tum"
    res = runner.invoke(
        app,
        ["convert", str(room), str(out), "--gt-topic", "/groundtruth", "--max-chunk-mb", "1"],
    )
    # Every chunk is refused, so there are no poses left to export.
    assert res.exit_code == 1, res.output
    assert "1 MB limit" in res.output


def test_library_limit_and_oversized_unchunked_message(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="max_chunk_bytes"):
        McapLog(tmp_path / "x.mcap", max_chunk_bytes=0)
    path = tmp_path / "flat.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh, use_chunking=False, compression=CompressionType.NONE)
        writer.start(profile="", library="slamcli-tests")
        sid = writer.register_schema("Blob", "jsonschema", b"{}")
        cid = writer.register_channel("/blob", "json", sid)
        for i, size in enumerate([10, 2 * MB, 10]):
            writer.add_message(cid, log_time=i, data=b"0" * size, publish_time=i)
        writer.finish()
    with McapLog(path, max_chunk_bytes=MB) as log:
        kept = [len(m.data) for m in log.messages()]
        assert kept == [10, 10]
        assert len(log.health.bad_chunks) == 1
        assert any("message at byte" in p for p in log.health.loss_problems())
    with McapLog(path, strict=True, max_chunk_bytes=MB) as log, pytest.raises(InputError) as err:
        list(log.messages())
    assert "message at byte" in err.value.msg and "1 MB limit" in err.value.msg
    with McapSource(path, max_chunk_bytes=4 * MB) as source:
        assert source.log.max_chunk_bytes == 4 * MB


@pytest.mark.parametrize("indexed", [True, False], ids=["indexed", "streamed"])
def test_a_chunk_record_too_long_for_the_limit_is_not_read(
    room: Path, tmp_path: Path, indexed: bool
) -> None:
    # The header declares 10 bytes, but 2 MB of compressed data cannot hold that little.
    path = tmp_path / "long.mcap"
    at = with_chunk(room, path, bytes(2 * MB), compression="zstd", declared=10, indexed=indexed)
    # 1.5 MB: the sample's own chunks (1.1 MB) stay readable.
    with McapLog(path, max_chunk_bytes=3 * MB // 2) as log:
        assert sum(1 for _ in log.messages()) > 0
        assert [c[2] for c in log.health.bad_chunks] == [at]
        assert log.health.oversized[at][0] == "chunk"
        assert "chunk record of 2" in log.health.oversized[at][1]


def test_a_chunk_of_countless_tiny_records_is_refused(room: Path, tmp_path: Path) -> None:
    # Empty records of a user opcode cost parsing time and nothing else; the limit allows one
    # record per 256 bytes (6144 for 1.5 MB), so 7000 of them, 63 kB in all, are refused.
    import zstandard

    records = (b"\x80" + bytes(8)) * 7000
    path = tmp_path / "tiny.mcap"
    data = zstandard.ZstdCompressor().compress(records)
    at = with_chunk(room, path, data, compression="zstd", declared=len(records))
    with McapLog(path, max_chunk_bytes=3 * MB // 2) as log:
        assert sum(1 for _ in log.messages()) > 0
        assert [c[2] for c in log.health.bad_chunks] == [at]
        assert "more than 6144 records" in log.health.oversized[at][1]
    with McapLog(path) as log:
        assert sum(1 for _ in log.messages()) > 0
        assert not log.health.bad_chunks


def _mutations(data: bytes, rng: random.Random, n: int) -> list[bytes]:
    out = []
    for _ in range(n):
        d = bytearray(data)
        kind = rng.randrange(3)
        if kind == 0:
            d[rng.randrange(len(d))] ^= 1 << rng.randrange(8)
        elif kind == 1:
            d = d[: rng.randrange(len(d))]
        else:
            p = rng.randrange(max(1, len(d) - 4))
            d[p : p + 4] = rng.randbytes(4)
        out.append(bytes(d))
    return out


def _first_messages(path: Path) -> list[tuple[ChannelInfo, bytes]]:
    seen: set[str] = set()
    out = []
    with path.open("rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.topic in seen or schema is None:
                continue
            seen.add(channel.topic)
            info = ChannelInfo.from_records(channel, schema)
            out.append((info, message.data))
    return out


@pytest.fixture(scope="module")
def flavours(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("flavours")
    out = {}
    for flavor in ("ros2", "foxglove"):
        out[flavor] = folder / f"{flavor}.mcap"
        with open_source(default_sample()) as source:
            write_source_mcap(source, out[flavor], flavor=flavor, max_frames=3)
    return out


def _protobuf_image() -> tuple[ChannelInfo, bytes]:
    pytest.importorskip("foxglove_schemas_protobuf")
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    msg = RawImage(frame_id="cam", width=5, height=4, encoding="rgb8", step=15)
    msg.data = bytes(range(60))
    fds = FileDescriptorSet()
    msg.DESCRIPTOR.file.CopyToProto(fds.file.add())
    for dep in msg.DESCRIPTOR.file.dependencies:
        dep.CopyToProto(fds.file.add())
    name = msg.DESCRIPTOR.full_name
    channel = ChannelInfo(3, "/fox", "protobuf", name, "protobuf", fds.SerializeToString())
    return channel, msg.SerializeToString()


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
def test_damaged_payloads_raise_only_slamcli_errors(flavours: dict[str, Path]) -> None:
    cases = _first_messages(flavours["ros2"]) + _first_messages(flavours["foxglove"])
    cases.append(_protobuf_image())
    encodings = {channel.message_encoding for channel, _ in cases}
    assert encodings == {"cdr", "json", "protobuf"}
    rng = random.Random(15)
    for channel, data in cases:
        decode = decoder_for(channel)
        adapt = adapter_for(channel.schema_name)
        assert adapt is not None
        for bad in _mutations(data, rng, 150):
            try:
                adapt(decode(bad), 0, channel.topic)
            except SlamcliError as exc:
                assert "\n" not in exc.msg
                assert "unpack_from" not in exc.msg


def _flip_image(src: Path, dst: Path, damage: Callable[[bytes], bytes]) -> None:
    """Copy a log with the payload of its second colour image damaged."""
    with src.open("rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None
        with dst.open("wb") as out:
            writer = Writer(out)
            writer.start(profile="", library="slamcli-tests")
            schemas = {
                sid: writer.register_schema(s.name, s.encoding, s.data)
                for sid, s in summary.schemas.items()
            }
            channels = {
                cid: writer.register_channel(ch.topic, ch.message_encoding, schemas[ch.schema_id])
                for cid, ch in summary.channels.items()
            }
            images = 0
            for _, channel, message in reader.iter_messages():
                data = message.data
                if channel.topic == "/camera/color/image_raw":
                    images += 1
                    if images == 2:
                        data = damage(data)
                writer.add_message(channels[channel.id], message.log_time, data, message.log_time)
            writer.finish()
    assert images >= 2


@pytest.mark.parametrize("flavor", ["ros2", "foxglove"])
@pytest.mark.parametrize("cut", [True, False], ids=["cut", "garbled"])
def test_a_damaged_image_message_is_skipped_or_one_line(
    flavours: dict[str, Path], tmp_path: Path, flavor: str, cut: bool
) -> None:
    def damage(data: bytes) -> bytes:
        if cut:
            return data[: len(data) // 3]
        garbled = bytearray(data)
        garbled[8:40] = np.random.default_rng(1).integers(0, 256, 32, dtype=np.uint8).tobytes()
        return bytes(garbled)

    bad = tmp_path / "bad.mcap"
    _flip_image(flavours[flavor], bad, damage)
    res = runner.invoke(app, ["run", "odometry", str(bad), "--out", str(tmp_path / "run")])
    assert res.exit_code in (0, 1, 3), res.output
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit)
    assert "Traceback" not in res.output
    errors = [line for line in res.output.splitlines() if line.startswith("error:")]
    assert len(errors) <= 1
    if cut:
        # A cut payload cannot decode: the message is skipped and counted as lost data.
        assert res.exit_code == 3, res.output


def test_the_sample_reads_unchanged_within_the_limit(room: Path) -> None:
    with McapLog(room) as log:
        count = sum(1 for _ in log.messages())
        assert not log.health.data_lost
    with room.open("rb") as fh:
        assert count == sum(1 for _ in make_reader(fh).iter_messages())
