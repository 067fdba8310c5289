"""A simulated 2-D laser log with exact ground truth: a robot driving a route through a map.

**Map.** Any occupancy map :func:`slamcli.planning.planner.load_map` reads (a map_server YAML, a
slamcli ``.npz``, a run folder with ``map.yaml``). A cell is an obstacle when its probability is
at least 0.65 (:data:`slamcli.planning.costmap.OCCUPIED_THRESH`); unknown cells and the world
beyond the map reflect nothing. Cell ``(row, col)`` is the square whose lower-left corner lies
at ``origin + (col, row) * resolution``, the grid's axes rotated by the origin's yaw, as
:func:`slamcli.formats.occupancy.world_to_cell` has it (:mod:`slamcli.synth.raycast`).

**Route.** The robot's centre keeps more than ``clearance`` metres from every obstacle square,
unknown square and the map's edge: a cell is free when its centre is further than
``clearance + sqrt(2) * resolution`` from the centre of each such cell, and the route never
touches a square that is not free. The start and the waypoints are free cells of the largest
4-connected free region, drawn from the seed: each next waypoint is 2 to 15 m of grid path from
the last one, until the route, with the way back to the start, is about as long as the scans
need; the last waypoint is picked so that it is. There are two waypoints at least where the
length allows (one alone would be driven out and back). Legs are the exact grid search's
shortest paths (:func:`slamcli.planning.search.grid_search`), shortcut by line of sight and
rounded (:func:`slamcli.planning.planner.smooth_path`, then the joints once more), and the
route ends where it started, so loop closure has a place to find (:mod:`slamcli.synth.route`).

**Driving.** :func:`slamcli.planning.trajectory.time_parameterise` times the route: constant
speed on straights, slower where it curves faster than 1 rad/s allows, stopping to turn in place
at corners over 60 degrees (0.5 m/s^2 to start and stop); the heading blends linearly in arc
length from one segment's direction to the next. That timing is stretched or squeezed as a whole
(speeds and turn rates by one factor) so that the route takes exactly ``scans - 1`` scan periods;
``world.json`` records the factor as the driven speed (a warning is logged when it is off by
more than 10 %: routes of a few seconds are driven faster, as turning in place takes its time).
Ground truth is the body pose (x, y, yaw)
at each scan, exactly the pose the scan was cast from.

**Scans.** The scanner sits at ``mounting`` (x, y, yaw) on the body. Each sweep is instantaneous,
taken at its stamp. Beams are spread over ``fov`` counter-clockwise from ``-fov / 2`` (a full
circle: ``beams`` beams ``2 pi / beams`` apart from ``-pi``; else ``fov / (beams - 1)`` apart,
both ends included). Each beam is cast exactly through the grid
(:class:`~slamcli.synth.raycast.RayCaster`): its range is where it first meets an obstacle
square. Readings get Gaussian noise (``range_sigma``) and are kept within
``[min_range, max_range]``; as ``sensor_msgs/LaserScan`` has it, a beam with nothing within
``max_range`` is ``+inf``, one whose obstacle lies nearer than ``min_range`` is ``-inf``, and a
dropout (probability ``dropout_prob`` per beam) is NaN.

**Odometry.** Wheel odometry integrates each true motion between scans (in the body frame of
the earlier one) with its translation scaled by ``(1 + scale_error) * (1 + n)``, ``n ~ N(0,
distance_sigma)``, and its turn plus ``drift_per_m`` radians per metre driven and ``N(0,
heading_sigma^2 * d)`` over ``d`` metres. It starts at the true first pose, so the odometry
frame is the world frame at the first scan; its path is ``1 + scale_error`` times as long as the
true one, up to the noise.

Folder layout (stamps from 1700000000.000000 s, one scan period apart, whole microseconds)::

    scans.log        CARMEN log (:func:`slamcli.formats.carmen.write_carmen`): one ROBOTLASER1
                     line per scan (FLASER when the beams are CARMEN's FLASER beams) whose robot
                     pose is the odometry; RAWLASER1 lines without odometry (those carry no pose
                     and no mounting)
    scans.mcap       ROS 2 log (:func:`slamcli.formats.mcap.write.write_scan_mcap`): /scan
                     sensor_msgs/msg/LaserScan, /odom nav_msgs/msg/Odometry (not without
                     odometry), /tf_static base_link -> laser
    groundtruth.tum  t x y 0 qx qy qz qw, world_from_body at every scan stamp
    world.json       seed, map, sensor, odometry model, route (waypoints, length, speed,
                     revisits) and counts

The same arguments give the same bytes.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError
from slamcli.formats.text import format_stamp
from slamcli.formats.trajectory import tum_lines
from slamcli.geometry import between_planar, compose_planar, planar_to_se3, wrap_angle
from slamcli.planning.costmap import OCCUPIED_THRESH
from slamcli.rundir import RunDir
from slamcli.synth.raycast import RAYS_PER_BATCH, RayCaster
from slamcli.synth.route import (
    REVISIT_GAP_M,
    REVISIT_RADIUS_M,
    Route,
    drive,
    plan_route,
    revisits,
)
from slamcli.types import OccupancyGrid, OdometryFrame, ProgressFn, ScanFrame, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]

EPOCH_NS = 1_700_000_000 * 1_000_000_000
"""Stamp of the first scan."""

ODOMETRY_CHOICES = ("drift", "none")
"""``--odometry``: wheel odometry with scale error and heading drift, or none."""

_RNG_ROUTE, _RNG_SCANS, _RNG_ODOMETRY = 0, 1, 2


@dataclass(frozen=True)
class LidarSensor:
    """A 2-D laser scanner (SI units, radians).

    Attributes:
        beams: beams per sweep.
        fov: field of view centred on the scanner's x axis, rad (2 pi = all around).
        max_range, min_range: the valid range, m.
        rate_hz: sweeps per second.
        range_sigma: Gaussian noise of a reading, m.
        dropout_prob: chance that a beam reads NaN.
        mounting: (x m, y m, yaw rad) of the scanner on the body.
    """

    beams: int = 360
    fov: float = 2 * math.pi
    max_range: float = 20.0
    min_range: float = 0.1
    rate_hz: float = 10.0
    range_sigma: float = 0.01
    dropout_prob: float = 0.002
    mounting: tuple[float, float, float] = (0.1, 0.0, 0.0)

    @property
    def full_circle(self) -> bool:
        return self.fov >= 2 * math.pi - 1e-9

    @property
    def angle_min(self) -> float:
        return -math.pi if self.full_circle else -self.fov / 2

    @property
    def angle_increment(self) -> float:
        if self.full_circle:
            return 2 * math.pi / self.beams
        return self.fov / (self.beams - 1)

    def angles(self) -> F64:
        """(beams,) beam angles in the scanner frame, rad."""
        return self.angle_min + self.angle_increment * np.arange(self.beams, dtype=np.float64)

    def noiseless(self) -> LidarSensor:
        """The same scanner without range noise and dropouts."""
        return replace(self, range_sigma=0.0, dropout_prob=0.0)

    def checked(self) -> LidarSensor:
        """This sensor, or a ConfigError naming the option that is out of range."""
        if not 1 <= self.beams <= 100_000 or (not self.full_circle and self.beams < 2):
            raise ConfigError(
                f"--beams: expected 1 to 100000 beams (2 or more below 360 degrees), "
                f"got {self.beams}"
            )
        if not (math.isfinite(self.fov) and 0 < self.fov <= 2 * math.pi + 1e-9):
            raise ConfigError(
                f"--fov-deg: expected more than 0 and at most 360 degrees, "
                f"got {math.degrees(self.fov):g}"
            )
        if not (math.isfinite(self.max_range) and 0 < self.min_range < self.max_range):
            raise ConfigError(
                f"--max-range: expected a finite range above the minimum range "
                f"({self.min_range:g} m), got {self.max_range:g} m"
            )
        if not (math.isfinite(self.rate_hz) and 0.01 <= self.rate_hz <= 1000):
            raise ConfigError(f"--rate: expected 0.01 to 1000 Hz, got {self.rate_hz:g}")
        if not (math.isfinite(self.range_sigma) and self.range_sigma >= 0):
            raise ConfigError(f"range_sigma: expected a finite value >= 0, got {self.range_sigma}")
        if not 0 <= self.dropout_prob < 1:
            raise ConfigError(f"dropout_prob: expected 0 <= p < 1, got {self.dropout_prob}")
        if len(self.mounting) != 3 or not all(math.isfinite(v) for v in self.mounting):
            raise ConfigError(f"mounting: expected 3 finite numbers, got {self.mounting}")
        return self


@dataclass(frozen=True)
class WheelOdometry:
    """Errors of wheel odometry (see the module docstring).

    Attributes:
        scale_error: relative error of every distance (0.02: 2 % too long).
        drift_per_m: heading error added per metre driven, rad/m (counter-clockwise).
        distance_sigma: relative white noise of each step's distance.
        heading_sigma: heading random walk, rad per square root of a metre driven.
    """

    scale_error: float = 0.02
    drift_per_m: float = 0.01
    distance_sigma: float = 0.01
    heading_sigma: float = 0.002

    def noiseless(self) -> WheelOdometry:
        """The same scale error and drift without white noise."""
        return replace(self, distance_sigma=0.0, heading_sigma=0.0)


DEFAULT_ODOMETRY = WheelOdometry()
"""2 % long, 0.01 rad of heading drift per metre, small white noise."""


@dataclass(frozen=True)
class LidarWorld:
    """A simulated laser log, in memory.

    Attributes:
        grid: the map.
        stamps_ns: (N,) int64 scan stamps.
        poses: (N, 3) true body x, y (m), yaw (rad, wrapped) at each scan.
        odometry: (N, 3) odometry poses, or None without odometry.
        ranges: (N, beams) float32 ranges as the scanner reports them.
        route: the route driven.
        speed_mps: the speed of the straights, as driven (the asked speed times the stretch).
        sensor, odometry_model, seed: as simulated.
    """

    grid: OccupancyGrid
    stamps_ns: I64
    poses: F64
    odometry: F64 | None
    ranges: NDArray[np.float32]
    route: Route
    speed_mps: float
    sensor: LidarSensor
    odometry_model: WheelOdometry | None
    seed: int

    def trajectory(self) -> Trajectory:
        """The true body poses as a planar SE(3) trajectory (z = 0, yaw about +z)."""
        return Trajectory(self.stamps_ns, planar_to_se3(self.poses))

    def sensor_poses(self) -> F64:
        """(N, 3) the scanner's world pose at each scan."""
        return compose_planar(self.poses, np.asarray(self.sensor.mounting, dtype=np.float64))

    def scans(self) -> Iterator[ScanFrame]:
        """The sweeps as :class:`ScanFrame` records."""
        mount = np.asarray(self.sensor.mounting, dtype=np.float64)
        for k, stamp in enumerate(self.stamps_ns.tolist()):
            yield ScanFrame(
                stamp_ns=int(stamp),
                ranges_m=self.ranges[k],
                angle_min_rad=self.sensor.angle_min,
                angle_increment_rad=self.sensor.angle_increment,
                range_min_m=self.sensor.min_range,
                range_max_m=self.sensor.max_range,
                body_from_sensor=mount.copy(),
                name=f"scan {k}",
            )

    def odometry_frames(self) -> Iterator[OdometryFrame]:
        """The odometry poses, with the speeds over the period before each (0 at the first)."""
        if self.odometry is None:
            return
        step = between_planar(self.odometry[:-1], self.odometry[1:])
        dt = np.diff(self.stamps_ns).astype(np.float64) * 1e-9
        v = np.concatenate([[0.0], np.hypot(step[:, 0], step[:, 1]) / dt])
        omega = np.concatenate([[0.0], step[:, 2] / dt])
        poses = planar_to_se3(self.odometry)
        for k, stamp in enumerate(self.stamps_ns.tolist()):
            yield OdometryFrame(int(stamp), float(v[k]), float(omega[k]), poses[k])


