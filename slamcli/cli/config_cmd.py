"""``slamcli config``: show pipeline settings as TOML."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary

config_app = typer.Typer(
    help="Show pipeline settings as TOML, to copy into a --config file.",
    no_args_is_help=True,
    rich_markup_mode="rich",
)


DUMP_HELP = """Print a pipeline's settings as TOML: its defaults, or the effective values.

Each setting comes with a comment saying what it does, and its unit and allowed range where \
the pipeline declares them. Save the output, edit it and pass it to a run with --config FILE; \
--set overrides one key (KEY=VALUE or PIPELINE.KEY=VALUE, the value written as in TOML: 0.01, \
true, [10, 5, 3]; text may be left unquoted). Only the file's [PIPELINE] table is read; it \
may hold the tables of other pipelines too.

Examples:

[bold]slamcli config dump dense > dense.toml[/]

[bold]slamcli config dump dense --config dense.toml --set voxel_size_m=0.02[/]
"""


def register(app: typer.Typer) -> None:
    app.add_typer(config_app, name="config", rich_help_panel="Run")


@config_app.command("dump", help=DUMP_HELP)
@boundary
def dump(
    pipeline: Annotated[
        str,
        typer.Argument(help="Pipeline name (odometry, dense, ...).", show_default=False),
    ],
    config: Annotated[
        Path | None,
        typer.Option(
            "--config",
            "-c",
            help="A TOML file whose [PIPELINE] table overrides the defaults.",
            show_default=False,
        ),
    ] = None,
    sets: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Override one setting: KEY=VALUE or PIPELINE.KEY=VALUE (repeatable).",
            show_default=False,
        ),
    ] = None,
) -> None:
    """Print a pipeline's settings as TOML: its defaults, or the effective values."""
    from slamcli.config import dump_config, load_config
    from slamcli.pipelines import get_pipeline

    cls = get_pipeline(pipeline)
    section = load_config(cls.config_class, pipeline, config, sets or ())
    render.plain(dump_config(section, pipeline))
