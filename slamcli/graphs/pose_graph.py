"""Pose-graph optimisation on GTSAM: SE(2) and SE(3) graphs, Sim(3) (monocular essential)
graphs, and the search for wrong loop closures by graduated non-convexity.

numpy in, numpy out: GTSAM objects never leave this module, and gtsam is imported inside the
functions that need it, so importing this module is cheap.

Conventions
-----------
- A node's pose is a ``(4, 4)`` float64 ``world_from_node`` rigid transform; node ``i`` is row
  ``i`` of the ``(N, 4, 4)`` stack. In SE(2) graphs it is a ``(3,)`` row x, y (m), yaw (rad)
  of an ``(N, 3)`` stack, and an edge's ``a_from_b`` is such a row too.
- An :class:`Edge` from ``a`` to ``b`` measures ``a_from_b`` = ``inverse(world_from_a) @
  world_from_b``: node ``b``'s pose seen from node ``a`` (GTSAM's ``BetweenFactor(a, b)``,
  g2o's ``EDGE_SE3:QUAT a b``).
- Information matrices are in GTSAM's tangent order: **rotation first, then translation**
  (``[ω (3) rad, v (3) m]``), the inverse covariance of the between-factor residual
  ``Log(measured⁻¹ · a_from_b(estimate))``. This is the reverse of ``slamcli.geometry.se3``'s
  ``[rho, phi]`` twists and of g2o files (translation first): :func:`from_g2o` and
  :func:`save_g2o` convert. SE(2) information is (3, 3) in the order (x, y, yaw) of the
  relative pose, GTSAM ``Pose2``'s tangent order and g2o ``EDGE_SE2``'s, so it is used as a
  g2o file gives it and every edge's χ² is the one g2o computes.
- Sim(3): node ``i`` carries a scale ``s_i`` besides its pose, and maps points of its own
  (drifting-scale) frame into the world as ``p_w = s_i R_i p_i + t_i``, i.e. the similarity
  ``[[s_i R_i, t_i], [0, 1]]``. An edge's ``a_from_b`` holds the rotation and translation of the
  relative similarity and ``scale`` its scale: ``p_a = scale · R_ab p_b + t_ab``. GTSAM's
  ``Similarity3(R, t, s)`` stores the same map as ``s (R p + t)``, so ``t`` is divided by ``s``
  at the boundary. Its tangent order is ``[ω (3), u (3), λ]`` (rotation, translation,
  log-scale), and a (7, 7) information matrix is in that order.
- Fixed nodes are held by ``NonlinearEquality`` factors, not by strong priors: a prior only
  approximates "fixed" (the node still moves by about its sigma and a very small sigma makes the
  system ill-conditioned), whereas ``NonlinearEquality`` removes the node's update exactly, so a
  fixed pose comes back bit for bit, and the constraint adds zero to the graph's error.
- Levenberg–Marquardt with COLAMD ordering. The installed GTSAM wheel is built without TBB (its
  shared library links no ``libtbb``), so elimination is single-threaded and the same input
  gives bit-identical output; ``tests/test_pose_graph.py`` checks this byte for byte.
- Robust kernels act on the whitened residual norm ``r = sqrt(chi2)`` of the edges marked
  ``robust``. ``kernel_width`` is in those units for every kernel (for DCS, GTSAM's parameter
  Φ is in squared units and gets ``kernel_width**2``); its default is ``sqrt`` of the 95 % χ²
  quantile for the residual's dimension (3 for SE(2), 6 for SE(3), 7 for Sim(3)), the usual
  gate.
  Cauchy and DCS reject wrong loop closures from an odometry-chain start; Huber only bounds
  their pull (a gross outlier still bends the graph), and Tukey gives zero weight to every
  edge beyond its width, so from a drifted start it also ignores the correct loops.
- ``outliers`` are the robust edges whose ``edge_chi2`` at the solution exceeds the 99 % χ²
  quantile for that dimension. The rule is only as good as the information matrices: they must
  be real inverse covariances for χ² bounds to mean anything.
- :func:`optimize_gnc` runs GTSAM's graduated non-convexity (``GncLMOptimizer``, truncated least
  squares) with the edges that are not ``robust`` and the fixed nodes as known inliers; its
  ``outliers`` are the robust edges it gives a weight below one half.

Invalid arguments (index out of range, a matrix that is not a rigid transform, an information
matrix that is not symmetric positive definite, an unknown kernel) raise ``ValueError``: these
are programming errors of the caller (a pipeline), not bad user files.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.geometry.chi2 import chi2_quantile
from slamcli.geometry.se3 import compose, inverse, make_pose, quat_xyzw_to_matrix

if TYPE_CHECKING:
    from typing_extensions import Unpack

    from slamcli.formats.g2o import PoseGraph

F64 = NDArray[np.float64]
KERNELS = ("none", "huber", "cauchy", "dcs", "tukey")
OUTLIER_PROBABILITY = 0.99
_WIDTH_PROBABILITY = 0.95
_RIGID_TOL = 1e-6


@dataclass
class Edge:
    """One relative-pose measurement between nodes ``a`` and ``b``.

    Attributes:
        a, b: node indices (rows of the pose stack).
        a_from_b: (4, 4) float64 rigid transform, node ``b``'s pose in node ``a``'s frame (for
            Sim(3): the rotation and translation of the relative similarity); in SE(2) graphs
            (3,) x, y (m), yaw (rad).
        scale: Sim(3) only, the relative scale of ``a_from_b`` (``p_a = scale R p_b + t``).
        information: (6, 6) float64, rotation then translation (GTSAM's Pose3 tangent order);
            for Sim(3) also (7, 7) with the log-scale last; for SE(2) (3, 3) in (x, y, yaw)
            order. None means identity.
        robust: apply the chosen robust kernel to this edge (loop closures), or not (odometry).
        kind: a free label ("odometry", "loop", ...), carried through for reporting.
    """

    a: int
    b: int
    a_from_b: F64
    scale: float = 1.0
    information: F64 | None = None
    robust: bool = False
    kind: str = "odometry"


@dataclass
class PoseGraphResult:
    """What the ``optimize_*`` functions return.

    Attributes:
        poses: (N, 4, 4) float64 optimised ``world_from_node`` rigid transforms; (N, 3) x, y,
            yaw rows for SE(2).
        scales: (N,) float64 node scales (Sim(3) only; None for SE(3)).
        error_before, error_after: GTSAM's ``graph.error``, ``0.5 Σ ρ(whitened residual)``
            (``0.5 Σ chi2`` without a kernel), at the initial and optimised values.
        iterations: Levenberg–Marquardt iterations run (0 from :func:`optimize_gnc`, whose
            GTSAM optimiser does not report them).
        edge_chi2: (E,) float64 whitened squared residual of each edge at the solution, without
            the kernel, in the order of the ``edges`` argument.
        outliers: (K,) int64 indices into ``edges`` of robust edges whose chi2 exceeds the 99 %
            χ² bound of the residual's dimension (of :func:`optimize_gnc`: that it drops).
    """

    poses: F64
    error_before: float
    error_after: float
    iterations: int
    edge_chi2: F64
    outliers: NDArray[np.int64]
    scales: F64 | None = field(default=None)


class SolveOptions(TypedDict, total=False):
    """How the ``optimize_*`` functions solve, given as keyword arguments (all optional).

    Attributes:
        fixed: indices of nodes held exactly at their initial pose (the gauge); (0,) unless
            given.
        kernel: robust kernel for edges with ``robust=True``: one of :data:`KERNELS`; ``none``
            unless given.
        kernel_width: kernel width in whitened-residual-norm units (see the module docstring);
            the 95 % χ² bound of the residual's dimension unless given.
        max_iterations: Levenberg–Marquardt iteration cap; 100 unless given.
    """

    fixed: Iterable[int]
    kernel: str
    kernel_width: float | None
    max_iterations: int


_SOLVE_DEFAULTS: SolveOptions = {
    "fixed": (0,),
    "kernel": "none",
    "kernel_width": None,
    "max_iterations": 100,
}


def optimize_se2(
    poses: ArrayLike, edges: Sequence[Edge], **options: Unpack[SolveOptions]
) -> PoseGraphResult:
    """Optimise an SE(2) pose graph with Levenberg–Marquardt.

    Args:
        poses: (N, 3) initial ``world_from_node`` x, y (m), yaw (rad).
        edges: relative-pose measurements, ``a_from_b`` (3,) and information (3, 3) in (x, y,
            yaw) order; ``scale`` is ignored.
        options: see :class:`SolveOptions`.
    """
    stack = _check_planar_poses(poses)
    _check_edges(edges, len(stack), "se2")
    return _optimize(stack, None, edges, options)


def optimize_se3(
    poses: ArrayLike, edges: Sequence[Edge], **options: Unpack[SolveOptions]
) -> PoseGraphResult:
    """Optimise an SE(3) pose graph with Levenberg–Marquardt.

    Args:
        poses: (N, 4, 4) initial ``world_from_node`` estimates.
        edges: relative-pose measurements; ``scale`` is ignored.
        options: see :class:`SolveOptions`.
    """
    stack = _check_poses(poses)
    _check_edges(edges, len(stack), "se3")
    return _optimize(stack, None, edges, options)


def optimize_sim3(
    poses: ArrayLike,
    scales: ArrayLike,
    edges: Sequence[Edge],
    *,
    scale_sigma: float = 1.0,
    **options: Unpack[SolveOptions],
) -> PoseGraphResult:
    """Optimise a Sim(3) graph (monocular essential graph): poses and per-node scales.

    Args:
        poses: (N, 4, 4) initial ``world_from_node`` rotations and translations.
        scales: (N,) initial node scales (usually ones), > 0.
        edges: relative similarities; loop edges carry ``scale != 1``, odometry usually 1.
        scale_sigma: standard deviation of the log-scale residual, used for edges whose
            information is None or (6, 6) (block-diagonal extension); a (7, 7) information is
            taken as given. The default with ``information=None`` is ORB-SLAM's identity (7, 7).
        options: see :class:`SolveOptions`; fixed nodes keep their scale too.

    Returns:
        the result with ``scales`` set.
    """
    stack = _check_poses(poses)
    s = _check_scales(scales, len(stack))
    if not (math.isfinite(scale_sigma) and scale_sigma > 0):
        raise ValueError(f"scale_sigma must be a finite number > 0, got {scale_sigma!r}")
    _check_edges(edges, len(stack), "sim3")
    return _optimize(stack, s, edges, options, scale_sigma)


def optimize_gnc(
    poses: ArrayLike,
    edges: Sequence[Edge],
    *,
    inlier_chi2: float,
    fixed: Iterable[int] = (0,),
    max_iterations: int = 100,
) -> PoseGraphResult:
    """Find the wrong robust edges (loop closures) of an SE(2) or SE(3) graph by graduated
    non-convexity (module docstring).

    Args:
        poses: (N, 3) SE(2) or (N, 4, 4) SE(3) starting poses.
        edges: the measurements; those not ``robust`` are known inliers.
        inlier_chi2: the χ² beyond which the truncated least squares loss drops an edge.
        fixed: nodes held exactly at their starting pose (known inliers too).
        max_iterations: Levenberg–Marquardt iteration cap of each inner solve.
    """
    import gtsam

    stack = _check_nodes(poses)
    _check_edges(edges, len(stack), "se2" if stack.ndim == 2 else "se3")
    if not (math.isfinite(inlier_chi2) and inlier_chi2 > 0):
        raise ValueError(f"inlier_chi2 must be a finite number > 0, got {inlier_chi2!r}")
    graph, factors = _build_graph(stack, None, edges, fixed, "none", None, 1.0)
    values = _values(stack, None)
    base = _lm_params(max_iterations)
    params = gtsam.GncLMParams(base)
    params.setLossType(gtsam.GncLossType.TLS)
    robust = np.fromiter((e.robust for e in edges), dtype=bool, count=len(edges))
    # The fixed nodes' equality factors follow the edges' in the graph.
    params.setKnownInliers(np.flatnonzero(~robust).tolist() + list(range(len(edges), graph.size())))
    params.setAllowNonNoiseModelFactors(True)
    optimizer = gtsam.GncLMOptimizer(graph, values, params)
    # GTSAM's threshold is on a factor's error, 0.5 χ².
    optimizer.setInlierCostThresholds(0.5 * inlier_chi2)
    solution = optimizer.optimize()
    weights = np.asarray(optimizer.getWeights(), dtype=np.float64).reshape(-1)[: len(edges)]
    return PoseGraphResult(
        poses=_poses_of(solution, stack, None)[0],
        error_before=float(graph.error(values)),
        error_after=float(graph.error(solution)),
        iterations=0,
        edge_chi2=_edge_chi2(edges, factors, solution, _dim(stack, None)),
        outliers=np.flatnonzero(robust & (weights < 0.5)).astype(np.int64),
    )


def graph_error(
    poses: ArrayLike,
    edges: Sequence[Edge],
    *,
    scales: ArrayLike | None = None,
    kernel: str = "none",
    kernel_width: float | None = None,
) -> float:
    """GTSAM's ``graph.error`` of the graph at ``poses`` ((N, 3) SE(2) or (N, 4, 4)) and
    ``scales`` for Sim(3).

    The same number the ``optimize_*`` functions report as ``error_before`` for these poses.
    """
    stack, s = _checked_graph(poses, edges, scales)
    graph, _ = _build_graph(stack, s, edges, (), kernel, kernel_width, 1.0)
    return float(graph.error(_values(stack, s)))


def edge_chi2(poses: ArrayLike, edges: Sequence[Edge], *, scales: ArrayLike | None = None) -> F64:
    """(E,) float64 whitened squared residual of each edge at ``poses`` ((N, 3) SE(2) or
    (N, 4, 4)) and ``scales`` for Sim(3), without a kernel: what
    :attr:`PoseGraphResult.edge_chi2` holds at the solution."""
    stack, s = _checked_graph(poses, edges, scales)
    _, factors = _build_graph(stack, s, edges, (), "none", None, 1.0)
    return _edge_chi2(edges, factors, _values(stack, s), _dim(stack, s))


def se3_edges_from_poses(
    poses: ArrayLike,
    pairs: Iterable[tuple[int, int]],
    *,
    information: ArrayLike | None = None,
    robust: bool = False,
    kind: str = "odometry",
) -> list[Edge]:
    """Exact edges ``a_from_b = inverse(poses[a]) @ poses[b]`` for each ``(a, b)`` pair.

    Args:
        poses: (N, 4, 4) ``world_from_node``.
        pairs: node index pairs.
        information: one (6, 6) information shared by all edges, or None (identity).
    """
    stack = _check_poses(poses)
    index = np.asarray(list(pairs), dtype=np.int64).reshape(-1, 2)
    if index.size and (index.min() < 0 or index.max() >= len(stack)):
        raise ValueError(f"pairs name nodes outside 0..{len(stack) - 1}")
    rel = compose(inverse(stack[index[:, 0]]), stack[index[:, 1]])
    info = None if information is None else np.asarray(information, dtype=np.float64)
    return [
        Edge(int(a), int(b), rel[k], information=info, robust=robust, kind=kind)
        for k, (a, b) in enumerate(index)
    ]


def from_g2o(graph: PoseGraph) -> tuple[F64, list[Edge], tuple[int, ...]]:
    """A g2o graph as ``(poses, edges, fixed indices)`` for :func:`optimize_se2` ((V, 3)
    poses) or :func:`optimize_se3` ((V, 4, 4) poses).

    Nodes are the graph's vertices in file order; edges name them by that index. In 3-D, g2o
    orders the information translation first and measures rotation by the quaternion's vector
    part (half the angle); both are converted to this module's ``[ω, v]`` order in radians, so
    the χ² of every edge is unchanged; 2-D information is used as it is. Consecutive-id edges
    become ``kind="odometry"``, the others ``kind="loop"`` and ``robust=True``.
    """
    ids = graph.vertex_ids
    if np.unique(ids).size != ids.size:
        raise ValueError(f"{graph.path}: vertex ids repeat; each VERTEX line needs its own id")
    order = np.argsort(ids, kind="stable")
    pos = np.searchsorted(ids[order], graph.edges)
    pos = np.minimum(pos, max(len(ids) - 1, 0))
    if not len(ids) or np.any(ids[order][pos] != graph.edges):
        raise ValueError(f"{graph.path}: edges name vertex ids that have no VERTEX line")
    index = order[pos]
    if graph.dim == 2:
        poses, rel, info = graph.poses, graph.measurements, graph.information
    else:
        poses = _g2o_to_matrix(graph.poses)
        rel = _g2o_to_matrix(graph.measurements)
        p = _g2o_jacobian()
        info = np.einsum("ji,ejk,kl->eil", p, graph.information, p)
    loop = np.abs(graph.edges[:, 1] - graph.edges[:, 0]) != 1
    edges = [
        Edge(
            int(index[k, 0]),
            int(index[k, 1]),
            rel[k],
            information=info[k],
            robust=bool(loop[k]),
            kind="loop" if loop[k] else "odometry",
        )
        for k in range(len(rel))
    ]
    fixed = tuple(int(order[np.searchsorted(ids[order], f)]) for f in graph.fixed if f in ids)
    return poses, edges, fixed


def save_g2o(
    path: str | Path,
    poses: ArrayLike,
    edges: Sequence[Edge],
    *,
    fixed: Iterable[int] = (),
) -> Path:
    """Write an SE(3) graph, or an SE(2) one (poses (N, 3) x, y, yaw), as a g2o file
    (atomically), the inverse of :func:`from_g2o`.

    Vertex ids are the node indices. The information is converted to g2o's order and units
    (SE(2) graphs share g2o's (x, y, theta) order).
    """
    from slamcli.formats.g2o import write_g2o_se3

    planar = np.asarray(poses, dtype=np.float64)
    if planar.ndim == 2 and planar.shape[1] == 3:
        return _save_g2o_se2(path, planar, edges, fixed)
    stack = _check_poses(poses)
    _check_edges(edges, len(stack), "se3")
    pinv = np.linalg.inv(_g2o_jacobian())
    info = np.stack([_information(e, 6) for e in edges]) if edges else np.zeros((0, 6, 6))
    return write_g2o_se3(
        path,
        stack,
        np.asarray([(e.a, e.b) for e in edges], dtype=np.int64).reshape(-1, 2),
        np.stack([e.a_from_b for e in edges]) if edges else np.zeros((0, 4, 4)),
        np.einsum("ji,ejk,kl->eil", pinv, info, pinv),
        fixed=tuple(int(f) for f in fixed),
    )


def _save_g2o_se2(
    path: str | Path, poses: F64, edges: Sequence[Edge], fixed: Iterable[int]
) -> Path:
    from slamcli.formats.g2o import PoseGraph, write_g2o

    stack = _check_planar_poses(poses)
    _check_edges(edges, len(stack), "se2")
    info = np.stack([_information(e, 3) for e in edges]) if edges else np.zeros((0, 3, 3))
    graph = PoseGraph(
        dim=2,
        vertex_ids=np.arange(len(stack), dtype=np.int64),
        poses=stack,
        edges=np.asarray([(e.a, e.b) for e in edges], dtype=np.int64).reshape(-1, 2),
        measurements=np.stack([e.a_from_b for e in edges]) if edges else np.zeros((0, 3)),
        information=info,
        fixed=tuple(int(f) for f in fixed),
        path=Path(path),
    )
    return write_g2o(path, graph)


def _g2o_to_matrix(values: F64) -> F64:
    return make_pose(quat_xyzw_to_matrix(values[:, 3:7]), values[:, :3])


def _g2o_jacobian() -> F64:
    """``e_g2o = P @ e_gtsam``: g2o's ``[t, q.xyz]`` residual from GTSAM's ``[ω, v]``."""
    p = np.zeros((6, 6))
    p[:3, 3:] = np.eye(3)
    p[3:, :3] = 0.5 * np.eye(3)
    return p


def _check_poses(poses: ArrayLike) -> F64:
    stack = np.asarray(poses, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[1:] != (4, 4) or len(stack) == 0:
        raise ValueError(f"poses must have shape (N, 4, 4) with N >= 1, got {stack.shape}")
    bad = _non_rigid(stack)
    if bad.size:
        raise ValueError(
            f"poses[{bad[0]}] is not a rigid (SE(3)) transform: its rotation block must be "
            f"orthonormal with determinant +1 and its last row [0, 0, 0, 1] "
            f"({bad.size} such pose(s))"
        )
    return stack


def _check_planar_poses(poses: ArrayLike) -> F64:
    stack = np.asarray(poses, dtype=np.float64)
    if stack.ndim != 2 or stack.shape[1] != 3 or len(stack) == 0:
        raise ValueError(f"planar poses must have shape (N, 3) with N >= 1, got {stack.shape}")
    if not np.isfinite(stack).all():
        bad = np.flatnonzero(~np.isfinite(stack).all(axis=1))
        raise ValueError(f"poses[{bad[0]}] is not finite ({bad.size} such pose(s))")
    return stack


def _check_nodes(poses: ArrayLike) -> F64:
    """(N, 3) planar or (N, 4, 4) rigid poses, checked as their shape says."""
    stack = np.asarray(poses, dtype=np.float64)
    return _check_planar_poses(stack) if stack.ndim == 2 else _check_poses(stack)


def _check_scales(scales: ArrayLike, n: int) -> F64:
    s = np.asarray(scales, dtype=np.float64)
    if s.shape != (n,):
        raise ValueError(f"scales must have shape ({n},), got {s.shape}")
    if not np.all(np.isfinite(s) & (s > 0)):
        raise ValueError(f"scales must be finite and > 0, got {s[~(np.isfinite(s) & (s > 0))]}")
    return s


def _checked_graph(
    poses: ArrayLike, edges: Sequence[Edge], scales: ArrayLike | None
) -> tuple[F64, F64 | None]:
    """Poses (SE(2), SE(3), or Sim(3) with ``scales``) and edges checked together."""
    stack = _check_nodes(poses)
    s = None if scales is None else _check_scales(scales, len(stack))
    if stack.ndim == 2 and s is not None:
        raise ValueError("scales apply to (N, 4, 4) Sim(3) poses, not to planar ones")
    _check_edges(edges, len(stack), "se2" if stack.ndim == 2 else "se3" if s is None else "sim3")
    return stack, s


def _dim(poses: F64, scales: F64 | None) -> int:
    """The residual's dimension: 3 for SE(2), 6 for SE(3), 7 for Sim(3)."""
    return 3 if poses.ndim == 2 else 6 if scales is None else 7


def _non_rigid(stack: F64) -> NDArray[np.intp]:
    r = stack[:, :3, :3]
    with np.errstate(invalid="ignore"):
        ortho = np.abs(np.swapaxes(r, 1, 2) @ r - np.eye(3)).max(axis=(1, 2))
        ok = (
            np.isfinite(stack).all(axis=(1, 2))
            & (ortho < _RIGID_TOL)
            & (np.linalg.det(r) > 0)
            & np.all(stack[:, 3] == [0.0, 0.0, 0.0, 1.0], axis=1)
        )
    return np.flatnonzero(~ok)


def _check_edges(edges: Sequence[Edge], n: int, group: str) -> None:
    """Edges of a ``group`` (``se2``, ``se3`` or ``sim3``) graph of ``n`` nodes."""
    sizes = {"se2": (3,), "se3": (6,), "sim3": (6, 7)}[group]
    for k, e in enumerate(edges):
        if not (0 <= e.a < n and 0 <= e.b < n):
            raise ValueError(f"edges[{k}] joins nodes {e.a} and {e.b}, outside 0..{n - 1}")
        if e.a == e.b:
            raise ValueError(f"edges[{k}] joins node {e.a} to itself")
        m = np.asarray(e.a_from_b, dtype=np.float64)
        if group == "se2":
            if m.shape != (3,) or not np.isfinite(m).all():
                raise ValueError(
                    f"edges[{k}].a_from_b is not a finite (3,) x, y, yaw row: shape {m.shape}"
                )
        elif m.shape != (4, 4) or _non_rigid(m[None]).size:
            raise ValueError(
                f"edges[{k}].a_from_b is not a rigid (SE(3)) (4, 4) transform: shape {m.shape}, "
                "or a rotation block that is not orthonormal with determinant +1"
            )
        if group == "sim3" and not (math.isfinite(e.scale) and e.scale > 0):
            raise ValueError(f"edges[{k}].scale must be finite and > 0, got {e.scale!r}")
        if e.information is not None:
            info = np.asarray(e.information, dtype=np.float64)
            if info.shape not in [(s, s) for s in sizes]:
                allowed = " or ".join(f"({s}, {s})" for s in sizes)
                raise ValueError(f"edges[{k}].information must be {allowed}, got {info.shape}")
            if not np.allclose(info, info.T, rtol=1e-9, atol=0.0) or not _positive_definite(info):
                raise ValueError(f"edges[{k}].information is not symmetric positive definite")


def _positive_definite(m: F64) -> bool:
    if not np.isfinite(m).all():
        return False
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return False
    return True


def _information(edge: Edge, dim: int, scale_sigma: float = 1.0) -> F64:
    if edge.information is None:
        info = np.eye(dim)
        if dim == 7:
            info[6, 6] = scale_sigma**-2
        return info
    given = np.asarray(edge.information, dtype=np.float64)
    if given.shape == (dim, dim):
        return 0.5 * (given + given.T)
    info = np.zeros((7, 7))
    info[:6, :6] = 0.5 * (given + given.T)
    info[6, 6] = scale_sigma**-2
    return info


def robust_kernel(name: str, width: float | None, dim: int) -> Any:
    """A maker of GTSAM's robust estimator ``name`` (one of :data:`KERNELS`, ``none`` gives
    None) of ``width`` in whitened units; None takes the 95 % chi-square bound of ``dim``
    degrees of freedom."""
    import gtsam

    if name not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {name!r}")
    if width is None:
        width = math.sqrt(chi2_quantile(_WIDTH_PROBABILITY, dim))
    if not (math.isfinite(width) and width > 0):
        raise ValueError(f"kernel_width must be a finite number > 0, got {width!r}")
    m = gtsam.noiseModel.mEstimator
    return {
        "none": None,
        "huber": lambda: m.Huber(width),
        "cauchy": lambda: m.Cauchy(width),
        "tukey": lambda: m.Tukey(width),
        "dcs": lambda: m.DCS(width * width),
    }[name]


def _values(poses: F64, scales: F64 | None) -> Any:
    import gtsam

    values = gtsam.Values()
    for i, t in enumerate(poses):
        if poses.ndim == 2:
            values.insert(i, gtsam.Pose2(*t.tolist()))
        elif scales is None:
            values.insert(i, gtsam.Pose3(t))
        else:
            values.insert(i, _similarity(t, float(scales[i])))
    return values


def _similarity(pose: F64, scale: float) -> Any:
    import gtsam

    return gtsam.Similarity3(gtsam.Rot3(pose[:3, :3]), pose[:3, 3] / scale, scale)


def _build_graph(
    poses: F64,
    scales: F64 | None,
    edges: Sequence[Edge],
    fixed: Iterable[int],
    kernel: str,
    kernel_width: float | None,
    scale_sigma: float,
) -> tuple[Any, list[Any]]:
    import gtsam

    dim = _dim(poses, scales)
    make_kernel = robust_kernel(kernel, kernel_width, dim)
    graph = gtsam.NonlinearFactorGraph()
    factors = []
    for e in edges:
        noise: Any = gtsam.noiseModel.Gaussian.Information(_information(e, dim, scale_sigma))
        if e.robust and make_kernel is not None:
            noise = gtsam.noiseModel.Robust.Create(make_kernel(), noise)
        a_from_b = np.asarray(e.a_from_b, dtype=np.float64)
        if dim == 3:
            measured = gtsam.Pose2(*a_from_b.tolist())
            factor: Any = gtsam.BetweenFactorPose2(e.a, e.b, measured, noise)
        elif scales is None:
            factor = gtsam.BetweenFactorPose3(e.a, e.b, gtsam.Pose3(a_from_b), noise)
        else:
            measured = _similarity(a_from_b, float(e.scale))
            factor = gtsam.BetweenFactorSimilarity3(e.a, e.b, measured, noise)
        graph.add(factor)
        factors.append(factor)
    for i in sorted(set(fixed)):
        if not 0 <= i < len(poses):
            raise ValueError(f"fixed node {i} is outside 0..{len(poses) - 1}")
        if dim == 3:
            graph.add(gtsam.NonlinearEqualityPose2(i, gtsam.Pose2(*poses[i].tolist())))
        elif scales is None:
            graph.add(gtsam.NonlinearEqualityPose3(i, gtsam.Pose3(poses[i])))
        else:
            graph.add(
                gtsam.NonlinearEqualitySimilarity3(i, _similarity(poses[i], float(scales[i])))
            )
    return graph, factors


def _optimize(
    poses: F64,
    scales: F64 | None,
    edges: Sequence[Edge],
    options: SolveOptions,
    scale_sigma: float = 1.0,
) -> PoseGraphResult:
    import gtsam

    unknown = sorted(set(options) - set(_SOLVE_DEFAULTS))
    if unknown:
        raise TypeError(f"unknown solve option(s) {', '.join(unknown)}")
    o = _SOLVE_DEFAULTS | options
    max_iterations = o["max_iterations"]
    if max_iterations < 1:
        raise ValueError(f"max_iterations must be >= 1, got {max_iterations}")
    graph, factors = _build_graph(
        poses, scales, edges, o["fixed"], o["kernel"], o["kernel_width"], scale_sigma
    )
    initial = _values(poses, scales)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, _lm_params(max_iterations))
    error_before = float(graph.error(initial))
    solution = optimizer.optimize()
    dim = _dim(poses, scales)
    out, out_scales = _poses_of(solution, poses, scales)
    chi2 = _edge_chi2(edges, factors, solution, dim, scale_sigma)
    bound = chi2_quantile(OUTLIER_PROBABILITY, dim)
    robust = np.fromiter((e.robust for e in edges), dtype=bool, count=len(edges))
    return PoseGraphResult(
        poses=out,
        scales=out_scales,
        error_before=error_before,
        error_after=float(graph.error(solution)),
        iterations=int(optimizer.iterations()),
        edge_chi2=chi2,
        outliers=np.flatnonzero(robust & (chi2 > bound)).astype(np.int64),
    )


def _lm_params(max_iterations: int) -> Any:
    """GTSAM's Levenberg–Marquardt defaults (COLAMD ordering), silent, with an iteration cap."""
    import gtsam

    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(int(max_iterations))
    params.setVerbosityLM("SILENT")
    return params


def _poses_of(solution: Any, poses: F64, scales: F64 | None) -> tuple[F64, F64 | None]:
    """The nodes' poses (shaped like ``poses``) and scales (Sim(3)) in GTSAM ``solution``."""
    out = np.empty_like(poses)
    out_scales = None if scales is None else np.empty_like(scales)
    for i in range(len(poses)):
        if poses.ndim == 2:
            p = solution.atPose2(i)
            out[i] = [p.x(), p.y(), p.theta()]
        elif out_scales is None:
            out[i] = solution.atPose3(i).matrix()
        else:
            sim = solution.atSimilarity3(i)
            out_scales[i] = sim.scale()
            out[i] = make_pose(sim.rotation().matrix(), sim.scale() * sim.translation())
    return out, out_scales


def _edge_chi2(
    edges: Sequence[Edge], factors: Sequence[Any], values: Any, dim: int, scale_sigma: float = 1.0
) -> F64:
    """(E,) each edge's unwhitened residual at ``values`` through its information, r' I r."""
    chi2 = np.empty(len(edges))
    for k, (e, factor) in enumerate(zip(edges, factors, strict=True)):
        r = factor.unwhitenedError(values)
        chi2[k] = r @ _information(e, dim, scale_sigma) @ r
    return chi2
