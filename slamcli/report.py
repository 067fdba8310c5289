"""Plots for evaluations and run reports (matplotlib's Agg canvas, no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from slamcli.atomic import atomic_path
from slamcli.errors import ExportError
from slamcli.evaluation import EvalResult
from slamcli.types import LandmarkMap, SlamResult, Trajectory, TriangleMesh

if TYPE_CHECKING:
    from slamcli.planar_eval import PlanarEval


def plot_evaluation(
    path: str | Path,
    result: EvalResult,
    gt_label: str = "ground truth",
    est_label: str = "estimate",
    timed: bool = True,
    mesh: TriangleMesh | None = None,
    imu_states: Any = None,
) -> Path:
    """Write a PNG with a top view of ground truth and the aligned estimate, and ATE over time.
    With ``imu_states`` ((K, 10) rows of a visual-inertial run's keyframes: stamp ns,
    velocity, gyroscope and accelerometer biases), a last column shows the speed and the
    biases over time.

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

    # Fixed margins, not the constrained layout, which draws the figure twice to measure it.
    inertial = imu_states is not None and len(imu_states) > 0
    widths = [1.0, 1.3] + ([1.0] if mesh is not None else []) + ([1.2] if inertial else [])
    fig = Figure(figsize=(6 * len(widths), 5))
    FigureCanvasAgg(fig)
    margins = {"left": 0.07 if len(widths) == 2 else 0.05, "right": 0.985, "bottom": 0.11}
    margins |= {"top": 0.91, "wspace": 0.25}
    grid = fig.add_gridspec(1, len(widths), width_ratios=widths, **margins)
    top, err = fig.add_subplot(grid[0]), fig.add_subplot(grid[1])
    if mesh is not None:
        _mesh_view(fig.add_subplot(grid[2]), mesh, result)
    if inertial:
        _inertial_panels(fig, grid[len(widths) - 1], np.asarray(imu_states), int(m.stamps_ns[0]))
    top.plot(gt_xyz[:, ax0], gt_xyz[:, ax1], color="0.35", lw=1.5, ls="--", label=gt_label)
    top.plot(est_xyz[:, ax0], est_xyz[:, ax1], color="tab:blue", lw=1.2, label=est_label)
    err.plot(t, result.ate_m, color="tab:red", lw=1.0, label="ATE")
    err.axhline(result.ate.rmse, color="k", lw=1.0, ls=":", label=f"rmse {result.ate.rmse:.4f} m")
    finish_evaluation_axes(
        top, err, (ax0, ax1), f"Top view, {result.alignment} alignment, {result.pairs} pairs", timed
    )
    return save_png(fig, path)


def _inertial_panels(fig: Any, cell: Any, states: Any, t0_ns: int) -> None:
    """Speed (upper) and biases (lower) per keyframe of a visual-inertial run."""
    import numpy as np

    speed_ax, bias_ax = cell.subgridspec(2, 1, hspace=0.45).subplots()
    t = (states[:, 0] - t0_ns) * 1e-9
    speed_ax.plot(t, np.linalg.norm(states[:, 1:4], axis=1), color="tab:blue", lw=1.2)
    speed_ax.set_ylabel("speed (m/s)")
    speed_ax.set_title("IMU state per keyframe")
    speed_ax.grid(alpha=0.3)
    for c, axis in enumerate("xyz"):
        colour = ("tab:red", "tab:green", "tab:blue")[c]
        bias_ax.plot(t, states[:, 7 + c], color=colour, lw=1.2, label=f"accel {axis} (m/s²)")
        bias_ax.plot(
            t,
            10 * states[:, 4 + c],
            color=colour,
            lw=1.0,
            ls="--",
            label=f"gyro {axis} ×10 (rad/s)",
        )
    bias_ax.set_xlabel("time since the first pair (s)")
    bias_ax.set_ylabel("bias")
    bias_ax.legend(loc="best", fontsize="x-small", ncol=2)
    bias_ax.grid(alpha=0.3)


