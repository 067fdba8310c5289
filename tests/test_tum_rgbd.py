"""TUM RGB-D folders: lists, association, decoding, skipping, undistortion and info()."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import open_source
from slamcli.formats.camera import save_camera_file
from slamcli.formats.pairing import associate_stamps
from slamcli.formats.text import parse_stamp_ns
from slamcli.formats.tum_rgbd import TumRgbdSource, depth_scale_problem, read_image_list
from slamcli.types import ImageFrame, ImuFrame, PinholeCamera, RgbdFrame

T0 = 1305031235.0
CAMERA = PinholeCamera(32, 24, 30.0, 30.0, 15.5, 11.5, ())


def write_tum_folder(
    root: Path,
    n: int = 4,
    *,
    camera: PinholeCamera | None = CAMERA,
    depth_raw: np.ndarray | None = None,
    depth_delay_s: float = 0.005,
    groundtruth_until_s: float | None = None,
    newline: str = "\n",
) -> Path:
    """A small TUM folder: n colour/depth pairs at 30 Hz, colour k filled with red = 10 k.

    ``depth_raw`` (H, W) uint16 is written for every frame (default 2 m at 5000 per metre).
    Ground truth runs at 100 Hz from before the first frame to ``groundtruth_until_s``.
    """
    w, h = (camera.width, camera.height) if camera else (640, 480)
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    raw = np.full((h, w), 10000, np.uint16) if depth_raw is None else depth_raw
    rgb_lines = ["# color images", "# timestamp filename", ""]
    depth_lines = ["# depth maps", "# timestamp filename"]
    for k in range(n):
        t = T0 + k / 30
        rgb = np.zeros((h, w, 3), np.uint8)
        rgb[..., 0] = 10 * k
        rgb[..., 2] = 200
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), rgb[..., ::-1])
        cv2.imwrite(str(root / f"depth/{t + depth_delay_s:.6f}.png"), raw)
        rgb_lines.append(f"{t:.6f} rgb/{t:.6f}.png")
        depth_lines.append(f"{t + depth_delay_s:.6f} depth/{t + depth_delay_s:.6f}.png")
    for name, lines in (("rgb.txt", rgb_lines), ("depth.txt", depth_lines)):
        (root / name).write_bytes(newline.join([*lines, ""]).encode())
    if camera is not None:
        save_camera_file(root / "camera.yaml", camera)
    end = T0 + n / 30 if groundtruth_until_s is None else T0 + groundtruth_until_s
    gt = [f"{t:.4f} 0 0 {t - T0:.4f} 0 0 0 1" for t in np.arange(T0 - 0.05, end, 0.01)]
    (root / "groundtruth.txt").write_text("# timestamp tx ty tz qx qy qz qw\n" + "\n".join(gt))
    return root


# --- the shared TUM excerpt --------------------------------------------------------------------


def test_excerpt_info(tum_excerpt: Path) -> None:
    with open_source(tum_excerpt) as src:
        info = src.info()
    assert info.format == "tum"
    assert info.frames == 150
    assert info.camera is not None and info.camera.fx == 517.306408
    assert "fr1" in info.camera_source and "detected" in info.camera_source
    assert info.groundtruth == 598
    streams = {s.name: s for s in info.streams}
    assert streams["rgb"].count == streams["depth"].count == 150
    assert streams["accelerometer"].count == 3033
    assert streams["rgb"].rate_hz == pytest.approx(30.0, abs=0.1)
    assert info.details["unmatched_rgb"] == info.details["unmatched_depth"] == 0
    assert info.details["groundtruth_coverage"] == 1.0
    assert 0.5 < info.details["depth_check"]["median_m"] < 5.0
    assert info.problems == []


def test_excerpt_association_equals_shipped_associations(tum_excerpt: Path) -> None:
    shipped = []
    for line in (tum_excerpt / "associations.txt").read_text().splitlines():
        ts, rgb, td, depth = line.split()
        shipped.append((parse_stamp_ns(ts, "a", 1), rgb, parse_stamp_ns(td, "a", 1), depth))
    with TumRgbdSource.open(tum_excerpt) as src:
        assert src.associations() == shipped


def test_excerpt_decoded_frame(tum_excerpt: Path) -> None:
    with TumRgbdSource.open(tum_excerpt) as src:
        frame = next(iter(src.frames()))
    assert isinstance(frame, RgbdFrame)
    assert frame.rgb.shape == (480, 640, 3) and frame.rgb.dtype == np.uint8
    assert frame.depth_m.shape == (480, 640) and frame.depth_m.dtype == np.float32
    assert 0.5 < float(np.median(frame.depth_m[frame.depth_m > 0])) < 5.0
    assert frame.name == "rgb/1305031235.861603.png"
    assert frame.stamp_ns == 1305031235861603000
    assert frame.depth_stamp_ns == 1305031235870067000
    bgr = cv2.imread(str(tum_excerpt / frame.name))
    assert np.array_equal(frame.rgb, bgr[..., ::-1])


def test_excerpt_frames_are_time_ordered_across_kinds(tum_excerpt: Path) -> None:
    with TumRgbdSource.open(tum_excerpt) as src:
        kinds: dict[type, int] = {}
        stamps = []
        for f in src.frames(("imu", "rgbd")):
            kinds[type(f)] = kinds.get(type(f), 0) + 1
            stamps.append(f.stamp_ns)
        gt = src.groundtruth()
    assert kinds == {ImuFrame: 3033, RgbdFrame: 150}
    assert stamps == sorted(stamps)
    assert gt is not None and len(gt) == 598
    assert gt.stamps_ns[0] == 1305031235363100000


# --- association -------------------------------------------------------------------------------


def _associate_reference(
    a: list[int], b: list[int], max_dt: int, offset: int
) -> list[tuple[int, int]]:
    """TUM associate.py, literally: every candidate pair, sorted, taken greedily 1:1."""
    candidates = sorted(
        (abs(ta - (tb + offset)), ta, tb, i, j)
        for i, ta in enumerate(a)
        for j, tb in enumerate(b)
        if abs(ta - (tb + offset)) < max_dt
    )
    used_a: set[int] = set()
    used_b: set[int] = set()
    pairs = []
    for _, _, _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs, key=lambda p: (a[p[0]], p[0]))


stamp_lists = st.lists(st.integers(0, 300), max_size=40)


@settings(max_examples=300, deadline=None)
@given(
    a=stamp_lists,
    b=stamp_lists,
    max_dt=st.integers(0, 60),
    offset=st.integers(-40, 40),
)
def test_association_matches_the_brute_force_reference(
    a: list[int], b: list[int], max_dt: int, offset: int
) -> None:
    i, j = associate_stamps(a, b, max_dt, offset)
    assert list(zip(i.tolist(), j.tolist(), strict=True)) == _associate_reference(
        a, b, max_dt, offset
    )


def test_association_is_fast_on_long_sequences() -> None:
    rng = np.random.default_rng(0)
    a = np.cumsum(rng.integers(30_000_000, 36_000_000, 200_000))
    b = a + rng.integers(-15_000_000, 15_000_000, a.size)
    i, j = associate_stamps(a, np.sort(b), 20_000_000)
    assert i.size > 0.9 * a.size
    assert np.all(np.abs(a[i] - np.sort(b)[j]) < 20_000_000)


def test_dt_offset_is_added_to_depth_stamps(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", depth_delay_s=0.1)
    with TumRgbdSource.open(folder) as src:
        assert len(src) == 1
        info = src.info()
    assert info.details["unmatched_rgb"] == 3 and info.details["unmatched_depth"] == 3
    with TumRgbdSource.open(folder, dt_offset=-0.1) as src:
        assert len(src) == 4
        pairs = src.associations()
    assert all(abs(td - tr - 100_000_000) < 1000 for tr, _, td, _ in pairs)


# --- list files and folders --------------------------------------------------------------------


def test_comments_blank_lines_and_crlf(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", newline="\r\n")
    assert b"\r\n" in (folder / "rgb.txt").read_bytes()
    lst = read_image_list(folder / "rgb.txt")
    assert len(lst) == 4 and lst.lines[0] == 4
    assert lst.stamps_ns[1] == 1305031235033333000
    with TumRgbdSource.open(folder) as src:
        frames = list(src.frames())
    assert len(frames) == 4 and all(not f.name.endswith("\r") for f in frames)


def test_unsorted_list_is_sorted_by_time(tmp_path: Path) -> None:
    p = tmp_path / "rgb.txt"
    p.write_text("2.0 b.png\n1.0 a.png\n")
    lst = read_image_list(p)
    assert lst.files == ("a.png", "b.png") and lst.lines == (2, 1)


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("1305031236.5 rgb/x.png extra", r"rgb\.txt:8: expected 'timestamp filename', found 3"),
        ("rgb/x.png", r"rgb\.txt:8: expected 'timestamp filename', found 1"),
        ("13050312x6.5 rgb/x.png", r"rgb\.txt:8: timestamp '13050312x6.5' is not a number"),
    ],
)
def test_malformed_list_line_names_file_and_line(tmp_path: Path, line: str, match: str) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with (folder / "rgb.txt").open("a") as fh:
        fh.write(line + "\n")
    with pytest.raises(FormatError, match=match):
        TumRgbdSource.open(folder)


def test_colour_only_folder_has_images_but_no_rgbd_frames(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    (folder / "depth.txt").unlink()
    assert TumRgbdSource.sniff(folder)
    with open_source(folder) as src:
        info = src.info()
        assert [s.kind for s in info.streams if s.kind in ("image", "depth")] == ["image"]
        assert any("no depth.txt" in p for p in info.problems)
        assert sum(1 for _ in src.frames(("image",))) == len(src.rgb_list)
        with pytest.raises(InputError, match=r"no depth\.txt: colour only"):
            next(iter(src.frames(("rgbd",))))


def test_missing_colour_list_names_what_is_missing(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    (folder / "rgb.txt").unlink()
    assert TumRgbdSource.sniff(folder)
    with pytest.raises(InputError, match=r"no rgb\.txt \(found depth\.txt\)"):
        open_source(folder)


def test_sniff(tmp_path: Path) -> None:
    assert TumRgbdSource.sniff(write_tum_folder(tmp_path / "d"))
    (tmp_path / "empty").mkdir()
    assert not TumRgbdSource.sniff(tmp_path / "empty")
    (tmp_path / "file.txt").write_text("x")
    assert not TumRgbdSource.sniff(tmp_path / "file.txt")


@pytest.mark.parametrize(
    ("options", "error", "match"),
    [
        ({"max_dt": 0.0}, ConfigError, "max_dt"),
        ({"depth_factor": -1.0}, ConfigError, "depth_factor"),
        ({"dt_offset": float("nan")}, ConfigError, "dt_offset"),
    ],
)
def test_bad_options(tmp_path: Path, options: dict, error: type, match: str) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with pytest.raises(error, match=match):
        TumRgbdSource.open(folder, **options)


def test_frame_kinds(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with TumRgbdSource.open(folder) as src:
        frames = list(src.frames(("image", "rgbd")))
        assert [type(f) for f in frames] == [ImageFrame, RgbdFrame] * 4
        assert frames[0].image is frames[1].rgb
        assert list(src.frames(("imu",))) == []
        with pytest.raises(ConfigError, match="unknown frame kind"):
            list(src.frames(("lidar",)))
        with pytest.raises(InputError, match="no odometry frames"):
            list(src.frames(("odometry",)))
    assert src.stats.read == 8


# --- decoding ----------------------------------------------------------------------------------


def test_colour_is_rgb_and_depth_is_metres(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with TumRgbdSource.open(folder) as src:
        frames = list(src.frames())
    assert [int(f.rgb[0, 0, 0]) for f in frames] == [0, 10, 20, 30]
    assert int(frames[0].rgb[0, 0, 2]) == 200
    assert frames[0].camera == CAMERA
    assert np.all(frames[0].depth_m == np.float32(2.0))


def test_depth_factor_option_and_camera_file(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", depth_raw=np.full((24, 32), 2000, np.uint16))
    with TumRgbdSource.open(folder) as src:
        assert src.depth_factor_source == "TUM default"
        assert next(iter(src.frames())).depth_m[0, 0] == pytest.approx(0.4)
    with TumRgbdSource.open(folder, depth_factor=1000) as src:
        assert next(iter(src.frames())).depth_m[0, 0] == pytest.approx(2.0)
    save_camera_file(folder / "camera.yaml", CAMERA, depth_factor=1000)
    with TumRgbdSource.open(folder) as src:
        assert src.depth_factor == 1000.0 and src.depth_factor_source == "camera file"
        assert next(iter(src.frames())).depth_m[0, 0] == pytest.approx(2.0)
    with TumRgbdSource.open(folder, depth_factor=500) as src:
        assert next(iter(src.frames())).depth_m[0, 0] == pytest.approx(4.0)


def test_missing_image_is_skipped_counted_and_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = write_tum_folder(tmp_path / "d")
    missing = sorted((folder / "rgb").iterdir())[1]
    missing.unlink()
    name = f"rgb/{missing.name}"
    with TumRgbdSource.open(folder) as src, caplog.at_level(logging.WARNING, logger="slamcli"):
        frames = list(src.frames())
    assert len(frames) == 3
    assert src.stats.read == 3 and src.stats.skipped == 1 and src.stats.skipped_names == [name]
    assert name in caplog.text and "does not exist" in caplog.text
    with (
        TumRgbdSource.open(folder, strict=True) as src,
        pytest.raises(FormatError, match=rf"rgb\.txt:5: lists {name}, which does not exist"),
    ):
        list(src.frames())


def test_corrupt_png_is_skipped_counted_and_named(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    folder = write_tum_folder(tmp_path / "d")
    corrupt = sorted((folder / "depth").iterdir())[2]
    corrupt.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
    with TumRgbdSource.open(folder) as src, caplog.at_level(logging.WARNING, logger="slamcli"):
        frames = list(src.frames())
        info = src.info(deep=True)
    assert len(frames) == 3 and src.stats.skipped == 1
    assert f"depth/{corrupt.name}" in caplog.text and "cannot be decoded" in caplog.text
    assert info.details["unreadable"] == [
        f"depth/{corrupt.name} cannot be decoded as an image (listed at depth.txt:5)"
    ]
    assert any(corrupt.name in p for p in info.problems)
    with TumRgbdSource.open(folder, strict=True) as src:
        with pytest.raises(FormatError, match=rf"{corrupt.name}: cannot be decoded.*depth\.txt:5"):
            list(src.frames())
        with pytest.raises(FormatError, match=corrupt.name):
            src.info(deep=True)


def test_eight_bit_depth_is_unreadable(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", depth_raw=np.full((24, 32), 20, np.uint8))
    with TumRgbdSource.open(folder) as src:
        assert list(src.frames()) == []
        assert src.stats.skipped == 4


def test_image_size_differing_from_the_camera_is_an_error(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    with TumRgbdSource.open(folder, camera="fr3") as src:
        info = src.info()
        assert any("images are 32x24 but the camera" in p for p in info.problems)
        with pytest.raises(InputError, match="image is 32x24, the camera"):
            list(src.frames())


def test_deep_info_reports_progress(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    calls: list[tuple[int, int | None]] = []
    with TumRgbdSource.open(folder) as src:
        info = src.info(deep=True, progress=lambda done, total: calls.append((done, total)))
    assert calls[-1] == (8, 8) and len(calls) == 8
    assert info.details["unreadable"] == [] and info.details["deep"]


# --- undistortion ------------------------------------------------------------------------------

DISTORTED = PinholeCamera(160, 120, 100.0, 100.0, 79.5, 59.5, (-0.3, 0.1, 0.001, -0.002, 0.0))


def _distort(cam: PinholeCamera, u: float, v: float) -> tuple[float, float]:
    """Where an undistorted pixel (u, v) lies in the raw image."""
    x, y = (u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy
    pts, _ = cv2.projectPoints(
        np.array([[x, y, 1.0]]), np.zeros(3), np.zeros(3), cam.K, np.array(cam.distortion)
    )
    return float(pts[0, 0, 0]), float(pts[0, 0, 1])


def test_undistort_maps_known_points_in_colour_and_depth(tmp_path: Path) -> None:
    cam = DISTORTED
    target = (140.0, 100.0)
    ud, vd = _distort(cam, *target)
    assert np.hypot(ud - target[0], vd - target[1]) > 5
    yy, xx = np.mgrid[0 : cam.height, 0 : cam.width]
    depth = np.where(np.hypot(xx - ud, yy - vd) < 3.0, 12345, 0).astype(np.uint16)
    folder = write_tum_folder(tmp_path / "d", n=1, camera=cam, depth_raw=depth)
    rgb_file = next((folder / "rgb").iterdir())
    blob = 255 * np.exp(-((xx - ud) ** 2 + (yy - vd) ** 2) / (2 * 1.5**2))
    cv2.imwrite(str(rgb_file), np.repeat(blob[..., None], 3, axis=2).round().astype(np.uint8))

    with TumRgbdSource.open(folder, undistort=True) as src:
        frame = next(iter(src.frames()))
        assert src.info().details["undistort"]
    assert frame.camera == cam.undistorted() and not frame.camera.is_distorted
    weight = frame.rgb[..., 0].astype(np.float64)
    centroid = (
        float((weight * xx).sum() / weight.sum()),
        float((weight * yy).sum() / weight.sum()),
    )
    assert np.hypot(centroid[0] - target[0], centroid[1] - target[1]) < 0.3
    values = set(np.unique(frame.depth_m).tolist())
    assert values == {0.0, float(np.float32(12345 / 5000))}
    rows, cols = np.nonzero(frame.depth_m)
    assert np.hypot(cols.mean() - target[0], rows.mean() - target[1]) < 0.5

    with TumRgbdSource.open(folder) as src:
        raw = next(iter(src.frames()))
    assert raw.camera == cam
    rows, cols = np.nonzero(raw.depth_m)
    assert np.hypot(cols.mean() - ud, rows.mean() - vd) < 0.5


def test_undistort_without_distortion_changes_nothing(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", n=1)
    with TumRgbdSource.open(folder, undistort=True) as src:
        a = next(iter(src.frames()))
    with TumRgbdSource.open(folder) as src:
        b = next(iter(src.frames()))
    assert a.camera == b.camera and np.array_equal(a.rgb, b.rgb)


# --- info: ground truth and depth scale --------------------------------------------------------


def test_groundtruth_coverage(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", n=10, groundtruth_until_s=0.15)
    with TumRgbdSource.open(folder) as src:
        info = src.info()
    # Ground truth ends at T0 + 0.15 s: frames at 0, 1/30, ..., 5/30 (<= 0.15 + 0.02) are covered.
    assert info.details["groundtruth_covered"] == 6
    assert info.details["groundtruth_coverage"] == pytest.approx(0.6)
    assert info.details["groundtruth_span_coverage"] == pytest.approx(0.5)
    assert any("only 6 of 10 frames have a ground-truth pose" in p for p in info.problems)


def test_no_groundtruth_file(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d")
    (folder / "groundtruth.txt").unlink()
    with TumRgbdSource.open(folder) as src:
        assert src.groundtruth() is None
        info = src.info()
    assert info.groundtruth == 0 and info.details["groundtruth_coverage"] is None
    assert [s.name for s in info.streams] == ["rgb", "depth"]


def test_depth_in_millimetres_is_flagged(tmp_path: Path) -> None:
    mm = np.tile(np.linspace(800, 3000, 32), (24, 1)).astype(np.uint16)
    folder = write_tum_folder(tmp_path / "d", depth_raw=mm)
    with TumRgbdSource.open(folder) as src:
        info = src.info()
    assert any("millimetres read with depth factor 5000" in p for p in info.problems)
    with TumRgbdSource.open(folder, depth_factor=1000) as src:
        assert src.info().problems == []


def test_depth_scale_judgement() -> None:
    tum = np.linspace(2500, 40000, 1000)  # 0.5-8 m at 5000 per metre
    assert depth_scale_problem(tum, 5000) is None
    flagged = depth_scale_problem(tum, 1000)
    assert flagged is not None and "TUM units" in flagged
    far = np.linspace(60000, 65000, 100)  # 12-13 m with either factor's neighbour
    assert depth_scale_problem(far, 5000) is not None
    assert depth_scale_problem(np.array([]), 5000) is None


def test_camera_fallback_is_a_problem(tmp_path: Path) -> None:
    folder = write_tum_folder(tmp_path / "d", n=2, camera=None)
    with TumRgbdSource.open(folder) as src:
        info = src.info()
    assert info.camera_source.startswith("preset ros-default (assumed")
    assert any(p.startswith("camera unknown") for p in info.problems)
