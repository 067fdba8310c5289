"""``build_map``: an occupancy grid from a run folder (dense RGB-D or EKF landmark run).

The kind of map follows the pipeline the run declares in ``run.json``
(:data:`MAP_KINDS`), never the files that happen to lie in the folder: an EKF run that lost
its ``landmarks.csv`` is an error, and a stray ``landmarks.csv`` in a dense run is ignored.

**Dense runs** (pipelines ``dense`` and ``odometry``; ``trajectory.tum``). The run's input
log is opened again (``run.json``'s ``inputs[0].path`` with the source options the run used,
or ``input_path``) and its depth frames are paired with the trajectory: a frame gets the pose
interpolated at its stamp when a trajectory stamp lies within :attr:`MapSettings.pose_max_dt_s`
(20 ms) of it, else it is skipped. Every ``frame_step``-th frame is used, every
``pixel_step``-th pixel in both directions, depths in (0, ``max_depth_m``]. Up and the floor
plane come from :mod:`slamcli.mapping.floor` (RANSAC over ``points.ply``, else ``mesh.ply``'s
vertices, else the back-projected depth points). In the floor frame (z = height above the
floor):

- a point whose height lies in the band ``[zmin, zmax]`` (default 0.1 to 1.5 m: the body of a
  ground robot; lower things are floor, higher ones pass over it) is a **hit**;
- the 3-D ray from the camera to each point is carved free, projected onto the floor, over
  the part of it that lies at or below ``zmax``: a ray to a floor point carves all the way and
  its end cell is free; a ray to a point above the band (a ceiling, a shelf) stops where it
  rises through ``zmax``, so it never clears the cells of a box it passes over. (Carving the
  whole 2-D ray to such points, as a plain 2-D projection would, erased box tops and table
  legs seen under the ceiling.)

Updates follow :mod:`slamcli.mapping.occupancy` (one scan per frame, l_occ +0.85, l_free -0.4,
clamped to [-2, 3.5]); the map's frame is the floor frame (x along the world's x projected on
the floor).

**EKF runs** (pipeline ``ekf``; ``trajectory.tum`` and ``landmarks.csv``). The map frame is the
run's world plane. Observations are read again from the input (``--robot`` and the other
options recorded in ``run.json``'s ``config.source``); each ray runs from the robot's pose,
interpolated in ``trajectory.tum`` at the observation's stamp, along the measured bearing for
the measured range minus ``landmark_radius_m`` and is carved free (one scan per observation
instant). Then the cells within ``robot_radius_m`` of the path are set free (log-odds -2) and
the cells within ``landmark_radius_m`` (default 0.2 m) of every mapped landmark occupied
(log-odds 3.5).

**Extent.** The bounding box of everything observed plus :attr:`MapSettings.margin_m`, its
origin snapped to a multiple of the resolution.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from slamcli.config import check_settings, setting
from slamcli.errors import ConfigError, InputError
from slamcli.formats.run_folder import RunRecord, read_run
from slamcli.geometry.camera import undistort_points, unproject
from slamcli.mapping.floor import (
    FloorPlane,
    Up,
    find_floor,
    up_from_accelerometer,
    up_from_cameras,
)
from slamcli.mapping.occupancy import L_FREE, L_MAX, L_MIN, L_OCC, LogOddsGrid
from slamcli.types import (
    LandmarkMap,
    OccupancyGrid,
    PinholeCamera,
    ProgressFn,
    SlamResult,
    Trajectory,
)

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

MAP_FILES = ("map.yaml", "map.pgm", "map.png", "map.json")
"""What :func:`write_map` writes into a folder."""

MAP_KINDS = {"dense": "depth", "odometry": "depth", "visual": "depth", "ekf": "landmarks"}
"""The map each pipeline's runs get: from depth frames, or from landmark observations."""

FREE_THRESH = 0.196
OCCUPIED_THRESH = 0.65
"""The trinary thresholds map.yaml is written with (see :mod:`slamcli.formats.occupancy`)."""


