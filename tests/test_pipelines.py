"""The pipeline registry: light declarations the CLI reads without importing the pipelines."""

from __future__ import annotations

import json
import subprocess
import sys
import typing
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.errors import ConfigError
from slamcli.formats import SOURCES, source_class
from slamcli.pipelines import (
    INPUT_FORMATS,
    PIPELINES,
    Evaluation,
    Pipeline,
    PipelineBase,
    get_pipeline,
    get_spec,
)


@pytest.mark.parametrize("name", sorted(PIPELINES))
def test_declaration_matches_the_class(name: str) -> None:
    spec = PIPELINES[name]
    cls = get_pipeline(name)
    assert cls.name == name
    assert cls.consumes and cls.config_class
    assert spec.evaluation in typing.get_args(Evaluation)
    assert spec.example.startswith(f"slamcli run {name} ")
    assert "trajectory.tum" in spec.produces
    assert spec.example in spec.doc
    # Every capability run_pipeline uses is declared by the protocol and given by the class:
    # nothing is probed for at run time.
    assert issubclass(cls, PipelineBase)
    members = {m for m in dir(Pipeline) if not m.startswith("_")} | set(
        typing.get_type_hints(Pipeline)
    )
    pipe = cls()
    missing = [m for m in sorted(members) if not hasattr(pipe, m)]
    assert not missing, missing
    assert pipe.evaluation == spec.evaluation
    if cls.frame_kinds is PipelineBase.frame_kinds:
        assert spec.reads == (cls.consumes,)
    pipe.close()


def _source_kinds(name: str) -> set[str]:
    """The frame kinds the source class of format ``name`` gives: its ``frame_kinds``, or the
    ``FRAME_KINDS`` of the module it (or the class it extends) is defined in."""
    for cls in source_class(name).__mro__:
        kinds = vars(cls).get("frame_kinds") or vars(sys.modules[cls.__module__]).get("FRAME_KINDS")
        if kinds:
            return set(kinds)
    raise AssertionError(f"{name}: no frame kinds found")


def test_input_formats_are_the_sources_with_their_kinds() -> None:
    """The help's table of formats has every source, with the kinds its class gives."""
    assert set(INPUT_FORMATS) == set(SOURCES)
    for name, fmt in INPUT_FORMATS.items():
        assert set(fmt.kinds) == _source_kinds(name), name


LOGS = {"mcap", "rosbag1", "rosbag2"}
READS = {
    "odometry": {"tum", "redwood"} | LOGS,
    "dense": {"tum", "redwood"} | LOGS,
    "visual": {"tum", "redwood", "kitti", "euroc"} | LOGS,
    "ekf": {"mrclam", "victoria", "landmarks"} | LOGS,
    "graph": {"mrclam", "victoria", "landmarks"} | LOGS,
    "lidar": {"carmen"} | LOGS,
}


@pytest.mark.parametrize("name", sorted(PIPELINES))
def test_run_help_names_what_the_pipeline_reads(name: str) -> None:
    """``run NAME --help`` describes INPUT as the formats that pipeline reads, and no other."""
    assert sorted(READS) == sorted(PIPELINES)
    spec = PIPELINES[name]
    assert set(spec.formats) == READS[name]
    command = typer.main.get_command(app).commands["run"].commands[name]
    (argument,) = [p for p in command.params if p.name == "input"]
    for fmt, described in INPUT_FORMATS.items():
        without_article = described.noun.split(" ", 1)[1]
        named = without_article in argument.help
        assert named == (fmt in READS[name]), (fmt, argument.help)
    shown = CliRunner().invoke(app, ["run", name, "--help"], terminal_width=400)
    assert shown.exit_code == 0
    assert argument.help in " ".join(shown.output.replace("│", " ").split())


def test_unknown_pipeline_names_the_known_ones() -> None:
    with pytest.raises(ConfigError, match="unknown pipeline 'sparse'") as err:
        get_spec("sparse")
    assert "odometry" in (err.value.hint or "")


def test_cli_start_imports_no_pipeline_module() -> None:
    code = (
        "import sys, slamcli.cli.app; "
        "print(sorted(m for m in sys.modules if m.startswith('slamcli.pipelines.') "
        "or m in ('numpy', 'cv2', 'open3d')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_run_json_says_which_alignment_scored_the_run(tmp_path: Path) -> None:
    from slamcli.demo import default_sample
    from slamcli.run import run_pipeline

    outcome = run_pipeline(default_sample(), "odometry", tmp_path / "run", max_frames=4)
    assert outcome.evaluation == "se3"
    record = json.loads((tmp_path / "run" / "run.json").read_text())
    assert record["metrics"]["alignment"] == "se3"
    assert record["metrics"]["evaluation"]["alignment"] == "se3"
