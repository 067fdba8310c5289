"""``slamcli merge``: join landmark maps of separate EKF runs into one frame."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import DataLossError

HELP = """Merge EKF runs of several robots or sessions into one map and frame.

Finds each run's transform to the first run from their common landmarks (by id when the runs
used the log's ids, else by matching landmark constellations with seeded RANSAC), chains runs
through each other, and optimises all transforms and landmarks jointly with GTSAM. Writes
trajectory_robotN.tum per run (N from the run's --robot, else its position), the merged
landmarks.csv, report.png and run.json (connections, inliers, residuals, and ATE per robot
and over all under one shared alignment when the runs' logs have ground truth).

A run that shares too few landmarks with the others is left out and named; the merge of the
rest is written and the exit code is 3.

Example, after 'slamcli synth landmarks runs/world3 --robots 3' and 'slamcli run ekf
runs/world3 --robot K --out runs/world3_rK' for K = 1, 2, 3:
[bold]slamcli merge runs/world3_r1 runs/world3_r2 runs/world3_r3 --out runs/merged[/]
"""


@boundary
def merge_command(
    runs: Annotated[
        list[Path],
        typer.Argument(
            help="EKF run folders; the first is the reference frame.", show_default=False
        ),
    ],
    out: Annotated[
        Path,
        typer.Option(
            "--out", "-o", help="Folder to write the merged map into.", show_default=False
        ),
    ],
    match: str = typer.Option(
        "auto", "--match", help="auto, ids or constellation (RANSAC, for runs without ids)."
    ),
    inlier_m: float = typer.Option(
        0.5, "--inlier-m", help="Largest landmark disagreement of an inlier, m."
    ),
    seed: int = typer.Option(0, "--seed", help="Seeds the RANSAC draws."),
    force: bool = typer.Option(False, "--force", help="Write into a non-empty OUT folder."),
) -> None:
    from slamcli.graphs.merge import MergeConfig, merge_runs

    config = MergeConfig(match=match, inlier_m=inlier_m, seed=seed)
    with render.progress("merging", 4) as progress:
        result = merge_runs(
            runs,
            out,
            config=config,
            force=force,
            command="merge " + " ".join(map(str, runs)),
            progress=progress,
        )
    labels = [r.label for r in result.runs]
    render.table(
        "Connections",
        ["a", "b", "by", "candidates", "inliers", "rms (m)", "connected"],
        [
            [
                labels[f.a],
                labels[f.b],
                f.method,
                f.candidates,
                len(f.pairs),
                f"{f.rms_m:.3f}" if len(f.pairs) else "-",
                "yes" if f.connected else "no",
            ]
            for f in result.pairs
        ],
        right_align=["candidates", "inliers", "rms (m)"],
    )
    per_run = result.evaluation.get("per_run", {})
    rows = []
    for r, m in enumerate(result.runs):
        pose = result.world_from_run[r]
        ev = per_run.get(m.label)
        rows.append(
            [
                m.label,
                "yes" if result.connected[r] else "no",
                f"{pose[0]:.3f}, {pose[1]:.3f}, {pose[2] * 180 / 3.141592653589793:.2f}"
                if result.connected[r]
                else "-",
                f"{result.residual_rms_m[r]:.3f}" if result.connected[r] else "-",
                f"{ev['ate']['rmse']:.4f}" if ev else "-",
                f"{ev['ate']['mean']:.4f}" if ev else "-",
            ]
        )
    if result.evaluation:
        ev_all = result.evaluation["all"]
        rows.append(["all", "", "", "", f"{ev_all['rmse']:.4f}", f"{ev_all['mean']:.4f}"])
    render.table(
        "Runs in one frame" + (" (ATE under one shared SE(2) alignment)" if per_run else ""),
        ["run", "merged", "x, y (m), yaw (deg)", "residual (m)", "ATE rmse (m)", "ATE mean (m)"],
        rows,
        right_align=["residual (m)", "ATE rmse (m)", "ATE mean (m)"],
    )
    outputs = sorted(p for p in Path(out).iterdir() if not p.name.startswith("."))
    render.written(outputs)
    left_out = [m for r, m in enumerate(result.runs) if not result.connected[r]]
    if left_out:
        raise DataLossError(
            f"{len(left_out)} run(s) share too few landmarks with the others and were left out: "
            + ", ".join(f"{m.path} ({m.label})" for m in left_out),
            hint="add a run that saw landmarks of both, or raise --inlier-m for noisy maps",
        )


def register(app: typer.Typer) -> None:
    app.command("merge", help=HELP, rich_help_panel="Maps and paths")(merge_command)
