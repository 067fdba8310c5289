"""Triangle meshes and point clouds on disk (PLY, GLB), and operations on :class:`TriangleMesh`.

Files:

- ``mesh.ply``: binary little-endian PLY; vertices as ``double`` x, y, z (metres), vertex
  colours as ``uchar`` red, green, blue, faces as ``uchar``-counted ``int`` index lists.
- ``mesh.glb``: binary glTF 2.0 written by trimesh, vertex colours as ``COLOR_0`` (normalised
  unsigned bytes). Open3D's own ``.glb`` writer produces files that fail the glTF validator, so
  it is never used. Coordinates are written as they are (glTF viewers assume +Y up).
- ``points.ply``: the same PLY layout as meshes, without faces.

Every writer goes through :func:`slamcli.atomic.atomic_path`: a failed write leaves nothing.

Operations (:func:`simplify`, :func:`crop`, :func:`remove_small_components`) return new meshes
and drop the vertices no remaining face uses, keeping the survivors in their original order.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.atomic import atomic_path
from slamcli.errors import ConfigError, ExportError, FormatError, InputError
from slamcli.types import TriangleMesh

log = logging.getLogger(__name__)

MESH_FILE = "mesh.ply"
"""Name of the mesh inside a run folder."""

_INT32_MAX = np.iinfo(np.int32).max


# --------------------------------------------------------------------------- validation


def check_mesh(mesh: TriangleMesh, where: str = "mesh") -> TriangleMesh:
    """The mesh with normalised arrays: (V,3) float64, (F,3) int64, (V,3) uint8 or None.

    Raises:
        ExportError: wrong shapes, non-finite vertices or face indices outside [0, V).
    """
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ExportError(f"{where}: vertices must be (V, 3), got shape {vertices.shape}")
    if faces.size == 0:
        faces = faces.reshape(0, 3)
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise ExportError(f"{where}: faces must be (F, 3) triangles, got shape {faces.shape}")
    if not np.isfinite(vertices).all():
        raise ExportError(
            f"{where}: {int((~np.isfinite(vertices)).any(axis=1).sum())} vertices are not finite"
        )
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ExportError(
            f"{where}: face indices must lie in [0, {len(vertices)}), found "
            f"{int(faces.min())}..{int(faces.max())}"
        )
    colors = mesh.vertex_colors
    if colors is not None:
        colors = np.asarray(colors)
        if colors.shape != vertices.shape:
            raise ExportError(
                f"{where}: vertex_colors must be (V, 3) = {vertices.shape}, got {colors.shape}"
            )
        colors = np.ascontiguousarray(colors, dtype=np.uint8)
    return TriangleMesh(vertices, faces, colors)


def _check_points(
    points: ArrayLike, colors: ArrayLike | None
) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ExportError(f"points must be (N, 3), got shape {pts.shape}")
    if colors is None:
        return pts, None
    cols = np.asarray(colors)
    if cols.ndim != 2 or len(cols) != len(pts) or cols.shape[1] not in (3, 4):
        raise ExportError(f"point colours must be (N, 3) with N = {len(pts)}, got {cols.shape}")
    return pts, np.ascontiguousarray(cols[:, :3], dtype=np.uint8)


# --------------------------------------------------------------------------- reading


def read_mesh(path: str | Path) -> TriangleMesh:
    """A triangle mesh from a PLY file, with its vertex colours when it has them.

    Returns:
        vertices (V, 3) float64 metres, faces (F, 3) int64, vertex_colors (V, 3) uint8 or None.

    Raises:
        InputError: the file is missing or not a .ply file.
        FormatError: the file cannot be parsed, has no faces or bad face indices.
    """
    import trimesh

    p = Path(path)
    loaded = _load_ply(p)
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.faces) == 0:
        raise FormatError(
            p, "has no faces; a mesh needs triangles", hint="points belong in points.ply"
        )
    faces = np.asarray(loaded.faces, dtype=np.int64)
    vertices = np.asarray(loaded.vertices, dtype=np.float64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise FormatError(p, f"face indices must lie in [0, {len(vertices)})")
    colors = _trimesh_vertex_colors(loaded)
    return TriangleMesh(vertices, faces, colors)


def read_points_ply(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.uint8] | None]:
    """Points from a PLY file (its vertices; faces, if any, are ignored).

    Returns:
        (N, 3) float64 points in metres and (N, 3) uint8 RGB colours, or None without colours.

    Raises:
        InputError: the file is missing. FormatError: it cannot be parsed.
    """
    import trimesh

    p = Path(path)
    loaded = _load_ply(p)
    points = np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)
    colors = None
    if isinstance(loaded, trimesh.Trimesh):
        colors = _trimesh_vertex_colors(loaded)
    elif isinstance(loaded, trimesh.PointCloud):
        raw = np.asarray(loaded.colors)
        if raw.ndim == 2 and len(raw) == len(points) and raw.shape[1] >= 3:
            colors = np.ascontiguousarray(raw[:, :3], dtype=np.uint8)
    return points, colors


def _load_ply(path: Path) -> Any:
    import trimesh

    if path.suffix.lower() != ".ply":
        raise InputError(f"{path}: expected a .ply file", hint="meshes are read from PLY files")
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        return trimesh.load(str(path), file_type="ply", process=False)
    except Exception as exc:  # trimesh raises assorted types for malformed files
        raise FormatError(path, f"cannot be read as PLY ({exc})") from exc


def _trimesh_vertex_colors(mesh: Any) -> NDArray[np.uint8] | None:
    """(V, 3) uint8 RGB of a trimesh mesh with per-vertex colours, else None."""
    visual = mesh.visual
    if visual is None or visual.kind != "vertex":
        return None
    return np.ascontiguousarray(np.asarray(visual.vertex_colors)[:, :3], dtype=np.uint8)


# --------------------------------------------------------------------------- writing


def write_ply(path: str | Path, mesh: TriangleMesh) -> Path:
    """Write a binary PLY mesh with vertex colours (when the mesh has them), atomically.

    Raises:
        ExportError: the mesh has no triangles or malformed arrays, or the file cannot be
            written.
    """
    m = _exportable(mesh, path)
    _write_ply(Path(path), m.vertices, m.vertex_colors, m.faces)
    return Path(path)


def write_points_ply(path: str | Path, points: ArrayLike, colors: ArrayLike | None = None) -> Path:
    """Write points as a binary PLY, atomically.

    Args:
        points: (N, 3) coordinates in metres.
        colors: (N, 3) uint8 RGB (an (N, 4) RGBA array has its alpha dropped), or None.

    Raises:
        ExportError: malformed arrays, or the file cannot be written.
    """
    pts, cols = _check_points(points, colors)
    _write_ply(Path(path), pts, cols, None)
    return Path(path)


def mesh_to_glb(mesh: TriangleMesh) -> bytes:
    """The mesh as binary glTF 2.0 bytes (trimesh's exporter; vertex colours as ``COLOR_0``).

    Raises:
        ExportError: malformed arrays, or trimesh did not return bytes.
    """
    import trimesh

    m = check_mesh(mesh)
    tm = trimesh.Trimesh(
        vertices=m.vertices, faces=m.faces, vertex_colors=m.vertex_colors, process=False
    )
    glb = tm.export(file_type="glb")
    if not isinstance(glb, bytes):
        raise ExportError(f"trimesh returned {type(glb).__name__} for a GLB export, not bytes")
    return glb


def write_glb(path: str | Path, mesh: TriangleMesh) -> Path:
    """Write the mesh as a binary glTF (``.glb``) with vertex colours, atomically.

    Raises:
        ExportError: the mesh has no triangles or malformed arrays, or the file cannot be
            written.
    """
    data = mesh_to_glb(_exportable(mesh, path))
    try:
        with atomic_path(path) as tmp:
            tmp.write_bytes(data)
    except OSError as exc:
        raise ExportError(f"{path}: cannot be written ({exc.strerror})") from exc
    return Path(path)


MESH_WRITERS: dict[str, Callable[[str | Path, TriangleMesh], Path]] = {
    "ply": write_ply,
    "glb": write_glb,
}
"""Mesh writers by format name (also the file extension)."""


def _exportable(mesh: TriangleMesh, path: str | Path) -> TriangleMesh:
    m = check_mesh(mesh, str(path))
    if len(m.faces) == 0:
        raise ExportError(f"{path}: the mesh has no triangles; nothing to write")
    return m


def _write_ply(
    path: Path,
    vertices: NDArray[np.float64],
    colors: NDArray[np.uint8] | None,
    faces: NDArray[np.int64] | None,
) -> None:
    if len(vertices) > _INT32_MAX:
        raise ExportError(f"{path}: {len(vertices)} vertices exceed PLY's int32 face indices")
    vdtype = [("x", "<f8"), ("y", "<f8"), ("z", "<f8")]
    if colors is not None:
        vdtype += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    vrec = np.empty(len(vertices), dtype=np.dtype(vdtype))
    vrec["x"], vrec["y"], vrec["z"] = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    if colors is not None:
        vrec["red"], vrec["green"], vrec["blue"] = colors[:, 0], colors[:, 1], colors[:, 2]
    header = [
        "ply",
        "format binary_little_endian 1.0",
        "comment written by slamcli",
        f"element vertex {len(vertices)}",
        "property double x",
        "property double y",
        "property double z",
    ]
    if colors is not None:
        header += ["property uchar red", "property uchar green", "property uchar blue"]
    frec = None
    if faces is not None:
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        frec = np.empty(len(faces), dtype=np.dtype([("n", "u1"), ("idx", "<i4", (3,))]))
        frec["n"] = 3
        frec["idx"] = faces
    header.append("end_header")
    try:
        with atomic_path(path) as tmp, tmp.open("wb") as fh:
            fh.write(("\n".join(header) + "\n").encode("ascii"))
            fh.write(vrec.tobytes())
            if frec is not None:
                fh.write(frec.tobytes())
    except OSError as exc:
        raise ExportError(f"{path}: cannot be written ({exc.strerror})") from exc


# --------------------------------------------------------------------------- operations


def compact(mesh: TriangleMesh) -> TriangleMesh:
    """Drop the vertices no face uses and renumber the faces; vertex order is kept."""
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[mesh.faces.ravel()] = True
    if used.all():
        return mesh
    new_index = np.cumsum(used) - 1
    colors = mesh.vertex_colors[used] if mesh.vertex_colors is not None else None
    return TriangleMesh(mesh.vertices[used], new_index[mesh.faces], colors)


def _keep_faces(mesh: TriangleMesh, keep: NDArray[np.bool_]) -> TriangleMesh:
    return compact(TriangleMesh(mesh.vertices, mesh.faces[keep], mesh.vertex_colors))


def crop(mesh: TriangleMesh, bounds: Sequence[float]) -> TriangleMesh:
    """The faces whose three vertices all lie inside an axis-aligned box (bounds inclusive).

    Args:
        mesh: the mesh to crop.
        bounds: ``(xmin, ymin, zmin, xmax, ymax, zmax)`` in the mesh's units (metres).

    Raises:
        ConfigError: not six finite numbers, or a minimum above its maximum.
    """
    box = np.asarray(bounds, dtype=np.float64).reshape(-1)
    if box.shape != (6,) or not np.isfinite(box).all():
        raise ConfigError(
            f"crop box: expected six finite numbers xmin,ymin,zmin,xmax,ymax,zmax, got {bounds}"
        )
    low, high = box[:3], box[3:]
    if (low > high).any():
        i = int(np.argmax(low > high))
        axis = "xyz"[i]
        raise ConfigError(
            f"crop box: {axis}min {low[i]:g} is above {axis}max {high[i]:g}",
            hint="give the box as xmin,ymin,zmin,xmax,ymax,zmax",
        )
    m = check_mesh(mesh)
    inside: NDArray[np.bool_] = np.all((m.vertices >= low) & (m.vertices <= high), axis=1)
    return _keep_faces(m, np.all(inside[m.faces], axis=1))


def component_sizes(mesh: TriangleMesh) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Connected components of a mesh, where faces that share a vertex are connected.

    Returns:
        (F,) int64 component label of each face and (C,) int64 number of faces per label.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    m = check_mesh(mesh)
    n = len(m.vertices)
    if len(m.faces) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    # Edges v0-v1 and v1-v2 of each face connect all three of its vertices.
    rows = np.concatenate([m.faces[:, 0], m.faces[:, 1]])
    cols = np.concatenate([m.faces[:, 1], m.faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows), dtype=np.int8), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    face_labels = labels[m.faces[:, 0]].astype(np.int64)
    return face_labels, np.bincount(face_labels).astype(np.int64)


def remove_small_components(mesh: TriangleMesh, min_triangles: int) -> TriangleMesh:
    """Drop every connected component (faces sharing vertices) with fewer than ``min_triangles``.

    Raises:
        ConfigError: ``min_triangles`` below 1.
    """
    if min_triangles < 1:
        raise ConfigError(f"min_triangles: expected an integer >= 1, got {min_triangles}")
    m = check_mesh(mesh)
    face_labels, sizes = component_sizes(m)
    return _keep_faces(m, sizes[face_labels] >= min_triangles)


def simplify(mesh: TriangleMesh, target_triangles: int) -> TriangleMesh:
    """Quadric edge-collapse decimation to about ``target_triangles`` faces.

    Uses Open3D's ``simplify_quadric_decimation`` (Garland-Heckbert quadrics with vertex
    colours interpolated along collapsed edges); it is single-threaded and deterministic. A mesh
    already at or below the target is returned unchanged.

    Raises:
        ConfigError: ``target_triangles`` below 1.
    """
    if target_triangles < 1:
        raise ConfigError(f"target_triangles: expected an integer >= 1, got {target_triangles}")
    m = check_mesh(mesh)
    if len(m.faces) <= target_triangles:
        return m
    from slamcli.backends import import_open3d

    o3d = import_open3d()
    legacy = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(m.vertices), o3d.utility.Vector3iVector(m.faces.astype(np.int32))
    )
    if m.vertex_colors is not None:
        legacy.vertex_colors = o3d.utility.Vector3dVector(m.vertex_colors / 255.0)
    out = legacy.simplify_quadric_decimation(int(target_triangles))
    colors = None
    if m.vertex_colors is not None:
        rgb = np.asarray(out.vertex_colors, dtype=np.float64)
        colors = np.clip(np.rint(rgb * 255.0), 0, 255).astype(np.uint8)
    result = TriangleMesh(
        np.asarray(out.vertices, dtype=np.float64).copy(),
        np.asarray(out.triangles, dtype=np.int64).copy(),
        colors,
    )
    log.debug("simplified %d -> %d triangles", len(m.faces), len(result.faces))
    return compact(result)


# --------------------------------------------------------------------------- export


@dataclass
class MeshExport:
    """What :func:`export_mesh` did: the input, each step's triangle count and the output."""

    source: Path
    out: Path
    format: str
    input_vertices: int
    input_faces: int
    vertices: int
    faces: int
    colors: bool
    steps: list[tuple[str, str, int]] = field(default_factory=list)
    """(step, what it did, triangles after it), in the order applied."""


