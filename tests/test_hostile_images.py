"""Images that declare an enormous size are refused from their header, before decoding.

A PNG of a few bytes can declare 40000x40000 pixels; OpenCV 5 raises on it, OpenCV 4 returns
None, and a decoder without a limit would allocate gigabytes. Each test runs the CLI as a
subprocess and measures its wall time and peak memory.
"""

from __future__ import annotations

import os
import re
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from measured import run_measured

from slamcli.errors import FormatError
from slamcli.formats.images import MAX_IMAGE_PIXELS, decode_image, image_size
from slamcli.formats.occupancy import read_map_yaml

ROOM = Path(__file__).resolve().parents[1] / "sample_data" / "rgbd_room"
HUGE = 40000
MAX_SECONDS = 10.0
MAX_RSS_MB = 500.0


def _lying_png(data: bytes, width: int, height: int) -> bytes:
    """``data`` (a PNG) with its IHDR width and height replaced and the chunk CRC fixed."""
    ihdr = bytearray(data[12:29])  # type + 13 bytes of fields
    ihdr[4:12] = struct.pack(">II", width, height)
    crc = struct.pack(">I", zlib.crc32(bytes(ihdr)) & 0xFFFFFFFF)
    return data[:12] + bytes(ihdr) + crc + data[33:]


