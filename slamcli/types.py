"""Core records shared by every module. numpy and the standard library only.

Conventions: poses are ``(N, 4, 4)`` float64 stacks named by their frames
(``world_from_body`` maps body coordinates into the world); times are int64 nanoseconds;
lengths are metres; images are ``(H, W, 3)`` uint8 RGB; depth is ``(H, W)`` float32 metres
with 0 or NaN meaning no reading.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import InputError

ProgressFn = Callable[[int, "int | None"], None]
"""Progress callback: ``progress(done, total)``; total is None when unknown."""


@dataclass(frozen=True)
class Trajectory:
    """A timed sequence of rigid poses.

    Attributes:
        stamps_ns: (N,) int64 nanoseconds, strictly increasing.
        world_from_body: (N, 4, 4) float64 homogeneous transforms.
    """

    stamps_ns: NDArray[np.int64]
    world_from_body: NDArray[np.float64]

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns, dtype=np.int64).reshape(-1)
        poses = np.asarray(self.world_from_body, dtype=np.float64)
        if poses.ndim != 3 or poses.shape[1:] != (4, 4) or poses.shape[0] != stamps.shape[0]:
            raise InputError(
                f"a trajectory needs (N,) stamps and (N,4,4) poses, got {stamps.shape} and "
                f"{poses.shape}"
            )
        if stamps.size > 1 and not np.all(np.diff(stamps) > 0):
            i = int(np.flatnonzero(np.diff(stamps) <= 0)[0])
            raise InputError(
                "a trajectory's stamps must be strictly increasing: pose "
                f"{i + 1} at {stamps[i + 1] * 1e-9:.9f} s follows pose {i} at "
                f"{stamps[i] * 1e-9:.9f} s",
                hint="sort the poses by time and drop repeated stamps",
            )
        object.__setattr__(self, "stamps_ns", stamps)
        object.__setattr__(self, "world_from_body", poses)

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    @property
    def positions(self) -> NDArray[np.float64]:
        """(N, 3) translation part in metres."""
        return self.world_from_body[:, :3, 3]

    @property
    def stamps_s(self) -> NDArray[np.float64]:
        """(N,) float64 seconds (for display and file edges only)."""
        return self.stamps_ns.astype(np.float64) * 1e-9

    def path_length(self) -> float:
        """Total travelled distance in metres."""
        if len(self) < 2:
            return 0.0
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum())

    def subset(self, index: NDArray[Any]) -> Trajectory:
        """The poses selected by a boolean mask or an increasing integer index."""
        return Trajectory(self.stamps_ns[index], self.world_from_body[index])


@dataclass(frozen=True)
class PinholeCamera:
    """A pinhole camera with OpenCV's distortion model (k1, k2, p1, p2[, k3, ...])."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()

    @property
    def K(self) -> NDArray[np.float64]:
        """(3, 3) intrinsic matrix."""
        return np.array(
            [[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]], dtype=np.float64
        )

    @property
    def is_distorted(self) -> bool:
        return any(abs(d) > 0.0 for d in self.distortion)

    def undistorted(self) -> PinholeCamera:
        """The same camera with its distortion removed (what an undistorted image follows)."""
        return PinholeCamera(self.width, self.height, self.fx, self.fy, self.cx, self.cy, ())

    def scaled(self, factor: float) -> PinholeCamera:
        """The camera for an image resized by ``factor`` (pixel-centre convention)."""
        return PinholeCamera(
            round(self.width * factor),
            round(self.height * factor),
            self.fx * factor,
            self.fy * factor,
            (self.cx + 0.5) * factor - 0.5,
            (self.cy + 0.5) * factor - 0.5,
            self.distortion,
        )

    def to_dict(self) -> dict[str, Any]:
        return {
            "width": self.width,
            "height": self.height,
            "fx": self.fx,
            "fy": self.fy,
            "cx": self.cx,
            "cy": self.cy,
            "distortion": list(self.distortion),
        }


@dataclass(frozen=True)
class RgbdFrame:
    """A colour image with registered depth.

    Attributes:
        stamp_ns: int64 nanoseconds of the colour image.
        rgb: (H, W, 3) uint8 RGB.
        depth_m: (H, W) float32 metres, 0 or NaN = no reading.
        camera: intrinsics both images follow.
        depth_stamp_ns: stamp of the depth image it was paired with.
        name: where the frame came from (file name, topic and index), for messages.
    """

    stamp_ns: int
    rgb: NDArray[np.uint8]
    depth_m: NDArray[np.float32]
    camera: PinholeCamera
    depth_stamp_ns: int | None = None
    name: str = ""


