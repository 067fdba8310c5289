"""The ``slamcli`` typer application."""

from __future__ import annotations

import inspect
import re
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
        kernels_cmd,
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
        kernels_cmd,
    ):
        module.register(app)


_register()


_LIST_ITEM = re.compile(r"(\d+[.)]|[-*]) ")


def reflow(text: str) -> str:
    """Help text with each paragraph's lines joined, as the terminal should wrap it.

    Typer keeps the line breaks of every paragraph after the first, so a docstring wrapped
    at the source's width would print ragged at any other. A line that starts a numbered or
    bulleted item keeps its break; a paragraph starting with ``\\b`` is left as written.
    """
    paragraphs = []
    for paragraph in inspect.cleandoc(text).split("\n\n"):
        if paragraph.startswith("\b"):
            paragraphs.append(paragraph)
            continue
        lines: list[str] = []
        for line in paragraph.splitlines():
            if lines and not _LIST_ITEM.match(line):
                lines[-1] = f"{lines[-1]} {line.strip()}"
            else:
                lines.append(line.strip())
        paragraphs.append("\n".join(lines))
    return "\n\n".join(paragraphs)


def _reflow_help(group: typer.Typer) -> None:
    """Reflow the help of every command and sub-group of ``group``."""
    for command in group.registered_commands:
        text = command.help or inspect.getdoc(command.callback)
        if text:
            command.help = reflow(text)
    for sub in group.registered_groups:
        if sub.help:
            sub.help = reflow(sub.help)
        if sub.typer_instance is not None:
            info = sub.typer_instance.info
            if isinstance(info.help, str):
                info.help = reflow(info.help)
            _reflow_help(sub.typer_instance)


_reflow_help(app)


def main() -> None:
    """The ``slamcli`` command."""
    from slamcli.kernels import on_compile

    # A kernel compiled on first use makes the command wait seconds (the car-like planner half
    # a minute) before anything moves: say why, once. Only here, in the installed command: code
    # that invokes ``app`` itself (CliRunner) keeps its output as it was.
    on_compile(render.compiling)
    try:
        try:
            app()
        finally:
            _ignore_late_interrupts()
            _skip_final_collection()
    except KeyboardInterrupt:
        # Ctrl-C between the error boundary and the line above: the command was interrupted.
        _exit_interrupted()
    except SystemExit as exc:
        if exc.code == 130:
            _exit_interrupted()
        raise


def _ignore_late_interrupts() -> None:
    """Ignore Ctrl-C once the command's outcome is decided.

    When the interpreter shuts down it puts SIGINT back to the operating system's default
    action, so a Ctrl-C landing in the last milliseconds, after the run folder was committed
    and the exit status chosen, killed the process by signal (status -2) instead of letting it
    end with its status. Shutdown keeps an ignored signal ignored.
    """
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)


def _skip_final_collection() -> None:
    """Keep the collector from walking every object once more as the interpreter shuts down.

    Everything alive once the command's outcome is decided lives until the process exits, and
    that last pass costs a tenth to a quarter of a second once numba, scipy and pycolmap are
    loaded. Not once Open3D is loaded (``run odometry``, ``run dense``): its allocator reports
    the tensors a frozen collector never freed as leaks, and the process exits 1.
    """
    import gc
    import sys

    if "open3d" not in sys.modules:
        gc.freeze()


def _exit_interrupted() -> NoReturn:
    """End an interrupted command with exit status 130, after the exit handlers.

    The error boundary turns Ctrl-C into exit status 130; a second Ctrl-C during the
    interpreter's shutdown would end the process by SIGINT (status -2), which scripts and CI
    read as a crash. The exit handlers run here and the process ends at once with 130.
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