def _png(image: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", image)
    assert ok
    return buf.tobytes()


def _run(args: list[str], cwd: Path) -> tuple[int, str, float, float]:
    """(exit code, stdout and stderr, CPU seconds, peak RSS in MB) of ``slamcli ARGS``.

    The time is the child's user + system CPU time, so a loaded CI machine does not count;
    the RSS is the command's own (see ``measured.py``).
    """
    env = {**os.environ, "COLUMNS": "200", "NO_COLOR": "1"}
    return run_measured([sys.executable, "-m", "slamcli", *args], cwd=cwd, env=env)


def _room_with(tmp_path: Path, replace: dict[str, bytes]) -> Path:
    """A copy of the sample room: symlinks, except for the files in ``replace``."""
    folder = tmp_path / "room"
    for src in ROOM.rglob("*"):
        rel = src.relative_to(ROOM)
        dst = folder / rel
        if src.is_dir():
            dst.mkdir(parents=True, exist_ok=True)
            continue
        dst.parent.mkdir(parents=True, exist_ok=True)
        if str(rel) in replace:
            dst.write_bytes(replace[str(rel)])
        else:
            dst.symlink_to(src)
    return folder


def _fifth_depth(list_name: str = "depth.txt") -> str:
    lines = [ln for ln in (ROOM / list_name).read_text().splitlines() if ln[:1].isdigit()]
    return lines[4].split()[1]


def test_header_sizes_are_read_without_decoding() -> None:
    import cv2

    grey = np.zeros((7, 11), np.uint8)
    assert image_size(_png(grey)) == (11, 7)
    for ext in (".jpg", ".bmp", ".pgm", ".webp"):
        ok, buf = cv2.imencode(ext, np.zeros((7, 11, 3) if ext != ".pgm" else (7, 11), np.uint8))
        assert ok
        assert image_size(buf.tobytes()) == (11, 7), ext
    assert image_size(b"P5\n# comment\n40000 40000\n255\n") == (HUGE, HUGE)
    assert image_size(b"not an image") is None


def test_a_lying_png_is_refused_before_decoding() -> None:
    lying = _lying_png(_png(np.zeros((4, 4), np.uint16)), HUGE, HUGE)
    img, reason = decode_image(lying)
    assert img is None
    assert f"{HUGE}x{HUGE}" in reason and f"{MAX_IMAGE_PIXELS / 1e6:g} megapixels" in reason
    img, reason = decode_image(_png(np.zeros((4, 4), np.uint16)), expect=(5, 4))
    assert img is None and "the camera is 5x4" in reason
    assert decode_image(b"")[1] == "is empty"


@pytest.mark.parametrize(
    "args",
    [
        ["run", "odometry", "{room}", "--out", "{out}", "--max-frames", "8"],
        ["info", "{room}", "--deep"],
    ],
    ids=["run-odometry", "info-deep"],
)
def test_tum_folder_with_a_40000x40000_depth_png(tmp_path: Path, args: list[str]) -> None:
    depth = _fifth_depth()
    lying = _lying_png((ROOM / depth).read_bytes(), HUGE, HUGE)
    room = _room_with(tmp_path, {depth: lying})
    argv = [a.format(room=room, out=tmp_path / "out") for a in args]
    code, err, seconds, rss_mb = _run(argv, tmp_path)
    assert code == 3, err
    assert "Traceback" not in err
    assert Path(depth).name in err and f"{HUGE}x{HUGE}" in err
    assert seconds < MAX_SECONDS and rss_mb < MAX_RSS_MB, (seconds, rss_mb)
    strict = [a.format(room=room, out=tmp_path / "strict") for a in args] + ["--strict"]
    code, err, _, _ = _run(strict, tmp_path)
    assert code == 1 and "Traceback" not in err and Path(depth).name in err


@pytest.mark.parametrize(
    ("list_name", "image"),
    [("depth.txt", np.zeros((10, 10), np.uint16)), ("rgb.txt", np.zeros((10, 10, 3), np.uint8))],
)
def test_a_frame_of_another_size_than_the_camera_is_skipped(
    tmp_path: Path, list_name: str, image: np.ndarray
) -> None:
    name = _fifth_depth(list_name)
    room = _room_with(tmp_path, {name: _png(image)})
    code, err, _, _ = _run(
        ["run", "odometry", str(room), "--out", str(tmp_path / "out"), "--max-frames", "8"],
        tmp_path,
    )
    assert code == 3 and "Traceback" not in err
    assert f"{name}: is 10x10, the camera is 320x240" in err


def _mcap_with_lying_depth(tmp_path: Path) -> Path:
    """The room as a ROS 2 MCAP whose 5th depth Image claims 40000x40000 pixels."""
    from mcap.reader import make_reader
    from mcap.writer import CompressionType, Writer
    from rosbags.typesys import Stores, get_typestore

    from slamcli.formats.mcap.write import write_source_mcap
    from slamcli.formats.tum_rgbd import TumRgbdSource

    honest = tmp_path / "honest.mcap"
    with TumRgbdSource.open(ROOM) as src:
        write_source_mcap(src, honest, max_frames=8)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    out = tmp_path / "lying.mcap"
    seen = 0
    with honest.open("rb") as fin, out.open("wb") as fout:
        reader = make_reader(fin)
        writer = Writer(fout, compression=CompressionType.NONE)
        writer.start()
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages():
            assert schema is not None
            if schema.id not in schemas:
                schemas[schema.id] = writer.register_schema(
                    schema.name, schema.encoding, schema.data
                )
            if channel.id not in channels:
                channels[channel.id] = writer.register_channel(
                    channel.topic, channel.message_encoding, schemas[schema.id]
                )
            data = bytes(message.data)
            if channel.topic == "/camera/depth/image_raw":
                seen += 1
                if seen == 5:
                    msg: Any = ts.deserialize_cdr(data, "sensor_msgs/msg/Image")
                    msg.width = msg.height = HUGE
                    data = bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/Image"))
            writer.add_message(channels[channel.id], message.log_time, data, message.publish_time)
        writer.finish()
    assert seen >= 5
    return out


def test_mcap_raw_depth_image_that_lies_about_its_size(tmp_path: Path) -> None:
    log = _mcap_with_lying_depth(tmp_path)
    argv = ["run", "odometry", str(log), "--out", str(tmp_path / "out")]
    code, err, seconds, rss_mb = _run(argv, tmp_path)
    assert code == 3, err
    assert "Traceback" not in err and f"{HUGE}x{HUGE}" in err
    assert seconds < MAX_SECONDS and rss_mb < MAX_RSS_MB, (seconds, rss_mb)
    code, err, _, _ = _run(["info", str(log), "--deep"], tmp_path)
    assert code == 3 and "Traceback" not in err and f"{HUGE}x{HUGE}" in err
    strict = [*argv[:-1], str(tmp_path / "strict"), "--strict"]
    code, err, _, _ = _run(strict, tmp_path)
    assert code == 1 and "Traceback" not in err and f"{HUGE}x{HUGE}" in err


def _map_with_image(tmp_path: Path, image: bytes, name: str) -> Path:
    (tmp_path / name).write_bytes(image)
    yaml_path = tmp_path / "map.yaml"
    yaml_path.write_text(
        f"image: {name}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    return yaml_path


@pytest.mark.parametrize(
    ("name", "image"),
    [
        ("map.pgm", b"P5\n40000 40000\n255\n" + bytes(100)),
        ("map.png", _lying_png(_png(np.zeros((4, 4), np.uint8)), HUGE, HUGE)),
    ],
)
def test_a_map_image_with_a_huge_header_is_one_line_error(
    tmp_path: Path, name: str, image: bytes
) -> None:
    yaml_path = _map_with_image(tmp_path, image, name)
    with pytest.raises(FormatError, match=rf"{name}: map image declares {HUGE}x{HUGE} pixels"):
        read_map_yaml(yaml_path)
    code, err, seconds, rss_mb = _run(["map", "show", str(yaml_path)], tmp_path)
    assert code == 1 and "Traceback" not in err and name in err
    assert seconds < MAX_SECONDS and rss_mb < MAX_RSS_MB, (seconds, rss_mb)


def test_a_list_naming_a_device_is_an_unreadable_frame_not_an_endless_read(
    tmp_path: Path,
) -> None:
    text = (ROOM / "rgb.txt").read_text()
    fifth = [ln for ln in text.splitlines() if ln[:1].isdigit()][4]
    room = _room_with(
        tmp_path, {"rgb.txt": text.replace(fifth, fifth.split()[0] + " /dev/zero").encode()}
    )
    argv = ["run", "odometry", str(room), "--out", str(tmp_path / "out"), "--max-frames", "8"]
    code, out, seconds, rss_mb = _run(argv, tmp_path)
    assert code == 3 and "Traceback" not in out
    assert "skipping /dev/zero: is not a regular file" in out
    assert seconds < MAX_SECONDS and rss_mb < MAX_RSS_MB, (seconds, rss_mb)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            b"width: 320\nheight: 240\n\x01fx: 3\n",
            r"camera\.yaml:3: not valid YAML \(character #x0001",
        ),
        (b"", "expected a mapping of keys, found an empty file"),
        (b"- 1\n", "expected a mapping of keys, found a list"),
        (b"width: 400000\nheight: 400000\nfx: 1\nfy: 1\ncx: 1\ncy: 1\n", "megapixels"),
    ],
)
def test_a_hostile_camera_file_is_a_one_line_error(
    tmp_path: Path, text: bytes, message: str
) -> None:
    from slamcli.formats.camera import load_camera_file

    (tmp_path / "camera.yaml").write_bytes(text)
    with pytest.raises(FormatError, match=message) as info:
        load_camera_file(tmp_path / "camera.yaml")
    assert "\n" not in str(info.value)


