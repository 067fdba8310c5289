"""The CLI skeleton: version, help, start-up imports and the error boundary."""

from __future__ import annotations

import subprocess
import sys

import typer
from typer.testing import CliRunner

from slamcli import __version__
from slamcli.cli.app import app
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError, DataLossError, InputError

runner = CliRunner()
HEAVY = ("open3d", "pycolmap", "trimesh", "matplotlib", "cv2")


def _modules_loaded_by(args: list[str]) -> set[str]:
    code = (
        "import sys\n"
        "from slamcli.cli.app import app\n"
        "try:\n"
        f"    app({args!r})\n"
        "except SystemExit:\n"
        "    pass\n"
        f"print(','.join(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    last = res.stdout.strip().splitlines()[-1] if res.stdout.strip() else ""
    return {m for m in last.split(",") if m in HEAVY}


def test_help_imports_no_heavy_library() -> None:
    assert _modules_loaded_by(["--help"]) == set()


def test_every_command_help_imports_no_heavy_library() -> None:
    for cmd in (
        ["info", "--help"],
        ["eval", "--help"],
        ["synth", "rgbd", "--help"],
        ["demo", "--help"],
        ["run", "odometry", "--help"],
        ["convert", "--help"],
        ["plan", "--help"],
        ["map", "build", "--help"],
        ["map", "show", "--help"],
    ):
        assert _modules_loaded_by(cmd) == set(), cmd


def test_version() -> None:
    res = runner.invoke(app, ["--version"])
    assert res.exit_code == 0
    assert res.stdout.strip() == f"slamcli {__version__}"


def test_help_lists_the_commands_and_exit_codes() -> None:
    res = runner.invoke(app, ["--help"])
    assert res.exit_code == 0
    for word in ("info", "eval", "synth", "demo", "Exit codes"):
        assert word in res.stdout


def test_unknown_option_is_a_usage_error() -> None:
    res = runner.invoke(app, ["info", "--no-such-option"])
    assert res.exit_code == 2


def _cli_raising(exc: Exception) -> typer.Typer:
    t = typer.Typer()

    @t.command()
    @boundary
    def go() -> None:
        raise exc

    return t


def test_boundary_maps_errors_to_exit_codes_and_one_line_messages() -> None:
    cases = [
        (InputError("data.txt:3: bad line", hint="fix it"), 1),
        (ConfigError("dense.voxel_m: must be > 0"), 1),
        (DataLossError("2 frames lost"), 3),
    ]
    for exc, code in cases:
        res = runner.invoke(_cli_raising(exc), [])
        assert res.exit_code == code
        assert f"error: {exc.msg}" in res.output
        assert "Traceback" not in res.output
    res = runner.invoke(_cli_raising(InputError("x", hint="fix it")), [])
    assert "hint: fix it" in res.output


def test_ctrl_c_during_shutdown_leaves_the_exit_status() -> None:
    """Ctrl-C after a command finished: the status is the command's, never death by SIGINT."""
    import os
    import signal
    import time

    if os.name != "posix":
        return
    # An exit handler marks the start of shutdown and then waits, while the parent sends
    # Ctrl-C after Ctrl-C until the process has ended.
    code = (
        "import atexit, sys, time\n"
        "def _shutdown():\n"
        "    print('shutdown', flush=True)\n"
        "    time.sleep(0.3)\n"
        "atexit.register(_shutdown)\n"
        "sys.argv = ['slamcli', '--version']\n"
        "from slamcli.cli.app import main\n"
        "main()\n"
    )
    statuses = []
    for _ in range(3):
        proc = subprocess.Popen(
            [sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert proc.stdout is not None
        for line in proc.stdout:
            if line.startswith("shutdown"):
                break
        deadline = time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < deadline:
            proc.send_signal(signal.SIGINT)
            time.sleep(0.001)
        proc.communicate(timeout=30)
        statuses.append(proc.returncode)
    assert statuses == [0, 0, 0]


def test_reflow_joins_paragraph_lines_but_keeps_list_items_and_paragraphs() -> None:
    from slamcli.cli.app import reflow

    text = """First line
    of the summary.

    A paragraph wrapped
    at the source's width.

    1. one item
    continued;
    2. another.

    \b
    kept
    as is"""
    assert reflow(text) == (
        "First line of the summary.\n\n"
        "A paragraph wrapped at the source's width.\n\n"
        "1. one item continued;\n2. another.\n\n"
        "\b\nkept\nas is"
    )


def test_command_help_wraps_at_the_terminal_width_not_the_source_width() -> None:
    import os

    env = {**os.environ, "COLUMNS": "200"}
    res = subprocess.run(
        [sys.executable, "-m", "slamcli", "batch", "--help"],
        capture_output=True,
        text=True,
        env=env,
        timeout=60,
    )
    assert res.returncode == 0
    # The source breaks this paragraph after "(a job that"; at 200 columns the terminal does not.
    line = next(ln for ln in res.stdout.splitlines() if "(a job that" in ln)
    assert "(a job that exceeds its timeout_s" in line
