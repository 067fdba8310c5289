"""The pipeline registry: light declarations the CLI reads without importing the pipelines."""

from __future__ import annotations

import json
import subprocess
import sys
import typing
from pathlib import Path

import pytest

from slamcli.errors import ConfigError
from slamcli.pipelines import PIPELINES, Evaluation, Pipeline, PipelineBase, get_pipeline, get_spec


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
    pipe.close()


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