def test_a_camera_json_error_names_line_and_column(tmp_path: Path) -> None:
    from slamcli.formats.camera import load_camera_file

    (tmp_path / "camera.json").write_text('{\n  "width": 320,,\n}')
    with pytest.raises(FormatError, match=r"camera\.json:2: not valid JSON \(.* at column 16\)"):
        load_camera_file(tmp_path / "camera.json")


@pytest.mark.parametrize("stamp", ["99999999999999999999", "1e300", "١٢٣.5", "1" * 400])
def test_out_of_range_or_foreign_timestamps_are_format_errors(tmp_path: Path, stamp: str) -> None:
    from slamcli.formats.trajectory import read_trajectory

    path = tmp_path / "t.txt"
    path.write_text(f"1.0 0 0 0 0 0 0 1\n{stamp} 0 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"t\.txt:2: timestamp"):
        read_trajectory(path)


@pytest.mark.parametrize("vertex", ["99999999999999999999999", "²"])
def test_g2o_ids_beyond_int64_or_not_ascii_digits(tmp_path: Path, vertex: str) -> None:
    from slamcli.formats.g2o import read_g2o

    path = tmp_path / "g.g2o"
    path.write_text(f"VERTEX_SE2 0 0 0 0\nVERTEX_SE2 {vertex} 1 0 0\n")
    with pytest.raises(FormatError, match=r"g\.g2o:2: column 2: vertex id"):
        read_g2o(path)


def test_a_map_yaml_with_a_control_character_names_its_line(tmp_path: Path) -> None:
    yaml_path = _map_with_image(tmp_path, _png(np.zeros((4, 4), np.uint8)), "map.png")
    yaml_path.write_bytes(yaml_path.read_bytes() + b"\x07: 1\n")
    with pytest.raises(FormatError, match=r"map\.yaml:7: is not valid YAML \(character #x0007"):
        read_map_yaml(yaml_path)


def test_mcap_image_payloads_that_lie_are_decode_errors() -> None:
    from slamcli.formats.mcap.adapters import decode_compressed_image, decode_raw_image
    from slamcli.formats.mcap.decode import DecodeError

    lying = _lying_png(_png(np.zeros((4, 4), np.uint16)), HUGE, HUGE)
    for fmt in ("png", "16UC1; compressedDepth png"):
        with pytest.raises(DecodeError, match=f"declares {HUGE}x{HUGE} pixels"):
            decode_compressed_image("/cam", fmt, lying)
    with pytest.raises(DecodeError, match=f"declares {HUGE}x{HUGE} pixels"):
        decode_raw_image("/cam", "16UC1", HUGE, HUGE, 0, bytes(32))
    with pytest.raises(DecodeError, match="needs 80 bytes, the message has 32"):
        decode_raw_image("/cam", "16UC1", 5, 8, 0, bytes(32))


def test_landmark_values_beyond_the_table_limit_are_format_errors(tmp_path: Path) -> None:
    from slamcli.formats.landmarks import MAX_TABLE_VALUE, read_table

    path = tmp_path / "odometry.csv"
    path.write_text("t,v,omega\n1.0,0.5,0.1\n1.1,1e308,0.1\n")
    limit = re.escape(f"{MAX_TABLE_VALUE:g}")
    with pytest.raises(FormatError, match=rf"odometry\.csv:3: column 2 \(v\): .*at most {limit}"):
        read_table(path, ("t", "v", "omega"), delimiter=",")


def test_trajectory_positions_beyond_the_limit_are_format_errors(tmp_path: Path) -> None:
    from slamcli.formats.trajectory import read_trajectory

    path = tmp_path / "t.txt"
    path.write_text("1.0 0 0 0 0 0 0 1\n2.0 1e308 0 0 0 0 0 1\n")
    with pytest.raises(FormatError, match=r"t\.txt:2: column 2: value '1e308' is out of range"):
        read_trajectory(path)


def test_an_npz_map_declaring_a_huge_array_is_refused_unread(tmp_path: Path) -> None:
    import io
    import zipfile

    from slamcli.formats.occupancy import NPZ_FORMAT, NPZ_FORMAT_VERSION, read_map_npz

    path = tmp_path / "map.npz"
    with zipfile.ZipFile(path, "w") as zf:
        for name, value in (
            ("format", np.array(NPZ_FORMAT)),
            ("format_version", np.array(NPZ_FORMAT_VERSION)),
            ("resolution_m", np.array(0.05)),
            ("origin_xy_yaw", np.zeros(3)),
        ):
            buf = io.BytesIO()
            np.save(buf, value)
            zf.writestr(f"{name}.npy", buf.getvalue())
        buf = io.BytesIO()
        header = {"descr": "<f4", "fortran_order": False, "shape": (HUGE, HUGE)}
        np.lib.format.write_array_header_1_0(buf, header)
        zf.writestr("prob.npy", buf.getvalue() + bytes(64))
    with pytest.raises(FormatError, match=r"array 'prob' declares shape \(40000, 40000\)"):
        read_map_npz(path)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("resolution: 1e-300", "'resolution' must be 1e-06 to"),
        ("resolution: 1e308", "'resolution' must be 1e-06 to"),
        ("origin: [1e308, 0.0, 0.0]", "'origin' values must be at most 1e"),
    ],
)
def test_map_yaml_values_out_of_range(tmp_path: Path, line: str, message: str) -> None:
    yaml_path = _map_with_image(tmp_path, _png(np.zeros((4, 4), np.uint8)), "map.png")
    key = line.split(":")[0]
    text = "\n".join(
        line if ln.startswith(key + ":") else ln for ln in yaml_path.read_text().splitlines()
    )
    yaml_path.write_text(text + "\n")
    with pytest.raises(FormatError, match=re.escape(message)):
        read_map_yaml(yaml_path)