def finish_evaluation_axes(
    top: Any, err: Any, axes: tuple[int, int], title: str, timed: bool
) -> None:
    """Labels, legends and grids of an evaluation figure's top view (world axes ``axes``)
    and its error-over-time panel."""
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel(f"{'xyz'[axes[0]]} (m)")
    top.set_ylabel(f"{'xyz'[axes[1]]} (m)")
    top.set_title(title)
    top.legend(loc="best", fontsize="small")
    top.grid(alpha=0.3)
    err.set_xlabel("time since the first pair (s)" if timed else "frame index")
    err.set_ylabel("position error (m)")
    err.set_title("Absolute trajectory error")
    err.legend(loc="upper right", fontsize="small")
    err.grid(alpha=0.3)


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


_MAX_LINE_POINTS = 20_000
"""Longest polyline drawn as is; longer ones are decimated (every k-th point and the last)."""


def _decimated(a: Any, limit: int = _MAX_LINE_POINTS) -> Any:
    n = len(a)
    if n <= limit:
        return a
    import numpy as np

    step = -(-n // limit)
    idx = np.arange(0, n, step)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return a[idx]


def _ellipses(ax: Any, xy: Any, cov: Any, sigma: float = 3.0, **kwargs: Any) -> None:
    """``sigma``-σ ellipses of (K, 2, 2) covariances at (K, 2) centres, as one collection."""
    import numpy as np
    from matplotlib.collections import EllipseCollection

    sym = 0.5 * (cov + np.swapaxes(cov, 1, 2))
    ok = np.all(np.isfinite(sym), axis=(1, 2)) & np.all(np.isfinite(xy), axis=1)
    if not np.any(ok):
        return
    vals, vecs = np.linalg.eigh(sym[ok])
    vals = np.clip(vals, 0.0, None)
    angles = np.rad2deg(np.arctan2(vecs[:, 1, 1], vecs[:, 0, 1]))  # major axis: last column
    coll = EllipseCollection(
        2.0 * sigma * np.sqrt(vals[:, 1]),  # full axis lengths
        2.0 * sigma * np.sqrt(vals[:, 0]),
        angles,
        units="xy",
        offsets=xy[ok],
        offset_transform=ax.transData,
        **kwargs,
    )
    ax.add_collection(coll, autolim=False)


def _log_y(ax: Any) -> None:
    """Log y axis with plain decade labels (0.01, 0.1, 1, 10) and no minor ticks.

    Minor log ticks and the default mathtext labels cost as much to draw as the data.
    """
    from matplotlib.ticker import FuncFormatter, NullLocator

    ax.set_yscale("log")
    ax.yaxis.set_minor_locator(NullLocator())
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _pos: f"{v:g}"))


