"""EuRoC / ASL folders: sensor files, rectification geometry, stereo pairs, IMU interleaving,
malformed input, and sniffing, on the shared V1_01 excerpt and on copies of it."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.formats import open_source, sniff
from slamcli.formats.euroc import (
    EurocSource,
    read_camera_sensor,
    read_imu_csv,
    read_imu_sensor,
    rectify_stereo,
)
from slamcli.formats.euroc.calibration import EQUIDISTANT, CameraSensor
from slamcli.geometry.camera import project, unproject
from slamcli.geometry.se3 import inverse
from slamcli.types import ImageFrame, ImuFrame, PinholeCamera, StereoFrame

FIRST_STAMP = 1403715273262142976
LAST_PAIR_STAMP = 1403715277962142976


@pytest.fixture(scope="module")
def excerpt() -> Path:
    return shared_path("stereo", "euroc_V1_01_micro")


@pytest.fixture(scope="module")
def source(excerpt: Path) -> EurocSource:
    return EurocSource(excerpt)


def _copy(excerpt: Path, dest: Path) -> Path:
    """A writable copy of the excerpt's mav0: text files copied, images and the IMU csv linked."""
    mav = dest / "mav0"
    for cam in ("cam0", "cam1"):
        (mav / cam / "data").mkdir(parents=True)
        for name in ("data.csv", "sensor.yaml"):
            shutil.copy(excerpt / "mav0" / cam / name, mav / cam / name)
        for png in (excerpt / "mav0" / cam / "data").iterdir():
            (mav / cam / "data" / png.name).symlink_to(png)
    (mav / "imu0").mkdir()
    shutil.copy(excerpt / "mav0" / "imu0" / "sensor.yaml", mav / "imu0" / "sensor.yaml")
    (mav / "imu0" / "data.csv").symlink_to(excerpt / "mav0" / "imu0" / "data.csv")
    return dest


def _raw_pixels(sensor: CameraSensor, points_cam: np.ndarray) -> np.ndarray:
    """(N, 3) points in a raw camera -> (N, 2) distorted pixels, by OpenCV's own models."""
    import cv2

    pts = points_cam.reshape(-1, 1, 3).astype(np.float64)
    zero = np.zeros(3)
    d = np.asarray(sensor.coefficients, dtype=np.float64)
    if sensor.model == EQUIDISTANT:
        uv = cv2.fisheye.projectPoints(pts, zero, zero, sensor.camera.K, d)[0]
    else:
        uv = cv2.projectPoints(pts, zero, zero, sensor.camera.K, d)[0]
    return np.asarray(uv, dtype=np.float64).reshape(-1, 2)


def _check_rectification(left: CameraSensor, right: CameraSensor) -> None:
    """A point seen by the raw cameras lands where the rectified rig puts it: the same row in
    both rectified images, disparity fx * b / z, and the rig's body_from_left consistent with
    the raw cameras' T_BS."""
    rect = rectify_stereo(left, right)
    rig = rect.rig
    cam = rig.camera
    # Integer rectified pixels in the left image and an integer disparity, so the remap tables
    # can be read at exact pixels.
    us, vs = np.meshgrid(np.arange(200, 560, 60), np.arange(100, 400, 60))
    disparity = 24
    z = cam.fx * rig.baseline_m / disparity
    left_px = np.stack([us.ravel(), vs.ravel()], axis=1).astype(np.float64)
    points_left = unproject(cam, left_px, z)
    right_px = project(cam, points_left - [rig.baseline_m, 0.0, 0.0])
    np.testing.assert_allclose(right_px[:, 1], left_px[:, 1], atol=1e-9)
    np.testing.assert_allclose(left_px[:, 0] - right_px[:, 0], disparity, atol=1e-9)
    homog = np.c_[points_left, np.ones(len(points_left))]
    in_body = homog @ rig.body_from_left.T
    for sensor, table, px in ((left, rect.left_map, left_px), (right, rect.right_map, right_px)):
        in_cam = (in_body @ inverse(sensor.body_from_sensor).T)[:, :3]
        expected = _raw_pixels(sensor, in_cam)
        cols, rows = np.round(px[:, 0]).astype(int), np.round(px[:, 1]).astype(int)
        np.testing.assert_allclose(np.stack(table, axis=-1)[rows, cols], expected, atol=0.02)


