"""Camera intrinsics for RGB-D folders: presets, camera files, and the resolution order.

A camera file sits next to the data as ``camera.yaml``, ``camera.yml`` or ``camera.json``::

    width: 640
    height: 480
    fx: 517.3
    fy: 516.5
    cx: 318.6
    cy: 255.3
    distortion: [0.262, -0.953, -0.005, 0.003, 1.163]   # optional: k1 k2 p1 p2 [k3 ...], [] = none
    depth_factor: 5000                                   # optional: raw depth units per metre

Open3D's ``PinholeCameraIntrinsic`` JSON (``width``, ``height`` and a column-major 3x3
``intrinsic_matrix``) is read as well.

:func:`resolve_camera` picks the camera in this order, first match wins:

1. what the caller gave: ``fx/fy/cx/cy``, a preset name, a camera file path or a camera;
2. a camera file next to the data;
3. a preset detected from the folder name (``rgbd_dataset_freiburg2_desk`` -> ``fr2``);
4. ``ros-default``, with a logged warning.
"""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypedDict

import yaml

from slamcli.atomic import write_text_atomic
from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats.images import size_problem
from slamcli.formats.text import (
    MAX_YAML_BYTES,
    check_yaml_expansion,
    read_limited_text,
    yaml_problem,
)
from slamcli.types import PinholeCamera

log = logging.getLogger(__name__)

DEFAULT_DEPTH_FACTOR = 5000.0
"""Raw depth units per metre in TUM RGB-D depth PNGs."""

CAMERA_FILE_NAMES = ("camera.yaml", "camera.yml", "camera.json")
"""Camera files looked for next to the data, in this order."""

PRESETS: dict[str, PinholeCamera] = {
    # TUM's published calibrations of the colour cameras (fr3 images are already undistorted).
    "fr1": PinholeCamera(
        640,
        480,
        517.306408,
        516.469215,
        318.643040,
        255.313989,
        (0.262383, -0.953104, -0.005358, 0.002628, 1.163314),
    ),
    "fr2": PinholeCamera(
        640,
        480,
        520.908620,
        521.007327,
        325.141442,
        249.701764,
        (0.231222, -0.784899, -0.003257, -0.000105, 0.917205),
    ),
    "fr3": PinholeCamera(640, 480, 535.4, 539.2, 320.1, 247.6, ()),
    # What the OpenNI driver registers depth to; TUM suggests it for every sequence.
    "ros-default": PinholeCamera(640, 480, 525.0, 525.0, 319.5, 239.5, ()),
}
"""Named cameras, all 640x480."""

_FILE_HINT = (
    "a camera file has width, height, fx, fy, cx, cy, optionally distortion [k1, k2, p1, p2, k3] "
    "and depth_factor; or Open3D's width, height, intrinsic_matrix"
)
_DISTORTION_LENGTHS = (4, 5, 8, 12, 14)
_PRESET_IN_NAME = re.compile(r"(?:^|_)(?:freiburg|fr)([123])(?:_|$)")
_YAML11_EXPONENT = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)[eE][+-]?\d+", re.ASCII)


@dataclass(frozen=True)
class CameraFile:
    """What a camera file holds: the camera and, if given, the depth factor (units per metre)."""

    camera: PinholeCamera
    depth_factor: float | None = None


@dataclass(frozen=True)
class ResolvedCamera:
    """The camera a source uses and where it came from.

    Attributes:
        camera: the intrinsics.
        source: human-readable origin, e.g. ``"preset fr1 (detected from folder name ...)"``.
        depth_factor: raw depth units per metre from a camera file, None if it gave none.
        fallback: True when nothing identified the camera and ``ros-default`` was assumed.
    """

    camera: PinholeCamera
    source: str
    depth_factor: float | None = None
    fallback: bool = False


class CameraChoice(TypedDict, total=False):
    """The camera options a folder source takes as keywords, for :func:`resolve_camera`.

    Attributes:
        camera: a :class:`PinholeCamera`, a preset name, or a camera file path.
        fx, fy, cx, cy: explicit intrinsics in pixels; all four or none.
    """

    camera: str | Path | PinholeCamera | None
    fx: float | None
    fy: float | None
    cx: float | None
    cy: float | None


def preset(name: str) -> PinholeCamera:
    """The preset camera called ``name`` (``fr1``, ``fr2``, ``fr3``, ``ros-default``)."""
    key = name.strip().lower()
    if key not in PRESETS:
        raise ConfigError(f"camera: unknown preset {name!r}", hint=f"presets: {', '.join(PRESETS)}")
    return PRESETS[key]


def detect_preset(folder: str | Path) -> str | None:
    """The preset named by a TUM folder name (``rgbd_dataset_freiburg1_xyz`` -> ``"fr1"``)."""
    m = _PRESET_IN_NAME.search(Path(folder).resolve().name.lower())
    return f"fr{m.group(1)}" if m else None


