"""A synthetic RGB-D sequence with exact ground truth, written as a TUM RGB-D folder.

The scene is a closed room, 6 m x 5 m x 2.6 m (x in [-3, 3], y in [-2.5, 2.5], z in [0, 2.6],
z up, gravity along -z), with seven boxes on the floor, one stacked on another. Every surface
carries its own seeded procedural texture (tiles, posters, checkerboards, text, shapes from
centimetres to half a metre), so feature detectors find corners at every scale and distance,
and a static point light shades it, so brightness stays constant from any viewpoint.

Images are ray cast with Open3D's ``RaycastingScene`` through a pinhole camera
(``fx = fy = 0.8 * width``, principal point at the image centre) in the optical frame
convention (x right, y down, z forward). Colour is the mean of 2x2 sub-pixel rays, sampled
from a texture mip level matched to the pixel footprint; depth is the z-depth of the ray
through the pixel centre.

The camera follows a smooth closed loop whose phase runs once over the sequence, so the
last frame sits one step before the first. Short sequences sway the view by up to 20 degrees
around a forward look at the boxes; sequences of 18 s or more turn once around the whole
room. The loop's size scales with the duration so speeds stay handheld: below 0.45 m/s and
35 degrees/s at 30 Hz.

With ``noise=True`` depth follows a Kinect-style structured-light model: Gaussian noise and
1/8-pixel quantisation in disparity (so error grows with z squared), holes at random blobs,
at depth discontinuities and at grazing angles; colour gets mild Gaussian noise, and the
accelerometer noise and a constant bias. In both modes depth outside [0.4, 6.0] m reads 0.

Folder layout (as TUM RGB-D)::

    rgb/<stamp>.png      (H, W, 3) 8-bit colour
    depth/<stamp>.png    (H, W) uint16, metres * 5000, 0 = no reading
    rgb.txt, depth.txt   "timestamp filename" lists with TUM comment headers
    groundtruth.txt      "t tx ty tz qx qy qz qw", world_from_camera at the colour stamps
    accelerometer.txt    "t ax ay az", specific force in the camera frame, m/s^2
    camera.yaml          width, height, fx, fy, cx, cy, distortion: [], depth_factor: 5000

Colour stamps start at 1700000000.000000 s; each depth image carries its colour stamp plus
5 ms, as in real Kinect logs, so readers must associate the two streams. Both images are
rendered at the colour instant: at handheld speeds the 5 ms moves the view by less than the
depth noise.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError
from slamcli.formats.text import format_stamp
from slamcli.formats.trajectory import tum_lines
from slamcli.geometry import make_pose
from slamcli.geometry.camera import unproject
from slamcli.rundir import RunDir
from slamcli.synth.textures import TEXEL_M, paint_texture
from slamcli.types import PinholeCamera, ProgressFn, Trajectory

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]
F32 = NDArray[np.float32]

FPS = 30.0
"""Colour frame rate in Hz."""
EPOCH_NS = 1_700_000_000 * 1_000_000_000
"""Stamp of the first colour frame."""
DEPTH_OFFSET_NS = 5_000_000
"""Depth stamps lag the colour stamps by this much."""
DEPTH_FACTOR = 5000
"""Depth PNG units per metre (TUM convention)."""
MIN_RANGE_M = 0.4
MAX_RANGE_M = 6.0
GRAVITY_MPS2 = 9.80665

ROOM_MIN = np.array([-3.0, -2.5, 0.0])
ROOM_MAX = np.array([3.0, 2.5, 2.6])
LIGHT_POSITION = np.array([0.0, 0.0, 2.45])

_MIP_LEVELS = 5
_SUPERSAMPLE_OFFSETS = ((-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25))

# Kinect v1 structured light: focal length (px) times projector baseline (m), and the
# disparity noise and step in pixels; together they give sigma_z ~= 1.6 mm at 1 m, 6 mm at 2 m.
_KINECT_FOCAL_BASELINE = 580.0 * 0.075
_DISPARITY_SIGMA_PX = 0.07
_DISPARITY_STEP_PX = 1.0 / 8.0
_COLOUR_SIGMA = 1.0
_ACCEL_SIGMA = 0.03
_ACCEL_BIAS_SIGMA = 0.05
_GRAZING_COS = 0.12

# (centre x, centre y, bottom z, size x, size y, size z, yaw in degrees); all clear of the
# camera loop, which stays within x in [-1.4, 0.6], |y| <= 0.75.
_BOXES = (
    (2.05, -0.90, 0.0, 0.80, 0.60, 0.50, 20.0),
    (2.30, 0.70, 0.0, 0.50, 0.50, 0.90, -10.0),
    (2.30, 0.70, 0.9, 0.30, 0.35, 0.25, 15.0),
    (1.65, 1.75, 0.0, 0.40, 0.60, 0.35, 35.0),
    (-2.30, 1.60, 0.0, 0.70, 0.50, 0.60, 0.0),
    (-1.90, -1.80, 0.0, 0.60, 0.60, 0.40, -25.0),
    (0.30, -2.10, 0.0, 1.00, 0.40, 0.75, 5.0),
)

_RNG_TEXTURES, _RNG_SENSOR, _RNG_IMU = 0, 1, 2


@dataclass(frozen=True)
class Surface:
    """A textured rectangle: ``origin + a * u_axis + b * v_axis`` for a <= size_u, b <= size_v.

    Attributes:
        name: e.g. ``"floor"``, ``"wall+x"``, ``"box2.top"``.
        kind: texture family: ``floor``, ``wall``, ``ceiling`` or ``box``.
        origin: (3,) metres, world frame.
        u_axis, v_axis: (3,) orthonormal edge directions.
        size_u, size_v: edge lengths in metres.
    """

    name: str
    kind: str
    origin: F64
    u_axis: F64
    v_axis: F64
    size_u: float
    size_v: float

    @property
    def normal(self) -> F64:
        """(3,) unit normal ``u_axis x v_axis``."""
        return np.cross(self.u_axis, self.v_axis)

    def corners(self) -> F64:
        """(4, 3) corners, counter-clockwise around ``normal``."""
        u, v = self.u_axis * self.size_u, self.v_axis * self.size_v
        return np.stack([self.origin, self.origin + u, self.origin + u + v, self.origin + v])


@dataclass(frozen=True)
class RoomScene:
    """The room's surfaces and their textures.

    Attributes:
        surfaces: every rectangle; surface ``i`` is triangles ``2i`` and ``2i + 1`` of the mesh.
        textures: per surface, mip levels of (rows, cols, 3) uint8 RGB; level ``l`` has texels of
            ``TEXEL_M * 2**l`` metres; columns run along ``u``, rows against ``v`` (row 0 at
            ``b = size_v``), so an upright image reads upright on a wall.
    """

    surfaces: tuple[Surface, ...]
    textures: tuple[tuple[NDArray[np.uint8], ...], ...]

    def mesh(self) -> tuple[F64, NDArray[np.int64]]:
        """Vertices (4S, 3) float64 metres and faces (2S, 3) int64 of all surfaces."""
        vertices = np.concatenate([s.corners() for s in self.surfaces])
        base = 4 * np.arange(len(self.surfaces))[:, None]
        faces = np.concatenate(
            [base + np.array([0, 1, 2]), base + np.array([0, 2, 3])], axis=1
        ).reshape(-1, 3)
        return vertices, faces.astype(np.int64)

    @property
    def normals(self) -> F64:
        """(S, 3) unit normals of the surfaces."""
        return np.stack([s.normal for s in self.surfaces])


def room_scene(seed: int = 0) -> RoomScene:
    """Build the room with its boxes and seeded textures (same seed -> identical textures)."""
    import cv2

    cv2.setRNGSeed(seed)
    rng = np.random.default_rng([seed, _RNG_TEXTURES])
    surfaces = _room_surfaces()
    textures = []
    for s in surfaces:
        cols = max(8, round(s.size_u / TEXEL_M))
        rows = max(8, round(s.size_v / TEXEL_M))
        level0 = paint_texture(rng, rows, cols, s.kind)
        levels: list[NDArray[np.uint8]] = [level0]
        for _ in range(1, _MIP_LEVELS):
            prev = levels[-1]
            if min(prev.shape[:2]) < 4:
                break
            levels.append(np.asarray(cv2.pyrDown(prev), dtype=np.uint8))
        textures.append(tuple(levels))
    return RoomScene(tuple(surfaces), tuple(textures))


def _room_surfaces() -> list[Surface]:
    x0, y0, z0 = ROOM_MIN
    x1, y1, z1 = ROOM_MAX
    ex, ey, ez = np.eye(3)
    sx, sy, sz = ROOM_MAX - ROOM_MIN
    surfaces = [
        Surface("floor", "floor", np.array([x0, y0, z0]), ex, ey, sx, sy),
        Surface("ceiling", "ceiling", np.array([x0, y1, z1]), ex, -ey, sx, sy),
        # Walls run left to right as seen from inside the room, so text on them reads.
        Surface("wall-y", "wall", np.array([x1, y0, z0]), -ex, ez, sx, sz),
        Surface("wall+x", "wall", np.array([x1, y1, z0]), -ey, ez, sy, sz),
        Surface("wall+y", "wall", np.array([x0, y1, z0]), ex, ez, sx, sz),
        Surface("wall-x", "wall", np.array([x0, y0, z0]), ey, ez, sy, sz),
    ]
    for i, (cx, cy, bz, bx, by, bh, yaw_deg) in enumerate(_BOXES):
        c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
        ax, ay = np.array([c, s, 0.0]), np.array([-s, c, 0.0])
        base = np.array([cx, cy, bz]) - ax * bx / 2 - ay * by / 2
        corners = [base, base + ax * bx, base + ax * bx + ay * by, base + ay * by]
        edges = [(ax, bx), (ay, by), (-ax, bx), (-ay, by)]
        for k, (corner, (axis, length)) in enumerate(zip(corners, edges, strict=True)):
            surfaces.append(Surface(f"box{i}.side{k}", "box", corner, axis, ez, length, bh))
        top = base + np.array([0.0, 0.0, bh])
        surfaces.append(Surface(f"box{i}.top", "box", top, ax, ay, bx, by))
    return surfaces


def camera_for_size(width: int, height: int) -> PinholeCamera:
    """The synthetic camera: ``fx = fy = 0.8 * width``, principal point at the image centre."""
    f = 0.8 * width
    return PinholeCamera(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, ())


@dataclass(frozen=True)
class _PathShape:
    """Amplitudes of the camera loop for one sequence duration (metres and radians)."""

    duration_s: float
    radius_x: float
    radius_y: float
    height_amp: float
    full_turn: bool
    yaw_amp: float
    pitch_amp: float
    roll_amp: float

    @classmethod
    def for_duration(cls, duration_s: float) -> _PathShape:
        # Each amplitude is the smaller of a size that looks natural and the one whose peak
        # rate (amplitude x angular frequency) stays at a handheld limit.
        w1 = 2 * math.pi / duration_s
        radius_x = min(1.0, 0.40 / w1)
        return cls(
            duration_s=duration_s,
            radius_x=radius_x,
            radius_y=0.75 * radius_x,
            height_amp=min(0.10, 0.04 / (2 * w1)),
            full_turn=duration_s >= 18.0,
            yaw_amp=min(math.radians(20.0), math.radians(24.0) / w1),
            pitch_amp=min(math.radians(6.0), math.radians(8.0) / (2 * w1)),
            roll_amp=min(math.radians(3.0), math.radians(4.0) / w1),
        )


_PATH_CENTRE = np.array([-0.4, 0.0, 1.35])
_PITCH0 = math.radians(-17.0)


def _path_position(shape: _PathShape, t_s: F64) -> tuple[F64, F64]:
    """Positions (N, 3) m and accelerations (N, 3) m/s^2 of the camera at times ``t_s`` (N,)."""
    w1 = 2 * math.pi / shape.duration_s
    phase = w1 * t_s
    pos = np.stack(
        [
            shape.radius_x * np.cos(phase),
            shape.radius_y * np.sin(phase),
            shape.height_amp * np.sin(2 * phase),
        ],
        axis=1,
    )
    acc = -np.stack(
        [
            w1**2 * shape.radius_x * np.cos(phase),
            w1**2 * shape.radius_y * np.sin(phase),
            (2 * w1) ** 2 * shape.height_amp * np.sin(2 * phase),
        ],
        axis=1,
    )
    return pos + _PATH_CENTRE, acc


def _path_rotation(shape: _PathShape, t_s: F64) -> F64:
    """World-from-camera rotations (N, 3, 3) at times ``t_s`` (N,), optical frame."""
    phase = 2 * math.pi * t_s / shape.duration_s
    yaw = shape.yaw_amp * np.sin(phase + 0.7) + (phase if shape.full_turn else 0.0)
    pitch = _PITCH0 + shape.pitch_amp * np.sin(2 * phase + 0.3)
    roll = shape.roll_amp * np.sin(phase + 1.1)
    forward = np.stack(
        [np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], axis=1
    )
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    down = np.cross(forward, right)
    cr, sr = np.cos(roll)[:, None], np.sin(roll)[:, None]
    x_axis = cr * right + sr * down
    y_axis = -sr * right + cr * down
    return np.stack([x_axis, y_axis, forward], axis=2)


def camera_path(frames: int, fps: float = FPS) -> Trajectory:
    """Ground-truth world_from_camera poses (frames, 4, 4) at the colour stamps."""
    stamps_ns = colour_stamps_ns(frames, fps)
    t_s = (stamps_ns - EPOCH_NS).astype(np.float64) * 1e-9
    shape = _PathShape.for_duration(frames / fps)
    pos, _ = _path_position(shape, t_s)
    return Trajectory(stamps_ns, make_pose(_path_rotation(shape, t_s), pos))


def path_motion(frames: int, t_s: F64, fps: float = FPS) -> tuple[F64, F64]:
    """The loop of a ``frames``-frame sequence at ``fps`` at any times ``t_s`` (N,) in seconds
    after its first frame: world_from_camera poses (N, 4, 4) and accelerations (N, 3) m/s^2 of
    the camera centre in the world."""
    shape = _PathShape.for_duration(frames / fps)
    pos, acc = _path_position(shape, t_s)
    return make_pose(_path_rotation(shape, t_s), pos), acc


def colour_stamps_ns(frames: int, fps: float = FPS) -> NDArray[np.int64]:
    """(frames,) int64 colour stamps, rounded to whole microseconds so 6 decimals are exact."""
    us = np.rint(np.arange(frames) * (1e6 / fps)).astype(np.int64)
    return EPOCH_NS + us * 1000


def accelerometer(frames: int, fps: float = FPS) -> F64:
    """Noise-free specific force (frames, 3) in m/s^2 in the camera frame at the colour stamps.

    ``f = R_wc^T (a_w - g_w)`` with ``g_w = (0, 0, -9.80665)``, so a camera at rest reads
    +9.81 m/s^2 along the world's up direction.
    """
    stamps_ns = colour_stamps_ns(frames, fps)
    t_s = (stamps_ns - EPOCH_NS).astype(np.float64) * 1e-9
    shape = _PathShape.for_duration(frames / fps)
    _, acc = _path_position(shape, t_s)
    rot = _path_rotation(shape, t_s)
    specific = acc + np.array([0.0, 0.0, GRAVITY_MPS2])
    return np.einsum("nji,nj->ni", rot, specific)


@dataclass
class RgbdWorld:
    """Everything needed to render the sequence: scene, camera and ground-truth poses.

    Attributes:
        scene: surfaces and textures.
        camera: intrinsics of both images.
        trajectory: world_from_camera poses at the colour stamps.
        depth_stamps_ns: (N,) int64 stamps of the depth images.
    """

    scene: RoomScene
    camera: PinholeCamera
    trajectory: Trajectory
    depth_stamps_ns: NDArray[np.int64]
    _raycaster: Any = field(default=None, repr=False)
    # Rays through the pixels in the camera frame, per set of sub-pixel offsets (the same for
    # every pose).
    _camera_rays: dict[tuple[tuple[float, float], ...], F64] = field(
        default_factory=dict, repr=False
    )
    # Per-surface arrays of the scene for the shading kernels, built on first use.
    _table: dict[str, NDArray[Any]] | None = field(default=None, repr=False)

    def cast(self, world_from_cam: F64) -> tuple[F32, NDArray[np.int32]]:
        """Ray cast through the pixel centres from a (4, 4) world_from_camera pose.

        Returns:
            depth (H, W) float32 z-depth in metres (inf where nothing is hit, no range limit),
            surface (H, W) int32 index into ``scene.surfaces`` (-1 where nothing is hit).
        """
        t, prim = self._cast(self._rays(world_from_cam, ((0.0, 0.0),)))
        return t[0], _surface_ids(t[0], prim[0])

    def render(
        self, world_from_cam: F64, rng: np.random.Generator | None = None
    ) -> tuple[NDArray[np.uint8], F32]:
        """Render one view from a (4, 4) world_from_camera pose.

        Args:
            world_from_cam: (4, 4) pose of the optical frame.
            rng: the noise generator; None renders without sensor noise.

        Returns:
            rgb (H, W, 3) uint8 and depth (H, W) float32 metres, 0 = no reading.
        """
        offsets = ((0.0, 0.0), *_SUPERSAMPLE_OFFSETS)
        rays = self._rays(world_from_cam, offsets)
        t, prim = self._cast(rays)
        colour = self._shade(rays[1:], t[1:], prim[1:])
        depth = t[0].copy()
        if rng is not None:
            sid = _surface_ids(t[0], prim[0])
            dirs = np.ascontiguousarray(rays[0, ..., 3:])
            depth = _kinect_depth(depth, sid, dirs, self.scene.normals, rng)
            colour += rng.normal(0.0, _COLOUR_SIGMA, colour.shape).astype(np.float32)
        depth[~((depth >= MIN_RANGE_M) & (depth <= MAX_RANGE_M))] = 0.0
        rgb = np.clip(np.rint(colour), 0, 255).astype(np.uint8)
        return rgb, depth.astype(np.float32)

    def render_colour(self, world_from_cam: F64) -> F32:
        """Noise-free colour (H, W, 3) float32 RGB of one view, not yet rounded or clipped to
        [0, 255]: the mean of the 2x2 sub-pixel rays :meth:`render` shades, without its depth
        ray."""
        rays = self._rays(world_from_cam, _SUPERSAMPLE_OFFSETS)
        t, prim = self._cast(rays)
        return self._shade(rays, t, prim)

    def _rays(self, world_from_cam: F64, offsets: tuple[tuple[float, float], ...]) -> F32:
        """Rays (K, H, W, 6) float32 from a (4, 4) world_from_camera pose, one image per pixel
        offset: the camera centre (world frame, metres), then the world direction through the
        offset pixel position, scaled to unit z in the camera frame."""
        cam = self.camera
        camera_rays = self._camera_rays.get(offsets)
        if camera_rays is None:
            uv = np.stack(
                np.meshgrid(np.arange(cam.width, dtype=np.float64), np.arange(cam.height)),
                axis=-1,
            )
            camera_rays = np.stack([unproject(cam, uv + offset, 1.0) for offset in offsets])
            self._camera_rays[offsets] = camera_rays
        from slamcli.synth._render_kernels import pack_rays

        out = np.empty((len(offsets), cam.height, cam.width, 6), dtype=np.float32)
        centre, rot = world_from_cam[:3, 3].copy(), world_from_cam[:3, :3]
        for k, rays in enumerate(camera_rays):
            pack_rays(centre, rays @ rot.T, out[k])
        return out

    def _cast(self, rays: F32) -> tuple[F32, NDArray[np.uint32]]:
        """First hits of rays (K, H, W, 6) from :meth:`_rays`: the ray parameter (K, H, W)
        float32 in units of the direction's length, so the z-depth in metres (inf for a miss),
        and the index (K, H, W) uint32 of the hit mesh triangle."""
        from slamcli.backends import import_open3d

        o3d = import_open3d()

        if self._raycaster is None:
            vertices, faces = self.scene.mesh()
            caster = o3d.t.geometry.RaycastingScene()
            caster.add_triangles(
                o3d.core.Tensor.from_numpy(np.ascontiguousarray(vertices, dtype=np.float32)),
                o3d.core.Tensor.from_numpy(np.ascontiguousarray(faces, dtype=np.uint32)),
            )
            self._raycaster = caster
        hits = self._raycaster.cast_rays(o3d.core.Tensor.from_numpy(rays))
        return hits["t_hit"].numpy(), hits["primitive_ids"].numpy()

    def _shade(self, rays: F32, t: F32, prim: NDArray[np.uint32]) -> F32:
        """Mean shaded texture colour (H, W, 3) float32 over the K images of rays (K, H, W, 6)
        from :meth:`_rays`, with their hits ``t`` and ``prim`` (K, H, W) from :meth:`_cast`;
        a ray that hits nothing counts as black.

        Each hit samples its surface's texture bilinearly at the mip level whose texels match
        the ray's footprint, and is lit by the point light at ``LIGHT_POSITION``.
        """
        import cv2

        from slamcli.synth import _render_kernels as kernels

        views, height, width = t.shape
        n = views * height * width
        table = self._surface_table()
        sid = np.empty(n, dtype=np.int32)
        footprint, a, b, shade = (np.empty(n, dtype=np.float32) for _ in range(4))
        kernels.hit_geometry(
            rays.reshape(n, 6),
            t.reshape(n),
            prim.reshape(n),
            table["origin"],
            table["u"],
            table["v"],
            table["normal"],
            LIGHT_POSITION.astype(np.float32),
            np.float32(2.0 * self.camera.fx),
            np.float32(TEXEL_M),
            sid,
            footprint,
            a,
            b,
            shade,
        )
        # The mip level is the rounded log2 of the footprint in level-0 texels. Samples are
        # grouped by (surface, level), each group in ray order and padded to whole map rows.
        log2_footprint = np.log2(footprint)
        counts = np.zeros(len(self.scene.surfaces) * _MIP_LEVELS, dtype=np.int64)
        kernels.count_keys(sid, log2_footprint, table["levels"], _MIP_LEVELS, counts)
        rows = -(-counts // _SAMPLE_ROW)
        starts = (np.cumsum(rows) - rows) * _SAMPLE_ROW
        total = int(rows.sum()) * _SAMPLE_ROW
        map_x = np.zeros(total, dtype=np.float32)
        map_y = np.zeros(total, dtype=np.float32)
        sample = np.empty(n, dtype=np.int32)
        kernels.place_samples(
            sid,
            log2_footprint,
            a,
            b,
            table["size_v"],
            table["levels"],
            table["texels"],
            starts,
            map_x,
            map_y,
            sample,
        )
        samples = np.empty((total, 3), dtype=np.uint8)
        for key in np.flatnonzero(counts):
            surface, lv = divmod(int(key), _MIP_LEVELS)
            block = slice(int(starts[key]), int(starts[key] + rows[key] * _SAMPLE_ROW))
            shape = (int(rows[key]), _SAMPLE_ROW)
            dst = samples[block].reshape(*shape, 3)
            sampled = cv2.remap(
                self.scene.textures[surface][lv],
                map_x[block].reshape(shape),
                map_y[block].reshape(shape),
                dst=dst,
                interpolation=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_REFLECT_101,
            )
            if sampled is not dst:
                dst[...] = sampled
        colour = np.empty((height * width, 3), dtype=np.float32)
        kernels.mean_colour(samples, sample, shade, views, colour)
        return colour.reshape(height, width, 3)

    def _surface_table(self) -> dict[str, NDArray[Any]]:
        """Per-surface arrays for the shading kernels: origin, u, v, normal (S, 3) float32,
        size_v (S,) float32 metres and the number of mip levels (S,) int64; and the texel edge
        (L,) float32 metres of each mip level."""
        if self._table is None:
            surfaces = self.scene.surfaces
            self._table = {
                "origin": np.stack([x.origin for x in surfaces]).astype(np.float32),
                "u": np.stack([x.u_axis for x in surfaces]).astype(np.float32),
                "v": np.stack([x.v_axis for x in surfaces]).astype(np.float32),
                "normal": self.scene.normals.astype(np.float32),
                "size_v": np.array([x.size_v for x in surfaces], dtype=np.float32),
                "levels": np.array([len(t) for t in self.scene.textures], dtype=np.int64),
                "texels": np.array([TEXEL_M * 2.0**lv for lv in range(_MIP_LEVELS)], np.float32),
            }
        return self._table


_SAMPLE_ROW = 1024
"""Texture samples per row of a ``cv2.remap`` map (which caps each side below 32767)."""


def _surface_ids(t: F32, prim: NDArray[np.uint32]) -> NDArray[np.int32]:
    """Surface index (int32, -1 for a miss) of hits ``t`` (ray parameters, inf for a miss) on
    mesh triangles ``prim``, any matching shapes."""
    return np.where(~np.isfinite(t), -1, prim.astype(np.int64) // 2).astype(np.int32)


def _kinect_depth(
    depth: F32, sid: NDArray[np.int32], dirs: F32, normals: F64, rng: np.random.Generator
) -> F32:
    """Apply the structured-light depth model to a clean z-depth image (H, W) in metres."""
    import cv2

    h, w = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    z = np.where(valid, depth, 1.0).astype(np.float64)
    disparity = _KINECT_FOCAL_BASELINE / z + rng.normal(0.0, _DISPARITY_SIGMA_PX, (h, w))
    disparity = np.maximum(np.rint(disparity / _DISPARITY_STEP_PX), 1.0) * _DISPARITY_STEP_PX
    noisy: F32 = np.asarray(_KINECT_FOCAL_BASELINE / disparity, dtype=np.float32)

    holes = ~valid
    coarse = rng.standard_normal((h // 12 + 3, w // 12 + 3)).astype(np.float32)
    blobs = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_CUBIC)
    holes |= blobs > 2.0
    # Structured light loses the pattern where depth jumps: both sides of the edge go dark.
    jump = 0.03 + 0.02 * z
    edge = np.zeros((h, w), dtype=bool)
    dx = np.abs(np.diff(z, axis=1)) > np.maximum(jump[:, 1:], jump[:, :-1])
    dy = np.abs(np.diff(z, axis=0)) > np.maximum(jump[1:], jump[:-1])
    edge[:, 1:] |= dx
    edge[:, :-1] |= dx
    edge[1:] |= dy
    edge[:-1] |= dy
    edge = cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    holes |= edge
    n = normals[np.clip(sid, 0, None)]
    cos_inc = np.abs(np.einsum("hwc,hwc->hw", n, dirs)) / np.linalg.norm(dirs, axis=-1)
    holes |= cos_inc < _GRAZING_COS
    noisy[holes] = 0.0
    return noisy


def build_rgbd_world(frames: int, size: tuple[int, int] = (640, 480), seed: int = 0) -> RgbdWorld:
    """The scene, camera and ground-truth trajectory of a sequence, without writing anything.

    Args:
        frames: number of colour/depth pairs (>= 2).
        size: (width, height) in pixels.
        seed: texture seed (the camera path depends only on ``frames``).
    """
    _check_options(frames, size)
    trajectory = camera_path(frames)
    return RgbdWorld(
        scene=room_scene(seed),
        camera=camera_for_size(*size),
        trajectory=trajectory,
        depth_stamps_ns=trajectory.stamps_ns + DEPTH_OFFSET_NS,
    )


def _check_options(frames: int, size: tuple[int, int]) -> None:
    if frames < 2:
        raise ConfigError(f"frames: expected at least 2, got {frames}")
    width, height = size
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise ConfigError(
            f"size: expected width and height in [16, 4096] pixels, got {width}x{height}"
        )


def render_rgbd_sequence(
    out: str | Path,
    frames: int = 300,
    size: tuple[int, int] = (640, 480),
    seed: int = 0,
    noise: bool = False,
    force: bool = False,
    progress: ProgressFn | None = None,
) -> dict[str, Any]:
    """Render a sequence into ``out`` as a TUM RGB-D folder (layout in the module docstring).

    Args:
        out: output folder; must be empty or absent unless ``force``.
        frames: number of colour/depth pairs (>= 2), at 30 Hz.
        size: (width, height) in pixels.
        seed: seeds the textures and all noise; same arguments -> bit-identical files.
        noise: apply the Kinect-style depth model, colour and accelerometer noise.
        force: replace a non-empty folder (once the new sequence is complete).
        progress: called as ``progress(done, frames)`` after each frame.

    Returns:
        Summary: ``frames``, ``size``, ``camera`` (dict), ``duration_s``, ``path_length_m``,
        ``max_speed_mps``, ``max_rotation_dps``, ``closure_m``, ``closure_deg``, ``seed``,
        ``noise``, ``hole_fraction`` (mean share of depth pixels with no reading), ``out`` and
        ``files`` (paths of the index files, then the image folders).
    """
    import cv2

    # The folder is staged and renamed into place at the end: it is checked before rendering,
    # and an interrupted render leaves no half-written sequence.
    with RunDir(out, force=force) as run:
        world = build_rgbd_world(frames, size, seed)
        rgb_dir, depth_dir = run.file("rgb"), run.file("depth")
        run.staged("rgb").mkdir()
        run.staged("depth").mkdir()
        noise_rng = np.random.default_rng([seed, _RNG_SENSOR]) if noise else None
        traj = world.trajectory
        rgb_names = [f"rgb/{format_stamp(s, 6)}.png" for s in traj.stamps_ns]
        depth_names = [f"depth/{format_stamp(s, 6)}.png" for s in world.depth_stamps_ns]
        holes = 0
        png = [cv2.IMWRITE_PNG_COMPRESSION, 6]
        for i in range(frames):
            pose = traj.world_from_body[i]
            rgb, depth = world.render(pose, noise_rng)
            holes += int(np.count_nonzero(depth == 0))
            raw = np.rint(depth.astype(np.float64) * DEPTH_FACTOR).astype(np.uint16)
            with run.atomic(rgb_names[i]) as tmp:
                _imwrite(tmp, cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), png)
            with run.atomic(depth_names[i]) as tmp:
                _imwrite(tmp, raw, png)
            if progress is not None:
                progress(i + 1, frames)

        origin = f"slamcli synth rgbd, {frames} frames, {size[0]}x{size[1]}, seed {seed}, " + (
            "noise" if noise else "no noise"
        )
        files = [
            run.write_text("rgb.txt", _index("color images", origin, traj.stamps_ns, rgb_names)),
            run.write_text(
                "depth.txt", _index("depth maps", origin, world.depth_stamps_ns, depth_names)
            ),
            run.write_text("groundtruth.txt", _groundtruth_text(origin, traj)),
            run.write_text("accelerometer.txt", _accelerometer_text(origin, frames, seed, noise)),
            run.write_text("camera.yaml", _camera_yaml(world.camera)),
        ]
        summary = _summary(world, seed, noise)
        summary["hole_fraction"] = holes / (frames * size[0] * size[1])
        summary["out"] = str(run.path)
        summary["files"] = [str(p) for p in files] + [str(rgb_dir), str(depth_dir)]
    log.info("rendered %d frames into %s", frames, run.path)
    return summary


def _imwrite(path: Path, image: NDArray[Any], params: list[int]) -> None:
    import cv2

    from slamcli.errors import ExportError

    if not cv2.imwrite(str(path), image, params):
        raise ExportError(f"{path}: OpenCV could not write the image")


def _index(what: str, origin: str, stamps_ns: NDArray[np.int64], names: list[str]) -> str:
    lines = [f"# {what}", f"# file: '{origin}'", "# timestamp filename"]
    lines += [f"{format_stamp(s, 6)} {n}" for s, n in zip(stamps_ns, names, strict=True)]
    return "\n".join(lines) + "\n"


def _groundtruth_text(origin: str, traj: Trajectory) -> str:
    lines = ["# ground truth trajectory", f"# file: '{origin}'", "# timestamp tx ty tz qx qy qz qw"]
    return "\n".join([*lines, *tum_lines(traj, stamp_decimals=6)]) + "\n"


def _accelerometer_text(origin: str, frames: int, seed: int, noise: bool) -> str:
    acc = accelerometer(frames)
    if noise:
        rng = np.random.default_rng([seed, _RNG_IMU])
        bias = rng.normal(0.0, _ACCEL_BIAS_SIGMA, 3)
        acc = acc + bias + rng.normal(0.0, _ACCEL_SIGMA, acc.shape)
    lines = ["# accelerometer data", f"# file: '{origin}'", "# timestamp ax ay az"]
    for s, a in zip(colour_stamps_ns(frames), acc, strict=True):
        lines.append(f"{format_stamp(s, 6)} {a[0]:.6f} {a[1]:.6f} {a[2]:.6f}")
    return "\n".join(lines) + "\n"


def _camera_yaml(cam: PinholeCamera) -> str:
    return (
        "# synthetic pinhole camera, no distortion; depth PNG value = metres * depth_factor\n"
        f"width: {cam.width}\nheight: {cam.height}\n"
        f"fx: {cam.fx!r}\nfy: {cam.fy!r}\ncx: {cam.cx!r}\ncy: {cam.cy!r}\n"
        f"distortion: []\ndepth_factor: {DEPTH_FACTOR}\n"
    )


def _summary(world: RgbdWorld, seed: int, noise: bool) -> dict[str, Any]:
    from slamcli.geometry import rotation_angle

    traj = world.trajectory
    poses = traj.world_from_body
    dt = np.diff(traj.stamps_ns).astype(np.float64) * 1e-9
    step = np.linalg.norm(np.diff(traj.positions, axis=0), axis=1)
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    turn = rotation_angle(rel)
    closure_rot = poses[0, :3, :3].T @ poses[-1, :3, :3]
    return {
        "frames": len(traj),
        "size": [world.camera.width, world.camera.height],
        "camera": world.camera.to_dict(),
        "duration_s": float(traj.stamps_ns[-1] - traj.stamps_ns[0]) * 1e-9,
        "path_length_m": traj.path_length(),
        "max_speed_mps": float(np.max(step / dt)),
        "max_rotation_dps": float(np.degrees(np.max(turn / dt))),
        "closure_m": float(np.linalg.norm(traj.positions[-1] - traj.positions[0])),
        "closure_deg": float(np.degrees(rotation_angle(closure_rot))),
        "seed": seed,
        "noise": noise,
    }
