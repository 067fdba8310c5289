"""KITTI odometry folders as a stereo source: the shared excerpt, KITTI's own layout, bad
calibration files, skipped pairs, sniffing and ``slamcli info``."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import typer
from conftest import shared_path
from typer.testing import CliRunner

from slamcli.cli import info as info_cmd
from slamcli.errors import FormatError, InputError
from slamcli.formats import open_source, sniff
from slamcli.formats.kitti import KittiSource, read_calib
from slamcli.types import ImageFrame, StereoFrame

# Sequence 00's calib.txt from KITTI's odometry benchmark.
P0 = "7.188560e+02 0 6.071928e+02 0 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
P1 = "7.188560e+02 0 6.071928e+02 -3.861448e+02 0 7.188560e+02 1.852157e+02 0 0 0 1 0"
P2 = (
    "7.188560e+02 0 6.071928e+02 4.538225e+01 0 7.188560e+02 1.852157e+02 -1.130887e-01 "
    "0 0 1 3.779761e-03"
)
P3 = (
    "7.188560e+02 0 6.071928e+02 -3.372877e+02 0 7.188560e+02 1.852157e+02 2.369057e+00 "
    "0 0 1 4.915215e-03"
)
TR = (
    "4.27e-04 -9.99e-01 -8.08e-03 -1.19e-02 -7.21e-03 8.08e-03 -9.99e-01 -5.40e-02 "
    "1 4.8e-04 -7.2e-03 -2.9e-01"
)
W, H = 40, 30


def _excerpt() -> Path:
    return shared_path("stereo", "kitti_excerpt_1")


def _write_pair(folder: Path, left: str, right: str, n: int, colour: bool) -> None:
    rng = np.random.default_rng(7)
    for side in (left, right):
        (folder / side).mkdir(parents=True, exist_ok=True)
        for k in range(n):
            shape = (H, W, 3) if colour else (H, W)
            img = rng.integers(0, 255, shape, dtype=np.uint8)
            if colour:
                img[0, 0] = (255, 0, 0)  # blue in OpenCV's BGR order
            cv2.imwrite(str(folder / side / f"{k:06d}.png"), img)


def _official(tmp_path: Path, n: int = 3, grey: bool = True, colour: bool = False) -> Path:
    """KITTI's download layout: dataset/sequences/07 and dataset/poses/07.txt."""
    seq = tmp_path / "dataset" / "sequences" / "07"
    seq.mkdir(parents=True)
    if grey:
        _write_pair(seq, "image_0", "image_1", n, colour=False)
    if colour:
        _write_pair(seq, "image_2", "image_3", n, colour=True)
    (seq / "calib.txt").write_text(f"P0: {P0}\nP1: {P1}\nP2: {P2}\nP3: {P3}\nTr: {TR}\n")
    (seq / "times.txt").write_text("".join(f"{0.103 * k + 0.5:.6e}\n" for k in range(n)))
    poses = tmp_path / "dataset" / "poses"
    poses.mkdir()
    (poses / "07.txt").write_text(
        "".join(f"1 0 0 {0.0} 0 1 0 0 0 0 1 {1.5 * k}\n" for k in range(n))
    )
    return seq


def test_excerpt_pairs_camera_baseline_stamps_and_groundtruth() -> None:
    folder = _excerpt()
    rows = np.loadtxt(folder / "calib.txt").reshape(2, 3, 4)
    baseline = -rows[1][0, 3] / rows[1][0, 0]
    with open_source(folder) as src:
        assert src.format_name == "kitti"
        info = src.info()
        frames = list(src.frames(["stereo"]))
        gt = src.groundtruth()
        stats = src.stats
    assert info.frames == 51 and len(frames) == 51 and stats.read == 51 and stats.skipped == 0
    assert info.camera is not None and info.camera.fx == 707.0912
    assert (info.camera.width, info.camera.height) == (1226, 370)
    assert info.details["baseline_m"] == pytest.approx(baseline, rel=1e-12)
    assert 0.53 < baseline < 0.55
    assert info.streams[0].kind == "stereo" and info.streams[0].count == 51
    assert info.streams[0].rate_hz == pytest.approx(10.0)
    assert "10 Hz" in info.details["times_source"] and info.problems == []
    first = frames[0]
    assert isinstance(first, StereoFrame)
    assert first.left.shape == (370, 1226) and first.left.dtype == np.uint8
    assert first.right.shape == first.left.shape and not np.array_equal(first.left, first.right)
    assert first.rig.baseline_m == pytest.approx(baseline)
    assert np.array_equal(first.rig.body_from_left, np.eye(4))
    stamps = np.array([f.stamp_ns for f in frames])
    assert stamps.dtype == np.int64 and np.all(np.diff(stamps) == 100_000_000)
    assert gt is not None and len(gt) == 51 and info.groundtruth == 51
    assert np.array_equal(gt.stamps_ns, stamps)
    assert 55.0 < gt.path_length() < 65.0


