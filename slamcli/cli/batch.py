"""``slamcli batch MANIFEST --out DIR``: many runs from one manifest, with gates, for CI."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary

if TYPE_CHECKING:
    from slamcli.batch.job import JobResult
    from slamcli.batch.runner import BatchOutcome

HELP = """Run every job of a manifest and say, for CI, what passed and what got worse.

A manifest is a TOML file of [bold]\\[\\[job]][/] tables: [bold]name[/] (the job's run folder),
[bold]input[/] (a path or a glob, relative to the manifest's folder; a glob makes one job per
match, with {stem} in the name), [bold]pipeline[/], [bold]set[/] (settings, as --set),
[bold]source[/] (source options, as on the command line), [bold]fail_if[/] (gates such as
"ate.rmse > 0.03", "frames.lost > 0" or "ms_per_frame > 1.2 * baseline"),
[bold]timeout_s[/], [bold]max_frames[/], [bold]map[/], [bold]mcap[/]; a [bold]\\[defaults][/]
table gives any of them to every job. sample_data/batch.toml is an example. Every job, gate
metric and setting is checked before anything runs; errors name the manifest's line.

Each job writes DIR/NAME/ exactly as 'slamcli run' would, in a process of its own (a job that
exceeds its timeout_s is stopped; one whose process dies is tried again, --retries). DIR gets
batch.json (every job: status, gates with their values, key metrics, changes against the
baseline, wall time, error), junit.xml (one test case per job: a failed gate is a failure, a
job that could not run an error) and report.html (one self-contained page with every job's
report). A job's failure never stops the others.

Jobs run --jobs at a time on this machine, or on a Dask cluster with --scheduler
tcp://HOST:PORT (pip install 'slamcli[dask]'; each worker needs slamcli and the data at the
same paths). Results do not depend on where a job ran.

Examples:

[bold]slamcli batch sample_data/batch.toml --out runs/batch[/]

[bold]slamcli batch sample_data/batch.toml --out runs/batch --resume[/]

[bold]slamcli batch sample_data/batch.toml --out runs/batch_next --baseline runs/batch --jobs 1[/]

Exit codes: 0 every job passed; 3 a gate failed or a run lost data; 1 a job could not run, or
the manifest is wrong (nothing runs then); 2 bad options.
"""


def register(app: typer.Typer) -> None:
    app.command("batch", help=HELP, rich_help_panel="Run")(batch)


@boundary
def batch(
    manifest: Annotated[
        Path, typer.Argument(help="The batch manifest (TOML).", show_default=False)
    ],
    out: Annotated[
        Path,
        typer.Option("--out", "-o", help="Folder for the job folders and the batch records."),
    ],
    jobs: Annotated[
        int | None,
        typer.Option(
            "--jobs",
            "-j",
            min=1,
            help="Jobs at once on this machine [default: its cores].",
            show_default=False,
        ),
    ] = None,
    scheduler: Annotated[
        str | None,
        typer.Option(
            help="Run the jobs on this Dask scheduler (tcp://HOST:PORT) instead.",
            show_default=False,
        ),
    ] = None,
    resume: Annotated[
        bool,
        typer.Option(
            help="Skip jobs whose folder holds a complete run of the same job (same input "
            "hash, pipeline, settings and slamcli version)."
        ),
    ] = False,
    baseline: Annotated[
        Path | None,
        typer.Option(
            help="An earlier batch's --out folder: every key metric's change is shown, and "
            "gates may use 'k * baseline'.",
            show_default=False,
        ),
    ] = None,
    retries: Annotated[
        int, typer.Option(min=0, help="Tries again of a job whose process died.")
    ] = 1,
    json_out: Annotated[
        bool, typer.Option("--json", help="Print batch.json instead of the table.")
    ] = False,
) -> None:
    from slamcli.batch.runner import plan_batch, run_batch

    plan = plan_batch(manifest, out, baseline)
    with render.progress("batch", len(plan.jobs)) as progress:

        def on_result(result: JobResult, done: int, total: int) -> None:
            progress(done, total)

        outcome = run_batch(
            plan,
            jobs=jobs,
            scheduler=scheduler,
            resume=resume,
            retries=retries,
            on_result=on_result,
        )
    if json_out:
        import json

        render.print_json(json.loads((plan.out / "batch.json").read_text(encoding="utf-8")))
    else:
        summary(outcome)
    raise typer.Exit(outcome.exit_code)


_STYLE = {"passed": "green", "gate_failed": "red", "data_lost": "yellow", "error": "bold red"}


def summary(outcome: BatchOutcome) -> None:
    """The console table: one row per job, its gates, key metrics and changes."""
    from rich.markup import escape
    from rich.table import Table

    from slamcli.batch.gates import format_value
    from slamcli.batch.runner import changes, key_metrics

    plan = outcome.plan
    table = Table(
        title=f"{plan.manifest.name}: {len(outcome.results)} jobs ({outcome.executor})",
        title_justify="left",
        show_edge=False,
        header_style="bold",
    )
    for col in ("job", "pipeline", "status", "gates", "metrics", "time s"):
        table.add_column(col, justify="right" if col == "time s" else "left")
    for r in outcome.results:
        delta = changes(plan, r)
        cells = []
        for metric, value in key_metrics(r).items():
            text = f"{metric} {format_value(value)}"
            before = delta.get(metric, (None, None))[0]
            if before:
                text += f" ({(value - before) / abs(before):+.1%})"
            cells.append(text)
        gates = [
            ("✗ " if g.failed else "✓ ") + g.gate + f"  ({format_value(g.value)})" for g in r.gates
        ]
        status = r.status + (" (resumed)" if r.resumed else "")
        if r.status == "error":
            gates = [r.error] + ([r.hint] if r.hint else [])
        table.add_row(
            escape(r.name),
            r.pipeline,
            f"[{_STYLE[r.status]}]{status}[/]",
            escape("\n".join(gates)),
            escape("\n".join(cells)),
            f"{r.wall_s:.1f}",
        )
    render.out.print(table)
    counts = outcome.counts()
    render.out.print(
        escape(
            ", ".join(f"{n} {status.replace('_', ' ')}" for status, n in counts.items() if n)
            + f"; records in {plan.out}"
        ),
        soft_wrap=True,
    )
    render.written(outcome.files)