def test_sensor_files_are_read(excerpt: Path) -> None:
    cam0 = read_camera_sensor(excerpt / "mav0" / "cam0" / "sensor.yaml")
    assert (cam0.camera.width, cam0.camera.height) == (752, 480)
    assert cam0.camera.fx == pytest.approx(458.654)
    assert cam0.camera.cy == pytest.approx(248.375)
    assert cam0.model == "radial-tangential"
    assert cam0.camera.distortion == pytest.approx(
        (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05)
    )
    assert cam0.body_from_sensor[1, 3] == pytest.approx(-0.064676986768)
    imu = read_imu_sensor(excerpt / "mav0" / "imu0" / "sensor.yaml")
    assert imu.rate_hz == 200.0
    assert imu.gyroscope_noise_density == pytest.approx(1.6968e-04)
    assert imu.accelerometer_random_walk == pytest.approx(3.0e-3)
    np.testing.assert_array_equal(imu.body_from_sensor, np.eye(4))


def test_shared_excerpt_pairs_and_stamps(source: EurocSource) -> None:
    assert len(source) == 95
    assert len(source.missing) == 4
    stamps = source.pair_stamps_ns
    assert stamps[0] == FIRST_STAMP and stamps[-1] == LAST_PAIR_STAMP
    assert np.all(np.diff(stamps) > 0)
    np.testing.assert_array_equal(stamps, source.left_csv.stamps_ns)
    before = source.stats.skipped
    frames = list(source.frames(("stereo",)))
    assert len(frames) == 95 and source.stats.skipped == before
    assert all(isinstance(f, StereoFrame) for f in frames)
    first = frames[0]
    assert isinstance(first, StereoFrame)
    assert first.stamp_ns == first.right_stamp_ns == FIRST_STAMP
    assert first.left.shape == first.right.shape == (480, 752)
    assert first.left.dtype == np.uint8
    assert (first.rig.camera.width, first.rig.camera.height) == (752, 480)
    assert first.rig.camera.distortion == ()
    assert "1403715273262142976.png" in first.name


def test_baseline_from_the_yaml_extrinsics(excerpt: Path, source: EurocSource) -> None:
    t0 = read_camera_sensor(excerpt / "mav0" / "cam0" / "sensor.yaml").body_from_sensor
    t1 = read_camera_sensor(excerpt / "mav0" / "cam1" / "sensor.yaml").body_from_sensor
    expected = float(np.linalg.norm((inverse(t0) @ t1)[:3, 3]))
    assert 0.10 < expected < 0.12
    assert source.rig.baseline_m == pytest.approx(expected, rel=1e-9)
    info = source.info()
    assert info.details["baseline_m"] == pytest.approx(expected, rel=1e-9)
    assert info.details["distortion_model"] == "radial-tangential"
    # The rectified left camera keeps cam0's centre on the body.
    np.testing.assert_allclose(source.rig.body_from_left[:3, 3], t0[:3, 3], atol=1e-12)


def test_rectification_puts_a_point_on_one_row_with_the_right_disparity(excerpt: Path) -> None:
    _check_rectification(
        read_camera_sensor(excerpt / "mav0" / "cam0" / "sensor.yaml"),
        read_camera_sensor(excerpt / "mav0" / "cam1" / "sensor.yaml"),
    )


def test_equidistant_rectification_has_the_same_geometry() -> None:
    """A synthetic fisheye pair (Kalibr's equidistant model) 0.12 m apart, slightly toed in."""
    from slamcli.geometry.se3 import make_pose, so3_exp

    cam = PinholeCamera(640, 480, 380.0, 381.0, 321.0, 238.0)
    coeffs = (-0.01, 0.004, -0.002, 0.0005)
    left = CameraSensor(Path("cam0.yaml"), cam, EQUIDISTANT, coeffs, np.eye(4))
    body_from_right = make_pose(so3_exp([0.01, -0.02, 0.005]), [0.12, 0.003, -0.002])
    right = CameraSensor(Path("cam1.yaml"), cam, EQUIDISTANT, coeffs, body_from_right)
    assert rectify_stereo(left, right).rig.baseline_m == pytest.approx(
        np.linalg.norm([0.12, 0.003, -0.002]), rel=1e-9
    )
    _check_rectification(left, right)