def _running_mean(t: Any, v: Any, ax: Any, label: str) -> None:
    """A centred moving average over about 2 % of the samples, drawn over the raw values."""
    import numpy as np

    w = max(1, len(v) // 50)
    if w < 3:
        return
    c = np.concatenate([[0.0], np.cumsum(v)])
    mean = (c[w:] - c[:-w]) / w
    tm = t[w // 2 : w // 2 + mean.size]
    ax.plot(*_decimated(np.stack([tm, mean], axis=1)).T, color="k", lw=1.2, label=label)


def _chi2_panel(
    ax: Any,
    t: Any,
    values: Any,
    band: tuple[float, float],
    dof: int,
    label: str,
    title: str,
    style: dict[str, Any],
) -> None:
    """A NEES or NIS panel: (N,) values at (N,) times (s) on a log axis, their running mean,
    the 95 % χ² band and the expected value (the degrees of freedom)."""
    import numpy as np

    vals = np.clip(values, 1e-3, None)
    ax.plot(*_decimated(np.stack([t, vals], axis=1)).T, color="tab:purple", label=label, **style)
    _running_mean(t, values, ax, "running mean")
    lo, hi = band
    ax.axhspan(lo, hi, color="tab:green", alpha=0.15, label=f"95 % band ({lo:.2f}, {hi:.2f})")
    ax.axhline(float(dof), color="k", lw=0.8, ls=":")
    _log_y(ax)
    ax.set_title(title)
    ax.legend(loc="lower right", fontsize="small")


def _empty_panel(ax: Any, text: str, title: str) -> None:
    """A panel that says what is missing instead of an empty plot."""
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes)
    ax.set_title(title)


def _series_time(series: Any, t0_s: float) -> Any:
    """Series stamps (s) relative to the estimate's first stamp when they share its clock."""
    t = series[:, 0]
    return t - t0_s if t.size and float(t.min()) >= t0_s - 1.0 else t


def plot_landmark_run(
    path: str | Path,
    *,
    estimate: Trajectory,
    landmarks: LandmarkMap | None,
    evaluation: PlanarEval | None = None,
    true_landmarks: LandmarkMap | None = None,
    dead_reckoning: Trajectory | None = None,
    series: dict[str, Any] | None = None,
    title: str = "",
) -> Path:
    """Write a PNG report of a planar landmark SLAM run (1400 x 700 pixels).

    Left: a top view with the ground truth (with an evaluation), the estimate and the dead
    reckoning moved by the evaluation's SE(2) alignment, the estimated landmarks with their
    3σ ellipses (covariances rotated by the alignment) and the surveyed landmarks. Right,
    with an evaluation: the position error over time (and the dead reckoning's, log scale)
    and the pose NEES with its 95 % band; without: ``series["nis"]`` ((K, 2) rows of stamp in
    seconds and NIS) with its 95 % band for 2 DoF, and ``series["landmarks"]`` (stamp, count).
    Series stamps in the estimate's clock are shown relative to its first pose.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    t0_ns = int(estimate.stamps_ns[0]) if len(estimate) else 0
    # Fixed margins, not the constrained layout: that would measure every tick label twice
    # and double the drawing time of a large run.
    fig = Figure(figsize=(14, 7))
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(
        2,
        2,
        width_ratios=(1.1, 1),
        left=0.06,
        right=0.985,
        bottom=0.08,
        top=0.87 if title else 0.9,
        wspace=0.16,
        hspace=0.32,
    )
    top = fig.add_subplot(grid[:, 0])
    upper = fig.add_subplot(grid[0, 1])
    lower = fig.add_subplot(grid[1, 1], sharex=upper)
    _landmark_top_view(top, estimate, landmarks, evaluation, true_landmarks, dead_reckoning)
    if evaluation is not None:
        _error_panels(upper, lower, evaluation, dead_reckoning, t0_ns)
    else:
        _filter_panels(upper, lower, series or {}, t0_ns)
    lower.set_xlabel("time since the first pose (s)")
    if title:
        fig.suptitle(title)
    return save_png(fig, path)


def _moved(ev: PlanarEval | None, xy: Any) -> Any:
    """(N, 2) positions moved by the evaluation's SE(2) alignment, when there is one."""
    return ev.transform_xy(xy) if ev is not None else xy


def _landmark_top_view(
    top: Any,
    estimate: Trajectory,
    landmarks: LandmarkMap | None,
    ev: PlanarEval | None,
    true_landmarks: LandmarkMap | None,
    dead_reckoning: Trajectory | None,
) -> None:
    """The top view of :func:`plot_landmark_run`: paths, landmarks with 3σ ellipses, title."""
    import numpy as np

    if ev is not None:
        g = _decimated(ev.gt[:, :2])
        top.plot(g[:, 0], g[:, 1], color="0.3", lw=1.4, ls="--", label="ground truth", zorder=2)
    if dead_reckoning is not None and len(dead_reckoning):
        d = _moved(ev, _decimated(dead_reckoning.positions[:, :2]))
        top.plot(d[:, 0], d[:, 1], color="tab:orange", lw=0.7, alpha=0.8, label="dead reckoning")
    est_xy = (
        _moved(ev, _decimated(estimate.positions[:, :2])) if len(estimate) else np.zeros((0, 2))
    )
    top.plot(est_xy[:, 0], est_xy[:, 1], color="tab:blue", lw=1.1, label="estimate", zorder=3)
    if len(est_xy):
        top.plot(*est_xy[0], marker="o", ms=8, mfc="none", mec="k", mew=1.5, ls="", label="start")
    n_lm = 0 if landmarks is None else len(landmarks)
    if landmarks is not None and n_lm:
        lxy = _moved(ev, np.asarray(landmarks.xy, dtype=np.float64).reshape(-1, 2))
        if landmarks.cov is not None:
            cov = np.asarray(landmarks.cov, dtype=np.float64).reshape(-1, 2, 2)
            _ellipses(
                top,
                lxy,
                ev.transform_cov(cov) if ev is not None else cov,
                facecolors="none",
                edgecolors="tab:green",
                linewidths=0.6,
                alpha=0.8,
                zorder=4,
            )
        top.scatter(
            lxy[:, 0],
            lxy[:, 1],
            s=9,
            c="tab:green",
            marker="+",
            linewidths=0.9,
            label=f"landmarks ({n_lm}, 3σ)",
            zorder=5,
        )
    if true_landmarks is not None and len(true_landmarks):
        txy = np.asarray(true_landmarks.xy, dtype=np.float64).reshape(-1, 2)
        top.scatter(
            txy[:, 0],
            txy[:, 1],
            s=20,
            marker="x",
            c="tab:red",
            linewidths=0.8,
            alpha=0.8,
            label="true landmarks",
            zorder=3.5,
        )
    top.set_aspect("equal", adjustable="datalim")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    parts = []
    if ev is not None:
        parts.append(f"ATE {ev.ate.rmse:.3f} m (SE(2)), {ev.ate_unaligned.rmse:.3f} m unaligned")
    if ev is not None and ev.landmarks is not None and ev.landmarks.rmse_m is not None:
        parts.append(f"landmark RMSE {ev.landmarks.rmse_m:.3f} m")
    parts.append(f"{n_lm} landmarks")
    top.set_title(
        "Top view" + (", SE(2) aligned" if ev is not None else "") + "\n" + ", ".join(parts)
    )
    top.legend(loc="best", fontsize="small")
    top.grid(alpha=0.3)


def _error_panels(
    upper: Any, lower: Any, ev: PlanarEval, dead_reckoning: Trajectory | None, t0_ns: int
) -> None:
    """With an evaluation: the position error over time (and the dead reckoning's) above, the
    pose NEES below; times relative to ``t0_ns``."""
    import numpy as np

    from slamcli.geometry import interpolate_planar, se3_to_planar

    t = (ev.stamps_ns - t0_ns) * 1e-9
    upper.plot(
        *_decimated(np.stack([t, ev.ate_m], axis=1)).T,
        color="tab:blue",
        lw=0.9,
        label=f"estimate, rmse {ev.ate.rmse:.3f} m",
    )
    if dead_reckoning is not None and len(dead_reckoning) > 1:
        dr = interpolate_planar(
            dead_reckoning.stamps_ns,
            se3_to_planar(dead_reckoning.world_from_body),
            ev.stamps_ns,
        )
        dr_err = np.linalg.norm(ev.transform_xy(dr[:, :2]) - ev.gt[:, :2], axis=1)
        ok = np.isfinite(dr_err)
        if np.any(ok):
            rmse = float(np.sqrt(np.mean(dr_err[ok] ** 2)))
            upper.plot(
                *_decimated(np.stack([t[ok], dr_err[ok]], axis=1)).T,
                color="tab:orange",
                lw=0.8,
                label=f"dead reckoning (same alignment), rmse {rmse:.3f} m",
            )
            _log_y(upper)
    upper.set_ylabel("position error (m)")
    upper.set_title("Position error after SE(2) alignment")
    upper.legend(loc="lower right", fontsize="small")
    upper.grid(alpha=0.3)
    if ev.nees is not None:
        nees = ev.nees
        verdict = "consistent" if nees.consistent else "inconsistent"
        _chi2_panel(
            lower,
            (nees.stamps_ns - t0_ns) * 1e-9,
            nees.values,
            nees.band,
            3,
            f"NEES, mean {nees.mean:.2f}",
            f"Pose NEES (3 DoF): {verdict}, {100 * nees.fraction_in_band:.0f} % in band",
            {"lw": 0.7, "alpha": 0.6},
        )
    else:
        _empty_panel(lower, "no pose covariances", "Pose NEES")
    lower.set_ylabel("NEES")
    lower.grid(alpha=0.3)


def _filter_panels(upper: Any, lower: Any, series: dict[str, Any], t0_ns: int) -> None:
    """Without an evaluation: the filter's NIS above and the landmark count below (see
    :func:`plot_landmark_run` for ``series``)."""
    import numpy as np

    from slamcli.planar_eval import nees_band

    t0_s = t0_ns * 1e-9
    nis = series.get("nis")
    if nis is not None and len(nis):
        nis = np.asarray(nis, dtype=np.float64).reshape(-1, 2)
        lo, hi = nees_band(2)
        inside = float(np.mean((nis[:, 1] >= lo) & (nis[:, 1] <= hi)))
        _chi2_panel(
            upper,
            _series_time(nis, t0_s),
            nis[:, 1],
            (lo, hi),
            2,
            f"NIS, mean {np.mean(nis[:, 1]):.2f}",
            f"Innovation NIS (2 DoF), {100 * inside:.0f} % in band",
            {"ls": "", "marker": ".", "ms": 1.5, "alpha": 0.5},
        )
    else:
        _empty_panel(upper, "no NIS series", "Innovation NIS")
    upper.set_ylabel("NIS")
    upper.grid(alpha=0.3)
    counts = series.get("landmarks")
    if counts is not None and len(counts):
        counts = np.asarray(counts, dtype=np.float64).reshape(-1, 2)
        lower.plot(
            *_decimated(np.stack([_series_time(counts, t0_s), counts[:, 1]], axis=1)).T,
            color="tab:green",
            lw=1.0,
            drawstyle="steps-post",
        )
        lower.set_title(f"Landmarks in the map ({int(counts[-1, 1])} at the end)")
    else:
        _empty_panel(lower, "no landmark count series", "Landmarks in the map")
    lower.set_ylabel("landmarks")
    lower.grid(alpha=0.3)


def save_png(fig: Any, path: str | Path) -> Path:
    """Write a matplotlib figure as PNG atomically; a failed write is an ExportError."""
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=100)
    except OSError as exc:
        raise ExportError(f"{path}: cannot write the plot ({exc.strerror})") from exc
    return Path(path)