@dataclass(frozen=True)
class ImageFrame:
    """A colour or grey image. ``image`` is (H, W, 3) uint8 RGB or (H, W) uint8.
    ``body_from_camera`` (4, 4) places the camera on the body the source's ground truth and
    IMU refer to (None: the camera is the body)."""

    stamp_ns: int
    image: NDArray[np.uint8]
    camera: PinholeCamera | None = None
    name: str = ""
    body_from_camera: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class OdometryFrame:
    """Odometry: a body velocity (v m/s forward, omega rad/s yaw rate) and/or a pose.

    ``world_from_body`` is (4, 4) float64 when the source reports a pose.
    """

    stamp_ns: int
    v: float | None = None
    omega: float | None = None
    world_from_body: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class LandmarkFrame:
    """Range-bearing observations taken at one instant.

    Attributes:
        ids: (M,) int64 landmark ids, -1 where the correspondence is unknown.
        ranges_m: (M,) float64 metres.
        bearings_rad: (M,) float64 radians, counter-clockwise from the robot's heading.
    """

    stamp_ns: int
    ids: NDArray[np.int64]
    ranges_m: NDArray[np.float64]
    bearings_rad: NDArray[np.float64]


@dataclass(frozen=True)
class ImuFrame:
    """Inertial measurement. Either part may be missing (an accelerometer-only log)."""

    stamp_ns: int
    accel_mps2: NDArray[np.float64] | None = None
    gyro_radps: NDArray[np.float64] | None = None


@dataclass(frozen=True)
class StereoRig:
    """The geometry of a rectified stereo pair.

    Both images follow ``camera`` (rectified: no distortion, rows aligned); the right camera's
    centre sits ``baseline_m`` along the left camera's x axis, so a point at depth ``z`` shows
    in the right image ``fx * baseline_m / z`` pixels left of where it shows in the left one.

    Attributes:
        camera: the rectified intrinsics of both images.
        baseline_m: distance between the two camera centres (> 0).
        body_from_left: (4, 4) float64 pose of the rectified left camera on the body the
            source's ground truth and IMU refer to (identity when they refer to the left
            camera, as KITTI's do).
    """

    camera: PinholeCamera
    baseline_m: float
    body_from_left: NDArray[np.float64] = field(default_factory=lambda: np.eye(4))


@dataclass(frozen=True)
class StereoFrame:
    """A rectified stereo pair taken at one instant.

    Attributes:
        stamp_ns: int64 nanoseconds of the left image.
        left, right: (H, W) uint8 grey or (H, W, 3) uint8 RGB images, rectified, same size.
        rig: the pair's geometry.
        right_stamp_ns: stamp of the right image it was paired with.
        name: where the pair came from (file names, or topics and index), for messages.
    """

    stamp_ns: int
    left: NDArray[np.uint8]
    right: NDArray[np.uint8]
    rig: StereoRig
    right_stamp_ns: int | None = None
    name: str = ""


@dataclass(frozen=True)
class ScanFrame:
    """One sweep of a 2-D laser scanner, as ``sensor_msgs/LaserScan`` records it.

    Beam ``i`` points at ``angle_min_rad + i * angle_increment_rad`` in the sensor frame
    (counter-clockwise from its x axis). Ranges are kept as recorded; which are readings
    follows the message's rules (REP 117): a reading is finite and within
    ``[range_min_m, range_max_m]``; ``+inf`` or a value above ``range_max_m`` is no return
    (nothing within range along that beam), ``-inf`` or one below ``range_min_m`` is too close,
    NaN is an erroneous beam.

    Attributes:
        stamp_ns: int64 nanoseconds of the sweep.
        ranges_m: (N,) float32 metres.
        angle_min_rad: angle of the first beam.
        angle_increment_rad: angle between beams (non-zero; negative for a clockwise scanner).
        range_min_m, range_max_m: the scanner's valid range.
        body_from_sensor: (3,) float64 planar mounting (x m, y m, yaw rad) of the scanner on
            the body whose odometry the source reports.
        name: where the scan came from (file and line, or topic and index), for messages.
    """

    stamp_ns: int
    ranges_m: NDArray[np.float32]
    angle_min_rad: float
    angle_increment_rad: float
    range_min_m: float
    range_max_m: float
    body_from_sensor: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))
    name: str = ""

    def angles(self) -> NDArray[np.float64]:
        """(N,) float64 beam angles in the sensor frame."""
        n = len(self.ranges_m)
        return self.angle_min_rad + self.angle_increment_rad * np.arange(n, dtype=np.float64)

    def readings(self) -> NDArray[np.bool_]:
        """(N,) bool: the beams whose range is a reading (finite, within the valid range)."""
        r = self.ranges_m
        with np.errstate(invalid="ignore"):
            return np.isfinite(r) & (r >= self.range_min_m) & (r <= self.range_max_m)

    def no_returns(self) -> NDArray[np.bool_]:
        """(N,) bool: the beams that saw nothing within ``range_max_m`` (``+inf`` or beyond)."""
        r = self.ranges_m
        with np.errstate(invalid="ignore"):
            return np.isposinf(r) | (np.isfinite(r) & (r > self.range_max_m))


