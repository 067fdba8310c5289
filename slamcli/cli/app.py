"""The ``slamcli`` typer application."""

from __future__ import annotations

from typing import NoReturn

import typer

from slamcli import __version__
from slamcli.cli import render

app = typer.Typer(
    name="slamcli",
    help=(
        "Turn recorded robot and camera logs into trajectories, meshes, maps and paths.\n\n"
        "Exit codes: 0 ok, 1 bad input or config, 2 usage, 3 finished but lost data."
    ),
    no_args_is_help=True,
    rich_markup_mode="rich",
    pretty_exceptions_enable=False,
    add_completion=False,
    context_settings={"help_option_names": ["-h", "--help"]},
)


def _version(value: bool) -> None:
    if value:
        render.out.print(f"slamcli {__version__}")
        raise typer.Exit()


@app.callback()
def _root(
    verbose: int = typer.Option(
        0, "--verbose", "-v", count=True, help="More log output (-v info, -vv debug)."
    ),
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    render.setup_logging(verbose)


def _register() -> None:
    # Command modules import only light things at import time; heavy libraries load inside
    # the command functions, so `slamcli --help` starts fast.
    from slamcli.cli import (
        batch,
        config_cmd,
        convert,
        demo,
        evaluate,
        graph_cmd,
        info,
        map_cmd,
        merge,
        mesh,
        plan,
        run,
        synth,
        vocab,
    )

    for module in (
        demo,
        run,
        batch,
        config_cmd,
        info,
        evaluate,
        synth,
        convert,
        mesh,
        map_cmd,
        plan,
        vocab,
        graph_cmd,
        merge,
    ):
        module.register(app)


_register()


def main() -> None:
    """The ``slamcli`` command."""
    try:
        app()
    except SystemExit as exc:
        if exc.code == 130:
            _exit_interrupted()
        raise


def _exit_interrupted() -> NoReturn:
    """End an interrupted command with exit status 130, after the exit handlers.

    The error boundary turns Ctrl-C into exit status 130, but a loaded machine showed the
    interpreter still ending by SIGINT afterwards now and then (status -2), which scripts and
    CI read as a crash. The exit handlers run here and the process ends at once with 130.
    """
    import atexit
    import contextlib
    import os
    import sys

    try:
        atexit._run_exitfuncs()
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(OSError, ValueError):
                stream.flush()
        os._exit(130)