def multi_robot_figure(
    estimates: dict[int, Trajectory],
    truths: dict[int, Trajectory],
    *,
    transform: Any = None,
    landmarks: LandmarkMap | None = None,
    true_landmarks: LandmarkMap | None = None,
    ate: dict[int, float] | None = None,
    title: str = "",
) -> Any:
    """The top view of a several-robot run: every robot on one map (1000 x 800 pixels).

    Each robot's estimate is a solid line in its own colour (labelled ``robot K``), its ground
    truth a dashed line in the same colour; estimated landmarks are black crosses, surveyed ones
    red. ``transform`` (x, y, yaw), the common SE(2) alignment of all robots onto the ground
    truth, moves the estimates and landmarks; None draws them as estimated. ``ate`` (m, per
    robot) goes into the labels.

    Returns:
        The matplotlib Figure (Agg canvas), for :func:`save_png`.
    """
    import numpy as np
    from matplotlib import colormaps
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    def moved(xy: Any) -> Any:
        if transform is None:
            return xy
        c, s = np.cos(transform[2]), np.sin(transform[2])
        return xy @ np.array([[c, s], [-s, c]]) + np.asarray(transform[:2])

    fig = Figure(figsize=(10, 8))
    FigureCanvasAgg(fig)
    ax = fig.add_axes((0.08, 0.07, 0.68, 0.85))
    colours = colormaps["tab10"]
    for i, (ident, est) in enumerate(sorted(estimates.items())):
        colour = colours(i % 10)
        gt = truths.get(ident)
        if gt is not None and len(gt):
            g = _decimated(gt.positions[:, :2])
            ax.plot(g[:, 0], g[:, 1], color=colour, lw=1.0, ls="--", alpha=0.7, zorder=2)
        xy = moved(_decimated(est.positions[:, :2])) if len(est) else np.zeros((0, 2))
        label = f"robot {ident}"
        if ate is not None and ident in ate:
            label += f" (ATE {ate[ident]:.3f} m)"
        ax.plot(xy[:, 0], xy[:, 1], color=colour, lw=1.2, label=label, zorder=3)
        if len(xy):
            ax.plot(*xy[0], marker="o", ms=7, mfc="none", mec=colour, mew=1.5, ls="", zorder=4)
    if landmarks is not None and len(landmarks):
        lxy = moved(np.asarray(landmarks.xy, dtype=np.float64).reshape(-1, 2))
        ax.scatter(
            lxy[:, 0],
            lxy[:, 1],
            s=14,
            c="k",
            marker="+",
            linewidths=1.0,
            zorder=5,
            label=f"landmarks ({len(landmarks)})",
        )
    if true_landmarks is not None and len(true_landmarks):
        txy = np.asarray(true_landmarks.xy, dtype=np.float64).reshape(-1, 2)
        ax.scatter(
            txy[:, 0],
            txy[:, 1],
            s=20,
            c="tab:red",
            marker="x",
            linewidths=0.8,
            alpha=0.8,
            zorder=3.5,
            label="true landmarks",
        )
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.grid(alpha=0.3)
    aligned = ", one common SE(2) alignment" if transform is not None else ""
    ax.set_title(
        title
        or f"{len(estimates)} robots in one frame{aligned}\n"
        "solid: estimate, dashed: ground truth, circle: start"
    )
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    return fig