def test_excerpt_left_images_as_image_frames() -> None:
    with KittiSource(_excerpt()) as src:
        frames = list(src.frames(["image", "stereo"]))
    assert len(frames) == 102
    image, pair = frames[0], frames[1]
    assert isinstance(image, ImageFrame) and isinstance(pair, StereoFrame)
    assert image.image is pair.left and image.stamp_ns == pair.stamp_ns
    assert image.camera is not None and image.camera.fx == 707.0912


def test_official_layout_grey_pair(tmp_path: Path) -> None:
    seq = _official(tmp_path, grey=True, colour=True)
    assert sniff.kitti(seq)
    with open_source(seq) as src:
        info = src.info()
        frames = list(src.frames())
        gt = src.groundtruth()
    assert info.details["pair_folders"] == ["image_0", "image_1"]
    assert info.camera_source == "calib.txt P0/P1"
    assert info.details["baseline_m"] == pytest.approx(386.1448 / 718.856)
    assert info.details["times_source"] == "times.txt"
    assert [f.stamp_ns for f in frames] == [500_000_000, 603_000_000, 706_000_000]
    assert all(isinstance(f, StereoFrame) and f.left.shape == (H, W) for f in frames)
    assert gt is not None and info.details["groundtruth_from"] == "poses/07.txt"
    assert list(gt.stamps_ns) == [500_000_000, 603_000_000, 706_000_000]
    assert gt.positions[:, 2] == pytest.approx([0.0, 1.5, 3.0])
    assert info.problems == []


def test_official_layout_colour_pair(tmp_path: Path) -> None:
    seq = _official(tmp_path, grey=False, colour=True)
    with open_source(seq) as src:
        info = src.info()
        frame = next(iter(src.frames(["stereo"])))
    assert info.camera_source == "calib.txt P2/P3"
    assert info.details["colour"] is True
    assert info.details["baseline_m"] == pytest.approx((45.38225 + 337.2877) / 718.856)
    assert isinstance(frame, StereoFrame) and frame.left.shape == (H, W, 3)
    assert tuple(frame.left[0, 0]) == (0, 0, 255)  # RGB
    # Camera 2 sits left of camera 0 (the ground truth's): x = -P2[0,3]/fx about -6 cm.
    offset = frame.rig.body_from_left[:3, 3]
    assert offset[0] == pytest.approx(-(45.38225 - 607.1928 * 3.779761e-03) / 718.856)
    assert -0.07 < offset[0] < -0.05


def test_sniffing_both_layouts_and_not_tum(tmp_path: Path) -> None:
    seq = _official(tmp_path)
    assert open_source(seq).format_name == "kitti"
    assert open_source(_excerpt()).format_name == "kitti"
    tum = tmp_path / "tum"
    tum.mkdir()
    (tum / "rgb.txt").write_text("1.0 rgb/1.png\n")
    (tum / "depth.txt").write_text("1.0 depth/1.png\n")
    (tum / "calib.txt").write_text(f"{P0}\n{P1}\n")
    assert not sniff.kitti(tum)
    assert open_source(tum).format_name == "tum"