def mesh_input(path: str | Path) -> Path:
    """The mesh file a path means: a run folder's ``mesh.ply``, or the file itself.

    Raises:
        InputError: the path does not exist, or a folder has no ``mesh.ply``.
    """
    p = Path(path)
    if p.is_dir():
        mesh = p / MESH_FILE
        if not mesh.is_file():
            raise InputError(
                f"{p}: folder has no {MESH_FILE}",
                hint="give a run folder of a pipeline that builds a mesh "
                "(slamcli run dense), or a .ply file",
            )
        return mesh
    if not p.exists():
        raise InputError(f"{p}: no such file or folder", hint="give a run folder or a .ply mesh")
    return p


def default_export_path(source: Path, format: str) -> Path:
    """``mesh.ply`` -> ``mesh.glb`` beside it; same format -> ``mesh.export.ply``."""
    out = source.with_suffix(f".{format}")
    if out == source:
        out = source.with_name(f"{source.stem}.export.{format}")
    return out


def export_mesh(
    path: str | Path,
    format: str,
    out: str | Path | None = None,
    *,
    simplify_to: int | None = None,
    crop_box: Sequence[float] | None = None,
    min_component: int | None = None,
    force: bool = False,
) -> MeshExport:
    """Read a mesh (or a run folder's ``mesh.ply``), optionally clean it, and write it.

    Steps run in this order: crop to the box, drop components with fewer than
    ``min_component`` triangles, decimate to about ``simplify_to`` triangles.

    Args:
        path: a run folder or a ``.ply`` mesh.
        format: ``"ply"`` or ``"glb"``.
        out: destination; default beside the input (see :func:`default_export_path`).

    Raises:
        InputError, FormatError: the input is missing or unreadable.
        ConfigError: unknown format, an ``out`` whose extension contradicts ``format``, or a
            step that leaves no triangles.
        ExportError: ``out`` exists and ``force`` is false, or the write failed.
    """
    fmt = format.lower().lstrip(".")
    if fmt not in MESH_WRITERS:
        raise ConfigError(
            f"--format: unknown mesh format {format!r}",
            hint=f"choose one of {', '.join(MESH_WRITERS)}",
        )
    source = mesh_input(path)
    dest = Path(out) if out is not None else default_export_path(source, fmt)
    if dest.suffix.lower() != f".{fmt}":
        raise ConfigError(
            f"--out {dest}: the name does not end in .{fmt} (--format {fmt})",
            hint=f"name the file *.{fmt}, or choose the --format its extension names",
        )
    if dest.is_dir():
        raise ExportError(f"{dest}: is a folder", hint="give --out a file name")
    if dest.exists() and not force:
        raise ExportError(
            f"{dest}: already exists", hint="pass --force to overwrite it, or choose another --out"
        )
    mesh = read_mesh(source)
    report = MeshExport(
        source=source,
        out=dest,
        format=fmt,
        input_vertices=len(mesh.vertices),
        input_faces=len(mesh.faces),
        vertices=0,
        faces=0,
        colors=mesh.vertex_colors is not None,
    )
    if crop_box is not None:
        lo = mesh.vertices.min(axis=0)
        hi = mesh.vertices.max(axis=0)
        mesh = crop(mesh, crop_box)
        if len(mesh.faces) == 0:
            raise ConfigError(
                f"--crop {','.join(f'{v:g}' for v in crop_box)}: no triangle of {source} lies "
                "inside the box",
                hint="the mesh spans "
                + ",".join(f"{v:.3g}" for v in (*lo, *hi))
                + " (xmin,ymin,zmin,xmax,ymax,zmax)",
            )
        box = ",".join(f"{v:g}" for v in crop_box)
        report.steps.append(("crop", f"inside {box}", len(mesh.faces)))
    if min_component is not None:
        before = mesh
        mesh = remove_small_components(mesh, min_component)
        if len(mesh.faces) == 0:
            _, sizes = component_sizes(before)
            raise ConfigError(
                f"--min-component {min_component}: every component of {source} is smaller",
                hint=f"the largest has {int(sizes.max())} triangles; choose a value at most that",
            )
        report.steps.append(
            ("min-component", f"pieces of {min_component}+ triangles", len(mesh.faces))
        )
    if simplify_to is not None:
        mesh = simplify(mesh, simplify_to)
        report.steps.append(("simplify", f"to about {simplify_to}", len(mesh.faces)))
    MESH_WRITERS[fmt](dest, mesh)
    report.vertices, report.faces = len(mesh.vertices), len(mesh.faces)
    log.info("wrote %s: %d vertices, %d faces", dest, report.vertices, report.faces)
    return report


__all__ = [
    "MESH_FILE",
    "MESH_WRITERS",
    "MeshExport",
    "check_mesh",
    "compact",
    "component_sizes",
    "crop",
    "default_export_path",
    "export_mesh",
    "mesh_input",
    "mesh_to_glb",
    "read_mesh",
    "read_points_ply",
    "remove_small_components",
    "simplify",
    "write_glb",
    "write_ply",
    "write_points_ply",
]
