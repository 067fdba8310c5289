"""A synthetic stereo rig with an IMU and exact ground truth, written as a EuRoC / ASL folder.

The scene is the textured room of :mod:`slamcli.synth.rgbd`, rendered the same way (Open3D ray
casting, 2x2 sub-pixel rays, mip-mapped textures, a static light) into 8-bit grey images. Two
pinhole cameras with equal intrinsics (``fx = fy = 0.8 * width``, principal point at the image
centre, no distortion) sit ``baseline`` metres apart along the left camera's x axis, so the pair
is rectified as rendered: a point at depth ``z`` shows on the same row in both images,
``fx * baseline / z`` pixels further left in the right one.

The left camera follows the closed loop of synth rgbd (:func:`slamcli.synth.rgbd.camera_path`)
at 20 Hz (EuRoC's rate), or at another rate ``fps`` that divides the IMU's 200 Hz (10 Hz as
KITTI's cameras): the loop's phase runs once over the sequence, so the last pair sits one step
before the first and loop closure has a place to find; sequences of 18 s (360 pairs at 20 Hz)
or more turn once around the room, whatever the rate. The body is the IMU's frame, as in EuRoC:
the left camera sits on it at :data:`BODY_FROM_LEFT`, a few centimetres off with EuRoC's
90-degree turn about the optical axis and a slight tilt, so body-frame evaluation is exercised;
the IMU's ``T_BS`` is the identity.

The IMU reads the exact motion of the body at 200 Hz, from the first pair's stamp to the last
one's (a sample at every pair's stamp): the gyroscope the body's angular velocity in rad/s, the
accelerometer the specific force ``R_wb^T (a_w - g_w)`` in m/s^2 with ``g_w = (0, 0, -9.80665)``,
so a body at rest reads +9.81 m/s^2 along the world's up direction. Both are in the body frame.

With ``noise=True`` each image gets Gaussian grey-level noise of its own (sigma 1, as synth
rgbd's colour noise) and the right image a brightness offset of +4 grey levels; the IMU gets
white noise at the densities its ``sensor.yaml`` lists and biases that start at seeded values
and random-walk at the listed rates. The ground truth records those biases (zero without
noise).

Folder layout (EuRoC's)::

    mav0/cam0/data.csv, mav0/cam1/data.csv   "#timestamp [ns],filename", one line per image
    mav0/cam0/data/<ns>.png, mav0/cam1/...    (H, W) 8-bit grey
    mav0/cam0/sensor.yaml, mav0/cam1/...      T_BS (body_from_sensor), rate_hz, resolution,
                                              intrinsics, radial-tangential, zero coefficients
    mav0/imu0/data.csv     t [ns], w_x w_y w_z [rad/s], a_x a_y a_z [m/s^2]
    mav0/imu0/sensor.yaml  T_BS (identity), rate_hz, noise densities and random walks
    mav0/state_groundtruth_estimate0/data.csv   t [ns], p xyz [m], q wxyz, v xyz [m/s],
                                                gyro bias xyz [rad/s], accel bias xyz [m/s^2]:
                                                world_from_body at every IMU stamp

Stamps start at 1700000000 s; both images of a pair carry the same stamp.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, ExportError
from slamcli.geometry import (
    inverse,
    make_pose,
    matrix_to_quat_wxyz,
    rotation_angle,
    so3_exp,
    so3_log,
)
from slamcli.rundir import RunDir
from slamcli.synth.rgbd import (
    EPOCH_NS,
    GRAVITY_MPS2,
    RgbdWorld,
    camera_for_size,
    camera_path,
    path_motion,
    room_scene,
)
from slamcli.types import PinholeCamera, ProgressFn, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

FPS = 20.0
"""Default stereo pair rate in Hz (EuRoC's)."""
IMU_RATE_HZ = 200.0
"""IMU sample rate in Hz (EuRoC's); a whole multiple of every pair rate, so that a sample falls
on every pair's stamp."""
DEFAULT_BASELINE_M = 0.12
MAX_BASELINE_M = 0.5

BODY_FROM_LEFT: F64 = make_pose(
    so3_exp(np.array([0.0, 0.0, math.pi / 2])) @ so3_exp(np.array([0.0040, 0.0257, -0.0149])),
    np.array([-0.0216, -0.0647, 0.0098]),
)
"""(4, 4) pose of the left camera on the body (cam0's ``T_BS``): EuRoC's mounting, rounded."""

GYRO_NOISE_DENSITY = 1.6968e-4
"""rad / s / sqrt(Hz), EuRoC's ADIS16448 figures, as are the three below."""
GYRO_RANDOM_WALK = 1.9393e-5
"""rad / s^2 / sqrt(Hz)."""
ACCEL_NOISE_DENSITY = 2.0e-3
"""m / s^2 / sqrt(Hz)."""
ACCEL_RANDOM_WALK = 3.0e-3
"""m / s^3 / sqrt(Hz)."""

_GYRO_BIAS_SIGMA = 0.003
_ACCEL_BIAS_SIGMA = 0.03
_GREY_SIGMA = 1.0
_RIGHT_OFFSET = 4.0
_STEP_S = 1e-3
"""Time step of the central differences that give velocity, angular velocity and the lever
arm's acceleration (their error is far below the written precision)."""
_RNG_LEFT, _RNG_RIGHT, _RNG_IMU = 11, 12, 13
_PNG_COMPRESSION = 6


@dataclass(frozen=True)
class ImuTrack:
    """The IMU's samples and the true state of the body at each of them.

    Attributes:
        stamps_ns: (M,) int64, at :data:`IMU_RATE_HZ`.
        gyro_radps: (M, 3) measured angular velocity, body frame.
        accel_mps2: (M, 3) measured specific force, body frame.
        world_from_body: (M, 4, 4) true poses.
        velocity_mps: (M, 3) true velocity of the body in the world.
        gyro_bias: (M, 3) the bias inside ``gyro_radps`` (zero without noise).
        accel_bias: (M, 3) the bias inside ``accel_mps2`` (zero without noise).
    """

    stamps_ns: NDArray[np.int64]
    gyro_radps: F64
    accel_mps2: F64
    world_from_body: F64
    velocity_mps: F64
    gyro_bias: F64
    accel_bias: F64


@dataclass
class StereoWorld:
    """Everything needed to render the sequence: the room, the rig and the camera poses.

    Attributes:
        room: scene, camera (both images' intrinsics) and the left camera's poses
            (``room.trajectory``: world_from_left at the pair stamps).
        baseline_m: distance between the two optical centres along the left camera's x axis.
        body_from_left: (4, 4) pose of the left camera on the body.
        fps: stereo pairs per second.
    """

    room: RgbdWorld
    baseline_m: float
    body_from_left: F64
    fps: float = FPS

    @property
    def camera(self) -> PinholeCamera:
        """The intrinsics of both cameras."""
        return self.room.camera

    @property
    def frames(self) -> int:
        """Number of stereo pairs."""
        return len(self.room.trajectory)

    @property
    def stamps_ns(self) -> NDArray[np.int64]:
        """(N,) int64 stamps of the pairs."""
        return self.room.trajectory.stamps_ns

    @property
    def left_from_right(self) -> F64:
        """(4, 4) pose of the right camera in the left camera's frame."""
        return make_pose(np.eye(3), np.array([self.baseline_m, 0.0, 0.0]))

    def world_from_left(self) -> F64:
        """(N, 4, 4) poses of the left camera at the pair stamps."""
        return self.room.trajectory.world_from_body

    def world_from_right(self) -> F64:
        """(N, 4, 4) poses of the right camera at the pair stamps."""
        return self.world_from_left() @ self.left_from_right

    def body_trajectory(self) -> Trajectory:
        """world_from_body at the pair stamps."""
        return Trajectory(self.stamps_ns, self.world_from_left() @ inverse(self.body_from_left))

    def render_pair(
        self,
        i: int,
        left_rng: np.random.Generator | None = None,
        right_rng: np.random.Generator | None = None,
    ) -> tuple[NDArray[np.uint8], NDArray[np.uint8]]:
        """Grey (H, W) uint8 left and right images of pair ``i``.

        Args:
            i: pair index.
            left_rng, right_rng: each camera's noise generator; None renders it without noise
                (and, for the right camera, without the brightness offset).
        """
        world_from_left = self.world_from_left()[i]
        views = (
            (world_from_left, left_rng, 0.0),
            (world_from_left @ self.left_from_right, right_rng, _RIGHT_OFFSET),
        )
        out: list[NDArray[np.uint8]] = []
        for pose, rng, offset in views:
            grey = _grey(self.room.render_colour(pose))
            if rng is not None:
                grey += rng.normal(0.0, _GREY_SIGMA, grey.shape).astype(np.float32) + offset
            out.append(np.clip(np.rint(grey), 0, 255).astype(np.uint8))
        return out[0], out[1]

    def imu_stamps_ns(self) -> NDArray[np.int64]:
        """(M,) int64 IMU stamps from the first pair to the last, every 5 ms."""
        per_frame = round(IMU_RATE_HZ / self.fps)
        step_ns = round(1e9 / IMU_RATE_HZ)
        count = (self.frames - 1) * per_frame + 1
        return self.stamps_ns[0] + step_ns * np.arange(count, dtype=np.int64)

    def body_motion(self, stamps_ns: NDArray[np.int64]) -> tuple[F64, F64, F64, F64]:
        """The body's exact motion at ``stamps_ns`` (M,).

        Returns:
            world_from_body (M, 4, 4), velocity (M, 3) m/s in the world, angular velocity
            (M, 3) rad/s in the body frame and specific force (M, 3) m/s^2 in the body frame.
        """
        t_s = (np.asarray(stamps_ns, dtype=np.int64) - EPOCH_NS).astype(np.float64) * 1e-9
        cam_from_body = inverse(self.body_from_left)
        lever = cam_from_body[:3, 3]
        h = _STEP_S
        world_from_cam, acc_cam = path_motion(self.frames, t_s, self.fps)
        cam_before = path_motion(self.frames, t_s - h, self.fps)[0]
        cam_after = path_motion(self.frames, t_s + h, self.fps)[0]
        before, after = cam_before @ cam_from_body, cam_after @ cam_from_body
        world_from_body = world_from_cam @ cam_from_body
        velocity = (after[:, :3, 3] - before[:, :3, 3]) / (2 * h)
        rel = np.einsum("nji,njk->nik", before[:, :3, :3], after[:, :3, :3])
        gyro = so3_log(rel) / (2 * h)
        # The body's centre is the camera's plus the lever arm, which turns with the camera.
        arm = np.stack([p[:, :3, :3] @ lever for p in (cam_before, world_from_cam, cam_after)])
        acc_body = acc_cam + (arm[0] - 2 * arm[1] + arm[2]) / h**2
        specific = acc_body + np.array([0.0, 0.0, GRAVITY_MPS2])
        accel = np.einsum("nji,nj->ni", world_from_body[:, :3, :3], specific)
        return world_from_body, velocity, gyro, accel

    def imu_track(self, noise: bool = False, seed: int = 0) -> ImuTrack:
        """The IMU samples at :meth:`imu_stamps_ns`, noise-free or with the noise model of the
        module docstring (seeded by ``seed``)."""
        stamps = self.imu_stamps_ns()
        poses, velocity, gyro, accel = self.body_motion(stamps)
        gyro_bias = np.zeros_like(gyro)
        accel_bias = np.zeros_like(accel)
        if noise:
            rng = np.random.default_rng([seed, _RNG_IMU])
            dt = 1.0 / IMU_RATE_HZ
            root = math.sqrt(dt)
            gyro_bias = _random_walk(rng, _GYRO_BIAS_SIGMA, GYRO_RANDOM_WALK * root, gyro.shape)
            accel_bias = _random_walk(rng, _ACCEL_BIAS_SIGMA, ACCEL_RANDOM_WALK * root, accel.shape)
            gyro = gyro + gyro_bias + rng.normal(0.0, GYRO_NOISE_DENSITY / root, gyro.shape)
            accel = accel + accel_bias + rng.normal(0.0, ACCEL_NOISE_DENSITY / root, accel.shape)
        return ImuTrack(stamps, gyro, accel, poses, velocity, gyro_bias, accel_bias)


def _grey(colour: F32) -> F32:
    """(H, W, 3) float RGB -> (H, W) float grey with OpenCV's weights."""
    import cv2

    return np.asarray(cv2.cvtColor(colour, cv2.COLOR_RGB2GRAY), dtype=np.float32)


def _random_walk(
    rng: np.random.Generator, start_sigma: float, step_sigma: float, shape: tuple[int, ...]
) -> F64:
    """A bias per sample: a seeded start plus a Gaussian random walk."""
    start = rng.normal(0.0, start_sigma, shape[1:])
    steps = rng.normal(0.0, step_sigma, shape)
    steps[0] = 0.0
    return start + np.cumsum(steps, axis=0)


def build_stereo_world(
    frames: int,
    size: tuple[int, int] = (640, 480),
    baseline_m: float = DEFAULT_BASELINE_M,
    seed: int = 0,
    fps: float = FPS,
) -> StereoWorld:
    """The room, rig and ground-truth poses of a sequence, without writing anything.

    Args:
        frames: number of stereo pairs (>= 2).
        size: (width, height) in pixels.
        baseline_m: distance between the cameras in metres, in (0, 0.5].
        seed: texture seed (the camera path depends only on ``frames / fps``).
        fps: stereo pairs per second; :data:`IMU_RATE_HZ` must be a whole multiple of it.

    Raises:
        ConfigError: a value out of range.
    """
    _check_options(frames, size, baseline_m, fps)
    trajectory = camera_path(frames, fps)
    room = RgbdWorld(
        scene=room_scene(seed),
        camera=camera_for_size(*size),
        trajectory=trajectory,
        depth_stamps_ns=trajectory.stamps_ns,
    )
    return StereoWorld(room, float(baseline_m), BODY_FROM_LEFT.copy(), float(fps))


def _check_options(frames: int, size: tuple[int, int], baseline_m: float, fps: float) -> None:
    if frames < 2:
        raise ConfigError(f"frames: expected at least 2 stereo pairs, got {frames}")
    width, height = size
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise ConfigError(
            f"size: expected width and height in [16, 4096] pixels, got {width}x{height}"
        )
    if not (math.isfinite(baseline_m) and 0.0 < baseline_m <= MAX_BASELINE_M):
        raise ConfigError(
            f"baseline: expected a distance in (0, {MAX_BASELINE_M:g}] metres, got {baseline_m}",
            hint="EuRoC's rig has 0.11 m; up to 0.5 m keeps both cameras clear of the room's "
            "boxes and walls",
        )
    per_frame = IMU_RATE_HZ / fps if math.isfinite(fps) and fps > 0.0 else math.nan
    if not (per_frame >= 1.0 and abs(per_frame - round(per_frame)) < 1e-9):
        raise ConfigError(
            f"fps: expected a rate that divides the IMU's {IMU_RATE_HZ:g} Hz, got {fps}",
            hint="10 (as KITTI's cameras), 20 (as EuRoC's), 25, 40 or 50, for example: an IMU "
            "sample then falls on every pair's stamp",
        )


def render_stereo_sequence(
    out: str | Path,
    frames: int = 300,
    size: tuple[int, int] = (640, 480),
    baseline_m: float = DEFAULT_BASELINE_M,
    seed: int = 0,
    noise: bool = False,
    force: bool = False,
    progress: ProgressFn | None = None,
    fps: float = FPS,
) -> dict[str, Any]:
    """Render a stereo sequence into ``out`` as a EuRoC / ASL folder (layout in the module
    docstring).

    Args:
        out: output folder; must be empty or absent unless ``force``.
        frames: number of stereo pairs (>= 2), at ``fps``.
        size: (width, height) in pixels.
        baseline_m: distance between the cameras in metres, in (0, 0.5].
        seed: seeds the textures and all noise; same arguments -> bit-identical files.
        noise: grey-level noise per camera, the right camera's brightness offset, IMU noise and
            biases.
        force: replace a non-empty folder (once the new sequence is complete).
        progress: called as ``progress(done, frames)`` after each pair.
        fps: stereo pairs per second; 200 (the IMU's rate) must be a whole multiple of it.

    Returns:
        Summary: ``frames``, ``fps``, ``size``, ``camera`` (dict), ``baseline_m``, ``imu_samples``,
        ``duration_s``, ``path_length_m``, ``max_speed_mps``, ``max_rotation_dps`` (of the
        left camera), ``closure_m``, ``closure_deg``, ``seed``, ``noise``, ``out`` and
        ``files`` (paths of the text files, then the two image folders).

    Raises:
        ConfigError: a value out of range.
        ExportError: the folder cannot be written.
    """
    with RunDir(out, force=force) as run:
        world = build_stereo_world(frames, size, baseline_m, seed, fps)
        names = [f"{s}.png" for s in world.stamps_ns.tolist()]
        for folder in ("cam0/data", "cam1/data", "imu0", "state_groundtruth_estimate0"):
            run.staged(f"mav0/{folder}").mkdir(parents=True)
        rngs = (
            (np.random.default_rng([seed, _RNG_LEFT]), np.random.default_rng([seed, _RNG_RIGHT]))
            if noise
            else (None, None)
        )
        for i in range(frames):
            for cam, image in zip(("cam0", "cam1"), world.render_pair(i, *rngs), strict=True):
                with run.atomic(f"mav0/{cam}/data/{names[i]}") as tmp:
                    _imwrite(tmp, image)
            if progress is not None:
                progress(i + 1, frames)
        imu = world.imu_track(noise, seed)
        right_on_body = world.body_from_left @ world.left_from_right
        files = []
        for cam, body_from_cam in (("cam0", world.body_from_left), ("cam1", right_on_body)):
            files.append(run.write_text(f"mav0/{cam}/data.csv", _image_csv(world.stamps_ns)))
            files.append(
                run.write_text(
                    f"mav0/{cam}/sensor.yaml",
                    _camera_yaml(cam, world.camera, body_from_cam, world.fps),
                )
            )
        files.append(run.write_text("mav0/imu0/data.csv", _imu_csv(imu)))
        files.append(run.write_text("mav0/imu0/sensor.yaml", _imu_yaml(noise)))
        files.append(
            run.write_text("mav0/state_groundtruth_estimate0/data.csv", _groundtruth_csv(imu))
        )
        summary = _summary(world, seed, noise)
        summary["imu_samples"] = len(imu.stamps_ns)
        summary["out"] = str(run.path)
        summary["files"] = [str(p) for p in files] + [
            str(run.file(f"mav0/{cam}/data")) for cam in ("cam0", "cam1")
        ]
    log.info("rendered %d stereo pairs into %s", frames, run.path)
    return summary


def _imwrite(path: Path, image: NDArray[np.uint8]) -> None:
    import cv2

    if not cv2.imwrite(str(path), image, [cv2.IMWRITE_PNG_COMPRESSION, _PNG_COMPRESSION]):
        raise ExportError(f"{path}: OpenCV could not write the image")


def _image_csv(stamps_ns: NDArray[np.int64]) -> str:
    lines = ["#timestamp [ns],filename", *(f"{s},{s}.png" for s in stamps_ns.tolist())]
    return "\n".join(lines) + "\n"


def _matrix_yaml(m: F64) -> str:
    rows = [", ".join(repr(float(v)) for v in row) for row in m]
    return "T_BS:\n  cols: 4\n  rows: 4\n  data: [" + ",\n         ".join(rows) + "]\n"


def _camera_yaml(name: str, cam: PinholeCamera, body_from_cam: F64, fps: float) -> str:
    return (
        "%YAML:1.0\n"
        "# General sensor definitions.\n"
        "sensor_type: camera\n"
        f"comment: slamcli synth stereo {name}, rendered pinhole camera without distortion\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        f"{_matrix_yaml(body_from_cam)}\n"
        "# Camera specific definitions.\n"
        f"rate_hz: {fps:g}\n"
        f"resolution: [{cam.width}, {cam.height}]\n"
        "camera_model: pinhole\n"
        f"intrinsics: [{cam.fx!r}, {cam.fy!r}, {cam.cx!r}, {cam.cy!r}] #fu, fv, cu, cv\n"
        "distortion_model: radial-tangential\n"
        "distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n"
    )


def _imu_yaml(noise: bool) -> str:
    samples = "noisy samples" if noise else "noise-free samples"
    return (
        "%YAML:1.0\n"
        "sensor_type: imu\n"
        f"comment: slamcli synth stereo IMU ({samples}; the noise model of EuRoC's ADIS16448)\n\n"
        "# Sensor extrinsics wrt. the body-frame.\n"
        f"{_matrix_yaml(np.eye(4))}"
        f"rate_hz: {IMU_RATE_HZ:g}\n\n"
        "# inertial sensor noise model parameters (static)\n"
        f"gyroscope_noise_density: {GYRO_NOISE_DENSITY!r}     # [ rad / s / sqrt(Hz) ]\n"
        f"gyroscope_random_walk: {GYRO_RANDOM_WALK!r}       # [ rad / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_noise_density: {ACCEL_NOISE_DENSITY!r}  # [ m / s^2 / sqrt(Hz) ]\n"
        f"accelerometer_random_walk: {ACCEL_RANDOM_WALK!r}    # [ m / s^3 / sqrt(Hz) ]\n"
    )


def _rows(stamps_ns: NDArray[np.int64], values: F64, fmt: str) -> list[str]:
    return [
        f"{s}," + ",".join(format(v, fmt) for v in row)
        for s, row in zip(stamps_ns.tolist(), values.tolist(), strict=True)
    ]


def _imu_csv(imu: ImuTrack) -> str:
    header = (
        "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
        "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]"
    )
    values = np.concatenate([imu.gyro_radps, imu.accel_mps2], axis=1)
    return "\n".join([header, *_rows(imu.stamps_ns, values, ".12g")]) + "\n"


def _groundtruth_csv(imu: ImuTrack) -> str:
    header = (
        "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], q_RS_w [], q_RS_x [], q_RS_y [], "
        "q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], "
        "b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], "
        "b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]"
    )
    poses = imu.world_from_body
    values = np.concatenate(
        [
            poses[:, :3, 3],
            matrix_to_quat_wxyz(poses),
            imu.velocity_mps,
            imu.gyro_bias,
            imu.accel_bias,
        ],
        axis=1,
    )
    return "\n".join([header, *_rows(imu.stamps_ns, values, ".12g")]) + "\n"


def _summary(world: StereoWorld, seed: int, noise: bool) -> dict[str, Any]:
    traj = world.room.trajectory
    poses = traj.world_from_body
    dt = np.diff(traj.stamps_ns).astype(np.float64) * 1e-9
    step = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1)
    turn = rotation_angle(np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3]))
    cam = world.camera
    return {
        "frames": world.frames,
        "fps": world.fps,
        "size": [cam.width, cam.height],
        "camera": cam.to_dict(),
        "baseline_m": world.baseline_m,
        "duration_s": float(traj.stamps_ns[-1] - traj.stamps_ns[0]) * 1e-9,
        "path_length_m": traj.path_length(),
        "max_speed_mps": float(np.max(step / dt)),
        "max_rotation_dps": float(np.degrees(np.max(turn / dt))),
        "closure_m": float(np.linalg.norm(traj.positions[-1] - traj.positions[0])),
        "closure_deg": float(np.degrees(rotation_angle(poses[0, :3, :3].T @ poses[-1, :3, :3]))),
        "seed": seed,
        "noise": noise,
    }


__all__ = [
    "BODY_FROM_LEFT",
    "DEFAULT_BASELINE_M",
    "FPS",
    "IMU_RATE_HZ",
    "ImuTrack",
    "StereoWorld",
    "build_stereo_world",
    "render_stereo_sequence",
]
