"""Batch manifests and gate syntax: valid manifests load, each mistake names its file:line."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from slamcli.batch.gates import Gate, GateError, parse_gate
from slamcli.batch.manifest import JobSpec, ManifestError, load_manifest
from slamcli.errors import FormatError, InputError

PIPELINES = ("dense", "ekf", "visual")


def _write(folder: Path, text: str, name: str = "manifest.toml") -> Path:
    path = folder / name
    path.write_text(text, encoding="utf-8")
    return path


@pytest.fixture
def data(tmp_path: Path) -> Path:
    """A manifest folder with three inputs: two TUM-like folders and a log file."""
    for name in ("rgbd_a", "rgbd_b"):
        (tmp_path / "data" / name).mkdir(parents=True)
    (tmp_path / "data" / "run1.mcap").write_bytes(b"")
    (tmp_path / "data" / ".hidden").mkdir()
    return tmp_path


def _load(path: Path, **kwargs: object) -> list[JobSpec]:
    return load_manifest(path, pipelines=PIPELINES, **kwargs)  # type: ignore[arg-type]


def _error(path: Path, **kwargs: object) -> ManifestError:
    with pytest.raises(ManifestError) as info:
        _load(path, **kwargs)
    return info.value


# --- gate syntax ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "metric", "op", "threshold", "factor"),
    [
        ("ate.rmse > 0.03", "ate.rmse", ">", 0.03, None),
        ("  frames.lost>=1 ", "frames.lost", ">=", 1.0, None),
        ("rpe.trans.rmse<1e-3", "rpe.trans.rmse", "<", 1e-3, None),
        ("nis.mean != -2.5E+1", "nis.mean", "!=", -25.0, None),
        ("keyframes == 3", "keyframes", "==", 3.0, None),
        ("ms_per_frame > 1.2 * baseline", "ms_per_frame", ">", 1.2, 1.2),
        ("ate.rmse>1.5*baseline", "ate.rmse", ">", 1.5, 1.5),
        ("ate.rmse <= baseline", "ate.rmse", "<=", 1.0, 1.0),
        ("ate.rmse > .5", "ate.rmse", ">", 0.5, None),
    ],
)
def test_parse_gate_forms(
    text: str, metric: str, op: str, threshold: float, factor: float | None
) -> None:
    gate = parse_gate(text)
    assert gate == Gate(metric, op, threshold, factor, text)
    assert gate.uses_baseline is (factor is not None)


@pytest.mark.parametrize(
    "text",
    [
        "",
        "ate.rmse",
        "ate.rmse > ",
        "ate.rmse >> 0.03",
        "ate.rmse => 0.03",
        "> 0.03",
        "ate.rmse > 0.03 m",
        "ate.rmse > 2 * 3",
        "ate.rmse > baseline * 2",
        "ate..rmse > 1",
        "ate.rmse > nan",
        "ate.rmse > inf",
        "0.03 < ate.rmse",
    ],
)
def test_parse_gate_rejects(text: str) -> None:
    with pytest.raises(GateError) as info:
        parse_gate(text)
    msg = str(info.value)
    assert f'"{text}"' in msg
    assert '"<metric> <op> <number>"' in msg
    assert '"<metric> <op> <k> * baseline"' in msg
    assert isinstance(info.value, InputError)


# --- valid manifests -----------------------------------------------------------------------


def test_full_job_and_defaults_merge(data: Path) -> None:
    path = _write(
        data,
        """
[defaults]
pipeline = "dense"
set = { max_features = 1000, dense = { depth_max_m = 3.5 } }
source = { robot = 1, max_dt = 0.05 }
fail_if = ["ate.rmse > 0.05"]
timeout_s = 300

[[job]]
name = "visual-a"
input = "data/rgbd_a"
pipeline = "visual"
set = { max_features = 1500 }
source = { robot = 2 }
fail_if = ["ate.rmse > 0.03", "frames.lost > 0"]
timeout_s = 600
max_frames = 100
map = true
mcap = true