@dataclass(frozen=True)
class MapSettings:
    """How a map is built (rules in the module docstring).

    Attributes:
        resolution_m: cell edge, metres.
        height_band_m: (zmin, zmax) heights above the floor that count as obstacles, metres.
        pixel_step: use every n-th depth pixel in both directions.
        frame_step: use every n-th depth frame.
        max_depth_m: depth readings beyond this are ignored, metres.
        pose_max_dt_s: a frame needs a trajectory stamp this close to its own, seconds.
        landmark_radius_m: radius of the obstacle drawn around each landmark (EKF runs).
        robot_radius_m: radius of the robot's footprint carved free along its path (EKF runs).
        margin_m: extra space around what was observed.
        seed: RANSAC's seed.
    """

    resolution_m: float = setting(0.05, unit="m", gt=0.0)
    height_band_m: tuple[float, float] = setting((0.1, 1.5), unit="m")
    pixel_step: int = setting(4, min=1)
    frame_step: int = setting(1, min=1)
    max_depth_m: float = setting(5.0, unit="m", gt=0.0)
    pose_max_dt_s: float = setting(0.02, unit="s", gt=0.0)
    landmark_radius_m: float = setting(0.2, unit="m", min=0.0)
    robot_radius_m: float = setting(0.2, unit="m", min=0.0)
    margin_m: float = setting(0.25, unit="m", min=0.0)
    seed: int = 0

    def checked(self) -> MapSettings:
        """These settings, or ConfigError naming the option (or field) that is out of range."""
        lo, hi = self.height_band_m
        # Before the field checks: a NaN band fails here, with the example to follow.
        if not lo < hi:
            raise ConfigError(
                f"--height-band: needs zmin < zmax (metres above the floor), got {lo:g},{hi:g}",
                hint="for example --height-band 0.1,1.5",
            )
        return check_settings(self, _MAP_OPTIONS)


_MAP_OPTIONS = {
    "resolution_m": "--resolution",
    "height_band_m": "--height-band",
    "pixel_step": "--pixel-step",
    "frame_step": "--frame-step",
    "landmark_radius_m": "--landmark-radius",
    "robot_radius_m": "--robot-radius",
}
"""The ``slamcli map build`` option that sets each of :class:`MapSettings`' fields."""


def parse_height_band(text: str) -> tuple[float, float]:
    """``"zmin,zmax"`` -> two floats with zmin < zmax; ConfigError naming ``--height-band``."""
    parts = [p.strip() for p in text.split(",")]
    try:
        lo, hi = (float(p) for p in parts)
    except ValueError:
        raise ConfigError(
            f"--height-band: expected two numbers zmin,zmax in metres, got {text!r}",
            hint="for example --height-band 0.1,1.5",
        ) from None
    return replace(MapSettings(), height_band_m=(lo, hi)).checked().height_band_m


class BuiltMap(NamedTuple):
    """What :func:`build_map` made.

    Attributes:
        grid: occupancy probabilities (NaN unknown) in the map frame.
        report: the figures written to map.json (JSON-ready).
        path_xy: (N, 2) float64 the camera's or robot's path in the map frame, metres.
    """

    grid: OccupancyGrid
    report: dict[str, Any]
    path_xy: F64


@dataclass
class _Rays:
    """One scan's 2-D rays in the map frame, for the two passes (extent, then carving)."""

    starts: F32
    ends: F32
    hit: NDArray[np.bool_]


@dataclass
class _Scans:
    scans: list[_Rays] = field(default_factory=list)

    def bounds(self) -> tuple[F64, F64] | None:
        parts = [np.concatenate([s.starts, s.ends]) for s in self.scans if len(s.hit)]
        if not parts:
            return None
        lo = np.min([p.min(axis=0) for p in parts], axis=0).astype(np.float64)
        hi = np.max([p.max(axis=0) for p in parts], axis=0).astype(np.float64)
        return lo, hi


