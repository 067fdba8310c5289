"""Every example in a ``--help`` text runs: each command documents at least one, and they work.

The examples are the ``[bold]slamcli …[/]`` command lines of the commands' help texts. They run
in order (:data:`ORDER`), each with the working folder ``root/work``, where ``sample_data`` links
to the repository's and ``root/shared`` to the real shared folder, so ``sample_data/…`` and
``../shared/data/…`` resolve as in a checkout beside the shared folder, and an example finds the
files an earlier one wrote (``runs/room_dense``, ``runs/landmarks``, …). A trailing ``> FILE``
writes the command's output to FILE, as the shell would.

An example that other tests run too (the demo, reference runs such as ``graph optimize`` on
intel or ``plan`` on the Nav2 map) runs once per test session (the ``shared_run`` fixture), and
its ``--out`` is copied into the work folder for the examples after it.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import typer
from conftest import SHARED_DATA, shared_path
from reference_runs import copy_out, out_argument, shareable_example
from typer.testing import CliRunner

from slamcli.cli.app import app

REPO = Path(__file__).resolve().parents[1]

# Commands whose examples read what another command's examples write come after it.
ORDER = [
    "kernels",
    "demo",
    "synth rgbd",
    "synth stereo",
    "synth landmarks",
    "synth lidar",
    "vocab train",
    "vocab info",
    "run odometry",
    "run dense",
    "run visual",
    "run ekf",
    "run graph",
    "run lidar",
    "merge",
    "batch",
    "config dump",
    "info",
    "eval",
    "map build",
    "map show",
    "graph optimize",
    "mesh export",
    "plan",
    "convert",
]

# What an example's help text says to run before it, when no earlier example writes it.
BEFORE = {
    "merge": [f"slamcli run ekf runs/world3 --robot {k} --out runs/world3_r{k}" for k in (1, 2, 3)],
}

_EXAMPLE = re.compile(r"\[bold\](slamcli\s[^\[]*?)\[/\]")


def _commands(command: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[str, str]]:
    """(``"map build"``, raw help text) for every leaf command under a click command."""
    # Typer ships its own copy of click, so groups are told apart by their sub-commands.
    subcommands = getattr(command, "commands", None)
    if subcommands is not None:
        for name, sub in subcommands.items():
            yield from _commands(sub, (*path, name))
    else:
        yield " ".join(path), command.help or ""


def examples_by_command() -> dict[str, list[str]]:
    """Each command's example command lines, whitespace-normalised."""
    return {
        name: [" ".join(m.split()) for m in _EXAMPLE.findall(text)]
        for name, text in _commands(typer.main.get_command(app))
    }


def test_every_command_has_an_example() -> None:
    found = examples_by_command()
    assert sum(map(len, found.values())) > 0, "no examples found in any --help text"
    assert sorted(found) == sorted(ORDER), "add new commands to ORDER"
    assert [name for name, lines in found.items() if not lines] == []
    for name, lines in found.items():
        for line in lines:
            assert line.startswith(f"slamcli {name}"), line


def test_help_renders_every_example() -> None:
    runner = CliRunner()
    for name, lines in examples_by_command().items():
        result = runner.invoke(app, [*name.split(), "--help"], terminal_width=400)
        assert result.exit_code == 0, result.output
        shown = " ".join(result.output.split())
        for line in lines:
            assert line in shown, f"{name} --help does not show {line}"


@pytest.fixture
def work(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    shared_path()  # skips (fails under CI) without the real data
    (tmp_path / "shared").symlink_to(SHARED_DATA.parent, target_is_directory=True)
    cwd = tmp_path / "work"
    cwd.mkdir()
    (cwd / "sample_data").symlink_to(REPO / "sample_data", target_is_directory=True)
    monkeypatch.chdir(cwd)
    return cwd


@pytest.mark.slow
def test_every_example_runs(work: Path, shared_run: Any) -> None:
    found = examples_by_command()
    lines = [line for name in ORDER for line in [*BEFORE.get(name, []), *found[name]]]
    assert lines, "no examples found"
    runner = CliRunner()
    for line in lines:
        args = shlex.split(line)[1:]
        target = None
        if ">" in args:
            at = args.index(">")
            args, target = args[:at], args[at + 1]
        if target is None and shareable_example(args, work):
            out = out_argument(args)
            assert out is not None
            run = shared_run(*args, cwd=work, suffix=Path(out).suffix)
            stdout, exception, exit_code = run.stdout, run.exception, run.exit_code
            output = run.stdout + run.stderr
            copy_out(run, work / out)
        else:
            result = runner.invoke(app, args, catch_exceptions=True)
            stdout, exit_code = result.stdout, result.exit_code
            output = result.stdout + result.stderr
            exception = None
            if result.exception is not None and not isinstance(result.exception, SystemExit):
                exception = repr(result.exception)
        assert "Traceback" not in output, f"{line}\n{output}"
        assert exception is None, f"{line}: {exception}\n{output}"
        assert exit_code == 0, f"{line} exited with {exit_code}\n{output}"
        if target:
            Path(target).write_text(stdout)
