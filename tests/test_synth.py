"""Synthetic data: rendered RGB-D against analytic geometry, the landmark world, the CLI, and
the committed sample data against a fresh regeneration."""

from __future__ import annotations

import hashlib
import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError, ExportError
from slamcli.formats.text import iter_data_lines, parse_stamp_ns
from slamcli.geometry import inverse, make_pose, quat_xyzw_to_matrix, rotation_angle
from slamcli.synth import landmarks as lm
from slamcli.synth import rgbd

SAMPLE = Path(__file__).resolve().parents[1] / "sample_data"
# Must match the commands in sample_data/README.md.
SAMPLE_RGBD = {"frames": 30, "size": (320, 240), "seed": 0, "noise": True}
SAMPLE_LANDMARKS = {"seed": 0, "landmarks": 40, "duration_s": 120.0}

runner = CliRunner()


def _look(position: tuple[float, float, float], yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(4, 4) world_from_camera for an optical frame looking along (yaw, pitch), no roll."""
    yaw, pitch = math.radians(yaw_deg), math.radians(pitch_deg)
    forward = np.array(
        [math.cos(pitch) * math.cos(yaw), math.cos(pitch) * math.sin(yaw), math.sin(pitch)]
    )
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return make_pose(np.stack([right, down, forward], axis=1), np.array(position))


def _rays(camera, pose: np.ndarray) -> np.ndarray:
    """World directions (H, W, 3) with unit camera z through every pixel centre."""
    u, v = np.meshgrid(np.arange(camera.width), np.arange(camera.height))
    d = np.stack([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, np.ones(u.shape)], -1)
    return d @ pose[:3, :3].T


@pytest.fixture(scope="module")
def world() -> rgbd.RgbdWorld:
    return rgbd.build_rgbd_world(30, (160, 120), seed=0)


def _surface(world: rgbd.RgbdWorld, name: str) -> int:
    return [s.name for s in world.scene.surfaces].index(name)


@pytest.mark.parametrize(
    ("name", "position", "yaw", "pitch", "axis", "plane"),
    [
        ("floor", (-0.5, 0.2, 1.3), 10.0, -60.0, 2, 0.0),
        ("wall+x", (0.0, -0.3, 1.9), 5.0, 12.0, 0, 3.0),
        ("wall-y", (-0.5, 0.0, 1.4), -95.0, 0.0, 1, -2.5),
        ("ceiling", (0.0, 0.0, 1.2), 30.0, 70.0, 2, 2.6),
    ],
)
def test_depth_equals_ray_plane_intersection(world, name, position, yaw, pitch, axis, plane):
    pose = _look(position, yaw, pitch)
    depth, sid = world.cast(pose)
    on = sid == _surface(world, name)
    assert on.mean() > 0.5
    d = _rays(world.camera, pose)
    expected = (plane - pose[axis, 3]) / d[..., axis]
    np.testing.assert_allclose(depth[on], expected[on], rtol=2e-6, atol=2e-6)


def test_written_depth_and_groundtruth_match_the_generator(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    summary = rgbd.render_rgbd_sequence(out, frames=4, size=(64, 48), seed=3)
    assert summary["frames"] == 4
    w = rgbd.build_rgbd_world(4, (64, 48), seed=3)

    rows = list(iter_data_lines(out / "groundtruth.txt"))
    stamps = np.array([parse_stamp_ns(f[0], "gt", n) for n, f in rows])
    values = np.array([[float(x) for x in f[1:]] for _, f in rows])
    np.testing.assert_array_equal(stamps, w.trajectory.stamps_ns)
    poses = make_pose(quat_xyzw_to_matrix(values[:, 3:]), values[:, :3])
    np.testing.assert_allclose(poses, w.trajectory.world_from_body, atol=1e-6)

    depth_rows = list(iter_data_lines(out / "depth.txt"))
    assert [parse_stamp_ns(f[0], "d", n) for n, f in depth_rows] == list(
        w.trajectory.stamps_ns + rgbd.DEPTH_OFFSET_NS
    )
    raw = cv2.imread(str(out / depth_rows[2][1][1]), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16 and raw.shape == (48, 64)
    clean, _ = w.cast(w.trajectory.world_from_body[2])
    valid = raw > 0
    assert valid.all()
    np.testing.assert_allclose(raw / 5000.0, clean, atol=0.5 / 5000 + 1e-6)

    rgb = cv2.imread(str(out / list(iter_data_lines(out / "rgb.txt"))[2][1][1]))
    expected_rgb, _ = w.render(w.trajectory.world_from_body[2])
    np.testing.assert_array_equal(cv2.cvtColor(rgb, cv2.COLOR_BGR2RGB), expected_rgb)


def test_camera_file_is_readable_by_the_tum_reader(tmp_path: Path) -> None:
    pytest.importorskip("yaml")
    from slamcli.formats.camera import load_camera_file

    rgbd.render_rgbd_sequence(tmp_path, frames=2, size=(64, 48))
    cam = load_camera_file(tmp_path / "camera.yaml")
    assert cam.camera == rgbd.camera_for_size(64, 48)
    assert cam.depth_factor == 5000


def _digests(folder: Path) -> dict[str, str]:
    return {
        p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def test_same_seed_same_bytes_other_seed_other_images(tmp_path: Path) -> None:
    options = {"frames": 3, "size": (64, 48), "noise": True}
    rgbd.render_rgbd_sequence(tmp_path / "a", seed=5, **options)
    rgbd.render_rgbd_sequence(tmp_path / "b", seed=5, **options)
    rgbd.render_rgbd_sequence(tmp_path / "c", seed=6, **options)
    a, b, c = (_digests(tmp_path / k) for k in "abc")
    assert a == b
    assert len(a) == 3 * 2 + 5
    assert all(a[k] != c[k] for k in a if k.endswith(".png"))


def test_noise_makes_holes_and_bounded_errors(world) -> None:
    pose = world.trajectory.world_from_body[0]
    _, clean = world.render(pose)
    _, noisy = world.render(pose, np.random.default_rng(0))
    holes = (noisy == 0) & (clean > 0)
    assert 0.005 < holes.mean() < 0.2
    both = (noisy > 0) & (clean > 0)
    z = clean[both].astype(np.float64)
    # Five sigma of the disparity noise plus one disparity step, mapped to depth.
    bound = z**2 * (5 * 0.07 + 0.125) / (580.0 * 0.075) + 1e-4
    err = np.abs(noisy[both] - z)
    assert np.all(err <= bound)
    assert 0.0 < np.median(err) < 0.02


def test_orb_finds_hundreds_of_features_on_a_qvga_frame() -> None:
    w = rgbd.build_rgbd_world(90, (320, 240), seed=0)
    orb = cv2.ORB_create(nfeatures=2000)
    for i in (0, 45):
        rgb, _ = w.render(w.trajectory.world_from_body[i], np.random.default_rng(1))
        keypoints = orb.detect(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY))
        assert len(keypoints) >= 400


@pytest.mark.parametrize("frames", [10, 90, 300, 600])
def test_path_closes_at_handheld_speeds(frames: int) -> None:
    traj = rgbd.camera_path(frames)
    poses = traj.world_from_body
    gap = inverse(poses[0]) @ poses[-1]
    assert np.linalg.norm(gap[:3, 3]) < 0.03
    assert math.degrees(rotation_angle(gap)) < 2.0
    dt = 1.0 / 30.0
    speed = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1) / dt
    turn = rotation_angle(np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])) / dt
    assert speed.max() < 0.5
    assert math.degrees(turn.max()) < 40.0
    # The camera stays inside the room and far enough from every surface to have depth.
    assert np.all(traj.positions > rgbd.ROOM_MIN + 1.0)
    assert np.all(traj.positions < rgbd.ROOM_MAX - 1.0)


def test_accelerometer_reads_gravity_plus_motion() -> None:
    traj = rgbd.camera_path(90)
    acc = rgbd.accelerometer(90)
    up_in_cam = np.einsum("nji,j->ni", traj.world_from_body[:, :3, :3], [0.0, 0.0, 9.80665])
    motion = np.linalg.norm(acc - up_in_cam, axis=1)
    assert motion.max() < 2.0
    assert motion.max() > 0.1


def test_bad_options_raise_config_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="frames"):
        rgbd.build_rgbd_world(1, (64, 48))
    with pytest.raises(ConfigError, match="size"):
        rgbd.build_rgbd_world(5, (0, 48))
    (tmp_path / "keep.txt").write_text("x")
    with pytest.raises(ExportError, match="not empty"):
        rgbd.render_rgbd_sequence(tmp_path, frames=2, size=(32, 24))


def test_force_replaces_images_of_an_earlier_run(tmp_path: Path) -> None:
    rgbd.render_rgbd_sequence(tmp_path, frames=4, size=(32, 24))
    rgbd.render_rgbd_sequence(tmp_path, frames=2, size=(32, 24), force=True)
    assert len(list((tmp_path / "rgb").iterdir())) == 2
    assert len(list((tmp_path / "depth").iterdir())) == 2


# Landmark world


def test_noiseless_observations_equal_the_geometry() -> None:
    sensor = lm.LandmarkSensor().noiseless()
    w = lm.simulate_landmark_world(seed=1, landmarks=30, duration_s=60.0, sensor=sensor)
    assert np.all((w.meas_ids >= 0) & (w.meas_ids < 30))
    pose = w.poses[w.meas_index]
    rel = w.landmarks[w.meas_ids] - pose[:, :2]
    np.testing.assert_allclose(w.meas_range, np.hypot(rel[:, 0], rel[:, 1]), rtol=0, atol=1e-12)
    bearing_err = np.angle(
        np.exp(1j * (np.arctan2(rel[:, 1], rel[:, 0]) - pose[:, 2] - w.meas_bearing))
    )
    assert np.abs(bearing_err).max() < 1e-12
    assert np.all(w.meas_range <= sensor.max_range)
    assert np.all(np.abs(w.meas_bearing) <= sensor.fov / 2)
    np.testing.assert_array_equal(w.odometry, w.controls)
    # Every landmark in range and view is reported when detection is certain.
    k = w.meas_index[0]
    rel_all = w.landmarks - w.poses[k, :2]
    b_all = np.angle(np.exp(1j * (np.arctan2(rel_all[:, 1], rel_all[:, 0]) - w.poses[k, 2])))
    seen = (np.hypot(*rel_all.T) <= sensor.max_range) & (np.abs(b_all) <= sensor.fov / 2)
    np.testing.assert_array_equal(np.flatnonzero(seen), w.meas_ids[w.meas_index == k])


def test_robot_loop_closes_and_landmarks_keep_clear() -> None:
    w = lm.simulate_landmark_world(seed=2, landmarks=40, duration_s=52.0)
    np.testing.assert_allclose(w.poses[-1, :2], w.poses[0, :2], atol=1e-9)
    assert math.isclose(w.poses[-1, 2] - w.poses[0, 2], 2 * math.pi, abs_tol=1e-9)
    gaps = np.linalg.norm(w.landmarks[:, None] - w.landmarks[None], axis=2)
    assert gaps[~np.eye(40, dtype=bool)].min() >= 1.0
    to_path = np.linalg.norm(w.landmarks[:, None] - w.poses[None, :, :2], axis=2).min(axis=1)
    assert to_path.min() >= 1.0
    assert np.all(np.bincount(w.meas_ids, minlength=40) > 0)


def test_odometry_errors_follow_the_model() -> None:
    w = lm.simulate_landmark_world(seed=4, duration_s=300.0)
    straight = w.controls[:, 1] == 0
    ratio = w.odometry[straight, 0] / w.controls[straight, 0]
    assert abs(ratio.mean() - w.odometry_scale[0]) < 0.01
    assert (
        abs(np.std(w.odometry[straight, 0] - w.controls[straight, 0] * w.odometry_scale[0]) - 0.05)
        < 0.01
    )


def test_landmark_files_round_trip(tmp_path: Path) -> None:
    summary = lm.generate_landmark_world(tmp_path, seed=7, landmarks=12, duration_s=20.0)
    w = lm.simulate_landmark_world(seed=7, landmarks=12, duration_s=20.0)
    names = sorted(Path(f).name for f in summary["files"])
    assert names == sorted(
        ["odometry.csv", "measurements.csv", "groundtruth.tum", "landmarks.csv", "world.json"]
    )
    meas = np.loadtxt(tmp_path / "measurements.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(meas) == summary["measurements"] == len(w.meas_ids)
    np.testing.assert_array_equal(meas[:, 1].astype(int), w.meas_ids)
    np.testing.assert_allclose(meas[:, 2], w.meas_range, atol=1e-6)
    odo = np.loadtxt(tmp_path / "odometry.csv", delimiter=",", skiprows=1, ndmin=2)
    assert len(odo) == 400
    np.testing.assert_allclose(np.diff(odo[:, 0]), 0.05, atol=1e-5)
    gt = np.loadtxt(tmp_path / "groundtruth.tum")
    assert len(gt) == 401
    np.testing.assert_allclose(gt[:, 1:3], w.poses[:, :2], atol=1e-6)
    marks = np.loadtxt(tmp_path / "landmarks.csv", delimiter=",", skiprows=1)
    np.testing.assert_allclose(marks[:, 1:], w.landmarks, atol=1e-6)


def test_landmark_world_rejects_bad_settings(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="landmarks"):
        lm.simulate_landmark_world(landmarks=0)
    with pytest.raises(ConfigError, match="landmarks"):
        lm.simulate_landmark_world(landmarks=5000)
    with pytest.raises(ConfigError, match="duration"):
        lm.simulate_landmark_world(duration_s=0.0)


# CLI


def test_cli_synth_rgbd_writes_a_tum_folder(tmp_path: Path) -> None:
    out = tmp_path / "seq"
    res = runner.invoke(app, ["synth", "rgbd", str(out), "--frames", "3", "--size", "64x48"])
    assert res.exit_code == 0, res.output
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "accelerometer.txt", "camera.yaml"):
        assert (out / name).is_file()
    assert len(list((out / "rgb").glob("*.png"))) == 3
    assert "Written" in res.stdout

    again = runner.invoke(app, ["synth", "rgbd", str(out), "--frames", "3", "--size", "64x48"])
    assert again.exit_code == 1
    assert "not empty" in again.stderr
    assert again.stderr.splitlines()[0].startswith("error:")
    assert len([ln for ln in again.stderr.splitlines() if ln.startswith("error:")]) == 1

    forced = runner.invoke(
        app, ["synth", "rgbd", str(out), "--frames", "2", "--size", "64x48", "--force"]
    )
    assert forced.exit_code == 0, forced.output


@pytest.mark.parametrize("size", ["abc", "0x5", "640", "64x48x3", "-64x48"])
def test_cli_bad_size_exits_1_naming_the_option(tmp_path: Path, size: str) -> None:
    res = runner.invoke(app, ["synth", "rgbd", str(tmp_path / "x"), "--size", size])
    assert res.exit_code == 1
    assert "--size" in res.stderr
    assert not (tmp_path / "x").exists()


def test_cli_synth_landmarks(tmp_path: Path) -> None:
    res = runner.invoke(
        app, ["synth", "landmarks", str(tmp_path / "w"), "--landmarks", "10", "--duration", "15"]
    )
    assert res.exit_code == 0, res.output
    assert (tmp_path / "w" / "measurements.csv").is_file()


# Committed sample data
#
# A regeneration is bit-identical on the machine that made it (test_same_seed_same_bytes_* and
# test_regeneration_is_bit_identical_on_this_machine). Across CPUs and library builds the
# renderer's floating-point rounding differs (vectorised sin/cos/exp, OpenCV's resampling), so
# the committed files are compared with these tolerances, stated once here and in
# sample_data/README.md:
#
# - colour: no channel differs by more than COLOUR_LEVELS, and at most PIXEL_FRACTION of the
#   pixels of a frame differ at all;
# - depth: at most PIXEL_FRACTION of the pixels of a frame differ by more than DEPTH_M (a pixel
#   on a depth edge may see the other surface, so its difference is not bounded);
# - text: the same words; every number equal to within one unit of its last printed digit (and
#   a relative 1e-12 for numbers printed at full precision).
COLOUR_LEVELS = 1
DEPTH_M = 0.001
PIXEL_FRACTION = 0.001
SAMPLE_DEPTH_FACTOR = 5000.0

_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _text_differences(fresh: str, committed: str) -> list[str]:
    """Where two text files differ beyond the stated tolerance (empty when they agree)."""
    problems = []
    fresh_lines, committed_lines = fresh.splitlines(), committed.splitlines()
    if len(fresh_lines) != len(committed_lines):
        return [f"{len(fresh_lines)} lines, committed {len(committed_lines)}"]
    for lineno, (a, b) in enumerate(zip(fresh_lines, committed_lines, strict=True), start=1):
        if _NUMBER.sub("#", a) != _NUMBER.sub("#", b):
            problems.append(f"line {lineno}: {a!r} != {b!r}")
            continue
        for x, y in zip(_NUMBER.findall(a), _NUMBER.findall(b), strict=True):
            mantissa = y.lower().split("e")[0]
            decimals = len(mantissa.split(".")[1]) if "." in mantissa else 0
            significant = len(mantissa.replace("-", "").replace(".", "").lstrip("0"))
            tol = 1e-12 * abs(float(y)) if significant >= 15 else 10.0**-decimals * 1.000001
            if "e" in y.lower() and significant < 15:
                tol *= 10.0 ** int(y.lower().split("e")[1])
            if abs(float(x) - float(y)) > tol:
                problems.append(f"line {lineno}: {x} != {y} (tolerance {tol:g})")
    return problems


def _image_differences(fresh: Path, committed: Path, kind: str) -> list[str]:
    a = cv2.imread(str(fresh), cv2.IMREAD_UNCHANGED)
    b = cv2.imread(str(committed), cv2.IMREAD_UNCHANGED)
    if a is None or b is None or a.shape != b.shape or a.dtype != b.dtype:
        return [f"{committed.name}: cannot compare (shape or type differs)"]
    pixels = a.shape[0] * a.shape[1]
    diff = np.abs(a.astype(np.int64) - b.astype(np.int64))
    if kind == "depth":
        bad = int(np.count_nonzero(diff > DEPTH_M * SAMPLE_DEPTH_FACTOR))
        if bad > PIXEL_FRACTION * pixels:
            return [f"{committed.name}: {bad} of {pixels} depth pixels differ by > {DEPTH_M} m"]
        return []
    per_pixel = diff.max(axis=-1)
    if per_pixel.max() > COLOUR_LEVELS:
        return [f"{committed.name}: a colour differs by {per_pixel.max()} levels"]
    changed = int(np.count_nonzero(per_pixel))
    if changed > PIXEL_FRACTION * pixels:
        return [f"{committed.name}: {changed} of {pixels} colour pixels differ"]
    return []


def _sample_differences(fresh: Path, committed: Path) -> list[str]:
    """Files that differ beyond the stated tolerances between a regeneration and the sample."""
    names = sorted(p.relative_to(committed).as_posix() for p in committed.rglob("*") if p.is_file())
    fresh_names = sorted(p.relative_to(fresh).as_posix() for p in fresh.rglob("*") if p.is_file())
    if names != fresh_names:
        return [f"file lists differ: {sorted(set(names) ^ set(fresh_names))[:5]}"]
    problems = []
    for name in names:
        a, b = fresh / name, committed / name
        if name.endswith(".png"):
            problems += _image_differences(a, b, "depth" if name.startswith("depth") else "rgb")
        else:
            problems += [f"{name} {p}" for p in _text_differences(a.read_text(), b.read_text())]
    return problems


def _content_digests(folder: Path) -> dict[str, str]:
    """sha256 per file; PNGs are hashed by their decoded pixels, so a different zlib or libpng
    build (which may compress the same pixels to other bytes) does not count as a change."""
    out = {}
    for p in sorted(folder.rglob("*")):
        if not p.is_file():
            continue
        if p.suffix == ".png":
            img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            data = str(img.dtype).encode() + str(img.shape).encode() + img.tobytes()
        else:
            data = p.read_bytes()
        out[p.relative_to(folder).as_posix()] = hashlib.sha256(data).hexdigest()
    return out


def test_regeneration_is_bit_identical_on_this_machine(tmp_path: Path) -> None:
    options = {**SAMPLE_RGBD, "frames": 4}
    rgbd.render_rgbd_sequence(tmp_path / "a", **options)
    rgbd.render_rgbd_sequence(tmp_path / "b", **options)
    assert _content_digests(tmp_path / "a") == _content_digests(tmp_path / "b")
    lm.generate_landmark_world(tmp_path / "la", **SAMPLE_LANDMARKS)
    lm.generate_landmark_world(tmp_path / "lb", **SAMPLE_LANDMARKS)
    assert _digests(tmp_path / "la") == _digests(tmp_path / "lb")


def test_committed_rgbd_sample_matches_a_fresh_regeneration(tmp_path: Path) -> None:
    committed = SAMPLE / "rgbd_room"
    if not (committed / "rgb.txt").is_file():
        pytest.fail(f"{committed} is missing; regenerate it with the command in its README")
    rgbd.render_rgbd_sequence(tmp_path / "rgbd_room", **SAMPLE_RGBD)
    assert _sample_differences(tmp_path / "rgbd_room", committed) == []


def test_committed_landmark_sample_matches_a_fresh_regeneration(tmp_path: Path) -> None:
    committed = SAMPLE / "landmarks"
    lm.generate_landmark_world(tmp_path / "landmarks", **SAMPLE_LANDMARKS)
    assert _sample_differences(tmp_path / "landmarks", committed) == []


def test_sample_comparison_catches_changes_beyond_the_tolerance(tmp_path: Path) -> None:
    fresh, committed = tmp_path / "fresh", tmp_path / "committed"
    for folder in (fresh, committed):
        (folder / "rgb").mkdir(parents=True)
        (folder / "depth").mkdir()
    rng = np.random.default_rng(0)
    colour = rng.integers(10, 240, size=(100, 100, 3), dtype=np.uint8)
    depth = rng.integers(1000, 20000, size=(100, 100), dtype=np.uint16)
    cv2.imwrite(str(committed / "rgb" / "0.png"), colour)
    cv2.imwrite(str(committed / "depth" / "0.png"), depth)
    (committed / "gt.txt").write_text("# t x\n1.000000 0.123456\n")

    def write_fresh(colour_img: np.ndarray, depth_img: np.ndarray, text: str) -> list[str]:
        cv2.imwrite(str(fresh / "rgb" / "0.png"), colour_img)
        cv2.imwrite(str(fresh / "depth" / "0.png"), depth_img)
        (fresh / "gt.txt").write_text(text)
        return _sample_differences(fresh, committed)

    within = colour.copy()
    within[:3, :3] += 1  # 9 pixels of 10,000 by one level: inside 0.1 %
    deep = depth.copy()
    deep[0, :9] += 1000  # 9 depth pixels by 0.2 m (edges), the rest exact
    deep[1:, :] += 4  # every other pixel by 0.8 mm
    assert write_fresh(within, deep, "# t x\n1.000000 0.123457\n") == []

    two_levels = colour.copy()
    two_levels[0, 0] += 2
    assert write_fresh(two_levels, depth, "# t x\n1.000000 0.123456\n")
    many = colour.copy()
    many[:11, :11] += 1  # 121 pixels: more than 0.1 %
    assert write_fresh(many, depth, "# t x\n1.000000 0.123456\n")
    far = depth.copy()
    far[:2, :] += 6  # 200 pixels by 1.2 mm
    assert write_fresh(colour, far, "# t x\n1.000000 0.123456\n")
    assert write_fresh(colour, depth, "# t x\n1.000000 0.123458\n")
    assert write_fresh(colour, depth, "# t y\n1.000000 0.123456\n")