@dataclass(frozen=True)
class MapInput:
    """What a map is built from: a run's poses and products, and its input log to read again.

    Attributes:
        pipeline: the pipeline that made the run (a key of :data:`MAP_KINDS` to have a map).
        trajectory: the run's poses.
        input_path: the run's input log.
        source_options: the options the run opened the log with.
        run_path: the run folder, for the record.
        poses_from: where the poses come from, for messages.
        exact: a depth frame takes the pose stamped exactly as it is (the run's own poses);
            else one within :attr:`MapSettings.pose_max_dt_s` of it (a trajectory file's,
            whose stamps are rounded).
        floor_points: (N, 3) points to look for the floor in, and what they are (None: the
            depth frames' points).
        landmarks: the mapped landmarks (landmark runs).
        mono: a monocular run (a map without metric scale).
    """

    pipeline: str | None
    trajectory: Trajectory
    input_path: Path
    source_options: dict[str, Any]
    run_path: Path
    poses_from: str
    exact: bool = False
    floor_points: tuple[F64, str] | None = None
    landmarks: LandmarkMap | None = None
    mono: bool = False

    @classmethod
    def from_run(cls, run_dir: str | Path, input_path: str | Path | None = None) -> MapInput:
        """A run folder's trajectory.tum, points.ply (else mesh.ply), landmarks.csv and
        run.json's input and source options.

        Raises:
            InputError: as :func:`build_map`.
        """
        run = read_run(run_dir)
        trajectory = run.trajectory()
        if len(trajectory) == 0:
            raise InputError(f"{run.files['trajectory']}: holds no poses")
        metrics = run.record.get("metrics")
        mono = isinstance(metrics, dict) and metrics.get("mode") == "mono"
        kind = _map_kind(run.pipeline, run.path, mono)
        source_path = run.input_path(input_path)
        return cls(
            run.pipeline,
            trajectory,
            source_path,
            run.source_options,
            run.path,
            str(run.files["trajectory"]),
            floor_points=_floor_points(run) if kind == "depth" else None,
            landmarks=run.landmarks() if kind == "landmarks" else None,
            mono=mono,
        )

    @classmethod
    def from_result(
        cls,
        pipeline: str,
        result: SlamResult,
        input_path: str | Path,
        source_options: dict[str, Any],
        run_path: Path,
        mono: bool = False,
    ) -> MapInput:
        """A run's result as it is in memory (``slamcli run --map``): each depth frame takes
        the pose the run gave that very frame."""
        assert result.trajectory is not None
        floor = None
        if result.points is not None and len(result.points):
            floor = (np.asarray(result.points, dtype=np.float64), "points.ply")
        elif result.mesh is not None and len(result.mesh.vertices):
            floor = (np.asarray(result.mesh.vertices, dtype=np.float64), "mesh.ply")
        return cls(
            pipeline,
            result.trajectory,
            Path(input_path),
            dict(source_options),
            run_path,
            "the run's trajectory",
            exact=True,
            floor_points=floor,
            landmarks=result.landmarks,
            mono=mono,
        )


def build_map(
    run_dir: str | Path,
    *,
    settings: MapSettings | None = None,
    input_path: str | Path | None = None,
    progress: ProgressFn | None = None,
) -> BuiltMap:
    """Build an occupancy grid from a run folder (rules in the module docstring).

    Args:
        run_dir: a run folder with trajectory.tum and run.json (and landmarks.csv for EKF runs).
        input_path: the run's input log, when it is not where run.json says.

    Raises:
        InputError: the folder lacks run.json, trajectory.tum (or landmarks.csv for an EKF run),
            run.json names no pipeline that has a map, the input moved, no frame has a pose, no
            floor was found. FormatError: a broken run.json. ConfigError: a bad setting.
    """
    cfg = (settings or MapSettings()).checked()
    return build(MapInput.from_run(run_dir, input_path), cfg, progress)


