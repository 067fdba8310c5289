"""A planar landmark world for EKF-SLAM: a robot driving laps of a closed loop among landmarks.

The robot is a unicycle. Its true controls are piecewise constant over each odometry period
``dt``: straight legs at ``speed`` m/s and 90-degree left turns of constant yaw rate, laid out as
a rounded rectangle (12 m and 8 m legs, turns of about 1.9 m radius, 52 m per lap) that closes
exactly, centred on the origin and starting at its lower-left leg heading +x. Poses advance by
the exact arc integration of each control (:func:`slamcli.geometry.integrate_unicycle`)::

    a = w dt / 2,  L = v dt sin(a) / a,  x += L cos(th + a),  y += L sin(th + a),  th += w dt

Odometry reports each control the way wheel encoders do: scaled by a constant factor per run
(``1 + b`` with ``b ~ N(0, bias_sigma)``, a wrong wheel radius or track width) plus white noise.
Landmarks lie in a band 1 to 5 m either side of the loop, at least 1 m apart. At every
measurement stamp each landmark inside ``max_range`` and the field of view is seen with
probability ``detection_prob``, as range (m) and bearing (rad, counter-clockwise from the
heading, in (-pi, pi]) with Gaussian noise.

Folder layout (times in seconds with 6 decimals, starting at 1700000000.000000)::

    odometry.csv      t,v,omega          control applied over [t, t + dt): m/s, rad/s
    measurements.csv  t,id,range,bearing one row per observation, sorted by t then id
    groundtruth.tum   t tx ty tz qx qy qz qw   true poses as TUM SE(3) (z = 0, yaw about +z),
                      one more stamp than odometry.csv: the pose after the last control
    landmarks.csv     id,x,y             true landmark positions, m
    world.json        seed, rates, sensor limits, noise parameters, the drawn odometry scale
                      factors and counts

Measurement stamps coincide with odometry stamps (every ``odometry_hz / measurement_hz``-th
one), and the pose in groundtruth.tum at that stamp is the pose the observation was taken
from.

Several robots (:func:`simulate_multi_robot_world`, ``robots`` 2 to 16) drive the same loop
through the same landmark field at the same time, from start points spread around the lap,
the even-numbered robots clockwise. They are written as an MRCLAM folder that
:class:`~slamcli.formats.landmarks.MrclamSource` reads (whitespace-separated, ``#`` comments,
the same stamps as above)::

    Barcodes.dat                 subject barcode   robots 1..N, landmark i is subject i + 6
                                                   (i + N + 1 with more than five robots);
                                                   each barcode equals its subject
    Landmark_Groundtruth.dat     subject x y x_std y_std   true positions, std-devs 0
    RobotK_Odometry.dat          t v omega
    RobotK_Measurement.dat       t barcode range bearing   landmarks and other robots (their
                                                           centres) in range and view, sorted
                                                           by t then barcode
    RobotK_Groundtruth.dat       t x y theta       true poses, theta in (-pi, pi]
    world.json                   seed, sensor, and per robot its start pose, direction,
                                 odometry scale factors and counts
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError
from slamcli.formats.landmarks import MRCLAM_ROBOT_SUBJECTS
from slamcli.formats.text import format_stamp
from slamcli.formats.trajectory import tum_lines
from slamcli.geometry import integrate_unicycle, make_pose, so3_exp
from slamcli.rundir import RunDir
from slamcli.types import ProgressFn, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]

EPOCH_NS = 1_700_000_000 * 1_000_000_000
"""Stamp of the first odometry record."""

_STRAIGHT_X_M, _STRAIGHT_Y_M = 12.0, 8.0
_TURN_S = 3.0
_BAND_M = (1.0, 5.0)
_MIN_SEPARATION_M = 1.0


@dataclass(frozen=True)
class LandmarkSensor:
    """Rates, sensor limits and noise of a landmark world (SI units, radians).

    Attributes:
        odometry_hz: odometry (control) rate.
        measurement_hz: observation rate; must divide ``odometry_hz``.
        speed: forward speed on every leg, m/s.
        max_range: farthest observed landmark, m.
        fov: full field of view centred on the heading, rad (2 pi = all around).
        detection_prob: chance that a landmark in range and view is reported.
        range_sigma, bearing_sigma: observation noise, m and rad.
        v_sigma, omega_sigma: odometry white noise, m/s and rad/s.
        v_bias_sigma, omega_bias_sigma: spread of the per-run odometry scale errors.
    """

    odometry_hz: float = 20.0
    measurement_hz: float = 10.0
    speed: float = 1.0
    max_range: float = 6.0
    fov: float = math.pi
    detection_prob: float = 0.95
    range_sigma: float = 0.10
    bearing_sigma: float = math.radians(2.0)
    v_sigma: float = 0.05
    omega_sigma: float = math.radians(3.0)
    v_bias_sigma: float = 0.02
    omega_bias_sigma: float = 0.03

    def noiseless(self) -> LandmarkSensor:
        """The same sensor with every noise term zero and every landmark in view detected."""
        return replace(
            self,
            detection_prob=1.0,
            range_sigma=0.0,
            bearing_sigma=0.0,
            v_sigma=0.0,
            omega_sigma=0.0,
            v_bias_sigma=0.0,
            omega_bias_sigma=0.0,
        )


@dataclass(frozen=True)
class LandmarkWorld:
    """A simulated run, in memory.

    Attributes:
        stamps_ns: (K + 1,) int64 ground-truth stamps; the first K are the odometry stamps.
        poses: (K + 1, 3) true x, y (m), heading (rad).
        controls: (K, 2) true v (m/s), omega (rad/s) applied after each stamp.
        odometry: (K, 2) reported v, omega.
        landmarks: (N, 2) true landmark positions, m; landmark ``i`` has id ``i``.
        meas_index: (M,) int64 index into ``stamps_ns`` of each observation.
        meas_ids: (M,) int64 landmark ids.
        meas_range: (M,) metres.
        meas_bearing: (M,) radians in (-pi, pi].
        odometry_scale: (2,) drawn scale factors (1 + b) of v and omega.
        sensor: the parameters used.
        seed: the seed used.
    """

    stamps_ns: NDArray[np.int64]
    poses: F64
    controls: F64
    odometry: F64
    landmarks: F64
    meas_index: NDArray[np.int64]
    meas_ids: NDArray[np.int64]
    meas_range: F64
    meas_bearing: F64
    odometry_scale: F64
    sensor: LandmarkSensor
    seed: int

    def trajectory(self) -> Trajectory:
        """The true poses as a planar SE(3) trajectory (z = 0, rotation about +z)."""
        rot = so3_exp(np.stack([np.zeros_like(self.poses[:, 2])] * 2 + [self.poses[:, 2]], 1))
        xyz = np.concatenate([self.poses[:, :2], np.zeros((len(self.poses), 1))], axis=1)
        return Trajectory(self.stamps_ns, make_pose(rot, xyz))


def _lap_controls(sensor: LandmarkSensor) -> F64:
    """True (v, omega) per odometry step for one lap, (L, 2)."""
    dt = 1.0 / sensor.odometry_hz
    steps_x = round(_STRAIGHT_X_M / (sensor.speed * dt))
    steps_y = round(_STRAIGHT_Y_M / (sensor.speed * dt))
    steps_turn = round(_TURN_S / dt)
    omega = (math.pi / 2) / (steps_turn * dt)
    legs = []
    for steps in (steps_x, steps_y, steps_x, steps_y):
        legs.append(np.tile([sensor.speed, 0.0], (steps, 1)))
        legs.append(np.tile([sensor.speed, omega], (steps_turn, 1)))
    return np.concatenate(legs)


def _wrap(angle: F64) -> F64:
    """Angles wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - angle, 2 * np.pi)