def test_a_camera_number_with_a_bare_exponent_is_read_as_a_number(tmp_path: Path) -> None:
    from slamcli.formats.camera import load_camera_file

    (tmp_path / "camera.yaml").write_text(
        "width: 320\nheight: 240\nfx: 256e0\nfy: 2.56e2\ncx: 1595e-1\ncy: 119.5\n"
    )
    cam = load_camera_file(tmp_path / "camera.yaml").camera
    assert (cam.fx, cam.fy, cam.cx) == (256.0, 256.0, 159.5)


def _png_with_a_lying_chunk(data: bytes) -> bytes:
    """``data`` (a PNG) with its first IDAT chunk declaring 4 GB."""
    at = data.index(b"IDAT") - 4
    return data[:at] + struct.pack(">I", 0xF8000000) + data[at + 4 :]


def test_a_png_chunk_longer_than_the_file_is_refused_before_decoding(tmp_path: Path) -> None:
    img, reason = decode_image(_png_with_a_lying_chunk(_png(np.zeros((4, 4), np.uint16))))
    assert img is None and reason == "cannot be decoded as an image"
    depth = _fifth_depth()
    room = _room_with(tmp_path, {depth: _png_with_a_lying_chunk((ROOM / depth).read_bytes())})
    code, out, seconds, rss_mb = _run(["info", str(room), "--deep"], tmp_path)
    assert code == 3 and "Traceback" not in out and Path(depth).name in out
    assert seconds < MAX_SECONDS and rss_mb < MAX_RSS_MB, (seconds, rss_mb)


def test_formats_without_a_checked_header_are_refused() -> None:
    import cv2

    ok, tiff = cv2.imencode(".tiff", np.zeros((4, 4), np.uint8))
    assert ok
    img, reason = decode_image(tiff.tobytes())
    assert img is None and "not PNG, JPEG, PNM, BMP or WebP" in reason


def test_an_npz_map_with_a_damaged_zip_field_is_a_format_error(tmp_path: Path) -> None:
    from slamcli.formats.occupancy import read_map_npz, write_map_npz
    from slamcli.types import OccupancyGrid

    path = tmp_path / "map.npz"
    write_map_npz(path, OccupancyGrid(np.zeros((4, 5), np.float32), 0.05, (0.0, 0.0, 0.0)))
    data = bytearray(path.read_bytes())
    entry = data.index(b"PK\x01\x02")
    data[entry + 6 : entry + 8] = struct.pack("<H", 99)  # "version needed to extract": 9.9
    path.write_bytes(bytes(data))
    with pytest.raises(FormatError, match=r"map\.npz: is not a readable \.npz archive"):
        read_map_npz(path)
