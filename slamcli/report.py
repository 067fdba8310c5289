"""Plots for evaluations and run reports (matplotlib's Agg canvas, no display needed)."""

from __future__ import annotations

from pathlib import Path

from slamcli.errors import ExportError
from slamcli.evaluation import EvalResult
from slamcli.rundir import atomic_path


def plot_evaluation(
    path: str | Path,
    result: EvalResult,
    gt_label: str = "ground truth",
    est_label: str = "estimate",
    timed: bool = True,
) -> Path:
    """Write a PNG with a top view of ground truth and the aligned estimate, and ATE over time.

    The top view shows the two axes along which the ground truth extends most: x-y for TUM
    and EuRoC conventions, x-z for KITTI's camera frame (y down). ``timed=False`` puts the
    frame index on the error plot's x axis (trajectories without timestamps).
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

    fig = Figure(figsize=(12, 5), layout="constrained")
    FigureCanvasAgg(fig)
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