def _place_landmarks(rng: np.random.Generator, path_xy: F64, count: int) -> F64:
    """(count, 2) landmarks in a band beside the path, at least ``_MIN_SEPARATION_M`` apart."""
    seg = np.diff(path_xy, axis=0)
    seg_len = np.linalg.norm(seg, axis=1)
    keep = seg_len > 0
    seg, seg_len, starts = seg[keep], seg_len[keep], path_xy[:-1][keep]
    cum = np.concatenate([[0.0], np.cumsum(seg_len)])
    # Random sequential placement fills about half the plane at most; ask for well below that
    # so rejection sampling ends quickly.
    band_area = 2.0 * (_BAND_M[1] - _BAND_M[0]) * cum[-1]
    limit = int(0.3 * band_area / _MIN_SEPARATION_M**2)
    if count > limit:
        raise ConfigError(
            f"landmarks: at most {limit} fit around the loop at least {_MIN_SEPARATION_M} m "
            f"apart, asked for {count}",
            hint=f"ask for {limit} or fewer",
        )
    accepted = np.empty((0, 2))
    for _ in range(50):
        n = 4 * count
        s = rng.uniform(0.0, cum[-1], n)
        i = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        tangent = seg[i] / seg_len[i][:, None]
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
        offset = rng.uniform(*_BAND_M, n) * rng.choice([-1.0, 1.0], n)
        cand = starts[i] + tangent * (s - cum[i])[:, None] + normal * offset[:, None]
        # Stay clear of every part of the path, not just the leg the point was drawn beside.
        clear = np.min(np.linalg.norm(cand[:, None] - path_xy[None], axis=2), axis=1) >= _BAND_M[0]
        for c in cand[clear]:
            if len(accepted) == count:
                return accepted
            if len(accepted) == 0 or np.min(np.linalg.norm(accepted - c, axis=1)) >= (
                _MIN_SEPARATION_M
            ):
                accepted = np.vstack([accepted, c])
    raise ConfigError(
        f"landmarks: cannot place {count} landmarks at least {_MIN_SEPARATION_M} m apart",
        hint="ask for fewer landmarks",
    )


