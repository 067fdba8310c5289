"""``slamcli run PIPELINE INPUT --out DIR``: one pipeline over one log, into a run folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary, exit_if_data_lost
from slamcli.cli.source_options import SourceOptions, source_options
from slamcli.pipelines import PIPELINES

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


def _command(pipeline: str) -> Any:
    def command(
        input: Annotated[
            Path,
            typer.Argument(
                help="A TUM RGB-D folder, an MCAP log, an MRCLAM folder, a Victoria Park file "
                "or a 'slamcli synth landmarks' folder.",
                show_default=False,
            ),
        ],
        out: Out,
        force: Force = False,
        max_frames: MaxFrames = None,
        mcap: Mcap = False,
        map_: BuildMap = False,
        config: ConfigFile = None,
        set_: Sets = None,
        *,
        source: SourceOptions,
    ) -> None:
        from slamcli.config import load_config
        from slamcli.pipelines import get_pipeline

        settings = load_config(get_pipeline(pipeline).config_class, pipeline, config, set_ or ())
        _run(pipeline, input, out, force, max_frames, mcap, source, settings, map_)

    command.__doc__ = PIPELINES[pipeline].doc
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
) -> None:
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
    exit_if_data_lost(outcome)
