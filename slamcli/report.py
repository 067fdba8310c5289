"""Plots for evaluations and run reports (matplotlib's Agg canvas, no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from slamcli.errors import ExportError
from slamcli.evaluation import EvalResult
from slamcli.rundir import atomic_path
from slamcli.types import TriangleMesh


def plot_evaluation(
    path: str | Path,
    result: EvalResult,
    gt_label: str = "ground truth",
    est_label: str = "estimate",
    timed: bool = True,
    mesh: TriangleMesh | None = None,
) -> Path:
    """Write a PNG with a top view of ground truth and the aligned estimate, and ATE over time.

    The top view shows the two axes along which the ground truth extends most: x-y for TUM
    and EuRoC conventions, x-z for KITTI's camera frame (y down). ``timed=False`` puts the
    frame index on the error plot's x axis (trajectories without timestamps). With a mesh, a
    third panel shows its vertices from above in their colours, with the estimated path.
    """
    # The Agg canvas directly, not pyplot: no global backend switch and no figure registry.
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    m = result.matched
    gt_xyz = m.gt[:, :3, 3]
    est_xyz = result.aligned_est[:, :3, 3]
    ax0, ax1 = sorted(np.argsort(np.ptp(gt_xyz, axis=0))[-2:].tolist())
    t = (m.stamps_ns - m.stamps_ns[0]) * 1e-9 if timed else m.est_index.astype(float)

    fig = Figure(figsize=(18 if mesh is not None else 12, 5), layout="constrained")
    FigureCanvasAgg(fig)
    if mesh is not None:
        top, err, view = fig.subplots(1, 3, width_ratios=(1, 1.3, 1))
        _mesh_view(view, mesh, result)
    else:
        top, err = fig.subplots(1, 2, width_ratios=(1, 1.3))
    top.plot(gt_xyz[:, ax0], gt_xyz[:, ax1], color="0.35", lw=1.5, ls="--", label=gt_label)
    top.plot(est_xyz[:, ax0], est_xyz[:, ax1], color="tab:blue", lw=1.2, label=est_label)
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel(f"{'xyz'[ax0]} (m)")
    top.set_ylabel(f"{'xyz'[ax1]} (m)")
    top.set_title(f"Top view, {result.alignment} alignment, {result.pairs} pairs")
    top.legend(loc="best", fontsize="small")
    top.grid(alpha=0.3)
    err.plot(t, result.ate_m, color="tab:red", lw=1.0, label="ATE")
    err.axhline(result.ate.rmse, color="k", lw=1.0, ls=":", label=f"rmse {result.ate.rmse:.4f} m")
    err.set_xlabel("time since first pair (s)" if timed else "frame index")
    err.set_ylabel("position error (m)")
    err.set_title("Absolute trajectory error")
    err.legend(loc="upper right", fontsize="small")
    err.grid(alpha=0.3)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=100)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write the plot ({exc.strerror})") from exc
    return Path(path)


def _mesh_view(ax: Any, mesh: TriangleMesh, result: EvalResult) -> None:
    """The mesh moved into the ground truth's frame by the alignment, seen from above (+z)."""
    import numpy as np

    # Every k-th vertex: enough for a picture, and the same picture on every run.
    step = max(1, len(mesh.vertices) // 60_000)
    pts = result.scale * mesh.vertices[::step] @ result.rotation.T + result.translation
    # Lowest first, so the tops of walls and boxes are painted over the floor.
    order = np.argsort(pts[:, 2], kind="stable")
    colors = mesh.vertex_colors[::step][order] / 255.0 if mesh.vertex_colors is not None else "0.4"
    ax.scatter(pts[order, 0], pts[order, 1], c=colors, s=0.5, linewidths=0)
    est = result.aligned_est[:, :3, 3]
    ax.plot(est[:, 0], est[:, 1], color="tab:blue", lw=1.0, label="estimate")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Mesh from above ({len(mesh.vertices)} vertices, {len(mesh.faces)} faces)")
    ax.legend(loc="best", fontsize="small")