def build(
    given: MapInput, settings: MapSettings | None = None, progress: ProgressFn | None = None
) -> BuiltMap:
    """Build an occupancy grid from ``given`` (rules in the module docstring).

    Raises:
        InputError: no map for the run's pipeline, no frame has a pose, no floor was found.
        ConfigError: a bad setting.
    """
    t0 = time.perf_counter()
    cfg = (settings or MapSettings()).checked()
    if _map_kind(given.pipeline, given.run_path, given.mono) == "landmarks":
        built = _landmark_map(given, cfg)
    else:
        built = _depth_map(given, cfg, progress)
    report = built.report
    report["cells"] = cell_counts(built.grid)
    report["time_s"] = round(time.perf_counter() - t0, 3)
    return built


# --- run folder ------------------------------------------------------------------------------


def _map_kind(pipeline: str | None, run_path: Path, mono: bool) -> str:
    """The kind of map (a value of :data:`MAP_KINDS`) for the pipeline the run declares."""
    if pipeline is None:
        raise InputError(
            f"{run_path / 'run.json'}: does not say which pipeline made the run",
            hint="map build takes folders written by 'slamcli run PIPELINE' (run.json's "
            "'pipeline' or 'command')",
        )
    if pipeline not in MAP_KINDS:
        raise InputError(
            f"{run_path}: a {pipeline} run; maps are built from runs of {', '.join(MAP_KINDS)}",
        )
    if mono:
        raise InputError(
            f"{run_path}: a monocular visual run: its map has no metric scale, so it cannot be "
            "laid on a metric occupancy grid",
            hint="build maps from RGB-D runs (slamcli run visual on an input with depth)",
        )
    return MAP_KINDS[pipeline]


def _floor_points(run: RunRecord) -> tuple[F64, str] | None:
    """Points to look for the floor in: points.ply, else mesh.ply's vertices, else None."""
    for kind in ("points", "mesh"):
        path = run.files.get(kind)
        if path is not None:
            from slamcli.formats.mesh import read_points_ply

            cloud, _ = read_points_ply(path)
            if len(cloud):
                return cloud, path.name
    return None


# --- dense runs ------------------------------------------------------------------------------


def _depth_map(given: MapInput, cfg: MapSettings, progress: ProgressFn | None) -> BuiltMap:
    from slamcli.formats import open_source
    from slamcli.geometry import interpolate_poses

    trajectory, source_path = given.trajectory, given.input_path
    pose_at = _exact_poses(trajectory) if given.exact else None

    cams: list[F64] = []
    points: list[F32] = []
    accel_stamps: list[int] = []
    accel: list[F64] = []
    frames_read = without_pose = 0
    with open_source(source_path, **given.source_options) as source:
        total = source.info().frames
        for frame in _depth_and_imu(source):
            if isinstance(frame, tuple):
                accel_stamps.append(frame[0])
                accel.append(frame[1])
                continue
            frames_read += 1
            if progress:
                progress(frames_read, max(total, frames_read))
            if (frames_read - 1) % cfg.frame_step:
                continue
            pose = (
                pose_at.get(int(frame.stamp_ns))
                if pose_at is not None
                else _pose_at(trajectory, frame.stamp_ns, cfg.pose_max_dt_s)
            )
            if pose is None:
                without_pose += 1
                continue
            pts = _back_project(frame.depth_m, frame.camera, cfg.pixel_step, cfg.max_depth_m)
            cams.append(pose)
            points.append((pts @ pose[:3, :3].T + pose[:3, 3]).astype(np.float32))
    if not cams:
        within = "" if given.exact else f" (within {cfg.pose_max_dt_s * 1000:g} ms)"
        raise InputError(
            f"{source_path}: none of its {frames_read} depth frames has a pose in "
            f"{given.poses_from}{within}",
            hint="is --input the log this run was made from?",
        )
    poses = np.stack(cams)
    up = None
    if accel:
        valid, at = interpolate_poses(
            trajectory.stamps_ns, trajectory.world_from_body, np.asarray(accel_stamps)
        )
        up = up_from_accelerometer(at[valid], np.stack(accel)[valid]) if valid.any() else None
    up = up or up_from_cameras(poses)
    cloud, cloud_source = given.floor_points or (
        np.concatenate(points).astype(np.float64),
        "depth frames",
    )
    centre = poses[:, :3, 3].mean(axis=0)
    floor = find_floor(cloud, up.direction, centre, seed=cfg.seed)

    scans = _Scans()
    lo, hi = cfg.height_band_m
    for pose, world_pts in zip(poses, points, strict=True):
        cam = floor.to_floor(pose[:3, 3])[0]
        scans.scans.append(_clip_rays(cam, floor.to_floor(world_pts), lo, hi))
    path_xy = floor.to_floor(poses[:, :3, 3])[:, :2]
    grid = _carve(scans, path_xy, cfg)
    report = {
        "kind": "depth",
        "run": str(given.run_path),
        "input": str(source_path),
        "resolution_m": cfg.resolution_m,
        "height_band_m": list(cfg.height_band_m),
        "frames": {
            "read": frames_read,
            "used": len(cams),
            "without_pose": without_pose,
            "frame_step": cfg.frame_step,
            "pixel_step": cfg.pixel_step,
        },
        "rays": int(sum(len(s.hit) for s in scans.scans)),
        "up": _up_record(up),
        "floor": _floor_record(floor, up, cloud_source),
        **_common_record(grid, cfg),
    }
    return BuiltMap(grid.to_grid(), report, path_xy)