Frame = RgbdFrame | ImageFrame | OdometryFrame | LandmarkFrame | ImuFrame | ScanFrame | StereoFrame
"""Frame kinds, by the name a pipeline asks for: rgbd, image, odometry, landmarks, imu, scan,
stereo."""


@dataclass(frozen=True)
class TriangleMesh:
    """vertices (V, 3) float64 metres, faces (F, 3) int64, vertex_colors (V, 3) uint8 or None."""

    vertices: NDArray[np.float64]
    faces: NDArray[np.int64]
    vertex_colors: NDArray[np.uint8] | None = None


@dataclass(frozen=True)
class OccupancyGrid:
    """prob (H, W) float32 occupancy probability, NaN = unknown; row 0 is the lowest y.

    ``origin_xy_yaw`` is the pose of cell (0, 0)'s lower-left corner in the world (m, m, rad).
    ``source_format`` is how a reader found the grid stored (plain JSON-like data, e.g. a
    map_server YAML's mode, thresholds and text), so a writer can store it back the same way;
    None for grids made in memory. It takes no part in comparisons.
    """

    prob: NDArray[np.float32]
    resolution_m: float
    origin_xy_yaw: tuple[float, float, float] = (0.0, 0.0, 0.0)
    source_format: dict[str, Any] | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class LandmarkMap:
    """Point landmarks in the plane.

    Attributes:
        ids: (K,) int64 landmark ids (the log's ids with known correspondences, else the
            filter's own numbering).
        xy: (K, 2) float64 positions, metres.
        cov: (K, 2, 2) float64 position covariances, m², or None when unknown.
    """

    ids: NDArray[np.int64]
    xy: NDArray[np.float64]
    cov: NDArray[np.float64] | None = None

    def __len__(self) -> int:
        return int(self.ids.shape[0])


@dataclass
class SlamResult:
    """What a pipeline produces; every field is optional. metrics and counts go to run.json."""

    trajectory: Trajectory | None = None
    keyframes: Trajectory | None = None
    landmarks: LandmarkMap | None = None
    pose_covariances: NDArray[np.float64] | None = None
    """(N, 3, 3) covariance of (x, y, yaw) for each row of ``filtered`` if given, else of
    ``trajectory`` (planar pipelines)."""
    filtered: Trajectory | None = None
    """The filter's own path when ``trajectory`` is a smoothed one (planar pipelines)."""
    dead_reckoning: Trajectory | None = None
    """The odometry integrated alone, for comparison (planar pipelines)."""
    series: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    """Time series for the report, e.g. ``nis``: (K, 2) rows of stamp (s) and value; not
    written to run.json."""
    points: NDArray[np.float64] | None = None
    point_colors: NDArray[np.uint8] | None = None
    mesh: TriangleMesh | None = None
    grid: OccupancyGrid | None = None
    pose_graph: tuple[NDArray[np.float64], list[Any]] | None = None
    """The final pose graph, for other tools: (N, 4, 4) world_from_node poses and
    :class:`slamcli.graphs.pose_graph.Edge` edges between their indices (written as graph.g2o)."""
    robots: dict[int, Trajectory] = field(default_factory=dict)
    """Each robot's trajectory, by robot id, when the run had several robots (one world frame;
    ``trajectory`` is the first robot's)."""
    metrics: dict[str, Any] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    imu_states: NDArray[np.float64] | None = None
    """(K, 10) per keyframe of a visual-inertial run: stamp (ns, as float64), the body's
    velocity (m/s, world frame), the gyroscope bias (rad/s) and the accelerometer bias (m/s²),
    written as imu_states.csv."""
    data_loss: list[str] = field(default_factory=list)
    """Input the pipeline had to leave out (an IMU's gaps or repeated stamps), one line each:
    the run ends with exit code 3, as for a damaged log."""
    truth_to_estimate: NDArray[np.float64] | None = None
    """(4, 4) pose of what ``trajectory`` follows on the ground truth's body, when it is not
    the body: the ground truth is moved onto it before scoring (a monocular run follows its
    camera, since a map without metric scale cannot carry the camera's offset on the body)."""
