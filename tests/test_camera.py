"""Camera presets, camera files (ours and Open3D's) and the camera resolution order."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import pytest
from conftest import shared_path

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats.camera import (
    PRESETS,
    detect_preset,
    load_camera_file,
    preset,
    resolve_camera,
    save_camera_file,
)
from slamcli.types import PinholeCamera

CAMERA_YAML = """\
width: 64
height: 48
fx: 50.5
fy: 51.0
cx: 31.5
cy: 23.5
distortion: [0.1, -0.2, 0.001, 0.002, 0.05]
depth_factor: 1000
"""


def test_presets_match_the_published_values() -> None:
    fr1 = preset("fr1")
    assert (fr1.width, fr1.height) == (640, 480)
    assert (fr1.fx, fr1.fy, fr1.cx, fr1.cy) == (517.306408, 516.469215, 318.643040, 255.313989)
    assert fr1.distortion == (0.262383, -0.953104, -0.005358, 0.002628, 1.163314)
    assert preset("FR2").distortion[4] == 0.917205
    assert not preset("fr3").is_distorted
    ros = preset("ros-default")
    assert (ros.fx, ros.fy, ros.cx, ros.cy, ros.distortion) == (525.0, 525.0, 319.5, 239.5, ())
    assert set(PRESETS) == {"fr1", "fr2", "fr3", "ros-default"}


def test_unknown_preset_lists_the_known_ones() -> None:
    with pytest.raises(ConfigError, match="fr4") as exc:
        preset("fr4")
    assert exc.value.hint is not None and "ros-default" in exc.value.hint


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("rgbd_dataset_freiburg1_rpy_excerpt", "fr1"),
        ("rgbd_dataset_freiburg2_desk", "fr2"),
        ("rgbd_dataset_freiburg3_long_office_household", "fr3"),
        ("fr2_pioneer_360", "fr2"),
        ("Freiburg3_Walking", "fr3"),
        ("my_recording", None),
        ("rgbd_dataset_freiburg12_x", None),
        ("frame_1", None),
    ],
)
def test_detect_preset_from_folder_name(tmp_path: Path, name: str, expected: str | None) -> None:
    assert detect_preset(tmp_path / name) == expected


def test_load_our_yaml_format(tmp_path: Path) -> None:
    p = tmp_path / "camera.yaml"
    p.write_text(CAMERA_YAML)
    f = load_camera_file(p)
    assert f.camera == PinholeCamera(
        64, 48, 50.5, 51.0, 31.5, 23.5, (0.1, -0.2, 0.001, 0.002, 0.05)
    )
    assert f.depth_factor == 1000.0


def test_optional_keys_may_be_absent_and_zero_distortion_means_none(tmp_path: Path) -> None:
    p = tmp_path / "camera.yml"
    p.write_text(
        "width: 64\nheight: 48\nfx: 50\nfy: 50\ncx: 32\ncy: 24\ndistortion: [0, 0, 0, 0]\n"
    )
    f = load_camera_file(p)
    assert f.camera.distortion == () and f.depth_factor is None


def test_synthetic_generator_camera_file(tmp_path: Path) -> None:
    p = tmp_path / "camera.yaml"
    p.write_text(
        "# synthetic pinhole camera, no distortion; depth PNG value = metres * depth_factor\n"
        "width: 320\nheight: 240\nfx: 262.5\nfy: 262.5\ncx: 159.5\ncy: 119.5\n"
        "distortion: []\ndepth_factor: 5000\n"
    )
    f = load_camera_file(p)
    assert f.camera == PinholeCamera(320, 240, 262.5, 262.5, 159.5, 119.5, ())
    assert f.depth_factor == 5000.0


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_save_and_load_round_trip(tmp_path: Path, suffix: str) -> None:
    cam = PinholeCamera(640, 480, 517.3, 516.5, 318.6, 255.3, (0.26, -0.95, -0.005, 0.003, 1.16))
    p = save_camera_file(tmp_path / f"camera{suffix}", cam, depth_factor=5000)
    f = load_camera_file(p)
    assert f.camera == cam and f.depth_factor == 5000.0


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("width: 64\nheight: 48\nfy: 50\ncx: 32\ncy: 24\n", "missing key 'fx'"),
        (
            "width: 64\nheight: 48\nfx: fast\nfy: 50\ncx: 32\ncy: 24\n",
            "key 'fx': expected a number",
        ),
        ("width: 64\nheight: 48\nfx: -5\nfy: 50\ncx: 32\ncy: 24\n", "key 'fx': must be > 0"),
        ("width: 64.5\nheight: 48\nfx: 5\nfy: 50\ncx: 32\ncy: 24\n", "key 'width'"),
        (
            "width: 64\nheight: 48\nfx: 5\nfy: 5\ncx: 32\ncy: 24\ndistortion: [1, 2, 3]\n",
            "key 'distortion'",
        ),
        ("width: 64\nheight: 48\nfx: 5\nfy: 5\ncx: 32\ncy: 24\ndepth_factor: 0\n", "depth_factor"),
        ("width: 64\nheight: 48\nfx: true\nfy: 5\ncx: 32\ncy: 24\n", "key 'fx'"),
        ("- 1\n- 2\n", "expected a mapping"),
    ],
)
def test_bad_camera_file_names_the_file_and_key(tmp_path: Path, text: str, match: str) -> None:
    p = tmp_path / "camera.yaml"
    p.write_text(text)
    with pytest.raises(FormatError, match=match) as exc:
        load_camera_file(p)
    assert str(p) in str(exc.value)


def test_yaml_syntax_error_names_the_line(tmp_path: Path) -> None:
    p = tmp_path / "camera.yaml"
    p.write_text("width: 64\nheight: [48\nfx: 5\n")
    with pytest.raises(FormatError, match=r"camera\.yaml:\d+: not valid YAML"):
        load_camera_file(p)


def test_json_syntax_error_names_the_line(tmp_path: Path) -> None:
    p = tmp_path / "camera.json"
    p.write_text('{\n  "width": 64,\n  "height": 48,,\n}')
    with pytest.raises(FormatError, match=r"camera\.json:3: not valid JSON"):
        load_camera_file(p)


def test_missing_camera_file_is_an_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not found"):
        load_camera_file(tmp_path / "nope.yaml")


def test_open3d_intrinsic_json_from_the_shared_data() -> None:
    p = shared_path("rgbd", "open3d_test_data_RGBD", "camera_primesense.json")
    f = load_camera_file(p)
    assert f.camera == PinholeCamera(640, 480, 525.0, 525.0, 319.5, 239.5, ())
    assert f.depth_factor is None


def test_open3d_intrinsic_json_is_column_major(tmp_path: Path) -> None:
    p = tmp_path / "intrinsic.json"
    matrix = [500.0, 0, 0, 0, 510.0, 0, 320.0, 240.0, 1]
    p.write_text(json.dumps({"width": 640, "height": 480, "intrinsic_matrix": matrix}))
    cam = load_camera_file(p).camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == (500.0, 510.0, 320.0, 240.0)


def test_row_major_open3d_matrix_is_rejected_with_a_hint(tmp_path: Path) -> None:
    p = tmp_path / "intrinsic.json"
    matrix = [500.0, 0, 320.0, 0, 510.0, 240.0, 0, 0, 1]
    p.write_text(json.dumps({"width": 640, "height": 480, "intrinsic_matrix": matrix}))
    with pytest.raises(FormatError, match="intrinsic_matrix") as exc:
        load_camera_file(p)
    assert exc.value.hint is not None and "column-major" in exc.value.hint


def test_resolution_order(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    folder = tmp_path / "rgbd_dataset_freiburg2_desk"
    folder.mkdir()
    detected = resolve_camera(folder)
    assert detected.camera == PRESETS["fr2"]
    assert detected.source == "preset fr2 (detected from folder name rgbd_dataset_freiburg2_desk)"

    (folder / "camera.yaml").write_text(CAMERA_YAML)
    beside = resolve_camera(folder)
    assert beside.camera.fx == 50.5 and beside.depth_factor == 1000.0
    assert beside.source == "camera file camera.yaml next to the data"

    given = resolve_camera(folder, "fr3")
    assert given.camera == PRESETS["fr3"] and given.source == "preset fr3 (given)"

    other = tmp_path / "other.json"
    save_camera_file(other, PRESETS["ros-default"])
    from_file = resolve_camera(folder, other)
    assert from_file.camera == PRESETS["ros-default"] and str(other) in from_file.source

    explicit = resolve_camera(folder, "fr1", fx=500, fy=501, cx=320, cy=240)
    assert explicit.camera == PinholeCamera(640, 480, 500, 501, 320, 240, ())
    assert explicit.source.startswith("explicit fx/fy/cx/cy")

    plain = tmp_path / "plain"
    plain.mkdir()
    with caplog.at_level(logging.WARNING, logger="slamcli"):
        fallback = resolve_camera(plain)
    assert fallback.fallback and fallback.camera == PRESETS["ros-default"]
    assert "ros-default" in caplog.text


def test_partial_intrinsics_and_unknown_camera_are_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="fx, cx given without fy, cy"):
        resolve_camera(tmp_path, fx=500, cx=320)
    with pytest.raises(ConfigError, match="fy must be a positive"):
        resolve_camera(tmp_path, fx=500, fy=0, cx=320, cy=240)
    with pytest.raises(ConfigError, match="neither a preset nor an existing camera file"):
        resolve_camera(tmp_path, "fr9")