def _depth_and_imu(source: Any) -> Any:
    """The source's RGB-D frames, with (stamp, accel) tuples for its accelerometer readings when
    it has them."""
    from slamcli.types import ImuFrame, RgbdFrame

    try:
        frames = iter(source.frames(("rgbd", "imu")))
        first = next(frames, None)
    except InputError:
        # A log without an IMU stream (an MCAP without Imu messages) refuses the kind.
        frames = iter(source.frames(("rgbd",)))
        first = next(frames, None)
    if first is None:
        return
    for frame in itertools.chain([first], frames):
        if isinstance(frame, ImuFrame):
            if frame.accel_mps2 is not None:
                yield (int(frame.stamp_ns), np.asarray(frame.accel_mps2, dtype=np.float64))
        elif isinstance(frame, RgbdFrame):
            yield frame


def _exact_poses(trajectory: Trajectory) -> dict[int, F64]:
    """World-from-body pose by stamp (ns)."""
    return {
        int(t): np.asarray(p, dtype=np.float64)
        for t, p in zip(trajectory.stamps_ns, trajectory.world_from_body, strict=True)
    }


def _pose_at(trajectory: Trajectory, stamp_ns: int, max_dt_s: float) -> F64 | None:
    from slamcli.geometry import interpolate_poses

    stamps = trajectory.stamps_ns
    k = int(np.searchsorted(stamps, stamp_ns))
    near = [abs(int(stamps[i]) - stamp_ns) for i in (k - 1, k) if 0 <= i < len(stamps)]
    if not near or min(near) > max_dt_s * 1e9:
        return None
    _, pose = interpolate_poses(stamps, trajectory.world_from_body, np.array([stamp_ns]))
    return np.asarray(pose[0], dtype=np.float64)


def _back_project(depth_m: F32, camera: PinholeCamera, step: int, max_depth_m: float) -> F64:
    """(M, 3) camera-frame points of every ``step``-th pixel with a depth in (0, max].

    A frame from a distorted camera (read without ``--undistort``) keeps its lens distortion:
    each pixel is undistorted before it is lifted, so the points follow the true rays.
    """
    z = np.asarray(depth_m, dtype=np.float32)[::step, ::step]
    rows, cols = np.nonzero(np.isfinite(z) & (z > 0) & (z <= max_depth_m))
    d = z[rows, cols].astype(np.float64)
    pixels = undistort_points(camera, np.stack([cols * step, rows * step], axis=1))
    return unproject(camera, pixels, d)