def find_camera_file(folder: str | Path) -> Path | None:
    """The first of :data:`CAMERA_FILE_NAMES` present in ``folder``, or None."""
    for name in CAMERA_FILE_NAMES:
        p = Path(folder) / name
        if p.is_file():
            return p
    return None


def load_camera_file(path: str | Path) -> CameraFile:
    """Read a camera file (our YAML/JSON keys or Open3D's intrinsic JSON).

    Raises:
        InputError: the file does not exist or cannot be read.
        FormatError: it is not YAML/JSON, or a key is missing or has a bad value (names the key);
            it is larger than :data:`~slamcli.formats.text.MAX_YAML_BYTES` or its YAML aliases
            expand past :data:`~slamcli.formats.text.MAX_YAML_VALUES` values.
    """
    p = Path(path)
    try:
        text = read_limited_text(p, MAX_YAML_BYTES, "a camera file", _FILE_HINT)
    except FileNotFoundError:
        raise InputError(f"{p}: camera file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot read camera file ({exc})") from None
    data = _parse_mapping(p, text)
    if "intrinsic_matrix" in data:
        return CameraFile(_open3d_camera(p, data))
    width, height = _size(p, data)
    fx, fy = (_number(p, data, k, positive=True) for k in ("fx", "fy"))
    cx, cy = (_number(p, data, k) for k in ("cx", "cy"))
    distortion = _distortion(p, data.get("distortion"))
    depth_factor = None
    if data.get("depth_factor") is not None:
        depth_factor = _number(p, data, "depth_factor", positive=True)
    return CameraFile(PinholeCamera(width, height, fx, fy, cx, cy, distortion), depth_factor)


def save_camera_file(
    path: str | Path, camera: PinholeCamera, depth_factor: float | None = None
) -> Path:
    """Write ``camera`` as a camera file (JSON for ``.json``, else YAML), atomically."""
    data: dict[str, Any] = camera.to_dict()
    if not camera.distortion:
        del data["distortion"]
    if depth_factor is not None:
        data["depth_factor"] = float(depth_factor)
    p = Path(path)
    if p.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    return write_text_atomic(p, text)


def resolve_camera(
    folder: str | Path,
    camera: str | Path | PinholeCamera | None = None,
    fx: float | None = None,
    fy: float | None = None,
    cx: float | None = None,
    cy: float | None = None,
) -> ResolvedCamera:
    """Choose the camera for the data in ``folder`` (order in the module docstring).

    Args:
        folder: the data folder (searched for a camera file; its name may name a preset).
        camera: a :class:`PinholeCamera`, a preset name, or a camera file path.
        fx, fy, cx, cy: explicit intrinsics in pixels; all four or none. They replace the
            intrinsics of the camera otherwise chosen, keep its image size and drop its
            distortion (explicit numbers describe a plain pinhole).

    Raises:
        ConfigError: some but not all of fx/fy/cx/cy, a non-positive focal length, or a
            ``camera`` string that is neither a preset nor an existing file.
    """
    explicit = {"fx": fx, "fy": fy, "cx": cx, "cy": cy}
    given = {k: v for k, v in explicit.items() if v is not None}
    if given:
        missing = [k for k, v in explicit.items() if v is None]
        if missing:
            raise ConfigError(
                f"camera: {', '.join(given)} given without {', '.join(missing)}",
                hint="give all of fx, fy, cx, cy, or none",
            )
        for k in ("fx", "fy"):
            if not (math.isfinite(given[k]) and given[k] > 0):
                raise ConfigError(
                    f"camera: {k} must be a positive number of pixels, got {given[k]}"
                )
        base = resolve_camera(folder, camera)
        w, h = base.camera.width, base.camera.height
        cam = PinholeCamera(w, h, given["fx"], given["fy"], given["cx"], given["cy"], ())
        return ResolvedCamera(
            cam,
            f"explicit fx/fy/cx/cy (image size from {base.source})",
            base.depth_factor,
        )
    if isinstance(camera, PinholeCamera):
        return ResolvedCamera(camera, "given by the caller")
    if camera is not None:
        text = str(camera)
        if text.strip().lower() in PRESETS:
            return ResolvedCamera(preset(text), f"preset {text.strip().lower()} (given)")
        p = Path(text)
        if p.is_file():
            f = load_camera_file(p)
            return ResolvedCamera(f.camera, f"camera file {p} (given)", f.depth_factor)
        raise ConfigError(
            f"camera: {text!r} is neither a preset nor an existing camera file",
            hint=f"presets: {', '.join(PRESETS)}; or a path to {' / '.join(CAMERA_FILE_NAMES)}",
        )
    found = find_camera_file(folder)
    if found is not None:
        f = load_camera_file(found)
        return ResolvedCamera(
            f.camera, f"camera file {found.name} next to the data", f.depth_factor
        )
    detected = detect_preset(folder)
    if detected is not None:
        name = Path(folder).resolve().name
        return ResolvedCamera(
            PRESETS[detected], f"preset {detected} (detected from folder name {name})"
        )
    log.warning(
        "%s: no camera file (%s) and no fr1/fr2/fr3 in the folder name; assuming ros-default "
        "intrinsics (525, 525, 319.5, 239.5)",
        folder,
        ", ".join(CAMERA_FILE_NAMES),
    )
    return ResolvedCamera(
        PRESETS["ros-default"],
        "preset ros-default (assumed: no camera file, no preset in the folder name)",
        fallback=True,
    )