[[job]]
name = "dense-b"
input = "data/rgbd_b"
""",
    )
    first, second = _load(path)
    assert first == JobSpec(
        name="visual-a",
        input=(data / "data" / "rgbd_a").absolute(),
        pipeline="visual",
        settings={"max_features": 1500, "dense.depth_max_m": 3.5},
        source={"robot": 2, "max_dt": 0.05},
        fail_if=(parse_gate("ate.rmse > 0.03"), parse_gate("frames.lost > 0")),
        timeout_s=600.0,
        max_frames=100,
        build_map=True,
        mcap=True,
        line=9,
    )
    assert second.pipeline == "dense"
    assert second.settings == {"max_features": 1000, "dense.depth_max_m": 3.5}
    assert second.source == {"robot": 1, "max_dt": 0.05}
    assert second.fail_if == (parse_gate("ate.rmse > 0.05"),)
    assert second.timeout_s == 300.0
    assert second.max_frames is None
    assert (second.build_map, second.mcap) == (False, False)
    assert second.line == 21
    assert second.input.is_absolute()


def test_minimal_job_has_plain_defaults(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\ninput = "data/run1.mcap"\npipeline = "ekf"\n')
    (job,) = _load(path)
    assert job.settings == {} and job.source == {} and job.fail_if == ()
    assert job.timeout_s is None and job.max_frames is None
    assert job.input == (data / "data" / "run1.mcap").absolute()


def test_empty_fail_if_in_job_replaces_defaults(data: Path) -> None:
    path = _write(
        data,
        """
[defaults]
fail_if = ["ate.rmse > 0.05"]
[[job]]
name = "x"
input = "data/rgbd_a"
pipeline = "dense"
fail_if = []
""",
    )
    assert _load(path)[0].fail_if == ()


def test_input_resolves_against_manifest_folder_not_cwd(
    data: Path, tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    sub = data / "manifests"
    sub.mkdir()
    path = _write(sub, '[[job]]\nname = "x"\ninput = "../data/rgbd_a"\npipeline = "dense"\n')
    monkeypatch.chdir(tmp_path_factory.mktemp("elsewhere"))
    (job,) = _load(Path(path))
    assert job.input.resolve() == (data / "data" / "rgbd_a").resolve()


def test_tilde_is_expanded(data: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(data / "data"))
    path = _write(data, '[[job]]\nname = "x"\ninput = "~/rgbd_b"\npipeline = "dense"\n')
    assert _load(path)[0].input == data / "data" / "rgbd_b"


def test_glob_expands_sorted_with_stem(data: Path) -> None:
    path = _write(
        data,
        """
[[job]]
name = "dense-{stem}"
input = "data/*"
pipeline = "dense"
""",
    )
    jobs = _load(path)
    assert [j.name for j in jobs] == ["dense-rgbd_a", "dense-rgbd_b", "dense-run1"]
    assert [j.input.name for j in jobs] == ["rgbd_a", "rgbd_b", "run1.mcap"]
    assert all(j.line == 2 for j in jobs)


def test_check_metric_accepts_known_metrics(data: Path) -> None:
    calls: list[tuple[str, str]] = []

    def check(pipeline: str, metric: str) -> bool:
        calls.append((pipeline, metric))
        return True

    path = _write(
        data,
        '[[job]]\nname = "x"\ninput = "data/rgbd_a"\npipeline = "visual"\n'
        'fail_if = ["ate.rmse > 1", "frames.lost > 0"]\n',
    )
    _load(path, check_metric=check)
    assert calls == [("visual", "ate.rmse"), ("visual", "frames.lost")]


# --- errors --------------------------------------------------------------------------------


def test_toml_syntax_error_has_line(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\ninput = data/rgbd_a\n')
    err = _error(path)
    assert isinstance(err, FormatError)
    assert err.line == 3
    assert str(err).startswith(f"{path}:3: not valid TOML")


def test_missing_manifest(tmp_path: Path) -> None:
    err = _error(tmp_path / "nope.toml")
    assert "manifest not found" in str(err)


def test_no_jobs(data: Path) -> None:
    path = _write(data, '[defaults]\npipeline = "dense"\n')
    err = _error(path)
    assert "no [[job]] entries" in str(err)
    assert err.hint is not None and "[[job]]" in err.hint


def test_job_written_as_single_table(data: Path) -> None:
    path = _write(data, '\n[job]\nname = "x"\n')
    err = _error(path)
    assert err.line == 2
    assert "[[job]]" in str(err)


def test_unknown_top_level_key(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\n\n[jobs]\nname = "y"\n')
    err = _error(path)
    assert err.line == 4
    assert "unknown top-level key 'jobs'" in str(err)


@pytest.mark.parametrize("missing", ["name", "input", "pipeline"])
def test_missing_required_key(data: Path, missing: str) -> None:
    keys = {"name": '"x"', "input": '"data/rgbd_a"', "pipeline": '"dense"'}
    body = "".join(f"{k} = {v}\n" for k, v in keys.items() if k != missing)
    path = _write(data, f"\n[defaults]\nmax_frames = 5\n\n[[job]]\n{body}")
    err = _error(path)
    assert err.line == 5
    assert f"missing '{missing}'" in str(err)


def test_pipeline_from_defaults_is_enough(data: Path) -> None:
    path = _write(data, '[defaults]\npipeline = "ekf"\n[[job]]\nname = "x"\ninput = "data"\n')
    assert _load(path)[0].pipeline == "ekf"


def test_unknown_pipeline_lists_known(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\ninput = "data/rgbd_a"\npipeline = "visul"\n')
    err = _error(path)
    assert str(err) == f'{path}:4: job "x": unknown pipeline "visul"'
    assert err.hint == "known pipelines: dense, ekf, visual"


def test_unknown_pipeline_from_defaults_points_at_defaults(data: Path) -> None:
    path = _write(data, '[defaults]\npipeline = "nope"\n[[job]]\nname = "x"\ninput = "data"\n')
    assert _error(path).line == 2


def test_duplicate_names_name_both_lines(data: Path) -> None:
    path = _write(
        data,
        """
