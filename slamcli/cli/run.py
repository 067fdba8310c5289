"""``slamcli run PIPELINE INPUT --out DIR``: one pipeline over one log, into a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary, exit_if_data_lost
from slamcli.cli.source_options import SourceOptions, source_options
from slamcli.errors import InputError, SlamcliError
from slamcli.pipelines import PIPELINES

if TYPE_CHECKING:
    from slamcli.run import RunOutcome


class GateFailed(SlamcliError):
    """A --fail-if gate held: the run finished, its figures failed the check (exit 3)."""

    exit_code = 3


run_app = typer.Typer(
    help="Run a SLAM pipeline over a log and write a run folder (trajectory, report, run.json).",
    no_args_is_help=True,
)


def register(app: typer.Typer) -> None:
    app.add_typer(run_app, name="run", rich_help_panel="Run")


Out = Annotated[Path, typer.Option("--out", "-o", help="Run folder to write.", show_default=False)]
Force = Annotated[bool, typer.Option("--force", help="Overwrite a non-empty --out folder.")]
MaxFrames = Annotated[
    int | None,
    typer.Option("--max-frames", min=1, help="Stop after this many frames.", show_default=False),
]
Mcap = Annotated[
    bool,
    typer.Option("--mcap", help="Also write result.mcap (open it in Foxglove)."),
]
BuildMap = Annotated[
    bool,
    typer.Option(
        "--map",
        help="Also build the occupancy map: map.yaml, map.pgm, map.png, map.json "
        "(as 'slamcli map build' with its defaults).",
    ),
]


ConfigFile = Annotated[
    Path | None,
    typer.Option(
        "--config",
        help="TOML file whose [PIPELINE] table overrides the defaults "
        "(see 'slamcli config dump PIPELINE').",
        show_default=False,
    ),
]
Sets = Annotated[
    list[str] | None,
    typer.Option(
        "--set",
        help="Override one setting, NAME=VALUE (names and ranges: 'slamcli config dump PIPELINE'; "
        "repeatable; applied after --config).",
        show_default=False,
    ),
]


FailIf = Annotated[
    list[str] | None,
    typer.Option(
        "--fail-if",
        help="A gate, '<metric> <op> <number>' (e.g. 'ate.rmse > 0.03', 'frames.lost > 0'): "
        "exit 3 when it holds (repeatable; metric names as 'slamcli batch' gates).",
        show_default=False,
    ),
]
Baseline = Annotated[
    Path | None,
    typer.Option(
        "--baseline",
        help="An earlier run folder, for gates of the form '<metric> <op> <k> * baseline'.",
        show_default=False,
    ),
]


def _command(pipeline: str) -> Any:
    def command(
        input: Path,
        out: Out,
        force: Force = False,
        max_frames: MaxFrames = None,
        mcap: Mcap = False,
        map_: BuildMap = False,
        config: ConfigFile = None,
        set_: Sets = None,
        fail_if: FailIf = None,
        baseline: Baseline = None,
        *,
        source: SourceOptions,
    ) -> None:
        from slamcli.config import load_config
        from slamcli.pipelines import get_pipeline

        settings = load_config(get_pipeline(pipeline).config_class, pipeline, config, set_ or ())
        gates = _gates(pipeline, fail_if or [], baseline)
        outcome = _run(pipeline, input, out, force, max_frames, mcap, source, settings, map_)
        if gates:
            _check_gates(gates, outcome, baseline)
        exit_if_data_lost(outcome)

    command.__doc__ = PIPELINES[pipeline].doc
    # INPUT names the formats this pipeline reads. Set as an object: the module's annotations
    # are strings evaluated in its globals, where ``pipeline`` does not exist.
    command.__annotations__["input"] = Annotated[
        Path, typer.Argument(help=PIPELINES[pipeline].input_help, show_default=False)
    ]
    return boundary(source_options()(command))


for _name in PIPELINES:
    run_app.command(_name)(_command(_name))


def _run(
    pipeline: str,
    input: Path,
    out: Path,
    force: bool,
    max_frames: int | None,
    mcap: bool,
    opts: SourceOptions,
    settings: Any,
    build_map: bool = False,
) -> RunOutcome:
    from slamcli.run import run_pipeline

    with render.progress(f"{pipeline}") as progress:
        outcome = run_pipeline(
            input,
            pipeline,
            out,
            force=force,
            config=settings,
            source_options=opts.open_kwargs(),
            max_frames=max_frames,
            command=f"run {pipeline}",
            mcap=mcap,
            build_map=build_map,
            progress=progress,
            map_progress=progress,
        )
    render.run_summary(outcome)
    return outcome


def _gates(pipeline: str, texts: list[str], baseline: Path | None) -> list[Any]:
    """The --fail-if gates, checked before the run: their syntax, their metrics, a
    baseline for the gates that need one."""
    if not texts and baseline is None:
        # Without gates a run needs none of the batch modules.
        return []
    from slamcli.batch.gates import GateError, parse_gate
    from slamcli.batch.job import read_run_json
    from slamcli.batch.metrics import known_metric

    gates = [parse_gate(t) for t in texts]
    for gate in gates:
        if not known_metric(pipeline, gate.metric):
            raise GateError(
                f"--fail-if {gate.text!r}: a {pipeline} run has no metric {gate.metric!r}",
                hint="metric names: ate.rmse, rpe.trans.rmse, ms_per_frame, frames.lost, and "
                "the counts and metrics of run.json (see docs/batch.md)",
            )
        if gate.uses_baseline and baseline is None:
            raise GateError(
                f"--fail-if {gate.text!r} compares with a baseline, but none was given",
                hint="pass --baseline RUN_DIR (an earlier run folder)",
            )
    if baseline is not None and read_run_json(baseline) is None:
        raise InputError(f"{baseline}: no run.json (--baseline takes a run folder)")
    return gates


def _check_gates(gates: list[Any], outcome: RunOutcome, baseline: Path | None) -> None:
    """Print every gate with its value; exit 3 when one holds."""
    from slamcli.batch.gates import evaluate_gates
    from slamcli.batch.job import read_run_json

    run_dir = outcome.run_dir
    results = evaluate_gates(gates, outcome.record, read_run_json(baseline) if baseline else None)
    render.table(
        "Gates",
        ["gate", "result"],
        [[g.gate, ("FAILED: " if g.failed else "passed: ") + g.reason] for g in results],
    )
    failed = [g for g in results if g.failed]
    if failed:
        raise GateFailed(
            f"{run_dir}: {len(failed)} of {len(results)} gate(s) failed: "
            + "; ".join(g.reason for g in failed),
            hint="the run folder is complete; the gates judge its figures",
        )