def _parse_mapping(p: Path, text: str) -> dict[str, Any]:
    if p.suffix.lower() == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise FormatError(
                p, f"not valid JSON ({exc.msg} at column {exc.colno})", exc.lineno, _FILE_HINT
            ) from None
    else:
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            problem, line = yaml_problem(exc, text)
            raise FormatError(p, f"not valid YAML ({problem})", line, _FILE_HINT) from None
        check_yaml_expansion(p, data)
    if not isinstance(data, dict):
        found = "an empty file" if data is None else f"a {type(data).__name__}"
        raise FormatError(p, f"expected a mapping of keys, found {found}", None, _FILE_HINT)
    return data


def _number(p: Path, data: dict[str, Any], key: str, positive: bool = False) -> float:
    if key not in data or data[key] is None:
        raise FormatError(p, f"missing key {key!r}", hint=_FILE_HINT)
    value = data[key]
    if isinstance(value, str) and _YAML11_EXPONENT.fullmatch(value.strip()):
        # YAML 1.1 (PyYAML) reads 5e2 or 1e-05, an exponent without a decimal point, as a
        # string; YAML 1.2, OpenCV and yaml-cpp read it as the number it looks like.
        value = float(value)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise FormatError(p, f"key {key!r}: expected a number, found {value!r}", hint=_FILE_HINT)
    if positive and value <= 0:
        raise FormatError(p, f"key {key!r}: must be > 0, found {value!r}", hint=_FILE_HINT)
    return float(value)


def _size(p: Path, data: dict[str, Any]) -> tuple[int, int]:
    out = []
    for key in ("width", "height"):
        v = _number(p, data, key, positive=True)
        if v != int(v):
            raise FormatError(p, f"key {key!r}: expected a whole number of pixels, found {v!r}")
        out.append(int(v))
    # A camera larger than any image slamcli decodes would only size gigabyte-sized buffers.
    problem = size_problem(out[0], out[1])
    if problem:
        raise FormatError(p, f"keys 'width', 'height': the camera {problem}", hint=_FILE_HINT)
    return out[0], out[1]


def _distortion(p: Path, value: Any) -> tuple[float, ...]:
    # An empty list is how PinholeCamera.to_dict() writes an undistorted camera.
    if value is None or value == []:
        return ()
    if not isinstance(value, list) or len(value) not in _DISTORTION_LENGTHS:
        raise FormatError(
            p,
            f"key 'distortion': expected [] or a list of 4, 5, 8, 12 or 14 numbers (OpenCV k1, "
            f"k2, p1, p2[, k3, ...]), found {value!r}",
        )
    out = tuple(
        _number(p, {f"distortion[{i}]": v}, f"distortion[{i}]") for i, v in enumerate(value)
    )
    # All-zero coefficients mean an undistorted camera; normalising keeps is_distorted honest.
    return out if any(c != 0.0 for c in out) else ()


def _open3d_camera(p: Path, data: dict[str, Any]) -> PinholeCamera:
    width, height = _size(p, data)
    m = data["intrinsic_matrix"]
    if not isinstance(m, list) or len(m) != 9:
        raise FormatError(
            p, f"key 'intrinsic_matrix': expected 9 numbers, found {m!r}", hint=_FILE_HINT
        )
    k = [
        _number(p, {f"intrinsic_matrix[{i}]": v}, f"intrinsic_matrix[{i}]") for i, v in enumerate(m)
    ]
    # Column-major: fx 0 0 | 0 fy 0 | cx cy 1. A row-major matrix has cx where a zero belongs.
    if k[8] != 1.0 or any(k[i] != 0.0 for i in (1, 2, 5)):
        raise FormatError(
            p,
            f"key 'intrinsic_matrix': not a column-major pinhole matrix: {m}",
            hint="Open3D stores it column-major: [fx, 0, 0, 0, fy, 0, cx, cy, 1]",
        )
    if k[3] != 0.0:
        raise FormatError(p, f"key 'intrinsic_matrix': skew {k[3]} is not supported")
    if k[0] <= 0 or k[4] <= 0:
        raise FormatError(
            p, f"key 'intrinsic_matrix': focal lengths must be > 0, found {k[0]}, {k[4]}"
        )
    return PinholeCamera(width, height, k[0], k[4], k[6], k[7], ())