# --- scans ------------------------------------------------------------------------------------


def sensor_readings(
    true_ranges: F64, sensor: LidarSensor, rng: np.random.Generator
) -> NDArray[np.float32]:
    """What the scanner reports for true ranges (m, inf = nothing within range): noise, limits
    and dropouts as in the module docstring. Draws the noise of every beam, then the dropouts."""
    noise = rng.normal(0.0, 1.0, true_ranges.shape) * sensor.range_sigma
    drop = rng.uniform(size=true_ranges.shape) < sensor.dropout_prob
    hit = np.isfinite(true_ranges)
    with np.errstate(invalid="ignore"):
        measured = np.clip(true_ranges + noise, sensor.min_range, sensor.max_range)
        out = np.where(hit, measured, np.inf)
        out[hit & (true_ranges < sensor.min_range)] = -np.inf
    out[drop] = np.nan
    return out.astype(np.float32)


# --- odometry ----------------------------------------------------------------------------------


def wheel_odometry(poses: F64, model: WheelOdometry, rng: np.random.Generator) -> F64:
    """(N, 3) odometry poses for true poses (N, 3) (module docstring); starts at ``poses[0]``.
    Draws the distance noise of every step, then the heading noise."""
    step = between_planar(poses[:-1], poses[1:])
    dist = np.hypot(step[:, 0], step[:, 1])
    factor = (1.0 + model.scale_error) * (
        1.0 + rng.normal(0.0, 1.0, len(step)) * model.distance_sigma
    )
    turn = (
        step[:, 2]
        + model.drift_per_m * dist
        + rng.normal(0.0, 1.0, len(step)) * model.heading_sigma * np.sqrt(dist)
    )
    yaw = np.cumsum(np.concatenate([[poses[0, 2]], turn]))
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    dx = factor * (c * step[:, 0] - s * step[:, 1])
    dy = factor * (s * step[:, 0] + c * step[:, 1])
    x = np.cumsum(np.concatenate([[poses[0, 0]], dx]))
    y = np.cumsum(np.concatenate([[poses[0, 1]], dy]))
    return np.stack([x, y, wrap_angle(yaw)], axis=1)