def _clip_rays(cam: F64, pts: F64, lo: float, hi: float) -> _Rays:
    """2-D rays (floor frame) for one frame: the parts of the camera-to-point rays at or below
    ``hi``; a ray ending in the band is a hit."""
    hc, hp = float(cam[2]), pts[:, 2]
    delta = hp - hc
    with np.errstate(divide="ignore", invalid="ignore"):
        t_cross = np.where(delta != 0, (hi - hc) / delta, np.inf)
    if hc <= hi:
        t0 = np.zeros_like(hp)
        t1 = np.where(hp <= hi, 1.0, t_cross)
    else:
        t0 = np.where(hp <= hi, t_cross, 1.0)
        t1 = np.ones_like(hp)
    keep = t1 > t0 if hc > hi else np.ones(hp.shape, dtype=bool)
    a, d = cam[:2], pts[:, :2] - cam[:2]
    starts = a + t0[keep, None] * d[keep]
    ends = a + t1[keep, None] * d[keep]
    hit = ((hp >= lo) & (hp <= hi))[keep]
    return _Rays(starts.astype(np.float32), ends.astype(np.float32), hit)


def _carve(scans: _Scans, also_xy: F64, cfg: MapSettings) -> LogOddsGrid:
    """A grid covering the scans' rays and the points ``also_xy`` (N, 2), with every scan
    integrated."""
    box = scans.bounds()
    lo, hi = also_xy.min(axis=0), also_xy.max(axis=0)
    if box is not None:
        lo, hi = np.minimum(lo, box[0]), np.maximum(hi, box[1])
    grid = LogOddsGrid.covering(lo, hi, cfg.resolution_m, cfg.margin_m)
    for s in scans.scans:
        grid.integrate(s.starts, s.ends, s.hit)
    return grid


# --- EKF runs --------------------------------------------------------------------------------


def _landmark_map(given: MapInput, cfg: MapSettings) -> BuiltMap:
    from slamcli.formats import open_source
    from slamcli.geometry import interpolate_planar, se3_to_planar
    from slamcli.types import LandmarkFrame

    trajectory, source_path = given.trajectory, given.input_path
    landmarks = given.landmarks
    if landmarks is None:
        landmarks = LandmarkMap(np.zeros(0, np.int64), np.zeros((0, 2)))
    planar = se3_to_planar(trajectory.world_from_body)
    stamps: list[int] = []
    frames: list[LandmarkFrame] = []
    with open_source(source_path, **given.source_options) as source:
        for frame in source.frames(("landmarks",)):
            if isinstance(frame, LandmarkFrame) and len(frame.ranges_m):
                stamps.append(int(frame.stamp_ns))
                frames.append(frame)
    at = (
        interpolate_planar(trajectory.stamps_ns, planar, np.asarray(stamps, dtype=np.int64))
        if stamps
        else np.zeros((0, 3))
    )
    scans = _Scans()
    for pose, frame in zip(at, frames, strict=True):
        if not np.all(np.isfinite(pose)):
            continue
        reach = np.asarray(frame.ranges_m, dtype=np.float64) - cfg.landmark_radius_m
        ok = np.isfinite(reach) & (reach > 0)
        angle = pose[2] + np.asarray(frame.bearings_rad, dtype=np.float64)[ok]
        ends = pose[:2] + reach[ok, None] * np.stack([np.cos(angle), np.sin(angle)], axis=1)
        starts = np.broadcast_to(pose[:2], ends.shape)
        scans.scans.append(
            _Rays(starts.astype(np.float32), ends.astype(np.float32), np.zeros(len(ends), bool))
        )
    used = len(scans.scans)
    path_xy = _densify(planar[:, :2], cfg.resolution_m / 2)
    extra = [path_xy - cfg.robot_radius_m, path_xy + cfg.robot_radius_m]
    if len(landmarks):
        extra += [landmarks.xy - cfg.landmark_radius_m, landmarks.xy + cfg.landmark_radius_m]
    grid = _carve(scans, np.concatenate(extra), cfg)
    grid.set_cells(grid.disc_cells(path_xy, cfg.robot_radius_m), L_MIN)
    if len(landmarks):
        grid.set_cells(grid.disc_cells(landmarks.xy, cfg.landmark_radius_m), L_MAX)
    report = {
        "kind": "landmarks",
        "run": str(given.run_path),
        "input": str(source_path),
        "resolution_m": cfg.resolution_m,
        "landmarks": len(landmarks),
        "landmark_radius_m": cfg.landmark_radius_m,
        "robot_radius_m": cfg.robot_radius_m,
        "frames": {"read": len(frames), "used": used, "without_pose": len(frames) - used},
        "rays": int(sum(len(s.hit) for s in scans.scans)),
        **_common_record(grid, cfg),
    }
    return BuiltMap(grid.to_grid(), report, planar[:, :2].copy())