def test_swapped_cameras_are_refused(excerpt: Path) -> None:
    cam0 = read_camera_sensor(excerpt / "mav0" / "cam0" / "sensor.yaml")
    cam1 = read_camera_sensor(excerpt / "mav0" / "cam1" / "sensor.yaml")
    with pytest.raises(InputError, match="not to the right"):
        rectify_stereo(cam1, cam0)


def test_rectified_rows_are_aligned_on_real_images(source: EurocSource) -> None:
    import cv2

    frames = [f for f in source.frames(("stereo",)) if isinstance(f, StereoFrame)]
    frame = frames[40]
    orb = cv2.ORB_create(nfeatures=1500)
    kl, dl = orb.detectAndCompute(frame.left, None)
    kr, dr = orb.detectAndCompute(frame.right, None)
    matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(dl, dr)
    good = [m for m in matches if m.distance < 40]
    assert len(good) > 100
    pl = np.array([kl[m.queryIdx].pt for m in good])
    pr = np.array([kr[m.trainIdx].pt for m in good])
    dy = np.abs(pl[:, 1] - pr[:, 1])
    assert float(np.median(dy)) < 1.0
    # Most matches lie left in the right image (positive disparity), as a rig to the right has.
    assert np.mean(pl[:, 0] - pr[:, 0] > 0) > 0.9


def test_imu_rate_and_noise_settings(source: EurocSource) -> None:
    info = source.info()
    imu = next(s for s in info.streams if s.kind == "imu")
    assert imu.count == 29120
    assert imu.rate_hz == pytest.approx(200.0, rel=0.01)
    noise = info.details["imu"]
    assert noise["rate_hz"] == 200.0
    assert noise["gyroscope_noise_density"] == pytest.approx(1.6968e-04)
    assert noise["gyroscope_random_walk"] == pytest.approx(1.9393e-05)
    assert noise["accelerometer_noise_density"] == pytest.approx(2.0e-3)
    assert noise["accelerometer_random_walk"] == pytest.approx(3.0e-3)
    assert "pass --groundtruth" in info.details["groundtruth"]
    assert any("4 listed image(s) missing" in p for p in info.problems)
    assert info.frames == 95 and info.groundtruth == 0


def test_imu_frames_keep_the_csv_columns(source: EurocSource) -> None:
    first = next(iter(source.frames(("imu",))))
    assert isinstance(first, ImuFrame) and first.stamp_ns == FIRST_STAMP
    assert first.gyro_radps is not None and first.accel_mps2 is not None
    np.testing.assert_allclose(
        first.gyro_radps, [-0.0020943951023931952, 0.017453292519943295, 0.07749261878854824]
    )
    np.testing.assert_allclose(
        first.accel_mps2, [9.0874956666666655, 0.13075533333333333, -3.6938381666666662]
    )
    # The drone sits still: the accelerometer reads gravity.
    assert np.linalg.norm(first.accel_mps2) == pytest.approx(9.81, abs=0.2)


def excerpt_imu_csv(source: EurocSource) -> Path:
    return source.mav / "imu0" / "data.csv"


def test_stereo_and_imu_interleave_by_stamp(source: EurocSource) -> None:
    frames = list(source.frames(("stereo", "imu")))
    kinds = ["stereo" if isinstance(f, StereoFrame) else "imu" for f in frames]
    stamps = np.array([f.stamp_ns for f in frames])
    # The excerpt's imu0/data.csv covers the whole sequence (29120 samples, 145 s): with the
    # images, the samples over their span and a second after the last are read.
    imu_t = stamps[[k == "imu" for k in kinds]]
    all_t = read_imu_csv(excerpt_imu_csv(source))[0]
    span = (all_t >= FIRST_STAMP) & (all_t <= LAST_PAIR_STAMP + 1_000_000_000)
    assert kinds.count("stereo") == 95 and kinds.count("imu") == int(span.sum()) == 1141
    np.testing.assert_array_equal(imu_t, all_t[span])
    assert np.all(np.diff(stamps) >= 0)
    # The first image and the first IMU sample share a stamp: the IMU sample comes first.
    assert kinds[:2] == ["imu", "stereo"] and stamps[0] == stamps[1] == FIRST_STAMP
    # Ten IMU samples (200 Hz) between consecutive pairs (20 Hz).
    at = [i for i, k in enumerate(kinds) if k == "stereo"]
    gaps = np.diff(at) - 1
    assert set(gaps.tolist()) <= {9, 10, 11} and int(np.median(gaps)) == 10