def simulate_landmark_world(
    seed: int = 0,
    landmarks: int = 40,
    duration_s: float = 120.0,
    sensor: LandmarkSensor | None = None,
) -> LandmarkWorld:
    """Simulate a run in memory (see the module docstring for the model).

    Args:
        seed: seeds landmark placement, odometry errors and observation noise.
        landmarks: number of landmarks, >= 1.
        duration_s: driving time in seconds (one lap is 52 s at 1 m/s).
        sensor: rates, limits and noise; defaults to :class:`LandmarkSensor()`.
    """
    sensor = sensor or LandmarkSensor()
    _check(landmarks, duration_s, sensor)
    dt = 1.0 / sensor.odometry_hz
    steps = round(duration_s * sensor.odometry_hz)
    lap = _lap_controls(sensor)
    controls = np.tile(lap, (steps // len(lap) + 1, 1))[:steps]
    start = np.array(
        [-_STRAIGHT_X_M / 2, -_STRAIGHT_Y_M / 2 - sensor.speed * _TURN_S * 2 / np.pi, 0.0]
    )
    poses = integrate_unicycle(start, controls, dt)
    lap_path = integrate_unicycle(start, lap, dt)[:, :2]

    marks = _place_landmarks(np.random.default_rng([seed, 0]), lap_path, landmarks)
    rng_odo = np.random.default_rng([seed, 1])
    rng_meas = np.random.default_rng([seed, 2])
    return _drive(poses, controls, marks, sensor, seed, rng_odo, rng_meas)


def _drive(
    poses: F64,
    controls: F64,
    marks: F64,
    sensor: LandmarkSensor,
    seed: int,
    rng_odo: np.random.Generator,
    rng_meas: np.random.Generator,
) -> LandmarkWorld:
    """One robot's run along ``poses``: its odometry and its observations of the landmarks.

    Args:
        poses: (K + 1, 3) true x, y (m), heading (rad), one per odometry stamp and the last.
        controls: (K, 2) true v (m/s), omega (rad/s) that drove them.
        marks: (N, 2) landmark positions, m.
        sensor, seed: as recorded in the world.
        rng_odo: draws the odometry scale factors, then the odometry white noise.
        rng_meas: draws the observations (see :func:`_observe`).
    """
    scale = 1.0 + rng_odo.normal(0.0, [sensor.v_bias_sigma, sensor.omega_bias_sigma])
    white = rng_odo.normal(0.0, [sensor.v_sigma, sensor.omega_sigma], controls.shape)
    at = _measurement_steps(len(poses), sensor)
    index, ids, ranges, bearings = _observe(poses, at, marks[None], sensor, rng_meas)
    return LandmarkWorld(
        stamps_ns=_stamps(len(poses), 1.0 / sensor.odometry_hz),
        poses=poses,
        controls=controls,
        odometry=controls * scale + white,
        landmarks=marks,
        meas_index=index,
        meas_ids=ids,
        meas_range=ranges,
        meas_bearing=bearings,
        odometry_scale=scale,
        sensor=sensor,
        seed=seed,
    )


def _stamps(count: int, dt: float) -> NDArray[np.int64]:
    """(count,) int64 stamps ``dt`` seconds apart from :data:`EPOCH_NS`, whole microseconds."""
    return EPOCH_NS + np.rint(np.arange(count) * dt * 1e6).astype(np.int64) * 1000


def _measurement_steps(count: int, sensor: LandmarkSensor) -> NDArray[np.int64]:
    """Indices of the poses observations are taken from: every ``odometry/measurement``-th."""
    return np.arange(0, count, round(sensor.odometry_hz / sensor.measurement_hz))


def _observe(
    poses: F64,
    at: NDArray[np.int64],
    points: F64,
    sensor: LandmarkSensor,
    rng: np.random.Generator,
) -> tuple[NDArray[np.int64], NDArray[np.int64], F64, F64]:
    """Range-bearing observations of points from ``poses[at]``.

    Args:
        poses: (K, 3) x, y (m), heading (rad).
        at: (T,) int64 indices into ``poses`` of the observing poses.
        points: (1 or T, P, 2) observed positions, m: fixed (landmarks) or one row per stamp
            (other robots).
        sensor: range, field of view, detection probability and noise.
        rng: draws detections, then range noise, then bearing noise.

    Returns:
        (M,) pose index, (M,) point index, (M,) range (m, >= 0), (M,) bearing (rad), in the
        order stamp then point.
    """
    rel = points - poses[at, None, :2]
    true_range = np.linalg.norm(rel, axis=2)
    true_bearing = _wrap(np.arctan2(rel[..., 1], rel[..., 0]) - poses[at, None, 2])
    visible = (true_range <= sensor.max_range) & (np.abs(true_bearing) <= sensor.fov / 2)
    detected = rng.uniform(size=visible.shape) < sensor.detection_prob
    row, ids = np.nonzero(visible & detected)
    ranges = true_range[row, ids] + rng.normal(0.0, sensor.range_sigma, row.size)
    bearings = _wrap(true_bearing[row, ids] + rng.normal(0.0, sensor.bearing_sigma, row.size))
    return at[row].astype(np.int64), ids.astype(np.int64), np.maximum(ranges, 0.0), bearings


@dataclass(frozen=True)
class Sightings:
    """One robot's observations of the other robots.

    Attributes:
        index: (S,) int64 index into the observer's ``stamps_ns``.
        robot: (S,) int64 number (1-based) of the robot seen.
        range: (S,) metres to the seen robot's centre.
        bearing: (S,) radians in (-pi, pi], counter-clockwise from the observer's heading.
    """

    index: NDArray[np.int64]
    robot: NDArray[np.int64]
    range: F64
    bearing: F64


@dataclass(frozen=True)
class MultiRobotWorld:
    """Several robots driving the loop of one landmark field at the same time, in memory.

    Attributes:
        robots: one :class:`LandmarkWorld` per robot (robot ``k + 1`` is ``robots[k]``), all
            with the same stamps and landmarks; ``meas_ids`` index the landmarks.
        sightings: per robot, its observations of the others.
        clockwise: (R,) bool, whether each robot drives the loop clockwise.
        start_fraction: (R,) float64 where along the lap each robot starts, in [0, 1).
        seed: the seed used.
    """

    robots: tuple[LandmarkWorld, ...]
    sightings: tuple[Sightings, ...]
    clockwise: NDArray[np.bool_]
    start_fraction: F64
    seed: int


MAX_ROBOTS = 16
"""Most robots of a multi-robot world."""


def landmark_subject0(robots: int) -> int:
    """MRCLAM subject (and barcode) of landmark 0 in a world of ``robots`` robots: 6 up to five
    robots (the real datasets' numbering), else ``robots + 1``; landmark i is this plus i."""
    return max(len(MRCLAM_ROBOT_SUBJECTS), robots) + 1


def simulate_multi_robot_world(
    seed: int = 0,
    robots: int = 2,
    landmarks: int = 40,
    duration_s: float = 120.0,
    sensor: LandmarkSensor | None = None,
) -> MultiRobotWorld:
    """Simulate ``robots`` robots driving the loop of one landmark field at the same time.

    The field is the one :func:`simulate_landmark_world` places for the same seed. Robot ``k``
    (0-based) starts at lap fraction ``(k + u) / robots`` with ``u ~ U[0, 0.5)`` drawn from the
    seed, and the even-numbered robots drive the loop clockwise (the same arcs, reversed), so
    robots meet and see each other. Each robot has its own odometry scale errors and noise. At every
    measurement stamp a robot observes the landmarks and the other robots (their centres) inside
    the sensor's range and field of view, with the same detection probability and noise.

    Args:
        seed: seeds landmark placement, start points, odometry errors and observation noise.
        robots: number of robots, 1 to :data:`MAX_ROBOTS`.
        landmarks, duration_s, sensor: as for :func:`simulate_landmark_world`.
    """
    sensor = sensor or LandmarkSensor()
    _check(landmarks, duration_s, sensor)
    if not 1 <= robots <= MAX_ROBOTS:
        raise ConfigError(f"robots: expected 1 to {MAX_ROBOTS}, got {robots}")
    dt = 1.0 / sensor.odometry_hz
    steps = round(duration_s * sensor.odometry_hz)
    lap = _lap_controls(sensor)
    start = np.array(
        [-_STRAIGHT_X_M / 2, -_STRAIGHT_Y_M / 2 - sensor.speed * _TURN_S * 2 / np.pi, 0.0]
    )
    lap_poses = integrate_unicycle(start, lap, dt)
    marks = _place_landmarks(np.random.default_rng([seed, 0]), lap_poses[:, :2], landmarks)
    fraction = (np.arange(robots) + np.random.default_rng([seed, 3]).uniform(0, 0.5, robots)) / (
        robots
    )
    clockwise = np.arange(robots) % 2 == 1
    n_lap = len(lap)
    at = _measurement_steps(steps + 1, sensor)
    paths, controls_all = [], []
    for k in range(robots):
        o = round(fraction[k] * n_lap) % n_lap
        if clockwise[k]:
            # Driving an arc backwards with the heading turned round retraces it: the control
            # that led into lap pose o, with its turn rate negated, leads back out of it.
            seq = np.roll(lap[::-1] * [1.0, -1.0], -(n_lap - o), axis=0)
            p0 = lap_poses[o] + [0.0, 0.0, np.pi]
        else:
            seq = np.roll(lap, -o, axis=0)
            p0 = lap_poses[o]
        controls = np.tile(seq, (steps // n_lap + 1, 1))[:steps]
        controls_all.append(controls)
        paths.append(integrate_unicycle(p0, controls, dt))
    positions = np.stack([p[:, :2] for p in paths])
    worlds, sightings = [], []
    for k in range(robots):
        rng_odo = np.random.default_rng([seed, 1, k])
        rng_meas = np.random.default_rng([seed, 2, k])
        worlds.append(_drive(paths[k], controls_all[k], marks, sensor, seed, rng_odo, rng_meas))
        others = np.delete(np.arange(robots), k)
        s_index, seen, s_range, s_bearing = _observe(
            paths[k],
            at,
            positions[others][:, at].transpose(1, 0, 2),
            sensor,
            np.random.default_rng([seed, 4, k]),
        )
        sightings.append(Sightings(s_index, others[seen] + 1, s_range, s_bearing))
    return MultiRobotWorld(tuple(worlds), tuple(sightings), clockwise, fraction, seed)


def _check(landmarks: int, duration_s: float, sensor: LandmarkSensor) -> None:
    if landmarks < 1:
        raise ConfigError(f"landmarks: expected at least 1, got {landmarks}")
    if not (math.isfinite(duration_s) and duration_s * sensor.odometry_hz >= 1):
        raise ConfigError(
            f"duration: expected at least one odometry period ({1 / sensor.odometry_hz:g} s), "
            f"got {duration_s}"
        )
    ratio = sensor.odometry_hz / sensor.measurement_hz
    if sensor.measurement_hz <= 0 or abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ConfigError(
            f"measurement_hz: must divide odometry_hz ({sensor.odometry_hz:g}), "
            f"got {sensor.measurement_hz:g}"
        )


def generate_landmark_world(
    out: str | Path,
    seed: int = 0,
    landmarks: int = 40,
    duration_s: float = 120.0,
    sensor: LandmarkSensor | None = None,
    force: bool = False,
    progress: ProgressFn | None = None,
    robots: int = 1,
) -> dict[str, Any]:
    """Simulate a run and write it into ``out`` (layouts in the module docstring).

    Args:
        out: output folder; must be empty or absent unless ``force``.
        seed, landmarks, duration_s, sensor: as for :func:`simulate_landmark_world`.
        force: replace a non-empty folder (once the new one is complete).
        progress: called as ``progress(done, total)`` after each file.
        robots: 1 writes the single-robot folder; 2 to :data:`MAX_ROBOTS` write an MRCLAM
            folder of :func:`simulate_multi_robot_world`.

    Returns:
        Summary: ``seed``, ``landmarks``, ``duration_s``, ``odometry`` (rows),
        ``measurements`` (rows), ``path_length_m``, ``laps``, ``out`` and ``files``; with
        several robots ``robots``, ``sightings`` (rows) and ``per_robot`` (a summary each),
        odometry, measurements and path length summed over the robots.
    """
    if robots != 1:
        return _generate_multi_robot(
            out, seed, landmarks, duration_s, sensor, force, progress, robots
        )
    # Staged and renamed into place at the end: checked before simulating, never half-written.
    with RunDir(out, force=force) as run:
        world = simulate_landmark_world(seed, landmarks, duration_s, sensor)
        total = 5
        stamps = [format_stamp(s, 6) for s in world.stamps_ns]

        def done(i: int) -> None:
            if progress is not None:
                progress(i, total)

        odo = ["t,v,omega"] + [
            f"{stamps[k]},{v:.6f},{w:.6f}" for k, (v, w) in enumerate(world.odometry)
        ]
        files = [run.write_text("odometry.csv", "\n".join(odo) + "\n")]
        done(1)
        meas = ["t,id,range,bearing"] + [
            f"{stamps[k]},{i},{r:.6f},{b:.6f}"
            for k, i, r, b in zip(
                world.meas_index, world.meas_ids, world.meas_range, world.meas_bearing, strict=True
            )
        ]
        files.append(run.write_text("measurements.csv", "\n".join(meas) + "\n"))
        done(2)
        gt = [
            "# ground truth: planar robot poses, world_from_body",
            "# timestamp tx ty tz qx qy qz qw",
        ]
        gt += tum_lines(world.trajectory(), stamp_decimals=6)
        files.append(run.write_text("groundtruth.tum", "\n".join(gt) + "\n"))
        done(3)
        marks = ["id,x,y"] + [f"{i},{x:.6f},{y:.6f}" for i, (x, y) in enumerate(world.landmarks)]
        files.append(run.write_text("landmarks.csv", "\n".join(marks) + "\n"))
        done(4)
        summary = _summary(world)
        meta = {
            "format": "slamcli-landmarks",
            "format_version": 1,
            "seed": seed,
            "landmarks": landmarks,
            "duration_s": duration_s,
            "start_stamp": stamps[0],
            "sensor": asdict(world.sensor),
            "odometry_scale": {
                "v": float(world.odometry_scale[0]),
                "omega": float(world.odometry_scale[1]),
            },
            "motion_model": "unicycle, exact arc integration of piecewise-constant controls",
            "counts": {k: summary[k] for k in ("odometry", "measurements")},
        }
        files.append(run.write_text("world.json", json.dumps(meta, indent=2) + "\n"))
        done(5)
        summary["out"] = str(run.path)
        summary["files"] = [str(p) for p in files]
    log.info("wrote a %d-landmark world into %s", landmarks, run.path)
    return summary


def _summary(world: LandmarkWorld) -> dict[str, Any]:
    lap_steps = len(_lap_controls(world.sensor))
    return {
        "seed": world.seed,
        "landmarks": len(world.landmarks),
        "duration_s": len(world.controls) / world.sensor.odometry_hz,
        "odometry": len(world.odometry),
        "measurements": len(world.meas_ids),
        "path_length_m": world.trajectory().path_length(),
        "laps": len(world.controls) / lap_steps,
    }


_MRCLAM_HEADER = "# slamcli synth landmarks --robots {robots}, seed {seed}\n# {what}\n"


def _generate_multi_robot(
    out: str | Path,
    seed: int,
    landmarks: int,
    duration_s: float,
    sensor: LandmarkSensor | None,
    force: bool,
    progress: ProgressFn | None,
    robots: int,
) -> dict[str, Any]:
    """Write :func:`simulate_multi_robot_world` as an MRCLAM folder (module docstring)."""
    if not 1 <= robots <= MAX_ROBOTS:
        raise ConfigError(
            f"robots: expected 1 to {MAX_ROBOTS}, got {robots}",
            hint=f"a multi-robot world has 2 to {MAX_ROBOTS} robots",
        )
    with RunDir(out, force=force) as run:
        world = simulate_multi_robot_world(seed, robots, landmarks, duration_s, sensor)
        total = 3 + 3 * robots
        count = 0

        def write(name: str, what: str, rows: list[str]) -> Path:
            nonlocal count
            head = _MRCLAM_HEADER.format(robots=robots, seed=seed, what=what)
            path = run.write_text(name, head + "".join(r + "\n" for r in rows))
            count += 1
            if progress is not None:
                progress(count, total)
            return path

        marks = world.robots[0].landmarks
        subject0 = landmark_subject0(robots)
        files = [write(*table) for table in _mrclam_landmark_files(robots, subject0, marks)]
        per_robot = []
        for k, (w, seen) in enumerate(zip(world.robots, world.sightings, strict=True)):
            files += [write(*table) for table in _mrclam_robot_files(k + 1, w, seen, subject0)]
            per_robot.append(_robot_summary(world, k))
        first = world.robots[0]
        meta = {
            "format": "slamcli-landmarks-mrclam",
            "format_version": 1,
            "seed": seed,
            "robots": robots,
            "landmarks": landmarks,
            "duration_s": duration_s,
            "start_stamp": format_stamp(int(first.stamps_ns[0]), 6),
            "sensor": asdict(first.sensor),
            "subjects": {
                "robots": f"1-{robots}",
                "landmarks": f"{subject0}-{subject0 + len(marks) - 1}",
                "barcode": "equal to the subject",
            },
            "motion_model": "unicycle, exact arc integration of piecewise-constant controls",
            "per_robot": per_robot,
        }
        files.append(run.write_text("world.json", json.dumps(meta, indent=2) + "\n"))
        count += 1
        if progress is not None:
            progress(count, total)
        result: dict[str, Any] = {
            "seed": seed,
            "robots": robots,
            "landmarks": landmarks,
            "duration_s": len(first.controls) / first.sensor.odometry_hz,
            "odometry": sum(r["odometry"] for r in per_robot),
            "measurements": sum(r["measurements"] for r in per_robot),
            "sightings": sum(r["sightings"] for r in per_robot),
            "path_length_m": sum(r["path_length_m"] for r in per_robot),
            "laps": len(first.controls) / len(_lap_controls(first.sensor)),
            "per_robot": per_robot,
        }
        result["out"] = str(run.path)
        result["files"] = [str(p) for p in files]
    log.info("wrote a %d-robot, %d-landmark MRCLAM folder into %s", robots, landmarks, run.path)
    return result


_Table = tuple[str, str, list[str]]
"""An MRCLAM file: its name, the column line of its header, its rows."""


def _mrclam_landmark_files(robots: int, subject0: int, marks: F64) -> list[_Table]:
    """``Barcodes.dat`` and ``Landmark_Groundtruth.dat`` of ``robots`` robots and the (N, 2)
    landmarks ``marks`` (m), landmark i being subject ``subject0 + i``."""
    subjects = list(range(1, robots + 1)) + [subject0 + i for i in range(len(marks))]
    return [
        ("Barcodes.dat", "Subject #    Barcode #", [f"{s}\t{s}" for s in subjects]),
        (
            "Landmark_Groundtruth.dat",
            "Subject #    x [m]    y [m]    x std-dev [m]    y std-dev [m]",
            [
                f"{subject0 + i}\t{x:.6f}\t{y:.6f}\t0.000000\t0.000000"
                for i, (x, y) in enumerate(marks)
            ],
        ),
    ]


def _mrclam_robot_files(
    number: int, w: LandmarkWorld, seen: Sightings, subject0: int
) -> list[_Table]:
    """Robot ``number``'s odometry, measurements (landmarks and robots seen, by stamp then
    barcode) and ground truth."""
    stamps = [format_stamp(t, 6) for t in w.stamps_ns]
    index = np.concatenate([w.meas_index, seen.index])
    barcode = np.concatenate([w.meas_ids + subject0, seen.robot])
    rng = np.concatenate([w.meas_range, seen.range])
    bearing = np.concatenate([w.meas_bearing, seen.bearing])
    order = np.lexsort((barcode, index))
    return [
        (
            f"Robot{number}_Odometry.dat",
            "Time [s]    forward velocity [m/s]    angular velocity [rad/s]",
            [f"{stamps[i]}\t{v:.6f}\t{om:.6f}" for i, (v, om) in enumerate(w.odometry)],
        ),
        (
            f"Robot{number}_Measurement.dat",
            "Time [s]    Subject #    range [m]    bearing [rad]",
            [
                f"{stamps[index[i]]}\t{barcode[i]}\t{rng[i]:.6f}\t{bearing[i]:.6f}"
                for i in order.tolist()
            ],
        ),
        (
            f"Robot{number}_Groundtruth.dat",
            "Time [s]    x [m]    y [m]    orientation [rad]",
            [
                f"{stamps[i]}\t{x:.6f}\t{y:.6f}\t{th:.6f}"
                for i, (x, y, th) in enumerate(
                    np.column_stack([w.poses[:, :2], _wrap(w.poses[:, 2])])
                )
            ],
        ),
    ]


def _robot_summary(world: MultiRobotWorld, k: int) -> dict[str, Any]:
    """``world.json``'s entry for robot ``k + 1``."""
    w, seen = world.robots[k], world.sightings[k]
    summary = _summary(w)
    return {
        "robot": k + 1,
        "start_pose": [float(v) for v in w.poses[0, :2]] + [float(_wrap(w.poses[:1, 2])[0])],
        "start_lap_fraction": float(world.start_fraction[k]),
        "clockwise": bool(world.clockwise[k]),
        "odometry_scale": {
            "v": float(w.odometry_scale[0]),
            "omega": float(w.odometry_scale[1]),
        },
        "odometry": summary["odometry"],
        "measurements": summary["measurements"],
        "sightings": len(seen.index),
        "sightings_of": {
            str(r): int(c) for r, c in zip(*np.unique(seen.robot, return_counts=True), strict=True)
        },
        "path_length_m": summary["path_length_m"],
    }
