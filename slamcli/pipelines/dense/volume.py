"""The dense pipeline's TSDF volume (Open3D's ``VoxelBlockGrid``, with colour) and the camera
of its tracking images. Open3D objects stay inside the pipeline's modules."""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.geometry import inverse
from slamcli.pipelines.dense.config import DenseConfig
from slamcli.types import PinholeCamera, TriangleMesh

log = logging.getLogger(__name__)

F64 = NDArray[np.float64]


class Volume:
    """An Open3D ``VoxelBlockGrid`` TSDF with colour that grows with the scene.

    Open3D allocates (and zeroes) every block of the capacity up front, 80 kB per 16**3 block,
    so the capacity follows the data: it starts at ``capacity`` blocks (or what the first frame
    needs) and is raised before a frame whose blocks might not fit.
    """

    def __init__(self, o3d: Any, config: DenseConfig, camera: PinholeCamera, capacity: int) -> None:
        self._o3d = o3d
        self._cfg = config
        self._camera = camera
        # Open3D's TSDF integration reads the depth pixel by truncating the voxel's projected
        # coordinate, while its ray cast shoots rays through pixel centres: without this half
        # pixel the model sits half a pixel off, and frame-to-model tracking drifts by that
        # much every frame.
        k_integrate = camera.K.copy()
        k_integrate[:2, 2] += 0.5
        self._K = o3d.core.Tensor(k_integrate)
        self._grid = o3d.t.geometry.VoxelBlockGrid(
            ("tsdf", "weight", "color"),
            (o3d.core.float32, o3d.core.float32, o3d.core.float32),
            ((1), (1), (3)),
            config.voxel_size_m,
            config.block_resolution,
            max(1, capacity),
        )
        self.growths = 0
        self._integrated = 0
        self._last_blocks: Any = None

    @property
    def size(self) -> int:
        """Number of allocated voxel blocks."""
        return int(self._grid.hashmap().size())

    @property
    def capacity(self) -> int:
        """Number of voxel blocks the volume holds before it must grow."""
        return int(self._grid.hashmap().capacity())

    def reserve(self, new_blocks: int) -> None:
        """Make room for ``new_blocks`` more blocks (an upper bound), growing by
        ``block_growth``.

        Open3D would grow the hash map by itself, but to twice its capacity whenever the size
        plus the frame's blocks (new or not) exceed it; growing first keeps the steady state at
        ``block_growth`` times the need.
        """
        needed = self.size + new_blocks
        if needed > self.capacity:
            capacity = math.ceil(self._cfg.block_growth * needed)
            log.debug("TSDF volume grows from %d to %d blocks", self.capacity, capacity)
            self._grid.hashmap().reserve(capacity)
            self.growths += 1

    def integrate(self, depth: NDArray[np.float32], rgb: NDArray[np.uint8], pose: F64) -> None:
        """Fuse depth (H, W) metres and colour (H, W, 3) seen from world_from_cam ``pose``."""
        o3d, cfg = self._o3d, self._cfg
        depth_img = o3d.t.geometry.Image(np.ascontiguousarray(depth))
        colour = o3d.t.geometry.Image(np.ascontiguousarray(rgb, dtype=np.float32) / 255.0)
        extrinsic = o3d.core.Tensor(np.ascontiguousarray(inverse(pose)))
        blocks = self._grid.compute_unique_block_coordinates(
            depth_img, self._K, extrinsic, 1.0, cfg.depth_max_m, cfg.sdf_trunc_voxels
        )
        self.reserve(len(blocks))
        self._grid.integrate(
            blocks,
            depth_img,
            colour,
            self._K,
            extrinsic,
            1.0,
            cfg.depth_max_m,
            cfg.sdf_trunc_voxels,
        )
        self._last_blocks = blocks
        self._integrated += 1

    def ray_cast(self, pose: F64, downsample: int) -> Any:
        """Model RGB-D image (depth metres, colour in [0, 1]) seen from ``pose`` at the
        tracking scale, or None when the volume shows nothing there."""
        o3d, cfg = self._o3d, self._cfg
        cam = tracking_camera(self._camera, downsample)
        extrinsic = o3d.core.Tensor(np.ascontiguousarray(inverse(pose)))
        # A fresh volume has weight 1 per fused frame; the threshold grows to 3 as frames arrive.
        weight = float(min(self._integrated, 3))
        result = self._grid.ray_cast(
            self._last_blocks,
            o3d.core.Tensor(cam.K),
            extrinsic,
            cam.width,
            cam.height,
            ["depth", "color"],
            1.0,
            cfg.depth_min_m,
            cfg.depth_max_m,
            weight,
            cfg.sdf_trunc_voxels,
        )
        depth = result["depth"]
        if int(np.count_nonzero(depth.numpy())) == 0:
            return None
        return o3d.t.geometry.RGBDImage(
            o3d.t.geometry.Image(result["color"]), o3d.t.geometry.Image(depth)
        )

    def extract(
        self, weight_threshold: float
    ) -> tuple[TriangleMesh, NDArray[np.float64], NDArray[np.uint8]]:
        """Marching-cubes mesh and surface points (N, 3) metres with colours (N, 3) uint8."""
        weight = min(weight_threshold, float(self._integrated))
        mesh = self._grid.extract_triangle_mesh(weight)
        vertices = mesh.vertex.positions.numpy().astype(np.float64)
        faces = mesh.triangle.indices.numpy().astype(np.int64).reshape(-1, 3)
        colours = _to_uint8(mesh.vertex.colors.numpy()) if "colors" in mesh.vertex else None
        cloud = self._grid.extract_point_cloud(weight)
        points = cloud.point.positions.numpy().astype(np.float64)
        point_colours = (
            _to_uint8(cloud.point.colors.numpy())
            if "colors" in cloud.point
            else np.zeros((len(points), 3), dtype=np.uint8)
        )
        return TriangleMesh(vertices, faces, colours), points, point_colours


def tracking_camera(camera: PinholeCamera, downsample: int) -> PinholeCamera:
    """The camera of the tracking images: shrunk by ``downsample`` and cropped at the right and
    bottom to whole multiples of 8 pixels (Open3D's ray cast never returns otherwise: its range
    map works in 8x8 tiles)."""
    small = camera.scaled(1.0 / downsample)
    width = camera.width // downsample // _RANGE_TILE * _RANGE_TILE
    height = camera.height // downsample // _RANGE_TILE * _RANGE_TILE
    return replace(small, width=width, height=height)


_RANGE_TILE = 8


def _to_uint8(colours: NDArray[Any]) -> NDArray[np.uint8]:
    return np.asarray(np.clip(np.rint(colours * 255.0), 0, 255), dtype=np.uint8)


def open3d() -> Any:
    """The open3d module (imported on first use)."""
    from slamcli.backends import import_open3d

    return import_open3d()