def test_sensor_yaml_without_t_bs_names_file_and_key(excerpt: Path, tmp_path: Path) -> None:
    root = _copy(excerpt, tmp_path)
    yaml_path = root / "mav0" / "cam1" / "sensor.yaml"
    text = yaml_path.read_text()
    start = text.index("T_BS:")
    end = text.index("# Camera specific")
    yaml_path.write_text(text[:start] + text[end:])
    with pytest.raises(FormatError, match=r"cam1/sensor\.yaml: missing key 'T_BS'") as err:
        EurocSource(root)
    assert err.value.path == yaml_path


def test_sensor_yaml_with_a_bad_value_names_the_key(excerpt: Path, tmp_path: Path) -> None:
    root = _copy(excerpt, tmp_path)
    yaml_path = root / "mav0" / "cam0" / "sensor.yaml"
    text = yaml_path.read_text().replace("[458.654, 457.296, 367.215, 248.375]", "[458.654, 1]")
    yaml_path.write_text(text)
    with pytest.raises(FormatError, match=r"cam0/sensor\.yaml: key 'intrinsics': expected a list"):
        EurocSource(root)


def test_malformed_data_csv_names_the_line(excerpt: Path, tmp_path: Path) -> None:
    root = _copy(excerpt, tmp_path)
    csv = root / "mav0" / "cam0" / "data.csv"
    lines = csv.read_text().splitlines()
    lines[3] = "14037152733.5,x.png"
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(FormatError, match=r"cam0/data\.csv:4: timestamp '14037152733\.5'"):
        EurocSource(root)