[[job]]
name = "same"
input = "data/rgbd_a"
pipeline = "dense"

[[job]]
input = "data/rgbd_b"
name = "same"
pipeline = "dense"
""",
    )
    err = _error(path)
    assert err.line == 9
    assert f"also used by the job at {path}:3" in str(err)
    assert 'duplicate job name "same"' in str(err)


def test_duplicate_names_differing_in_case(data: Path) -> None:
    path = _write(
        data,
        '[[job]]\nname = "Run"\ninput = "data"\npipeline = "dense"\n'
        '[[job]]\nname = "run"\ninput = "data"\npipeline = "dense"\n',
    )
    err = _error(path)
    assert err.line == 6
    assert "differs only in case" in str(err)


def test_duplicate_names_after_glob_expansion(data: Path) -> None:
    (data / "data" / "rgbd_a.bag").write_bytes(b"")
    path = _write(data, '[[job]]\nname = "j-{stem}"\ninput = "data/rgbd_a*"\npipeline = "dense"\n')
    err = _error(path)
    assert 'duplicate job name "j-rgbd_a"' in str(err)
    assert "rgbd_a.bag" in str(err)


def test_unknown_key(data: Path) -> None:
    path = _write(
        data,
        '[[job]]\nname = "x"\ninput = "data"\npipeline = "dense"\n\ntimeout = 5\n',
    )
    err = _error(path)
    assert str(err) == f"{path}:6: job \"x\": unknown key 'timeout'"
    assert err.hint is not None and "timeout_s" in err.hint


def test_unknown_key_in_defaults(data: Path) -> None:
    path = _write(data, '[defaults]\npipline = "dense"\n[[job]]\nname = "x"\n')
    err = _error(path)
    assert err.line == 2
    assert "[defaults]: unknown key 'pipline'" in str(err)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ('set = "max_features=1500"', "set must be a table"),
        ("source = [1, 2]", "source must be a table"),
        ("source = { robot = { id = 2 } }", "source.robot must be a value"),
        ('fail_if = "ate.rmse > 1"', "fail_if must be a list of strings"),
        ("fail_if = [1]", "fail_if must be a list of strings"),
        ("timeout_s = 0", "timeout_s must be a positive number"),
        ("timeout_s = -5.0", "timeout_s must be a positive number"),
        ('timeout_s = "600"', "timeout_s must be a positive number"),
        ("timeout_s = true", "timeout_s must be a positive number"),
        ("timeout_s = nan", "timeout_s must be a positive number"),
        ("max_frames = 1.5", "max_frames must be a positive integer"),
        ("max_frames = 0", "max_frames must be a positive integer"),
        ('map = "yes"', "map must be true or false"),
        ("mcap = 1", "mcap must be true or false"),
        ("name = 3", "name must be a non-empty string"),
        ('input = ""', "input must be a non-empty string"),
    ],
)
def test_wrong_types(data: Path, line: str, expected: str) -> None:
    key = line.split()[0]
    other = "".join(
        f"{k} = {v}\n" for k, v in (("pipeline", '"dense"'), ("input", '"data"')) if k != key
    )
    path = _write(data, f"[[job]]\n{other}{line}\n")
    err = _error(path)
    expected_line = other.count("\n") + 2
    assert err.line == expected_line
    assert expected in str(err)
    assert str(err).startswith(f"{path}:{expected_line}: ")


def test_bad_gate_text_points_at_its_line(data: Path) -> None:
    path = _write(
        data,
        """
