"""Open3D / Redwood RGB-D folders: recognition, frames, ground truth, camera, errors, a run.

The real data is Open3D's test folder (5 frames of the augmented ICL-NUIM living room, depth in
millimetres, ``trajectory.log`` as ground truth, ``camera_primesense.json``); its
``other_formats/`` holds single frames of TUM, SUN and NYU that must not confuse the source.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError, FormatError, InputError, UnknownFormatError
from slamcli.formats import SNIFFERS, open_source
from slamcli.formats.redwood import RedwoodSource, read_redwood_log
from slamcli.run import run_pipeline
from slamcli.types import ImageFrame, RgbdFrame

runner = CliRunner()

DENSE_ATE_MAX_M = 0.005
"""Dense tracking of the 5 frames measured an ATE RMSE of 0.0024 m. The ground-truth camera
moves 0.098 m over them, and a camera left standing still scores 0.035 m after alignment; 5 mm
is about twice the measured error, 5 % of the path and a seventh of the standing-still score."""


@pytest.fixture
def folder() -> Path:
    return shared_path("rgbd", "open3d_test_data_RGBD")


def _copy(folder: Path, dest: Path) -> Path:
    return Path(shutil.copytree(folder, dest))


def _log_matrices(path: Path) -> tuple[list[int], np.ndarray]:
    """Frame ids and 4x4 matrices of a Redwood .log, read plainly."""
    lines = [line.split() for line in path.read_text().splitlines() if line.strip()]
    ids = [int(lines[i][0]) for i in range(0, len(lines), 5)]
    mats = [np.array(lines[i + 1 : i + 5], dtype=float) for i in range(0, len(lines), 5)]
    return ids, np.stack(mats)


def test_shared_folder_is_recognised(folder: Path) -> None:
    assert [name for name, looks_like in SNIFFERS.items() if looks_like(folder)] == ["redwood"]
    with open_source(folder) as src:
        assert isinstance(src, RedwoodSource)
        assert src.colour_dir.name == "color"
        assert len(src) == 5
        assert src.groundtruth_path is not None and src.groundtruth_path.name == "trajectory.log"
        assert [p.name for p in src.other_logs] == ["odometry.log"]
    with pytest.raises(UnknownFormatError):
        open_source(folder / "other_formats")


def test_info_cli_describes_the_folder(folder: Path) -> None:
    res = runner.invoke(app, ["info", str(folder), "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["format"] == "redwood"
    assert data["frames"] == 5 and data["groundtruth"] == 5
    assert data["camera"]["fx"] == 525.0 and data["camera"]["cx"] == 319.5
    assert "camera_primesense.json" in data["camera_source"]
    assert data["details"]["groundtruth_from"] == "trajectory.log"
    assert data["details"]["groundtruth_coverage"] == 1.0
    assert data["details"]["depth_factor"] == 1000.0
    assert 1.0 < data["details"]["depth_check"]["median_m"] < 3.0
    assert data["problems"] == []
    res = runner.invoke(app, ["info", str(folder)])
    assert res.exit_code == 0, res.output
    for text in ("redwood", "5 paired RGB-D frames", "camera_primesense.json", "trajectory.log"):
        assert text in res.stdout
    assert "no problems found" in res.stdout


def test_frames_are_rgb_and_metres(folder: Path) -> None:
    raw = cv2.imread(str(folder / "depth" / "00002.png"), cv2.IMREAD_UNCHANGED)
    bgr = cv2.imread(str(folder / "color" / "00002.jpg"), cv2.IMREAD_COLOR)
    with RedwoodSource(folder) as src:
        frames = list(src.frames(("rgbd", "image")))
        assert src.stats.read == 10 and src.stats.skipped == 0
    rgbd = [f for f in frames if isinstance(f, RgbdFrame)]
    images = [f for f in frames if isinstance(f, ImageFrame)]
    assert len(rgbd) == len(images) == 5
    assert [f.stamp_ns for f in rgbd] == [round(k * 1e9 / 30) for k in range(5)]
    assert [f.stamp_ns for f in images] == [f.stamp_ns for f in rgbd]
    f = rgbd[2]
    assert f.rgb.shape == (480, 640, 3) and f.rgb.dtype == np.uint8
    assert f.depth_m.shape == (480, 640) and f.depth_m.dtype == np.float32
    v, u = 240, 320
    assert raw[v, u] > 0
    assert f.depth_m[v, u] == pytest.approx(raw[v, u] / 1000.0)
    np.testing.assert_array_equal(f.depth_m, (raw / np.float32(1000)).astype(np.float32))
    np.testing.assert_array_equal(f.rgb, bgr[:, :, ::-1])
    assert f.name == "color/00002.jpg"


def test_groundtruth_equals_the_log(folder: Path) -> None:
    ids, mats = _log_matrices(folder / "trajectory.log")
    with RedwoodSource(folder) as src:
        gt = src.groundtruth()
    assert gt is not None
    np.testing.assert_array_equal(gt.world_from_body, mats)
    assert gt.stamps_ns.tolist() == [round(k * 1e9 / 30) for k in ids]


def test_dense_run_tracks_all_frames(folder: Path, tmp_path: Path) -> None:
    outcome = run_pipeline(folder, "dense", tmp_path / "run")
    assert outcome.counts["frames_read"] == 5
    assert outcome.counts["frames_tracked"] == 5 and outcome.counts["frames_lost"] == 0
    evaluation = outcome.metrics["evaluation"]
    assert evaluation["pairs"] == 5
    ate = evaluation["ate"]["rmse"]
    print(f"dense ATE RMSE on open3d_test_data_RGBD: {ate:.4f} m")
    assert ate < DENSE_ATE_MAX_M


@pytest.mark.parametrize(
    ("edit", "where", "match"),
    [
        (lambda lines: lines.__setitem__(7, "1 0 0"), 8, "matrix row of 4 numbers"),
        (lambda lines: lines.__setitem__(5, "1 1"), 6, "block header"),
        (lambda lines: lines.__setitem__(2, "0 1 0 x"), 3, "'x' is not a number"),
        (lambda lines: lines.__setitem__(4, "0 0 0 2"), 5, "expected 0 0 0 1"),
        (lambda lines: lines.__setitem__(1, "2 0 0 0"), 1, "not a rotation"),
        (lambda lines: lines.__setitem__(5, "0 0 1"), 6, "given twice"),
        (lambda lines: lines.__delitem__(slice(22, 25)), 22, "has 1 matrix row"),
    ],
)
def test_malformed_log_names_file_and_line(
    folder: Path, tmp_path: Path, edit: object, where: int, match: str
) -> None:
    copy = _copy(folder, tmp_path / "d")
    log = copy / "trajectory.log"
    lines = log.read_text().splitlines()
    edit(lines)  # type: ignore[operator]
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError, match=match) as exc:
        read_redwood_log(log)
    assert str(exc.value).startswith(f"{log}:{where}:")
    assert exc.value.hint and "5 lines" in exc.value.hint
    res = runner.invoke(app, ["info", str(copy)])
    assert res.exit_code == 1
    assert f"trajectory.log:{where}:" in res.output and "Traceback" not in res.output


def test_depth_without_colour_is_not_redwood(folder: Path, tmp_path: Path) -> None:
    d = tmp_path / "depth_only"
    shutil.copytree(folder / "depth", d / "depth")
    with pytest.raises(UnknownFormatError, match="image/ \\(or color/\\) and depth/"):
        open_source(d)
    with pytest.raises(InputError, match="has no image/ or color/") as exc:
        RedwoodSource(d)
    assert exc.value.hint and "depth/" in exc.value.hint
    res = runner.invoke(app, ["info", str(d)])
    assert res.exit_code == 1 and "not a recognised input" in res.output


def test_image_folder_and_open3d_intrinsic_json(folder: Path, tmp_path: Path) -> None:
    copy = _copy(folder, tmp_path / "d")
    (copy / "color").rename(copy / "image")
    k = [500.0, 0, 0, 0, 501.0, 0, 320.0, 240.0, 1]
    (copy / "camera_intrinsic.json").write_text(
        json.dumps({"width": 640, "height": 480, "intrinsic_matrix": k})
    )
    with open_source(copy) as src:
        assert isinstance(src, RedwoodSource) and src.colour_dir.name == "image"
        cam = src.camera
        assert (cam.fx, cam.fy, cam.cx, cam.cy) == (500.0, 501.0, 320.0, 240.0)
        assert "camera_intrinsic.json" in src.camera_source
        frame = next(iter(src.frames()))
        assert isinstance(frame, RgbdFrame) and frame.camera == cam
    res = runner.invoke(app, ["info", str(copy), "--camera", "ros-default", "--json"])
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["camera"]["fx"] == 525.0 and "ros-default" in data["camera_source"]


def test_primesense_default_without_camera_file(folder: Path, tmp_path: Path) -> None:
    copy = _copy(folder, tmp_path / "d")
    (copy / "camera_primesense.json").unlink()
    with RedwoodSource(copy) as src:
        assert (src.camera.fx, src.camera.cx, src.camera.cy) == (525.0, 319.5, 239.5)
        assert "PrimeSense default" in src.camera_source
        assert src.info().problems == []


def test_unequal_counts_pair_by_number_and_report_the_rest(folder: Path, tmp_path: Path) -> None:
    copy = _copy(folder, tmp_path / "d")
    (copy / "depth" / "00001.png").unlink()
    with RedwoodSource(copy) as src:
        info = src.info()
        frames = list(src.frames())
    assert info.frames == 4 and info.details["pairing"] == "file-name number"
    assert info.details["unpaired_colour"] == ["color/00001.jpg"]
    assert any("color/00001.jpg" in p for p in info.problems)
    assert [f.name for f in frames] == [f"color/0000{k}.jpg" for k in (0, 2, 3, 4)]
    # Frame k keeps the stamp of its number, so it still meets pose k of the .log.
    assert [f.stamp_ns for f in frames] == [round(k * 1e9 / 30) for k in (0, 2, 3, 4)]


def test_unreadable_image_is_skipped_and_counted(folder: Path, tmp_path: Path) -> None:
    copy = _copy(folder, tmp_path / "d")
    (copy / "depth" / "00003.png").write_bytes(b"not a png")
    with RedwoodSource(copy) as src:
        frames = list(src.frames())
        assert len(frames) == 4
        assert src.stats.skipped == 1 and src.stats.skipped_names == ["color/00003.jpg"]
        assert src.info(deep=True).details["unreadable"] == [
            "depth/00003.png cannot be decoded as an image (not PNG, JPEG, PNM, BMP or WebP)"
        ]
    with (
        RedwoodSource(copy, strict=True) as src,
        pytest.raises(FormatError, match=r"00003\.png: cannot be decoded"),
    ):
        list(src.frames())


def test_depth_factor_and_options(folder: Path, tmp_path: Path) -> None:
    raw = cv2.imread(str(folder / "depth" / "00000.png"), cv2.IMREAD_UNCHANGED)
    with open_source(folder, depth_factor=5000.0) as src:
        frame = next(iter(src.frames()))
        assert isinstance(frame, RgbdFrame)
        np.testing.assert_array_equal(frame.depth_m, (raw / np.float32(5000)).astype(np.float32))
        assert src.info().details["depth_factor_source"] == "given"
    with pytest.raises(ConfigError, match="--max-dt does not apply to redwood inputs"):
        open_source(folder, max_dt=0.1)
