"""Decoding images from files and message payloads with a size limit checked first.

An image file states its size in a header of a few bytes, and a decoder allocates that many
pixels before it reads any pixel data: a 3 MB PNG can declare 40000x40000 pixels (3.2 GB as
16-bit depth). :func:`decode_image` reads the size from the header (PNG, JPEG, PNM, BMP, WebP)
and refuses an image larger than :data:`MAX_IMAGE_PIXELS`, or of another size than the caller
expects, or a PNG whose chunks do not fit in the file, before OpenCV allocates anything; other
formats are refused, since their sizes are not checked. OpenCV's own refusals differ by version
(4.x returns None, 5.x raises ``cv2.error``); both come back here as a reason, never as an
exception.
"""

from __future__ import annotations

import os
import stat
import struct
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

MAX_IMAGE_PIXELS = 50_000_000
"""Largest image (width x height) slamcli decodes: 50 megapixels, far above any camera frame
or occupancy map it works with, and small enough that decoding stays well under a gigabyte."""

MAX_IMAGE_FILE_BYTES = 512 * 1024 * 1024
"""Largest image file read: an uncompressed 16-bit RGB image at the pixel limit fits."""

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic); C4, C8 and CC are not.
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}


def image_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) from an image header, or None when the format is not one parsed here.

    Raises:
        ValueError: the header is one of the known formats but is cut short or malformed.
    """
    head = data[:32]
    if head.startswith(_PNG_MAGIC):
        if len(head) < 24 or head[12:16] != b"IHDR":
            raise ValueError("PNG header is truncated or has no IHDR chunk first")
        _check_png_chunks(data)
        width, height = struct.unpack(">II", head[16:24])
        return int(width), int(height)
    if head.startswith(b"\xff\xd8"):
        return _jpeg_size(data)
    if len(head) >= 2 and head[:1] == b"P" and head[1:2] in b"123456":
        return _pnm_size(data[:4096])
    if head.startswith(b"BM"):
        if len(head) < 26:
            raise ValueError("BMP header is truncated")
        width, height = struct.unpack("<ii", head[18:26])
        return abs(width), abs(height)
    if head.startswith(b"RIFF") and head[8:12] == b"WEBP":
        return _webp_size(head)
    return None


def _check_png_chunks(data: bytes) -> None:
    """Every chunk must fit in the data: OpenCV allocates a chunk's declared length before it
    reads it, so one flipped length byte in a 40 kB file asked for 4 GB."""
    pos = len(_PNG_MAGIC)
    while pos + 8 <= len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        kind = data[pos + 4 : pos + 8]
        if pos + 12 + length > len(data):
            raise ValueError(
                f"PNG chunk {kind.decode('latin-1')!r} at byte {pos} declares {length} bytes, "
                f"{len(data) - pos - 12} remain"
            )
        if kind == b"IEND":
            return
        pos += 12 + length
    raise ValueError("PNG data is truncated before its IEND chunk")


def _jpeg_size(data: bytes) -> tuple[int, int]:
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            # libjpeg skips stray bytes between segments, so the search for a marker does too.
            i += 1
            continue
        marker = data[i + 1]
        if marker == 0xFF:
            i += 1
            continue
        if marker in (0x01, 0xD8) or 0xD0 <= marker <= 0xD7:
            i += 2
            continue
        (length,) = struct.unpack(">H", data[i + 2 : i + 4])
        if marker in _JPEG_SOF:
            if i + 9 > len(data):
                break
            height, width = struct.unpack(">HH", data[i + 5 : i + 9])
            return int(width), int(height)
        if marker == 0xDA or length < 2:
            break
        i += 2 + length
    raise ValueError("JPEG has no frame header (SOF) before its image data")


def _pnm_size(head: bytes) -> tuple[int, int]:
    fields: list[int] = []
    i = 2
    while len(fields) < 2:
        if i >= len(head):
            raise ValueError("PNM header is truncated")
        ch = head[i : i + 1]
        if ch == b"#":
            end = head.find(b"\n", i)
            if end < 0:
                raise ValueError("PNM header is truncated")
            i = end + 1
        elif ch.isspace():
            i += 1
        else:
            j = i
            while j < len(head) and head[j : j + 1].isdigit():
                j += 1
            if j == i or j - i > 12:
                raise ValueError(f"PNM header has a bad number at byte {i}")
            fields.append(int(head[i:j]))
            i = j
    return fields[0], fields[1]


def _webp_size(head: bytes) -> tuple[int, int]:
    chunk = head[12:16]
    if chunk == b"VP8X" and len(head) >= 30:
        return 1 + int.from_bytes(head[24:27], "little"), 1 + int.from_bytes(head[27:30], "little")
    if chunk == b"VP8L" and len(head) >= 25:
        bits = int.from_bytes(head[21:25], "little")
        return 1 + (bits & 0x3FFF), 1 + ((bits >> 14) & 0x3FFF)
    if chunk == b"VP8 " and len(head) >= 30:
        width, height = struct.unpack("<HH", head[26:30])
        return width & 0x3FFF, height & 0x3FFF
    raise ValueError("WebP header is truncated or of an unknown kind")


def read_image_file(path: Path) -> tuple[bytes | None, str]:
    """An image file's bytes: ``(data, "")``, or ``(None, reason)``.

    Only regular files are read, and only up to :data:`MAX_IMAGE_FILE_BYTES`: a list file may
    name a device such as ``/dev/zero``, which would otherwise be read forever.
    """
    try:
        with path.open("rb") as fh:
            st = os.fstat(fh.fileno())
            if not stat.S_ISREG(st.st_mode):
                return None, "is not a regular file"
            if st.st_size > MAX_IMAGE_FILE_BYTES:
                return None, (
                    f"is {st.st_size / 2**20:.0f} MiB, more than the limit of "
                    f"{MAX_IMAGE_FILE_BYTES / 2**20:.0f} MiB for an image file"
                )
            return fh.read(), ""
    except FileNotFoundError:
        return None, "does not exist"
    except IsADirectoryError:
        return None, "is a folder"
    except OSError as exc:
        return None, f"cannot be read ({exc.strerror})"
    except ValueError:
        # A damaged list can name a path holding a NUL byte, which no file system accepts.
        return None, "has a name with a NUL byte"


def size_problem(
    width: int, height: int, expect: tuple[int, int] | None = None, limit: int = MAX_IMAGE_PIXELS
) -> str:
    """Why an image of this size is refused ("" if it is fine); ``expect`` is (width, height)."""
    if width <= 0 or height <= 0:
        return f"declares {width}x{height} pixels"
    if width * height > limit:
        return (
            f"declares {width}x{height} pixels, more than the limit of {limit / 1e6:g} megapixels"
        )
    if expect is not None and (width, height) != tuple(expect):
        return f"is {width}x{height}, the camera is {expect[0]}x{expect[1]}"
    return ""


def decode_image(
    data: bytes | NDArray[np.uint8],
    flags: int | None = None,
    *,
    expect: tuple[int, int] | None = None,
    limit: int = MAX_IMAGE_PIXELS,
) -> tuple[NDArray[Any] | None, str]:
    """Decode an encoded image: ``(image, "")``, or ``(None, reason)`` if it is refused.

    Args:
        data: the encoded bytes: PNG, JPEG, PNM, BMP or WebP; other formats are refused.
        flags: ``cv2.IMREAD_*`` flags; default ``IMREAD_UNCHANGED``.
        expect: (width, height) the image must have, checked from the header before decoding.
        limit: largest width x height decoded.
    """
    from slamcli.backends import import_cv2

    cv2 = import_cv2()
    buf = np.frombuffer(data, dtype=np.uint8)
    if buf.size == 0:
        return None, "is empty"
    try:
        size = image_size(data if isinstance(data, bytes) else buf.tobytes())
    except ValueError:
        # A decoder refuses these headers too; the reason is worded as for any undecodable image.
        return None, "cannot be decoded as an image"
    if size is None:
        # Only formats whose header is checked here reach a decoder.
        return None, "cannot be decoded as an image (not PNG, JPEG, PNM, BMP or WebP)"
    problem = size_problem(size[0], size[1], expect, limit)
    if problem:
        return None, problem
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED if flags is None else flags)
    except cv2.error as exc:
        detail = str(exc).strip().splitlines()[-1] if str(exc).strip() else "OpenCV error"
        return None, f"cannot be decoded as an image ({detail})"
    if img is None or img.size == 0:
        return None, "cannot be decoded as an image"
    h, w = img.shape[:2]
    problem = size_problem(w, h, expect, limit)
    if problem:
        return None, problem
    return img, ""


DEPTH_STEPS_PER_M = 5000.0
"""Depth packed by :func:`pack_rgbd` is kept in steps of 1/5000 m (TUM's depth unit)."""


def pack_rgbd(rgb: NDArray[np.uint8], depth_m: NDArray[np.float32]) -> tuple[bytes, bytes] | None:
    """An RGB-D frame kept small in memory: the depth (H, W) metres as a lossless 16-bit PNG
    in steps of 1/5000 m, the colour (H, W, 3) RGB as a JPEG of quality 95; about 0.3 MB at
    640x480. None when OpenCV cannot encode the images. :func:`unpack_rgbd` reverses it."""
    import cv2

    steps = np.rint(depth_m * DEPTH_STEPS_PER_M).astype(np.uint16)
    ok_d, depth_png = cv2.imencode(".png", steps)
    bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
    ok_c, colour_jpg = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not (ok_d and ok_c):
        return None
    return depth_png.tobytes(), colour_jpg.tobytes()


def unpack_rgbd(packed: tuple[bytes, bytes]) -> tuple[NDArray[np.uint8], NDArray[np.float32]]:
    """The colour (H, W, 3) uint8 RGB and depth (H, W) float32 metres of a
    :func:`pack_rgbd` frame."""
    import cv2

    depth_png, colour_jpg = packed
    steps = np.asarray(cv2.imdecode(np.frombuffer(depth_png, np.uint8), cv2.IMREAD_UNCHANGED))
    depth = steps.astype(np.float32) / np.float32(DEPTH_STEPS_PER_M)
    bgr = np.asarray(cv2.imdecode(np.frombuffer(colour_jpg, np.uint8), cv2.IMREAD_COLOR))
    rgb = np.ascontiguousarray(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), dtype=np.uint8)
    return rgb, depth
