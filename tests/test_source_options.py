"""The source options are declared once and reach each command as one SourceOptions."""

from __future__ import annotations

from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from slamcli.cli.source_options import DEFAULTS, SourceOptions, source_options

runner = CliRunner()


def _app(without: tuple[str, ...] = ()) -> tuple[typer.Typer, list[SourceOptions]]:
    seen: list[SourceOptions] = []
    app = typer.Typer()

    @app.command()
    @source_options(without)
    def cmd(input: Path, deep: bool = False, *, source: SourceOptions) -> None:
        seen.append(source)

    return app, seen


def test_every_option_reaches_the_command() -> None:
    app, seen = _app()
    res = runner.invoke(app, ["x", "--max-dt", "0.05", "--robot", "2", "--rgb-topic", "/c"])
    assert res.exit_code == 0, res.output
    assert seen == [SourceOptions(max_dt=0.05, robot=2, rgb_topic="/c")]
    assert seen[0].open_kwargs() == {"max_dt": 0.05, "robot": 2, "rgb_topic": "/c"}


def test_defaults_and_a_subset() -> None:
    app, seen = _app(("robot", "ignore_ids"))
    assert runner.invoke(app, ["x"]).exit_code == 0
    assert seen == [DEFAULTS]
    res = runner.invoke(app, ["x", "--robot", "2"])
    assert res.exit_code == 2 and "No such option" in res.output


def test_unknown_names_are_refused() -> None:
    with pytest.raises(ValueError, match="not source options: voxel"):
        source_options(without=("voxel",))
