"""``slamcli eval``: score estimated trajectories against ground truth (ATE, RPE)."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Annotated, Any

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError, InputError

if TYPE_CHECKING:
    from slamcli.evaluation import EvalResult
    from slamcli.formats.relations import Relations
    from slamcli.formats.trajectory import PoseTable

HELP = """Score one or more estimated trajectories against ground truth: ATE and, with
--rpe-delta, RPE; with --relations, the relative errors over a .relations file.

The figures equal evo's (evo_ape / evo_rpe 1.38) for the same files and options: the poses are
associated by nearest timestamps (within --t-max-diff seconds, after adding --t-offset to the
estimate's stamps), the estimate is aligned onto the ground truth (Umeyama), and the position
errors are summarised as rmse, mean, median, std, min, max and sse.

[bold]Formats[/] (--format): [bold]tum[/] (t tx ty tz qx qy qz qw) for both files;
[bold]euroc[/]: GT is a EuRoC ground-truth CSV (ns stamps, wxyz), EST is TUM, as in evo_ape euroc;
[bold]kitti[/]: 12 numbers per line, no stamps, so poses pair by index, unless both files get
a times file (--gt-times, --est-times); [bold]auto[/] decides per file from its contents.

[bold]Alignment[/] (--align): se3 (evo --align), sim3 (evo --align --correct_scale, for monocular
SLAM), scale (evo --correct_scale alone), none; and se2 for planar robots (2-D lidar, wheeled
robots): a rigid fit of x, y and yaw about +z, the ATE measured in the x-y plane, and the RPE
and relation errors in SE(2) as Kümmerle et al. (2009) define them.

[bold]RPE[/] (--rpe-delta N --delta-unit frames|m|seconds): the relative motion between
consecutive matched poses N frames, N metres of path or N seconds apart (each pair ends at the
first pose at least that far on), compared with the ground truth's: translation error in
metres, rotation error in degrees. In SE(2) (with se2) these are |t(δ) - t(δ*)| and
|wrap(yaw(δ) - yaw(δ*))| for δ = est_i⁻¹ est_j and δ* = gt_i⁻¹ gt_j, and the pair count is
reported.

[bold]Relations[/] (--relations FILE): Kümmerle's benchmark files, one relation per line,
"t1 t2 x y z roll pitch yaw": the motion from the pose at t1 to the pose at t2 (seconds) in the
frame of the pose at t1 (metres, radians; # lines are comments). The estimate's poses at t1 and
t2 are those of nearest stamp within --t-max-diff (after --t-offset); relations without both are
counted as missing. The same translation and rotation errors are reported over the others,
after the alignment's scale with sim3 or scale.

[bold]Several estimates[/] (EST EST ...) are each scored exactly as one would be, with the same
options, and shown as one table: a row per estimate (matched pairs, ATE rmse, mean, median, max,
the RPE rmse with --rpe-delta, the relations matched and their mean errors with --relations),
the lowest ATE rmse marked with *. --json then prints
{"groundtruth", "alignment", "estimates": [{"path", ...one estimate's fields}]} and --plot
draws every aligned estimate over the ground truth. An EST may be a run folder (the --out of
'slamcli run ...'): its trajectory.tum is scored and the row is named by the folder.

Examples:

[bold]slamcli eval ../shared/data/trajectories/freiburg1_xyz-groundtruth.txt \
../shared/data/trajectories/freiburg1_xyz-rgbdslam.txt[/]

[bold]slamcli eval ../shared/data/trajectories/freiburg1_xyz-groundtruth.txt \
../shared/data/trajectories/freiburg1_xyz-rgbdslam.txt \
../shared/data/trajectories/freiburg1_xyz-ORB_kf_mono.txt --align sim3 --rpe-delta 1[/]

[bold]slamcli eval ../shared/data/trajectories/fr2_desk_groundtruth.txt \
../shared/data/trajectories/fr2_desk_ORB_kf_mono.txt --align sim3 --rpe-delta 1[/]

[bold]slamcli eval ../shared/data/trajectories/V102_groundtruth.csv \
../shared/data/trajectories/V102.txt --format euroc --json[/]

[bold]slamcli eval ../shared/data/trajectories/KITTI_00_gt.txt \
../shared/data/trajectories/KITTI_00_ORB.txt --format kitti --rpe-delta 100 --delta-unit m \
--plot ate.png[/]

[bold]slamcli eval sample_data/landmarks/groundtruth.tum runs/landmarks --align se2 \
--rpe-delta 10 --delta-unit seconds[/]

Exit codes: 0 ok; 1 unreadable or malformed file (a relations line names file:line), too few
matched poses, no relation with estimated poses at both ends, bad option value (with several
estimates: any of them, named in the message; nothing is printed on stdout).
"""


class TrajFormat(str, Enum):
    auto = "auto"
    tum = "tum"
    kitti = "kitti"
    euroc = "euroc"


class AlignChoice(str, Enum):
    se3 = "se3"
    sim3 = "sim3"
    scale = "scale"
    se2 = "se2"
    none = "none"


class DeltaUnitChoice(str, Enum):
    frames = "frames"
    m = "m"
    seconds = "seconds"


def register(app: typer.Typer) -> None:
    app.command("eval", help=HELP, rich_help_panel="Evaluate")(eval_command)


@boundary
def eval_command(
    gt: Annotated[Path, typer.Argument(help="Ground-truth trajectory file.", show_default=False)],
    ests: Annotated[
        list[Path],
        typer.Argument(
            help="Estimated trajectory files or run folders (their trajectory.tum); one or more.",
            show_default=False,
            metavar="est",
        ),
    ],
    format: Annotated[
        TrajFormat,
        typer.Option("--format", "-f", help="File formats (see above); auto reads the contents."),
    ] = TrajFormat.auto,
    align: Annotated[
        AlignChoice, typer.Option("--align", "-a", help="Alignment of the estimate onto GT.")
    ] = AlignChoice.se3,
    t_max_diff: Annotated[
        float,
        typer.Option("--t-max-diff", help="Largest stamp difference of a GT/EST pair, seconds."),
    ] = 0.01,
    t_offset: Annotated[
        float,
        typer.Option("--t-offset", help="Seconds added to EST stamps before associating."),
    ] = 0.0,
    rpe_delta: Annotated[
        float | None,
        typer.Option(
            "--rpe-delta",
            help="Also compute the RPE over pose pairs this far apart (see --delta-unit).",
            show_default=False,
        ),
    ] = None,
    delta_unit: Annotated[
        DeltaUnitChoice,
        typer.Option(
            "--delta-unit",
            help="RPE spacing: every N frames, every N metres travelled, or every N seconds.",
        ),
    ] = DeltaUnitChoice.frames,
    relations: Annotated[
        Path | None,
        typer.Option(
            "--relations",
            help="Also score the estimate's motions against this .relations file "
            "(t1 t2 x y z roll pitch yaw per line; see above).",
            show_default=False,
        ),
    ] = None,
    gt_times: Annotated[
        Path | None,
        typer.Option(
            "--gt-times",
            help="KITTI: times file for GT (one time in s per line).",
            show_default=False,
        ),
    ] = None,
    est_times: Annotated[
        Path | None,
        typer.Option("--est-times", help="KITTI: times file for EST.", show_default=False),
    ] = None,
    plot: Annotated[
        Path | None,
        typer.Option(
            "--plot",
            help="Write a PNG: top view of GT and the aligned estimate(s), ATE over time.",
            show_default=False,
        ),
    ] = None,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout instead of tables.")
    ] = False,
) -> None:
    if plot is not None and plot.suffix.lower() != ".png":
        raise ConfigError(f"--plot {plot}: expected a .png file name")
    gt_poses, est_tables = _load(gt, ests, format.value, gt_times, est_times)
    _require_stamps(
        gt_poses, est_tables, rpe_delta is not None and delta_unit.value == "seconds", relations
    )
    options = {
        "align": align.value,
        "max_diff_s": t_max_diff,
        "offset_s": t_offset,
        "rpe_delta": rpe_delta,
        "delta_unit": delta_unit.value,
        "relations": _read_relations(relations),
    }
    if len(ests) > 1:
        scored = [_score(gt_poses, entry, options, named=True) for entry in est_tables]
        _report_many(gt, gt_poses, scored, align.value, plot, json_out, t_max_diff, t_offset)
        return
    est = est_tables[0]
    one = _score(gt_poses, est, options, named=False)
    result, by_index = one.result, one.by_index
    if plot is not None:
        from slamcli.report import plot_evaluation

        plot_evaluation(
            plot,
            result,
            f"GT: {gt_poses.path.name}",
            f"EST: {est.label.name}",
            timed=not by_index,
        )
    if json_out:
        render.print_json(result.to_dict())
        if plot is not None:
            render.note(f"wrote {plot}")
        return
    _show(result, gt_poses, est.poses, by_index, t_max_diff, t_offset)
    if plot is not None:
        render.written([plot])


@dataclass(frozen=True)
class _Estimate:
    """One EST argument: the path as given (a file or a run folder) and the poses read."""

    label: Path
    poses: PoseTable


@dataclass(frozen=True)
class _Scored:
    """One estimate's evaluation."""

    label: Path
    result: EvalResult
    by_index: bool


def _trajectory_file(est: Path) -> Path:
    """The file to read for an EST argument: the file itself, or a run folder's trajectory.tum."""
    if not est.is_dir():
        return est
    from slamcli.formats.run_folder import read_run

    return read_run(est).require("trajectory")


def _load(
    gt: Path, ests: list[Path], format: str, gt_times: Path | None, est_times: Path | None
) -> tuple[PoseTable, list[_Estimate]]:
    from slamcli.formats.trajectory import read_poses, sniff_trajectory_format

    files = [_trajectory_file(est) for est in ests]
    if format == "euroc":
        gt_format, est_formats = "euroc", ["tum" for _ in files]
    elif format == "auto":
        gt_format = sniff_trajectory_format(gt)
        est_formats = [sniff_trajectory_format(f) for f in files]
    else:
        gt_format, est_formats = format, [format for _ in files]
    # A run folder's trajectory.tum is TUM whatever the ground truth is.
    est_formats = [
        "tum" if file != est else fmt
        for est, file, fmt in zip(ests, files, est_formats, strict=True)
    ]
    checks = [(gt_times, gt_format, "--gt-times")]
    checks += [(est_times, fmt, "--est-times") for fmt in est_formats]
    for times, fmt, name in checks:
        if times is not None and fmt != "kitti":
            raise ConfigError(
                f"{name} only goes with a KITTI file, and this one is {fmt}",
                hint="TUM and EuRoC files carry their own timestamps",
            )
    gt_table = read_poses(gt, gt_format, times=gt_times)
    est_tables = [
        read_poses(file, fmt, times=est_times) for file, fmt in zip(files, est_formats, strict=True)
    ]
    for table in (gt_table, *est_tables):
        rep = table.repeated()
        if rep.size:
            render.warn(
                f"{table.path}: {rep.size} row(s) repeat the previous timestamp (first at line "
                f"{int(table.lines[rep[0]])}); each row is evaluated as its own pose, as evo does"
            )
    untimed = [
        (gt_table if not gt_table.timed else table).path
        for table in est_tables
        if gt_table.timed != table.timed
    ]
    for path in dict.fromkeys(untimed):
        render.warn(
            f"{path} has no timestamps (KITTI without a times file): pairing poses by index"
        )
    return gt_table, [_Estimate(e, t) for e, t in zip(ests, est_tables, strict=True)]


def _require_stamps(
    gt: PoseTable, ests: list[_Estimate], by_seconds: bool, relations: Path | None
) -> None:
    """RPE pairs in seconds and relations need real stamps, which KITTI files lack without
    their times files."""
    untimed = [t.path for t in (gt, *(e.poses for e in ests)) if not t.timed]
    if not untimed or not (by_seconds or relations is not None):
        return
    what = "--delta-unit seconds" if by_seconds else "--relations"
    raise ConfigError(
        f"{what} needs timestamps, and {untimed[0]} has none (KITTI without a times file)",
        hint="give the KITTI files their times (--gt-times, --est-times)",
    )


def _read_relations(path: Path | None) -> Relations | None:
    if path is None:
        return None
    from slamcli.formats.relations import read_relations

    return read_relations(path)


def _score(gt: PoseTable, est: _Estimate, options: dict[str, Any], named: bool) -> _Scored:
    """Evaluate one estimate; with ``named``, an input error says which estimate it is about."""
    from slamcli.evaluation import evaluate

    by_index = not (gt.timed and est.poses.timed)
    try:
        result = evaluate(gt, est.poses, by_index=by_index, **options)
    except InputError as exc:
        if not named:
            raise
        raise InputError(f"{est.label}: {exc.msg}", hint=exc.hint) from None
    return _Scored(est.label, result, by_index)


def _display_names(paths: list[Path]) -> list[str]:
    """Short names for paths: the last component, or as many trailing components as it takes
    to tell apart paths that share their last ones (the same path twice keeps one name)."""
    parts = [PurePath(p).parts for p in paths]
    names = []
    for mine in parts:
        others = [theirs for theirs in parts if theirs != mine]
        k = 1
        while k < len(mine) and any(theirs[-k:] == mine[-k:] for theirs in others):
            k += 1
        names.append(str(PurePath(*mine[-k:])))
    return names


def _report_many(
    gt: Path,
    gt_poses: PoseTable,
    scored: list[_Scored],
    align: str,
    plot: Path | None,
    json_out: bool,
    t_max_diff: float,
    t_offset: float,
) -> None:
    names = _display_names([s.label for s in scored])
    if plot is not None:
        _plot_many(plot, gt_poses, scored, names)
    if json_out:
        render.print_json(
            {
                "groundtruth": str(gt),
                "alignment": align,
                "estimates": [{"path": str(s.label), **s.result.to_dict()} for s in scored],
            }
        )
        if plot is not None:
            render.note(f"wrote {plot}")
        return
    _show_many(gt_poses, scored, names, align, t_max_diff, t_offset)
    if plot is not None:
        render.written([plot])


def _show_many(
    gt: PoseTable,
    scored: list[_Scored],
    names: list[str],
    align: str,
    t_max_diff: float,
    t_offset: float,
) -> None:
    first = scored[0].result
    facts = {
        "ground truth": f"{gt.path} ({gt.format}, {len(gt)} poses)",
        "estimates": str(len(scored)),
        "pairing": f"by time (max diff {t_max_diff:g} s, offset {t_offset:g} s)"
        if not all(s.by_index for s in scored)
        else "by index",
        "alignment": align,
    }
    if first.rpe is not None:
        facts["RPE"] = f"over pose pairs {_spacing(first)} apart"
    if first.relations is not None:
        facts["relations"] = f"{first.relations.path} ({first.relations.relations} relations)"
    render.key_values("Evaluation", facts)
    best = min(s.result.ate.rmse for s in scored)
    with_scale = align in ("sim3", "scale")
    with_rpe = first.rpe is not None
    with_relations = first.relations is not None
    columns = ["estimate", "pairs", "ATE rmse", "mean", "median", "max"]
    if with_rpe:
        columns += ["RPE trans rmse", "RPE rot rmse"]
    if with_relations:
        columns += ["relations", "REL trans mean", "REL rot mean"]
    if with_scale:
        columns.append("scale")
    rows = []
    for name, s in zip(names, scored, strict=True):
        r = s.result
        pairs = f"{r.pairs} by index" if s.by_index else f"{r.pairs} of {r.matched.possible}"
        mark = "*" if r.ate.rmse == best else " "
        row = [name, pairs, f"{r.ate.rmse:.6f}{mark}"]
        row += [f"{r.ate.mean:.6f}", f"{r.ate.median:.6f}", f"{r.ate.max:.6f}"]
        if r.rpe is not None:
            row += [f"{r.rpe.trans.rmse:.6f}", f"{r.rpe.rot.rmse:.6f}"]
        if r.relations is not None:
            rel = r.relations
            row += [f"{rel.pairs} of {rel.relations}", f"{rel.trans.mean:.6f}"]
            row.append(f"{rel.rot.mean:.6f}")
        if with_scale:
            row.append(f"{r.scale:.6f}")
        rows.append(row)
    units = "ATE in m" + (", RPE trans in m, rot in deg" if with_rpe else "")
    if with_relations:
        units += ", REL trans in m, rot in deg"
    _wide_table(f"{len(scored)} estimates ({units}); * lowest ATE rmse", columns, rows)


def _wide_table(title: str, columns: list[str], rows: list[list[str]]) -> None:
    """A table like :func:`render.table` whose cells are never cut or wrapped: on a narrow
    terminal its lines run past the edge rather than shorten the estimates' paths."""
    from rich.markup import escape
    from rich.measure import Measurement
    from rich.segment import Segments
    from rich.table import Table

    t = Table(title=title, title_justify="left", show_edge=False, header_style="bold")
    for i, c in enumerate(columns):
        t.add_column(c, justify="left" if i == 0 else "right", no_wrap=True)
    for r in rows:
        t.add_row(*(escape(v) for v in r))
    console = render.out
    wide = console.options.update_width(10_000)
    width = max(console.width, Measurement.get(console, wide, t).maximum)
    lines = console.render_lines(t, console.options.update_width(width), new_lines=True)
    console.print(Segments([seg for line in lines for seg in line]))


def _spacing(result: EvalResult) -> str:
    assert result.rpe is not None
    d = result.rpe.delta
    unit = result.rpe.delta_unit
    if unit == "frames":
        unit = "frame" if d == 1 else "frames"
    elif unit == "seconds":
        unit = "s"
    return f"{d:g} {unit}"


def _plot_many(path: Path, gt: PoseTable, scored: list[_Scored], names: list[str]) -> Path:
    """A PNG: the ground truth and every aligned estimate from above, and each one's ATE over
    time (over the frame index when any estimate is paired by index), one colour each."""
    import numpy as np
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from slamcli.report import finish_evaluation_axes, save_png

    gt_xyz = gt.positions
    ax0, ax1 = sorted(np.argsort(np.ptp(gt_xyz, axis=0))[-2:].tolist())
    timed = not any(s.by_index for s in scored)
    t0 = min(int(s.result.matched.stamps_ns[0]) for s in scored)
    fig = Figure(figsize=(12, 5))
    FigureCanvasAgg(fig)
    margins = {"left": 0.07, "right": 0.985, "bottom": 0.11, "top": 0.91, "wspace": 0.2}
    top, err = fig.subplots(1, 2, width_ratios=(1, 1.3), gridspec_kw=margins)
    top.plot(gt_xyz[:, ax0], gt_xyz[:, ax1], color="0.35", lw=1.5, ls="--", label="ground truth")
    colours = [f"C{i % 10}" for i in range(len(scored))]
    for name, s, colour in zip(names, scored, colours, strict=True):
        r = s.result
        est_xyz = r.aligned_est[:, :3, 3]
        top.plot(est_xyz[:, ax0], est_xyz[:, ax1], color=colour, lw=1.1, label=name)
        m = r.matched
        t = (m.stamps_ns - t0) * 1e-9 if timed else m.est_index.astype(float)
        err.plot(t, r.ate_m, color=colour, lw=1.0, label=f"{name} (rmse {r.ate.rmse:.4f} m)")
    title = f"Top view, {scored[0].result.alignment} alignment, {len(scored)} estimates"
    finish_evaluation_axes(top, err, (ax0, ax1), title, timed)
    return save_png(fig, path)


_PLANAR = "se2 (x, y, yaw about +z; ATE in the x-y plane, relative errors in SE(2))"


def _show(
    result: EvalResult,
    gt: PoseTable,
    est: PoseTable,
    by_index: bool,
    t_max_diff: float,
    t_offset: float,
) -> None:
    from slamcli.evaluation import STAT_KEYS

    m = result.matched
    pairing = (
        f"{result.pairs} by index"
        if by_index
        else f"{result.pairs} of {m.possible} (max diff {t_max_diff:g} s, offset {t_offset:g} s)"
    )
    facts = {
        "ground truth": f"{gt.path} ({gt.format}, {len(gt)} poses)",
        "estimate": f"{est.path} ({est.format}, {len(est)} poses)",
        "pairs": pairing,
        "alignment": _PLANAR if result.alignment == "se2" else result.alignment,
        "scale": f"{result.scale:.6f}",
    }
    if result.rpe is not None:
        facts["RPE pairs"] = f"{result.rpe.count} ({_spacing(result)} apart)"
    rel = result.relations
    if rel is not None:
        facts["relations"] = f"{rel.pairs} of {rel.relations} in {rel.path}" + (
            f" ({rel.missing.size} missing: no estimated pose within {t_max_diff:g} s of t1 or t2)"
            if rel.missing.size
            else ""
        )
    render.key_values("Evaluation", facts)
    columns = {"ATE (m)": result.ate}
    if result.rpe is not None:
        columns["RPE trans (m)"] = result.rpe.trans
        columns["RPE rot (deg)"] = result.rpe.rot
    if rel is not None:
        columns["REL trans (m)"] = rel.trans
        columns["REL rot (deg)"] = rel.rot
    title = None
    if result.rpe is not None:
        title = f"RPE over pose pairs {_spacing(result)} apart"
    if rel is not None:
        title = (title + "; " if title else "") + "REL over the relations"
    render.table(
        title,
        ["statistic", *columns],
        [[k, *(f"{st.to_dict()[k]:.6f}" for st in columns.values())] for k in STAT_KEYS],
        right_align=list(columns),
    )