def plot_multi_robot_run(path: str | Path, **kwargs: Any) -> Path:
    """Write :func:`multi_robot_figure` (same keyword arguments) as a PNG."""
    estimates = kwargs.pop("estimates")
    truths = kwargs.pop("truths")
    return save_png(multi_robot_figure(estimates, truths, **kwargs), path)


def plot_scan_run(path: str | Path, result: SlamResult, evaluation: PlanarEval | None) -> Path:
    """Write a PNG report of a lidar run (1400 x 700 pixels).

    Left: the map (free white, occupied black, unknown grey; placed with its origin's yaw)
    with the path and the loop closures (edges between the poses they tie), and the ground
    truth moved onto the estimate when there is an evaluation. Right, with an evaluation: the
    position error over time.
    """
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from slamcli.geometry.planar import se3_to_planar
    from slamcli.planning.plot import draw_grid, grid_view, occupancy_colours

    assert result.trajectory is not None and result.grid is not None
    fig = Figure(figsize=(14, 7))
    FigureCanvasAgg(fig)
    top = fig.add_axes((0.05, 0.08, 0.5, 0.84))
    grid = result.grid
    xy = se3_to_planar(result.trajectory.world_from_body)[:, :2]
    moved = None
    if evaluation is not None:
        # The ground truth, moved onto the estimate by the inverse of the alignment.
        moved = (evaluation.gt[:, :2] - evaluation.translation) @ evaluation.rotation
    # The axes show the map's area in the world and the paths; they are known before the map
    # is drawn, so its image holds only what shows.
    view = np.array(grid_view(grid)).reshape(2, 2)
    paths = np.concatenate([view.T, xy] + ([] if moved is None else [moved[:, :2]]))
    lo, hi = paths.min(axis=0), paths.max(axis=0)
    limits = (float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1]))
    draw_grid(
        top,
        grid,
        lambda rows, cols: occupancy_colours(grid.prob, rows, cols, unknown_grey=0.75),
        limits,
        fig.get_figwidth() * fig.dpi * 0.5,
    )
    top.set_xlim(limits[0], limits[1])
    top.set_ylim(limits[2], limits[3])
    if moved is not None:
        top.plot(*_decimated(moved).T, color="tab:green", lw=1.0, label="ground truth")
    top.plot(*_decimated(xy).T, color="tab:blue", lw=1.0, label="estimate")
    if result.pose_graph is not None:
        nodes, edges = result.pose_graph
        loops = [e for e in edges if e.kind == "loop"]
        for e in loops[:: max(1, len(loops) // 300)]:
            top.plot(*np.array([nodes[e.a][:2], nodes[e.b][:2]]).T, color="tab:red", lw=0.6)
        top.plot([], [], color="tab:red", lw=0.6, label=f"loop closures ({len(loops)})")
    top.set_aspect("equal")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.legend(loc="upper right", fontsize=8)
    top.set_title("map and path")
    right = fig.add_axes((0.62, 0.08, 0.35, 0.84))
    if evaluation is not None:
        t = (evaluation.stamps_ns - evaluation.stamps_ns[0]) * 1e-9
        right.plot(t, evaluation.ate_m, color="tab:blue", lw=1.0)
        right.set_xlabel("time (s)")
        right.set_ylabel("position error after SE(2) alignment (m)")
        right.set_title(f"ATE rmse {evaluation.ate.rmse:.3f} m")
    else:
        _empty_panel(right, "no ground truth", "position error")
    return save_png(fig, path)