def _densify(xy: F64, spacing: float) -> F64:
    """The polyline ``xy`` (N, 2) with points at most ``spacing`` apart."""
    if len(xy) < 2:
        return np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    seg = np.diff(xy, axis=0)
    n = np.maximum(np.ceil(np.linalg.norm(seg, axis=1) / spacing).astype(np.int64), 1)
    owner = np.repeat(np.arange(len(seg)), n)
    t = (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
    return np.concatenate([xy[owner] + t[:, None] * seg[owner], xy[-1:]])


# --- report ----------------------------------------------------------------------------------


def cell_counts(grid: OccupancyGrid) -> dict[str, int]:
    """Cells as a trinary map.yaml stores them: free (p <= 0.196), occupied (p >= 0.65), and
    unknown (the rest, ``unobserved`` of them never seen)."""
    prob = np.asarray(grid.prob)
    known = ~np.isnan(prob)
    free = int(np.count_nonzero(known & (np.rint(prob * 100) <= round(FREE_THRESH * 100))))
    occ = int(np.count_nonzero(known & (np.rint(prob * 100) >= round(OCCUPIED_THRESH * 100))))
    return {
        "total": int(prob.size),
        "free": free,
        "occupied": occ,
        "unknown": int(prob.size) - free - occ,
        "unobserved": int(np.count_nonzero(~known)),
    }


def _common_record(grid: LogOddsGrid, cfg: MapSettings) -> dict[str, Any]:
    h, w = grid.shape
    return {
        "size_cells": [w, h],
        "size_m": [round(w * grid.resolution_m, 6), round(h * grid.resolution_m, 6)],
        "origin_xy_yaw": [float(grid.origin_xy[0]), float(grid.origin_xy[1]), 0.0],
        "logodds": {"occupied": L_OCC, "free": L_FREE, "min": L_MIN, "max": L_MAX},
        "settings": {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(cfg).items()},
    }


def _up_record(up: Up) -> dict[str, Any]:
    return {
        "method": up.method,
        "direction_world": [round(float(v), 6) for v in up.direction],
        "accelerometer_readings": up.readings,
        "coherence": None if up.coherence is None else round(up.coherence, 4),
    }


def _floor_record(floor: FloorPlane, up: Up, source: str) -> dict[str, Any]:
    tilt = math.degrees(math.acos(float(np.clip(floor.normal @ up.direction, -1.0, 1.0))))
    return {
        "normal_world": [round(float(v), 6) for v in floor.normal],
        "offset_m": round(floor.offset, 6),
        "inliers": floor.inliers,
        "points": floor.points,
        "points_from": source,
        "angle_to_up_deg": round(tilt, 3),
        "floor_from_world": [[round(float(v), 9) for v in row] for row in floor.floor_from_world],
    }