def test_a_pair_of_another_size_is_skipped_and_counted(
    excerpt: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    import cv2

    root = _copy(excerpt, tmp_path)
    name = "1403715273512143104.png"
    target = root / "mav0" / "cam1" / "data" / name
    image = cv2.imread(str(target), cv2.IMREAD_UNCHANGED)
    target.unlink()
    cv2.imwrite(str(target), cv2.resize(image, (640, 480)))
    with EurocSource(root) as src, caplog.at_level(logging.WARNING):
        frames = list(src.frames(("stereo",)))
        assert len(frames) == 94
        assert all(name not in f.name for f in frames if isinstance(f, StereoFrame))
        assert src.stats.skipped == 1 and name in src.stats.skipped_names[0]
        info = src.info(deep=True)
    assert any(name in r.getMessage() and "752x480" in r.getMessage() for r in caplog.records)
    assert any(f"cam1/data/{name} is 640x480" in p for p in info.problems)


def test_groundtruth_csv_in_mav0_is_read(excerpt: Path, tmp_path: Path) -> None:
    root = _copy(excerpt, tmp_path)
    folder = root / "mav0" / "state_groundtruth_estimate0"
    folder.mkdir()
    rows = [
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
        "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], b_w_RS_S_x, "
        "b_w_RS_S_y, b_w_RS_S_z, b_a_RS_S_x, b_a_RS_S_y, b_a_RS_S_z",
        f"{FIRST_STAMP},0.8789,2.1834,0.9484,0.0694,-0.8242,-0.1069,-0.5517" + ",0" * 9,
        f"{FIRST_STAMP + 5_000_000},0.8790,2.1835,0.9483,0.0694,-0.8242,-0.1069,-0.5517" + ",0" * 9,
    ]
    (folder / "data.csv").write_text("\n".join(rows) + "\n")
    with EurocSource(root / "mav0") as src:
        gt = src.groundtruth()
        assert gt is not None and len(gt) == 2
        assert gt.stamps_ns[0] == FIRST_STAMP
        assert gt.positions[1] == pytest.approx([0.8790, 2.1835, 0.9483])
        info = src.info()
    assert info.groundtruth == 2
    assert any(s.name == "groundtruth" for s in info.streams)


def test_open_source_sniffs_the_folder_and_mav0(excerpt: Path, tmp_path: Path) -> None:
    for path in (excerpt, excerpt / "mav0"):
        with open_source(path) as src:
            assert isinstance(src, EurocSource) and len(src) == 95
            assert src.mav == excerpt / "mav0"
    assert not sniff.euroc(excerpt / "mav0" / "cam0")
    assert not sniff.euroc(excerpt / "groundtruth_body.txt")
    lone = tmp_path / "notmav" / "cam0"
    lone.mkdir(parents=True)
    (lone / "data.csv").write_text("#timestamp [ns],filename\n")
    assert not sniff.euroc(tmp_path / "notmav")


def test_a_folder_with_cam0_alone_is_a_monocular_input(excerpt: Path, tmp_path: Path) -> None:
    import cv2

    root = _copy(excerpt, tmp_path)
    shutil.rmtree(root / "mav0" / "cam1")
    src = EurocSource(root)
    sensor = read_camera_sensor(excerpt / "mav0" / "cam0" / "sensor.yaml")
    assert not src.stereo and src.frame_kinds == ("image", "imu")
    assert len(src) == len(src.left_csv) == 95
    frames = list(src.frames())
    assert all(isinstance(f, ImageFrame) for f in frames) and len(frames) == 95
    first = frames[0]
    assert isinstance(first, ImageFrame)
    # The recorded image with its camera as calibrated (distortion and all) and cam0's T_BS.
    recorded = cv2.imread(str(excerpt / "mav0" / "cam0" / "data" / src.left_csv.files[0]), 0)
    assert np.array_equal(first.image, recorded)
    assert first.camera == sensor.camera and first.camera.is_distorted
    assert first.body_from_camera is not None
    np.testing.assert_array_equal(first.body_from_camera, sensor.body_from_sensor)
    kinds = [type(f).__name__ for f in src.frames(("image", "imu"))]
    assert kinds.count("ImuFrame") > 0 and kinds.count("ImageFrame") == 95
    with pytest.raises(InputError, match="has no stereo frames"):
        next(iter(src.frames(("stereo",))))
    with pytest.raises(InputError, match=r"no cam1/data\.csv: no stereo pairs"):
        _ = src.rig
    info = src.info()
    assert [s.name for s in info.streams][:2] == ["cam0", "imu0"]
    assert not any(s.kind == "stereo" for s in info.streams)
    assert info.camera == sensor.camera and "monocular" in info.camera_source
    assert info.problems == []


def test_a_stereo_folder_gives_cam0_alone_as_images(source: EurocSource) -> None:
    frames = list(source.frames(("image",)))
    assert len(frames) == len(source.left_csv)
    assert all(isinstance(f, ImageFrame) and f.camera is not None for f in frames)
    assert frames[0].camera == source.left_sensor.camera
    with pytest.raises(ConfigError, match="stereo pairs or cam0's images, not both"):
        next(iter(source.frames(("stereo", "image"))))


def test_an_equidistant_cam0_is_remapped_to_a_pinhole(excerpt: Path, tmp_path: Path) -> None:
    import cv2

    root = _copy(excerpt, tmp_path)
    shutil.rmtree(root / "mav0" / "cam1")
    yaml_path = root / "mav0" / "cam0" / "sensor.yaml"
    text = yaml_path.read_text().replace("radial-tangential", "equidistant")
    yaml_path.write_text(text)
    src = EurocSource(root)
    raw = src.left_sensor
    assert raw.model == EQUIDISTANT
    frame = next(iter(src.frames()))
    assert isinstance(frame, ImageFrame) and frame.camera is not None
    cam = frame.camera
    assert not cam.is_distorted and (cam.fx, cam.cx) == (raw.camera.fx, raw.camera.cx)
    # A pinhole pixel of the remapped image shows the raw pixel the fisheye model puts there.
    u, v = 600.0, 100.0
    ray = np.array([[[(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy]]])
    d = np.asarray(raw.coefficients, np.float64)
    expected = cv2.fisheye.distortPoints(ray, raw.camera.K, d).reshape(2)
    mx, my = src._fisheye_maps
    np.testing.assert_allclose([mx[int(v), int(u)], my[int(v), int(u)]], expected, atol=0.05)


def test_a_folder_without_cam0_is_refused(excerpt: Path, tmp_path: Path) -> None:
    root = _copy(excerpt, tmp_path)
    shutil.rmtree(root / "mav0" / "cam0")
    with pytest.raises(InputError, match=r"no cam0/data\.csv"):
        EurocSource(root)


def test_a_monocular_run_is_scored_against_the_truth_moved_onto_its_camera(
    tmp_path: Path,
) -> None:
    """A monocular trajectory follows its camera (its map has no metric scale to carry the
    camera's offset on the body): the body's ground truth is moved onto the camera."""
    from scipy.spatial.transform import Rotation

    from slamcli.geometry.se3 import make_pose
    from slamcli.rundir import RunDir, Timings
    from slamcli.scoring import evaluate_run
    from slamcli.types import SlamResult, Trajectory

    t = np.arange(50, dtype=np.int64) * 50_000_000
    rng = np.random.default_rng(0)
    # A body that turns about every axis while it moves: the camera's offset on it moves
    # differently from the body, which no similarity of the whole path undoes.
    turns = Rotation.from_rotvec(rng.normal(0.0, 0.6, (50, 3))).as_matrix()
    body = np.stack(
        [
            make_pose(r, np.array([np.cos(0.1 * i), np.sin(0.1 * i), 0.01 * i]))
            for i, r in enumerate(turns)
        ]
    )
    body_from_camera = make_pose(np.eye(3)[[1, 2, 0]], np.array([0.3, -0.1, 0.05]))
    truth = Trajectory(t, body)
    camera = Trajectory(t, body @ body_from_camera)
    scores = []
    for moved in (body_from_camera, None):
        with RunDir(tmp_path / f"run{moved is None}") as run:
            result = SlamResult(trajectory=camera, truth_to_estimate=moved)
            ev = evaluate_run(truth, result, run, Timings(), "sim3")
        scores.append(ev["evaluation"]["ate"]["rmse"])
    assert scores[0] < 1e-9 < 0.05 < scores[1]


def test_unknown_kinds_are_refused(source: EurocSource) -> None:
    with pytest.raises(InputError, match="has no rgbd frames"):
        next(iter(source.frames(("rgbd",))))


def test_info_checks_the_imu_against_the_camera(tmp_path: Path) -> None:
    """The in-flight excerpt's IMU is clean, and lines up with cam0; the same IMU written in
    deg/s is named as such, with the file."""
    mh05 = shared_path("vi", "euroc_MH05_a")
    clean = EurocSource(mh05).info()
    check = clean.details["imu_check"]
    assert clean.problems == [] and check["gaps"] == 0 and check["uncovered_images"] == 0
    assert abs(check["rate_hz"] - 200.0) < 0.1
    assert check["imu_before_first_image_s"] == pytest.approx(1.0, abs=0.01)
    copy = tmp_path / "mh05"
    shutil.copytree(mh05, copy, symlinks=True)
    csv = copy / "mav0" / "imu0" / "data.csv"
    csv.parent.chmod(0o755)  # the shared data may be read-only, and its copy with it
    rows = csv.read_text().splitlines()
    out = [rows[0]]
    for row in rows[1:]:
        f = row.split(",")
        out.append(",".join([f[0], *(f"{float(v) * 180 / np.pi:.9f}" for v in f[1:4]), *f[4:]]))
    csv.unlink()
    csv.write_text("\n".join(out) + "\n")
    bad = EurocSource(copy).info()
    assert bad.details["imu_check"]["gyro_units_suspect"]
    assert any("mav0/imu0/data.csv" in p and "deg/s" in p for p in bad.problems)
