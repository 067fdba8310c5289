"""``slamcli graph optimize``: a g2o pose graph optimised in its own dimension, with GTSAM.

:func:`optimize_graph` takes a :class:`~slamcli.formats.g2o.PoseGraph` as read from a file and
returns the optimised graph (same pose ids, same edges) with the figures ``run.json`` records.

Conventions
-----------
- 2-D graphs are optimised on SE(2), 3-D graphs on SE(3), through
  :func:`slamcli.graphs.pose_graph.optimize_se2` and
  :func:`~slamcli.graphs.pose_graph.optimize_se3` (each edge's χ² is the one g2o computes; see
  :mod:`slamcli.graphs.pose_graph`).
- The graph's pose ids are the listed vertices and every id an edge names. A pose without a
  ``VERTEX`` line (Manhattan lists edges only) starts where the edges place it: the
  consecutive-id (odometry) edges are chained from the smallest id first, loop closures reach
  what remains.
- The gauge: the ``FIX`` vertices, or the smallest pose id when there are none, are held
  exactly by ``NonlinearEquality`` factors, which add nothing to the error.
- Robust kernels act on loop closures only (edges between non-consecutive ids); odometry
  edges keep their quadratic cost. ``kernel_width`` is in whitened-residual-norm units; its
  default is ``sqrt`` of the 95 % χ² quantile of the residual's dimension (3 in 2-D, 6 in 3-D).
- ``error_before`` and ``error_after`` are GTSAM's ``NonlinearFactorGraph.error`` of the
  final solve's graph (``0.5 Σ ρ(r²)``, ``0.5 Σ χ²`` without a kernel) at the initial and the
  optimised values.
- Outliers: GTSAM's graduated non-convexity (``GncLMOptimizer``, truncated least squares,
  odometry edges known inliers, inlier threshold the ``1 - 1e-5`` χ² quantile;
  :func:`slamcli.graphs.pose_graph.optimize_gnc`) over every edge from the starting poses
  drops the candidates; a least-squares solve without them re-admits the loop closures
  within the 99 % χ² gate (up to 5 rounds), and the loop closures beyond the gate are the
  outliers. The final solve leaves them out, with ``kernel`` when one is
  given. The GNC solve does not report its iteration count (``iterations`` 0).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, InputError
from slamcli.geometry.chi2 import chi2_quantile
from slamcli.geometry.planar import planar_to_se3, se3_to_planar
from slamcli.geometry.se3 import inverse, make_pose, quat_xyzw_to_matrix

if TYPE_CHECKING:
    from slamcli.formats.g2o import PoseGraph
    from slamcli.graphs.pose_graph import PoseGraphResult

F64 = NDArray[np.float64]
KERNELS = ("none", "huber", "cauchy", "dcs")
GNC_METHOD = "gnc-tls"
"""The outlier search: graduated non-convexity with a truncated least squares loss."""
GNC_PROBABILITY = 1.0 - 1e-5
"""χ² probability of the GNC search's inlier threshold: the wrong loop closures it is meant
for lie far beyond it, and a tighter threshold also drops real loops the least-squares
solution fits."""
OUTLIER_PROBABILITY = 0.99
_WIDTH_PROBABILITY = 0.95
_RECHECK_ROUNDS = 5


@dataclass(frozen=True)
class Solve:
    """One Levenberg–Marquardt solve.

    Attributes:
        kernel, kernel_width: the robust kernel on loop closures and its width (whitened
            residual norm), ``"none"`` and None without one.
        error_before, error_after: GTSAM's ``graph.error`` at the initial and optimised values.
        iterations: Levenberg–Marquardt iterations run.
        edge_chi2: (E,) float64 χ² of every edge of the input at the solution (edges left out
            of the solve included), without the kernel.
        edges_used: (E,) bool, the edges the solve used.
        time_s: wall-clock seconds of the solve.
    """

    kernel: str
    kernel_width: float | None
    error_before: float
    error_after: float
    iterations: int
    edge_chi2: F64
    edges_used: NDArray[np.bool_]
    time_s: float

    @classmethod
    def of(
        cls,
        result: PoseGraphResult,
        kernel: str,
        kernel_width: float | None,
        edge_chi2: F64,
        edges_used: NDArray[np.bool_],
        clock: float,
    ) -> Solve:
        """The solve that gave ``result``, started at ``time.perf_counter()`` = ``clock``."""
        return cls(
            kernel=kernel,
            kernel_width=kernel_width,
            error_before=result.error_before,
            error_after=result.error_after,
            iterations=result.iterations,
            edge_chi2=edge_chi2,
            edges_used=edges_used.copy(),
            time_s=time.perf_counter() - clock,
        )


@dataclass(frozen=True)
class GraphOptimization:
    """What :func:`optimize_graph` returns.

    Attributes:
        initial: the input graph with a vertex for every pose id, sorted by id, starting
            poses filled in from the edges where the file listed none.
        optimized: ``initial`` with the optimised poses: same ids, edges and ``FIX`` lines.
        final: the solve that gave ``optimized``.
        detection: the GNC solve that found the outlier candidates (with --outliers).
        loop: (E,) bool, the loop closures (edges between non-consecutive ids).
        outliers: (K,) int64 indices into the edges of the loop closures reported as outliers.
        outlier_bound: the χ² gate (99 % quantile of the residual's dimension).
        fixed_ids: pose ids held fixed (the gauge).
        filled_ids: pose ids that had no vertex line.
    """

    initial: PoseGraph
    optimized: PoseGraph
    final: Solve
    detection: Solve | None
    loop: NDArray[np.bool_]
    outliers: NDArray[np.int64]
    outlier_bound: float
    fixed_ids: tuple[int, ...]
    filled_ids: tuple[int, ...]

    def summary(self) -> dict[str, Any]:
        """The JSON-able figures run.json records (without input and timing details)."""
        g = self.optimized
        detection = self.detection
        chi2 = self.final.edge_chi2
        return {
            "dimension": g.dim,
            "vertices": int(g.vertex_ids.size),
            "vertices_filled_from_edges": len(self.filled_ids),
            "edges": int(g.edges.shape[0]),
            "odometry_edges": int((~self.loop).sum()),
            "loop_closure_edges": int(self.loop.sum()),
            "fixed": list(self.fixed_ids),
            "kernel": self.final.kernel,
            "kernel_width": self.final.kernel_width,
            "error_before": self.final.error_before,
            "error_after": self.final.error_after,
            "iterations": self.final.iterations,
            "solve_time_s": round(self.final.time_s, 4),
            "edges_used": int(self.final.edges_used.sum()),
            "outlier_search": None
            if detection is None
            else {
                "kernel": detection.kernel,
                "kernel_width": detection.kernel_width,
                "error_before": detection.error_before,
                "error_after": detection.error_after,
                "iterations": detection.iterations,
                "solve_time_s": round(detection.time_s, 4),
                "method": "graduated non-convexity (GTSAM GncLMOptimizer), truncated least "
                "squares loss, odometry edges known inliers",
                "note": "outlier candidates are the loop closures this solve drops; a "
                "least-squares solve without them re-admits those it fits within the gate "
                "(up to 5 rounds); the final solve leaves the outliers out",
            },
            "outlier_chi2_bound": self.outlier_bound,
            "outliers": [
                {
                    "edge": int(k),
                    "from": int(g.edges[k, 0]),
                    "to": int(g.edges[k, 1]),
                    "chi2": float(chi2[k]),
                    "chi2_robust_solve": float(detection.edge_chi2[k]),
                }
                for k in self.outliers
            ]
            if detection is not None
            else [],
        }


def default_kernel_width(dim: int) -> float:
    """``sqrt`` of the 95 % χ² quantile of a ``dim``-D graph's residual (3 or 6 dof)."""
    return math.sqrt(chi2_quantile(_WIDTH_PROBABILITY, _dof(dim)))


def optimize_graph(
    graph: PoseGraph,
    *,
    kernel: str = "none",
    kernel_width: float | None = None,
    max_iterations: int = 100,
    find_outliers: bool = False,
) -> GraphOptimization:
    """Optimise a g2o pose graph with Levenberg–Marquardt in its own dimension.

    Args:
        graph: a 2-D or 3-D graph from :func:`slamcli.formats.g2o.read_g2o`.
        kernel: robust kernel on loop closures, one of :data:`KERNELS`.
        kernel_width: kernel width (whitened residual norm); None for the default.
        max_iterations: Levenberg–Marquardt iteration cap, >= 1.
        find_outliers: search for wrong loop closures (GNC, then least-squares re-checks; see
            the module docstring) and leave them out of the final solve.

    Raises:
        ConfigError: an unknown kernel, a width that is not > 0, max_iterations < 1.
        InputError: repeated vertex ids, or poses the edges do not connect to the rest.
    """
    if kernel not in KERNELS:
        raise ConfigError(
            f"--kernel must be one of {', '.join(KERNELS)}, got {kernel!r}",
            hint="kernels: none (least squares), huber, cauchy, dcs",
        )
    if kernel_width is not None and not (math.isfinite(kernel_width) and kernel_width > 0):
        raise ConfigError(f"--kernel-width must be a number > 0, got {kernel_width!r}")
    if max_iterations < 1:
        raise ConfigError(f"--max-iterations must be >= 1, got {max_iterations}")
    initial, filled = complete_vertices(graph)
    ids = initial.vertex_ids
    fixed_ids = tuple(sorted(set(initial.fixed) & set(ids.tolist()))) or (int(ids[0]),)
    fixed = tuple(int(i) for i in np.searchsorted(ids, fixed_ids))
    loop = np.abs(initial.edges[:, 1] - initial.edges[:, 0]) != 1
    everything = np.ones(len(loop), dtype=bool)
    bound = chi2_quantile(OUTLIER_PROBABILITY, _dof(graph.dim))
    width = None if kernel == "none" else kernel_width or default_kernel_width(graph.dim)

    def solve(
        name: str, w: float | None, used: NDArray[np.bool_], start: F64 | None = None
    ) -> tuple[F64, Solve]:
        return _solve(initial, used, fixed, name, w, max_iterations, start)

    detection: Solve | None = None
    outliers = np.zeros(0, dtype=np.int64)
    if not find_outliers:
        poses, final = solve(kernel, width, everything)
    else:
        detection, rejected = _gnc(initial, fixed, max_iterations)
        for _ in range(_RECHECK_ROUNDS):
            poses, final = solve("none", None, ~rejected)
            recheck = loop & (final.edge_chi2 > bound)
            if np.array_equal(recheck, rejected):
                break
            rejected = recheck
        outliers = np.flatnonzero(rejected).astype(np.int64)
        if kernel != "none":
            poses, final = solve(kernel, width, ~rejected, start=poses)
    optimized = dataclasses.replace(initial, poses=poses)
    return GraphOptimization(
        initial=initial,
        optimized=optimized,
        final=final,
        detection=detection,
        loop=loop,
        outliers=outliers,
        outlier_bound=bound,
        fixed_ids=fixed_ids,
        filled_ids=filled,
    )


def gnc_inlier_bound(dim: int) -> float:
    """The χ² beyond which the GNC search's truncated least squares drops a loop closure."""
    return chi2_quantile(GNC_PROBABILITY, _dof(dim))


def _gnc(
    graph: PoseGraph, fixed: tuple[int, ...], max_iterations: int
) -> tuple[Solve, NDArray[np.bool_]]:
    """GTSAM's graduated non-convexity over every edge of ``graph`` (odometry edges and the
    gauge known inliers); returns the solve and the (E,) loop closures it drops."""
    from slamcli.graphs.pose_graph import from_g2o, optimize_gnc

    clock = time.perf_counter()
    nodes, edges, _ = from_g2o(dataclasses.replace(graph, fixed=()))
    result = optimize_gnc(
        nodes,
        edges,
        inlier_chi2=gnc_inlier_bound(graph.dim),
        fixed=fixed,
        max_iterations=max_iterations,
    )
    dropped = np.zeros(len(edges), dtype=bool)
    dropped[result.outliers] = True
    used = np.ones(len(edges), dtype=bool)
    width = math.sqrt(gnc_inlier_bound(graph.dim))
    return Solve.of(result, GNC_METHOD, width, result.edge_chi2, used, clock), dropped


def complete_vertices(graph: PoseGraph) -> tuple[PoseGraph, tuple[int, ...]]:
    """``graph`` with a vertex for every pose id, sorted by id, and the ids that were added.

    Listed vertices keep their poses. A missing pose is placed by composing an edge's
    measurement onto a placed neighbour: consecutive-id edges first, in id order (the odometry
    chain), then loop closures, until every pose is placed. With no vertices at all, the
    smallest id starts at the origin.

    Raises:
        InputError: a vertex id listed twice, or pose ids no chain of edges reaches.
    """
    ids = graph.vertex_ids
    if np.unique(ids).size != ids.size:
        repeated = int(ids[np.flatnonzero(np.diff(np.sort(ids)) == 0)[0]])
        raise InputError(
            f"{graph.path}: vertex id {repeated} is listed twice",
            hint="each VERTEX line needs its own id",
        )
    all_ids = np.union1d(ids, graph.edges.ravel()).astype(np.int64)
    order = np.argsort(ids, kind="stable")
    matrices = np.zeros((all_ids.size, 4, 4))
    known = np.zeros(all_ids.size, dtype=bool)
    at = np.searchsorted(all_ids, ids[order])
    matrices[at] = _to_matrices(graph.dim, graph.poses[order])
    known[at] = True
    if not known.any():
        matrices[0] = np.eye(4)
        known[0] = True
    rel = _to_matrices(graph.dim, graph.measurements)
    pos = np.searchsorted(all_ids, graph.edges)
    sequential = np.abs(graph.edges[:, 1] - graph.edges[:, 0]) == 1
    by_priority = np.lexsort((pos.min(axis=1), ~sequential))
    while not known.all():
        progress = False
        for k in by_priority.tolist():
            a, b = pos[k]
            if known[a] and not known[b]:
                matrices[b] = matrices[a] @ rel[k]
                known[b] = True
                progress = True
            elif known[b] and not known[a]:
                matrices[a] = matrices[b] @ inverse(rel[k])
                known[a] = True
                progress = True
        if not progress:
            lost = all_ids[~known]
            raise InputError(
                f"{graph.path}: {lost.size} pose id(s) ({', '.join(map(str, lost[:5].tolist()))}"
                f"{', ...' if lost.size > 5 else ''}) have no vertex line and no chain of edges "
                "to a placed pose",
                hint="the graph must be connected, or list a VERTEX line for each pose",
            )
    poses = _from_matrices(graph.dim, matrices)
    poses[at] = graph.poses[order]
    filled = tuple(int(i) for i in np.setdiff1d(all_ids, ids))
    return dataclasses.replace(graph, vertex_ids=all_ids, poses=poses), filled


def _dof(dim: int) -> int:
    return 3 if dim == 2 else 6


def _to_matrices(dim: int, values: F64) -> F64:
    """g2o rows ((N, 3) x y theta or (N, 7) x y z qx qy qz qw) as (N, 4, 4) transforms."""
    if dim == 2:
        return planar_to_se3(values)
    return make_pose(quat_xyzw_to_matrix(values[:, 3:7]), values[:, :3])


def _from_matrices(dim: int, matrices: F64) -> F64:
    if dim == 2:
        return se3_to_planar(matrices)
    from slamcli.geometry.se3 import matrix_to_quat_xyzw

    return np.concatenate([matrices[:, :3, 3], matrix_to_quat_xyzw(matrices)], axis=1)


def _to_nodes(dim: int, values: F64) -> F64:
    """g2o rows as the poses :mod:`slamcli.graphs.pose_graph` takes: (N, 3) rows themselves
    (a copy) in 2-D, (N, 4, 4) transforms in 3-D."""
    return np.array(values, dtype=np.float64) if dim == 2 else _to_matrices(dim, values)


def _from_nodes(dim: int, nodes: F64) -> F64:
    """The inverse of :func:`_to_nodes`."""
    return nodes if dim == 2 else _from_matrices(dim, nodes)


def _solve(
    graph: PoseGraph,
    used: NDArray[np.bool_],
    fixed: tuple[int, ...],
    kernel: str,
    width: float | None,
    max_iterations: int,
    start: F64 | None = None,
) -> tuple[F64, Solve]:
    """Optimise ``graph``'s poses using the ``used`` edges, from ``start`` (g2o rows) or the
    graph's own poses; returns (poses as g2o rows, solve). ``error_before`` is always at the
    graph's own poses."""
    from slamcli.graphs.pose_graph import (
        edge_chi2,
        from_g2o,
        graph_error,
        optimize_se2,
        optimize_se3,
    )

    clock = time.perf_counter()
    nodes, edges, _ = from_g2o(dataclasses.replace(graph, fixed=()))
    kept = [e for e, u in zip(edges, used.tolist(), strict=True) if u]
    begin = nodes if start is None else _to_nodes(graph.dim, start)
    if start is not None:
        # The fixed poses stay where the file puts them.
        begin[list(fixed)] = nodes[list(fixed)]
    optimize = optimize_se2 if graph.dim == 2 else optimize_se3
    result = optimize(
        begin, kept, fixed=fixed, kernel=kernel, kernel_width=width, max_iterations=max_iterations
    )
    chi2 = np.empty(len(edges))
    chi2[used] = result.edge_chi2
    if not used.all():
        chi2[~used] = edge_chi2(result.poses, [edges[k] for k in np.flatnonzero(~used).tolist()])
    solve = Solve.of(result, kernel, width, chi2, used, clock)
    if start is not None:
        before = graph_error(nodes, kept, kernel=kernel, kernel_width=width)
        solve = dataclasses.replace(solve, error_before=before)
    return _from_nodes(graph.dim, result.poses), solve


@dataclass(frozen=True)
class OptimizeRun:
    """What :func:`optimize_to_folder` returns.

    Attributes:
        result: the optimisation.
        record: the run.json record as written.
        written: final paths of the files written, run.json last.
    """

    result: GraphOptimization
    record: dict[str, Any]
    written: list[Path]


def optimize_to_folder(
    path: str | Path,
    out: str | Path,
    *,
    kernel: str = "none",
    kernel_width: float | None = None,
    max_iterations: int = 100,
    find_outliers: bool = False,
    force: bool = False,
) -> OptimizeRun:
    """Read a g2o graph, optimise it (:func:`optimize_graph`) and write a run folder.

    ``out`` receives, all or nothing (:class:`slamcli.rundir.RunDir`): ``optimized.g2o`` (the
    input's pose ids, a vertex line for each, the same edges and ``FIX`` lines),
    ``trajectory.tum`` (the optimised poses, pose id ``i`` stamped ``i`` seconds; 2-D poses
    at z = 0 with their yaw about +z), ``report.png`` (top view before and after) and
    ``run.json`` (the input's path and SHA-256 and :meth:`GraphOptimization.summary` under
    ``"graph"``).

    Raises:
        InputError: a missing or malformed file (``FormatError`` names ``file:line``).
        ConfigError: bad options. ExportError: ``out`` not empty without ``force``.
    """
    from slamcli.formats.g2o import read_g2o, write_g2o
    from slamcli.formats.trajectory import write_tum
    from slamcli.rundir import RunDir, Timings, hash_input
    from slamcli.types import Trajectory

    source = Path(path)
    if not source.is_file():
        raise InputError(
            f"{source}: no such file" if not source.exists() else f"{source}: is not a file",
            hint="give the path of a .g2o pose graph",
        )
    timings = Timings()
    with timings.stage("read"):
        graph = read_g2o(source)
        described = hash_input(source)
    with RunDir(out, force=force) as target:
        with timings.stage("optimize"):
            result = optimize_graph(
                graph,
                kernel=kernel,
                kernel_width=kernel_width,
                max_iterations=max_iterations,
                find_outliers=find_outliers,
            )
        with timings.stage("write"):
            optimized = result.optimized
            write_g2o(target.output("optimized.g2o"), optimized)
            trajectory = Trajectory(
                stamps_ns=optimized.vertex_ids * 1_000_000_000,
                world_from_body=_to_matrices(optimized.dim, optimized.poses),
            )
            write_tum(target.output("trajectory.tum"), trajectory)
            plot_optimization(target.output("report.png"), result)
        summary = result.summary()
        target.write_run_json(
            command="graph optimize",
            inputs=[described],
            config={
                "kernel": kernel,
                "kernel_width": kernel_width,
                "max_iterations": max_iterations,
                "outliers": find_outliers,
            },
            timings=timings,
            counts={k: summary[k] for k in ("vertices", "edges", "loop_closure_edges")},
            metrics={k: summary[k] for k in ("error_before", "error_after", "iterations")}
            | {"outliers": len(summary["outliers"])},
            extra={"graph": summary, "trajectory_stamps": "pose id i is stamped i seconds"},
        )
        record = json.loads(target.staged("run.json").read_text(encoding="utf-8"))
    written = [target.file(name) for name in target.outputs]
    return OptimizeRun(result=result, record=record, written=written)


def plot_optimization(path: str | Path, result: GraphOptimization) -> Path:
    """Write a PNG: the graph from above (x-y) before and after, loop closures and outliers.

    Left, the starting poses; right, the optimised ones. Thin grey lines are loop closures,
    red ones the reported outliers.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.collections import LineCollection
    from matplotlib.figure import Figure

    from slamcli.report import save_png

    fig = Figure(figsize=(12, 6))
    FigureCanvasAgg(fig)
    panels = (
        ("before", result.initial, result.final.error_before),
        ("after", result.optimized, result.final.error_after),
    )
    index = np.searchsorted(result.optimized.vertex_ids, result.optimized.edges)
    outlier = np.zeros(len(result.loop), dtype=bool)
    outlier[result.outliers] = True
    for k, (label, graph, error) in enumerate(panels):
        ax = fig.add_subplot(1, 2, k + 1)
        xy = graph.poses[:, :2]
        for mask, color, width in (
            (result.loop & ~outlier, "0.75", 0.3),
            (outlier, "tab:red", 0.8),
        ):
            segments = xy[index[mask]]
            if len(segments):
                ax.add_collection(LineCollection(list(segments), colors=color, linewidths=width))
        ax.plot(xy[:, 0], xy[:, 1], color="tab:blue", linewidth=0.8)
        ax.set_title(f"{label}: error {error:.6g}")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    fig.suptitle(
        f"{result.optimized.dim}-D pose graph, {len(result.optimized.vertex_ids)} poses, "
        f"{len(result.loop)} edges, kernel {result.final.kernel}, "
        f"{result.outliers.size} outlier(s) in red"
    )
    fig.tight_layout()
    return save_png(fig, path)