[[job]]
name = "x"
input = "data"
pipeline = "dense"
fail_if = [
  "ate.rmse > 0.03",
  "frames.lost >> 0",
]
""",
    )
    err = _error(path)
    assert err.line == 8
    assert 'job "x": fail_if: bad gate "frames.lost >> 0"' in str(err)
    assert '"<metric> <op> <number>"' in str(err)


def test_unknown_metric(data: Path) -> None:
    text = "\n" * 9 + (
        '[[job]]\nname = "visual-rpy"\ninput = "data/rgbd_a"\npipeline = "visual"\n'
        'fail_if = ["fram.lost > 0"]\n'
    )
    path = _write(data, text)
    path.write_text(text, encoding="utf-8")
    err = _error(path, check_metric=lambda pipeline, metric: metric != "fram.lost")
    assert str(err) == (
        f'{path}:14: job "visual-rpy": fail_if "fram.lost > 0": unknown metric "fram.lost" '
        "for the visual pipeline"
    )


def test_unknown_metric_checked_against_the_jobs_pipeline(data: Path) -> None:
    path = _write(
        data,
        """
[defaults]
fail_if = ["nis.mean > 3"]
[[job]]
name = "e"
input = "data"
pipeline = "ekf"
[[job]]
name = "d"
input = "data"
pipeline = "dense"
""",
    )
    err = _error(path, check_metric=lambda pipeline, metric: pipeline == "ekf")
    assert err.line == 3
    assert 'job "d": fail_if "nis.mean > 3": unknown metric "nis.mean" for the dense pipeline' in (
        str(err)
    )


def test_an_input_that_does_not_exist_is_left_to_the_job(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\npipeline = "dense"\ninput = "data/nope"\n')
    (spec,) = load_manifest(path, pipelines=PIPELINES)
    assert spec.input == (data / "data" / "nope").absolute()
    assert not spec.input.exists()


def test_glob_that_matches_nothing(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x-{stem}"\npipeline = "dense"\ninput = "data/*.bag"\n')
    err = _error(path)
    assert err.line == 4
    assert 'input glob "data/*.bag" matches nothing' in str(err)
    assert f"resolved against {data.absolute()}" in str(err)


def test_hidden_entries_are_not_glob_matches(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x-{stem}"\npipeline = "dense"\ninput = "data/*"\n')
    assert ".hidden" not in [j.input.name for j in _load(path)]


def test_glob_under_a_folder_whose_name_looks_like_a_glob(tmp_path: Path) -> None:
    folder = tmp_path / "runs[1]"
    (folder / "logs").mkdir(parents=True)
    (folder / "logs" / "a.mcap").write_bytes(b"")
    path = _write(folder, '[[job]]\nname = "x-{stem}"\npipeline = "ekf"\ninput = "logs/*.mcap"\n')
    assert [j.input for j in _load(path)] == [folder.absolute() / "logs" / "a.mcap"]


def test_glob_under_home_with_tilde(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    home = tmp_path / "home[x]"
    (home / "logs").mkdir(parents=True)
    for name in ("b.mcap", "a.mcap"):
        (home / "logs" / name).write_bytes(b"")
    monkeypatch.setenv("HOME", str(home))
    path = _write(tmp_path, '[[job]]\nname = "{stem}"\npipeline = "ekf"\ninput = "~/logs/*"\n')
    assert [j.name for j in _load(path)] == ["a", "b"]


def test_glob_name_needs_stem(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x"\npipeline = "dense"\ninput = "data/rgbd_?"\n')
    err = _error(path)
    assert err.line == 2
    assert "must contain {stem}" in str(err)


def test_stem_needs_a_glob(data: Path) -> None:
    path = _write(data, '[[job]]\nname = "x-{stem}"\npipeline = "dense"\ninput = "data"\n')
    assert "needs a glob input" in str(_error(path))


@pytest.mark.parametrize("name", ["a b", "a/b", "..", ".", "x:y", "REPORT.html", "batch.json"])
def test_names_must_be_folder_names(data: Path, name: str) -> None:
    path = _write(data, f'[[job]]\nname = "{name}"\npipeline = "dense"\ninput = "data"\n')
    err = _error(path)
    assert err.line == 2
    assert re.search(r"cannot be a folder name|reserved", str(err))


def test_glob_stem_that_is_not_a_folder_name(data: Path) -> None:
    (data / "data" / "bad name.mcap").write_bytes(b"")
    path = _write(data, '[[job]]\nname = "x-{stem}"\npipeline = "dense"\ninput = "data/*.mcap"\n')
    err = _error(path)
    assert 'name "x-bad name"' in str(err)
    assert "bad name.mcap" in str(err)