# --- the whole log -----------------------------------------------------------------------------


def simulate_lidar_world(
    grid: OccupancyGrid,
    seed: int = 0,
    scans: int = 1200,
    sensor: LidarSensor | None = None,
    odometry: WheelOdometry | None = DEFAULT_ODOMETRY,
    speed_mps: float = 0.5,
    clearance_m: float = 0.4,
    progress: ProgressFn | None = None,
) -> LidarWorld:
    """Simulate a drive through ``grid`` in memory (see the module docstring for the model).

    Args:
        grid: the map.
        seed: seeds the route, the scan noise and the odometry errors.
        scans: number of sweeps (>= 2); the route takes ``(scans - 1) / rate_hz`` seconds.
        sensor: the scanner; defaults to :class:`LidarSensor()`.
        odometry: the odometry's errors, or None for no odometry.
        speed_mps: speed on straights (the route's length is chosen for it).
        clearance_m: least distance of the robot's centre from obstacles and unknown cells.
        progress: called as ``progress(done, scans)`` as sweeps are cast.

    Raises:
        ConfigError: an option out of range. MapError: no free space to drive in.
    """
    sensor = (sensor or LidarSensor()).checked()
    if not 2 <= scans <= 10_000_000:
        raise ConfigError(f"--scans: expected 2 to 10000000 sweeps, got {scans}")
    if not (math.isfinite(speed_mps) and 0.01 <= speed_mps <= 20):
        raise ConfigError(f"--speed: expected 0.01 to 20 m/s, got {speed_mps:g}")
    duration = (scans - 1) / sensor.rate_hz
    route = plan_route(
        grid,
        speed_mps * duration,
        np.random.default_rng([seed, _RNG_ROUTE]),
        clearance_m=clearance_m,
        speed_mps=speed_mps,
        duration_s=duration,
    )
    poses, stretch = drive(route, scans, sensor.rate_hz)
    if abs(stretch - 1.0) > 0.1:
        log.warning(
            "the route takes %.1f s at %.2f m/s; driving it at %.2f m/s to fit %d scans",
            route.profile.duration_s,
            speed_mps,
            speed_mps * stretch,
            scans,
        )
    stamps = EPOCH_NS + np.rint(np.arange(scans) * (1e6 / sensor.rate_hz)).astype(np.int64) * 1000
    caster = RayCaster(grid)
    angles = sensor.angles()
    sensor_poses = compose_planar(poses, np.asarray(sensor.mounting, dtype=np.float64))
    rng_scans = np.random.default_rng([seed, _RNG_SCANS])
    ranges = np.empty((scans, sensor.beams), dtype=np.float32)
    per_batch = max(1, RAYS_PER_BATCH // sensor.beams)
    for a in range(0, scans, per_batch):
        b = min(a + per_batch, scans)
        true = caster.cast(sensor_poses[a:b], angles, sensor.max_range)
        ranges[a:b] = sensor_readings(true, sensor, rng_scans)
        if progress is not None:
            progress(b, scans)
    odo = None
    if odometry is not None:
        odo = wheel_odometry(poses, odometry, np.random.default_rng([seed, _RNG_ODOMETRY]))
    return LidarWorld(
        grid=grid,
        stamps_ns=stamps,
        poses=poses,
        odometry=odo,
        ranges=ranges,
        route=route,
        speed_mps=speed_mps * stretch,
        sensor=sensor,
        odometry_model=odometry,
        seed=seed,
    )


def generate_lidar_world(
    map_path: str | Path,
    out: str | Path,
    *,
    seed: int = 0,
    scans: int = 1200,
    sensor: LidarSensor | None = None,
    odometry: WheelOdometry | None = DEFAULT_ODOMETRY,
    speed_mps: float = 0.5,
    clearance_m: float = 0.4,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Simulate a drive through the map at ``map_path`` and write it into ``out`` (layout in the
    module docstring).

    Args:
        map_path: a map_server YAML, a slamcli ``.npz`` grid or a run folder with map.yaml.
        out: output folder; must be empty or absent unless ``force``.
        seed, scans, sensor, odometry, speed_mps, clearance_m: as for
            :func:`simulate_lidar_world`.
        force: replace a non-empty folder (once the new one is complete).
        progress: called as ``progress(done, scans + 4)``: sweeps cast, then files written.

    Returns:
        Summary: ``seed``, ``scans``, ``duration_s``, ``path_length_m``, ``speed_mps`` (as
        driven), ``waypoints``, ``revisits`` (count), ``odometry`` (records), ``beams``,
        ``no_return_share`` (beams with nothing in range), ``out`` and ``files``.
    """
    from slamcli.formats.carmen import write_carmen
    from slamcli.formats.mcap.write import write_scan_mcap
    from slamcli.planning.planner import load_map

    grid, map_file = load_map(map_path)
    total = scans + 4

    def done(i: int) -> None:
        if progress is not None:
            progress(i, total)

    # Staged and renamed into place at the end: checked before simulating, never half-written.
    with RunDir(out, force=force) as run:
        world = simulate_lidar_world(
            grid,
            seed=seed,
            scans=scans,
            sensor=sensor,
            odometry=odometry,
            speed_mps=speed_mps,
            clearance_m=clearance_m,
            progress=lambda d, _n: done(d),
        )
        frames = list(world.scans())
        poses: list[F64 | None] = (
            [None] * len(frames) if world.odometry is None else list(world.odometry)
        )
        write_carmen(run.output("scans.log"), zip(frames, poses, strict=True))
        files = [run.file("scans.log")]
        done(scans + 1)
        odo_frames = list(world.odometry_frames())
        merged: list[ScanFrame | OdometryFrame] = []
        for k, scan in enumerate(frames):
            if odo_frames:
                merged.append(odo_frames[k])
            merged.append(scan)
        write_scan_mcap(run.output("scans.mcap"), merged)
        files.append(run.file("scans.mcap"))
        done(scans + 2)
        gt = [
            "# ground truth: planar robot poses, world_from_body",
            "# timestamp tx ty tz qx qy qz qw",
        ]
        gt += tum_lines(world.trajectory(), stamp_decimals=6)
        files.append(run.write_text("groundtruth.tum", "\n".join(gt) + "\n"))
        done(scans + 3)
        record = world_record(world, str(map_path), map_file)
        files.append(run.write_text("world.json", json.dumps(record, indent=2) + "\n"))
        done(scans + 4)
        summary = {
            "seed": seed,
            "scans": scans,
            "duration_s": record["route"]["duration_s"],
            "path_length_m": record["route"]["length_m"],
            "speed_mps": world.speed_mps,
            "waypoints": len(world.route.waypoints) - 2,
            "revisits": len(record["route"]["revisits"]),
            "odometry": 0 if world.odometry is None else scans,
            "beams": world.sensor.beams,
            "no_return_share": record["counts"]["no_return_beams"] / max(world.ranges.size, 1),
            "out": str(run.path),
            "files": [str(p) for p in files],
        }
    log.info("wrote %d simulated scans into %s", scans, run.path)
    return summary


def world_record(world: LidarWorld, map_arg: str, map_file: Path) -> dict[str, Any]:
    """``world.json``: how the log was made and what it holds."""
    grid = world.grid
    r = world.ranges
    h, w = np.asarray(grid.prob).shape
    odometry = (
        {"model": "none"}
        if world.odometry_model is None
        else {"model": "drift", **asdict(world.odometry_model), "frame": "world at the first scan"}
    )
    sensor = asdict(world.sensor)
    sensor["mounting"] = list(world.sensor.mounting)
    sensor["angle_min"] = world.sensor.angle_min
    sensor["angle_increment"] = world.sensor.angle_increment
    duration = float(world.stamps_ns[-1] - world.stamps_ns[0]) * 1e-9
    return {
        "format": "slamcli-lidar",
        "format_version": 1,
        "seed": world.seed,
        "map": {
            "path": map_arg,
            "file": map_file.name,
            "size": [int(w), int(h)],
            "resolution_m": float(grid.resolution_m),
            "origin_xy_yaw": [float(v) for v in grid.origin_xy_yaw],
            "occupied_thresh": OCCUPIED_THRESH,
        },
        "start_stamp": format_stamp(int(world.stamps_ns[0]), 6),
        "sensor": sensor,
        "odometry": odometry,
        "route": {
            "clearance_m": world.route.clearance,
            "waypoints": [
                [round(float(x), 6), round(float(y), 6)] for x, y in world.route.waypoints
            ],
            "length_m": round(float(world.trajectory().path_length()), 6),
            "duration_s": round(duration, 6),
            "speed_mps": round(world.speed_mps, 6),
            "revisits": revisits(world.poses),
            "revisit_rule": f"within {REVISIT_RADIUS_M:g} m of a pose driven at least "
            f"{REVISIT_GAP_M:g} m (or half the route) before",
        },
        "counts": {
            "scans": len(world.stamps_ns),
            "odometry": 0 if world.odometry is None else len(world.stamps_ns),
            "beams": int(r.size),
            "no_return_beams": int(np.count_nonzero(np.isposinf(r))),
            "too_close_beams": int(np.count_nonzero(np.isneginf(r))),
            "dropouts": int(np.count_nonzero(np.isnan(r))),
        },
    }
