"""g2o pose graphs (``.g2o``): 2-D (``VERTEX_SE2``/``EDGE_SE2``) and 3-D (``VERTEX_SE3:QUAT``/
``EDGE_SE3:QUAT``), as the benchmark graphs (Intel, Manhattan, sphere2500) are written.

An edge's information matrix is stored as its upper triangle, row by row (6 numbers in 2-D,
21 in 3-D). ``FIX id`` lines name vertices held fixed. Vertices may be absent (a file of edges
only, like Manhattan): then the graph's pose ids are those its edges name.

:func:`write_g2o` writes a :class:`PoseGraph` back (either dimension) and :func:`write_g2o_se3`
builds one from (4, 4) matrices; both write atomically, with every number in Python's shortest
round-trip form so that reading the file gives back the same float64 values.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.atomic import write_text_atomic
from slamcli.errors import FormatError
from slamcli.formats.text import iter_data_lines, parse_count, parse_floats
from slamcli.geometry.se3 import matrix_to_quat_xyzw

# Tag -> (dimension, number of values after the ids, number of ids).
_TAGS = {
    "VERTEX_SE2": (2, 3, 1),
    "EDGE_SE2": (2, 3 + 6, 2),
    "VERTEX_SE3:QUAT": (3, 7, 1),
    "EDGE_SE3:QUAT": (3, 7 + 21, 2),
}


@dataclass(frozen=True)
class PoseGraph:
    """A pose graph as a g2o file lists it.

    Attributes:
        dim: 2 (SE(2): x, y, theta) or 3 (SE(3): x, y, z, qx, qy, qz, qw).
        vertex_ids: (V,) int64 ids of the listed vertices.
        poses: (V, 3) float64 (x m, y m, theta rad) in 2-D, (V, 7) (x y z m, quaternion xyzw) in
            3-D: the initial estimates.
        edges: (E, 2) int64 (from, to) vertex ids.
        measurements: (E, 3) or (E, 7) float64 relative poses, as ``poses``.
        information: (E, 3, 3) or (E, 6, 6) float64 symmetric information matrices.
        fixed: ids of the ``FIX`` lines.
        path: the file read.
    """

    dim: int
    vertex_ids: NDArray[np.int64]
    poses: NDArray[np.float64]
    edges: NDArray[np.int64]
    measurements: NDArray[np.float64]
    information: NDArray[np.float64]
    fixed: tuple[int, ...]
    path: Path

    def summary(self) -> dict[str, Any]:
        """Counts for ``slamcli info``: vertices, edges, odometry and loop-closure edges."""
        ids = np.union1d(self.vertex_ids, self.edges.ravel())
        sequential = np.abs(self.edges[:, 1] - self.edges[:, 0]) == 1
        return {
            "dimension": f"{self.dim}-D",
            "vertices": int(self.vertex_ids.size),
            "pose_ids": int(ids.size),
            "edges": int(self.edges.shape[0]),
            "odometry_edges": int(sequential.sum()),
            "loop_closure_edges": int((~sequential).sum()),
            "fixed": list(self.fixed),
        }


def read_g2o(path: str | Path) -> PoseGraph:
    """Read a g2o pose graph; FormatError names ``file:line`` for any malformed line."""
    p = Path(path)
    dim: int | None = None
    vertex_ids: list[int] = []
    poses: list[list[float]] = []
    edges: list[tuple[int, int]] = []
    values: list[list[float]] = []
    fixed: list[int] = []
    for number, fields in iter_data_lines(p):
        tag = fields[0]
        if tag == "FIX":
            fixed += [_id(f, p, number, k + 2) for k, f in enumerate(fields[1:])]
            continue
        if tag not in _TAGS:
            raise FormatError(
                p,
                f"unsupported record {tag!r}",
                number,
                hint=f"slamcli reads {', '.join(_TAGS)} and FIX lines",
            )
        tag_dim, n_values, n_ids = _TAGS[tag]
        if dim is None:
            dim = tag_dim
        elif tag_dim != dim:
            raise FormatError(p, f"{tag} in a {dim}-D graph: 2-D and 3-D records are mixed", number)
        if len(fields) != 1 + n_ids + n_values:
            raise FormatError(
                p,
                f"{tag} has {n_ids} id(s) and {n_values} values, found {len(fields) - 1} fields",
                number,
            )
        ids = [_id(f, p, number, k + 2) for k, f in enumerate(fields[1 : 1 + n_ids])]
        numbers = parse_floats(fields[1 + n_ids :], p, number, first_column=2 + n_ids)
        if n_ids == 1:
            vertex_ids.append(ids[0])
            poses.append(numbers)
        else:
            edges.append((ids[0], ids[1]))
            values.append(numbers)
    if dim is None:
        raise FormatError(p, "no vertices or edges: the file is empty or has only comments")
    width = 3 if dim == 2 else 7
    size = 3 if dim == 2 else 6
    raw = np.asarray(values, dtype=np.float64).reshape(-1, width + size * (size + 1) // 2)
    information = np.zeros((raw.shape[0], size, size))
    upper = np.triu_indices(size)
    information[:, upper[0], upper[1]] = raw[:, width:]
    information[:, upper[1], upper[0]] = raw[:, width:]
    return PoseGraph(
        dim=dim,
        vertex_ids=np.asarray(vertex_ids, dtype=np.int64),
        poses=np.asarray(poses, dtype=np.float64).reshape(-1, width),
        edges=np.asarray(edges, dtype=np.int64).reshape(-1, 2),
        measurements=raw[:, :width].copy(),
        information=information,
        fixed=tuple(fixed),
        path=p,
    )


def _id(text: str, path: Path, line: int, column: int) -> int:
    return parse_count(text, path, line, f"column {column}: vertex id")


def write_g2o(path: str | Path, graph: PoseGraph) -> Path:
    """Write ``graph`` (2-D or 3-D) to ``path`` atomically: vertices, edges, then FIX lines.

    ``graph.path`` is ignored. Information matrices are written as their upper triangle, row by
    row, as :func:`read_g2o` reads them; ``read_g2o(write_g2o(p, g))`` returns ``g``'s arrays.

    Raises:
        ValueError: arrays of the wrong shape for ``graph.dim``, or non-finite values.
    """
    if graph.dim not in (2, 3):
        raise ValueError(f"g2o graphs are 2-D or 3-D, got dim={graph.dim}")
    vertex_tag, edge_tag = (
        ("VERTEX_SE2", "EDGE_SE2")
        if graph.dim == 2
        else (
            "VERTEX_SE3:QUAT",
            "EDGE_SE3:QUAT",
        )
    )
    width, size = (3, 3) if graph.dim == 2 else (7, 6)
    ids = np.asarray(graph.vertex_ids, dtype=np.int64)
    poses = np.asarray(graph.poses, dtype=np.float64)
    edges = np.asarray(graph.edges, dtype=np.int64)
    measurements = np.asarray(graph.measurements, dtype=np.float64)
    information = np.asarray(graph.information, dtype=np.float64)
    n_edges = edges.shape[0] if edges.ndim == 2 else -1
    expected = {
        "vertex_ids": (ids.shape, (ids.size,)),
        "poses": (poses.shape, (ids.size, width)),
        "edges": (edges.shape, (n_edges, 2)),
        "measurements": (measurements.shape, (n_edges, width)),
        "information": (information.shape, (n_edges, size, size)),
    }
    for name, (shape, want) in expected.items():
        if shape != want:
            raise ValueError(
                f"{name} must have shape {want} for a {graph.dim}-D graph, got {shape}"
            )
    for name, values in (("poses", poses), ("measurements", measurements)):
        if not np.isfinite(values).all():
            raise ValueError(f"{name} has non-finite values: g2o files hold finite numbers only")
    if not np.isfinite(information).all():
        raise ValueError("information has non-finite values: g2o files hold finite numbers only")
    if (ids < 0).any() or (edges < 0).any():
        raise ValueError("vertex ids must be >= 0")
    upper = np.triu_indices(size)
    lines = [f"{vertex_tag} {i} {_numbers(p)}" for i, p in zip(ids.tolist(), poses, strict=True)]
    lines += [
        f"{edge_tag} {a} {b} {_numbers(m)} {_numbers(info[upper])}"
        for (a, b), m, info in zip(edges.tolist(), measurements, information, strict=True)
    ]
    lines += [f"FIX {int(f)}" for f in graph.fixed]
    return write_text_atomic(path, "\n".join(lines) + "\n")


def write_g2o_se3(
    path: str | Path,
    poses: NDArray[np.float64],
    edges: NDArray[np.int64],
    measurements: NDArray[np.float64],
    information: NDArray[np.float64] | None = None,
    *,
    vertex_ids: NDArray[np.int64] | None = None,
    fixed: tuple[int, ...] = (),
) -> Path:
    """Write a 3-D pose graph from matrices (atomically); returns the path.

    Args:
        poses: (V, 4, 4) float64 ``world_from_vertex`` rigid transforms.
        edges: (E, 2) int64 (from, to) vertex ids.
        measurements: (E, 4, 4) float64 ``from_from_to`` relative transforms.
        information: (E, 6, 6) float64 in g2o's own convention (translation first, rotation
            measured by the quaternion's vector part), or None for identity.
            :func:`slamcli.graphs.pose_graph.save_g2o` converts from GTSAM's order.
        vertex_ids: (V,) ids of the vertices; default ``0..V-1``.
        fixed: ids written as ``FIX`` lines.
    """
    t = np.asarray(poses, dtype=np.float64)
    m = np.asarray(measurements, dtype=np.float64)
    for name, arr in (("poses", t), ("measurements", m)):
        if arr.ndim != 3 or arr.shape[1:] != (4, 4):
            raise ValueError(f"{name} must have shape (N, 4, 4), got {arr.shape}")
    info = np.broadcast_to(np.eye(6), (len(m), 6, 6)) if information is None else information
    return write_g2o(
        path,
        PoseGraph(
            dim=3,
            vertex_ids=np.arange(len(t), dtype=np.int64) if vertex_ids is None else vertex_ids,
            poses=_se3_values(t),
            edges=np.asarray(edges, dtype=np.int64),
            measurements=_se3_values(m),
            information=np.asarray(info, dtype=np.float64),
            fixed=tuple(fixed),
            path=Path(path),
        ),
    )


def _se3_values(transforms: NDArray[np.float64]) -> NDArray[np.float64]:
    """(N, 4, 4) -> (N, 7) ``x y z qx qy qz qw`` rows."""
    return np.concatenate([transforms[:, :3, 3], matrix_to_quat_xyzw(transforms)], axis=-1)


def _numbers(values: NDArray[np.float64]) -> str:
    return " ".join(repr(v) for v in values.tolist())
