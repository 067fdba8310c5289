"""``slamcli eval``: score an estimated trajectory against ground truth (ATE, RPE)."""

from __future__ import annotations

from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError

if TYPE_CHECKING:
    from slamcli.evaluation import EvalResult
    from slamcli.formats.trajectory import PoseTable

HELP = """Score an estimated trajectory against ground truth: ATE and, with --rpe-delta, RPE.

The figures equal evo's (evo_ape / evo_rpe 1.38) for the same files and options: the poses are
associated by nearest timestamps (within --t-max-diff seconds, after adding --t-offset to the
estimate's stamps), the estimate is aligned onto the ground truth (Umeyama), and the position
errors are summarised as rmse, mean, median, std, min, max and sse.

[bold]Formats[/] (--format): [bold]tum[/] (t tx ty tz qx qy qz qw) for both files;
[bold]euroc[/]: GT is a EuRoC ground-truth CSV (ns stamps, wxyz), EST is TUM, as in evo_ape euroc;
[bold]kitti[/]: 12 numbers per line, no stamps, so poses pair by index, unless both files get
a times file (--gt-times, --est-times); [bold]auto[/] decides per file from its contents.

[bold]Alignment[/] (--align): se3 (evo --align), sim3 (evo --align --correct_scale, for monocular
SLAM), scale (evo --correct_scale alone), none.

Examples:

[bold]slamcli eval ../shared/data/trajectories/freiburg1_xyz-groundtruth.txt \
../shared/data/trajectories/freiburg1_xyz-rgbdslam.txt[/]

[bold]slamcli eval ../shared/data/trajectories/fr2_desk_groundtruth.txt \
../shared/data/trajectories/fr2_desk_ORB_kf_mono.txt --align sim3 --rpe-delta 1[/]

[bold]slamcli eval ../shared/data/trajectories/V102_groundtruth.csv \
../shared/data/trajectories/V102.txt --format euroc --json[/]

[bold]slamcli eval ../shared/data/trajectories/KITTI_00_gt.txt \
../shared/data/trajectories/KITTI_00_ORB.txt --format kitti --rpe-delta 100 --delta-unit m \
--plot ate.png[/]

Exit codes: 0 ok; 1 unreadable or malformed file, too few matched poses, bad option value.
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
    none = "none"


class DeltaUnitChoice(str, Enum):
    frames = "frames"
    m = "m"


def register(app: typer.Typer) -> None:
    app.command("eval", help=HELP, rich_help_panel="Evaluate")(eval_command)


@boundary
def eval_command(
    gt: Annotated[Path, typer.Argument(help="Ground-truth trajectory file.", show_default=False)],
    est: Annotated[Path, typer.Argument(help="Estimated trajectory file.", show_default=False)],
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
            "--delta-unit", help="RPE spacing: every N frames, or every N metres travelled."
        ),
    ] = DeltaUnitChoice.frames,
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
            help="Write a PNG: top view of GT and the aligned estimate, ATE over time.",
            show_default=False,
        ),
    ] = None,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print one JSON object on stdout instead of tables.")
    ] = False,
) -> None:
    from slamcli.evaluation import evaluate

    if plot is not None and plot.suffix.lower() != ".png":
        raise ConfigError(f"--plot {plot}: expected a .png file name")
    gt_poses, est_poses = _load(gt, est, format.value, gt_times, est_times)
    by_index = not (gt_poses.timed and est_poses.timed)
    result = evaluate(
        gt_poses,
        est_poses,
        align=align.value,
        max_diff_s=t_max_diff,
        offset_s=t_offset,
        by_index=by_index,
        rpe_delta=rpe_delta,
        delta_unit=delta_unit.value,
    )
    if plot is not None:
        from slamcli.report import plot_evaluation

        plot_evaluation(
            plot,
            result,
            f"GT: {gt_poses.path.name}",
            f"EST: {est_poses.path.name}",
            timed=not by_index,
        )
    if json_out:
        render.print_json(result.to_dict())
        if plot is not None:
            render.note(f"wrote {plot}")
        return
    _show(result, gt_poses, est_poses, by_index, t_max_diff, t_offset)
    if plot is not None:
        render.written([plot])


def _load(
    gt: Path, est: Path, format: str, gt_times: Path | None, est_times: Path | None
) -> tuple[PoseTable, PoseTable]:
    from slamcli.formats.trajectory import read_poses, sniff_trajectory_format

    if format == "euroc":
        gt_format, est_format = "euroc", "tum"
    elif format == "auto":
        gt_format, est_format = sniff_trajectory_format(gt), sniff_trajectory_format(est)
    else:
        gt_format = est_format = format
    for times, fmt, name in (
        (gt_times, gt_format, "--gt-times"),
        (est_times, est_format, "--est-times"),
    ):
        if times is not None and fmt != "kitti":
            raise ConfigError(
                f"{name} only goes with a KITTI file, and this one is {fmt}",
                hint="TUM and EuRoC files carry their own timestamps",
            )
    tables = (
        read_poses(gt, gt_format, times=gt_times),
        read_poses(est, est_format, times=est_times),
    )
    for table in tables:
        rep = table.repeated()
        if rep.size:
            render.warn(
                f"{table.path}: {rep.size} row(s) repeat the previous timestamp (first at line "
                f"{int(table.lines[rep[0]])}); each row is evaluated as its own pose, as evo does"
            )
    if tables[0].timed != tables[1].timed:
        untimed = tables[0] if not tables[0].timed else tables[1]
        render.warn(
            f"{untimed.path} has no timestamps (KITTI without a times file): pairing poses by index"
        )
    return tables


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
    render.key_values(
        "Evaluation",
        {
            "ground truth": f"{gt.path} ({gt.format}, {len(gt)} poses)",
            "estimate": f"{est.path} ({est.format}, {len(est)} poses)",
            "pairs": pairing,
            "alignment": result.alignment,
            "scale": f"{result.scale:.6f}",
        },
    )
    columns = {"ATE (m)": result.ate}
    if result.rpe is not None:
        columns["RPE trans (m)"] = result.rpe.trans
        columns["RPE rot (deg)"] = result.rpe.rot
    title = None
    if result.rpe is not None:
        d = result.rpe.delta
        unit = ("frame" if d == 1 else "frames") if result.rpe.delta_unit == "frames" else "m"
        title = f"RPE over pose pairs {d:g} {unit} apart"
    render.table(
        title,
        ["statistic", *columns],
        [[k, *(f"{getattr(st, k):.6f}" for st in columns.values())] for k in STAT_KEYS],
        right_align=list(columns),
    )