@pytest.mark.parametrize(
    ("text", "found"),
    [
        (f"{P0}\n", ":1: has 1 projection row(s), expected two"),
        (f"P0: {P0}\nP2: {P2}\n", "has no P1: line (found P0, P2)"),
        (f"P0: {P0}\nP1: {P1.replace('-3.861448e+02', 'abc')}\n", ":2: column 5: matrix entry"),
        (
            f"{P0}\n{P1.rsplit(' ', 1)[0]}\n",
            ":2: projection row expected 12 numbers (a 3x4 matrix, row-major), found 11",
        ),
        (
            f"P0: {P0}\nP1: {P1}\nTr: 1 2 3\n",
            ":3: Tr: expected 12 numbers (a 3x4 matrix, row-major), found 3",
        ),
        (f"P0: {P0}\n{P1}\n", ":2: mixes labelled lines"),
        (f"{P1}\n{P0}\n", ":2: the baseline"),
        ("# empty\n", "holds no projection matrices"),
        (f"{P0}\n{P1.replace('7.188560e+02', '7.0e+02', 1)}\n", ":2: the right camera's"),
    ],
)
def test_bad_calib(tmp_path: Path, text: str, found: str) -> None:
    path = tmp_path / "calib.txt"
    path.write_text(text)
    with pytest.raises(FormatError) as err:
        read_calib(path)
    assert found in str(err.value)
    assert str(path) in str(err.value) and err.value.hint


def test_bad_calib_stops_open(tmp_path: Path) -> None:
    seq = _official(tmp_path)
    (seq / "calib.txt").write_text(f"P0: {P0}\n")
    with pytest.raises(FormatError, match="has no P1: line"):
        open_source(seq)


def test_too_few_times(tmp_path: Path) -> None:
    seq = _official(tmp_path)
    (seq / "times.txt").write_text("0.0\n0.1\n")
    with pytest.raises(FormatError, match=r"times.txt: has 2 times, but image_0/ holds 000002"):
        open_source(seq)


def test_pair_of_different_sizes_and_missing_right_skipped(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    seq = _official(tmp_path, n=4)
    cv2.imwrite(str(seq / "image_1" / "000001.png"), np.zeros((H, W // 2), np.uint8))
    (seq / "image_1" / "000003.png").unlink()
    with caplog.at_level(logging.WARNING), open_source(seq) as src:
        frames = list(src.frames(["stereo"]))
        info = src.info()
        stats = src.stats
    names = [f.name for f in frames if isinstance(f, StereoFrame)]
    assert names == [
        "image_0/000000.png + image_1/000000.png",
        "image_0/000002.png + image_1/000002.png",
    ]
    assert stats.read == 2 and stats.skipped == 2
    assert stats.skipped_names == ["image_0/000001.png", "image_0/000003.png"]
    assert "image_1/000001.png" in caplog.text and "is 20x30" in caplog.text
    assert "image_1/000003.png" in caplog.text and "does not exist" in caplog.text
    assert info.details["unreadable"] == ["image_1/000003.png does not exist"]
    with KittiSource(seq, strict=True) as src, pytest.raises(FormatError, match=r"000001\.png"):
        list(src.frames(["stereo"]))


def test_deep_info_finds_the_odd_sized_image(tmp_path: Path) -> None:
    seq = _official(tmp_path, n=3)
    cv2.imwrite(str(seq / "image_1" / "000002.png"), np.zeros((H, W // 2), np.uint8))
    with open_source(seq) as src:
        assert src.info().details["unreadable"] == []
        deep = src.info(deep=True).details["unreadable"]
    assert len(deep) == 1 and deep[0].startswith("image_1/000002.png is 20x30")


def test_unknown_and_absent_kinds(tmp_path: Path) -> None:
    seq = _official(tmp_path)
    with open_source(seq) as src, pytest.raises(InputError, match="has no rgbd frames"):
        list(src.frames(["rgbd"]))


def test_missing_right_folder(tmp_path: Path) -> None:
    seq = _official(tmp_path)
    for p in (seq / "image_1").iterdir():
        p.unlink()
    (seq / "image_1").rmdir()
    with pytest.raises(InputError, match="has image_0/ but no image_1/"):
        open_source(seq)


def test_cli_info_shows_the_stereo_facts() -> None:
    app = typer.Typer(pretty_exceptions_enable=False)

    @app.callback()
    def _root() -> None:
        """Root, so ``info`` stays a subcommand."""

    info_cmd.register(app)
    res = CliRunner().invoke(app, ["info", str(_excerpt())])
    assert res.exit_code == 0, res.output
    for text in ("51 (image_l/ + image_r/)", "1226x370, grey", "0.5372 m", "no times.txt"):
        assert text in res.stdout
    assert "RGB-D" not in res.stdout
