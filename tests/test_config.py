"""Config sections: TOML loading, --set overrides, type and range checks, dump round trips."""

from __future__ import annotations

import dataclasses
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import pytest
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.config import check_settings, dump_config, load_config, setting
from slamcli.errors import ConfigError, FormatError, InputError
from slamcli.pipelines import PIPELINES, get_pipeline

if sys.version_info >= (3, 11):
    import tomllib
else:
    import tomli as tomllib

runner = CliRunner()


@dataclass(frozen=True)
class Section:
    """Settings of a made-up pipeline. Lengths in metres.

    Attributes:
        note: free text, described only
            in this docstring.
    """

    voxel_m: float = setting(0.01, help="TSDF voxel edge", unit="m", gt=0.0, max=0.5)
    levels: int = setting(3, help="pyramid levels", min=1, max=8)
    fitness: float = setting(0.2, help="least fitness", min=0.0, lt=1.0)
    colour: bool = setting(True, help="integrate colour")
    method: str = setting("hybrid", help="loss", choices=("hybrid", "point_to_plane"))
    mode: Literal["fast", "exact"] = "fast"
    iterations: tuple[int, ...] = setting((10, 5, 3), help="per level", min=1)
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)
    depth_factor: float | None = setting(None, help="depth units per metre", gt=0.0)
    note: str = "plain"


def _write(tmp_path: Path, text: str, name: str = "cfg.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


# --------------------------------------------------------------------------- loading


def test_defaults_without_file_or_sets() -> None:
    assert load_config(Section, "demo") == Section()


def test_file_section_overrides_defaults_and_other_tables_are_ignored(tmp_path: Path) -> None:
    cfg = _write(
        tmp_path,
        "[other]\nvoxel_m = 'ignored'\n\n[demo]\nvoxel_m = 0.02\nlevels = 4\n"
        "iterations = [7, 7]\norigin = [1, 2.5, -3]\nmethod = 'point_to_plane'\n"
        "mode = 'exact'\ncolour = false\ndepth_factor = 5000\n",
    )
    got = load_config(Section, "demo", cfg)
    assert got == Section(
        voxel_m=0.02,
        levels=4,
        iterations=(7, 7),
        origin=(1.0, 2.5, -3.0),
        method="point_to_plane",
        mode="exact",
        colour=False,
        depth_factor=5000.0,
    )
    assert isinstance(got.origin[0], float) and isinstance(got.depth_factor, float)


def test_file_without_the_section_gives_defaults(tmp_path: Path) -> None:
    assert load_config(Section, "demo", _write(tmp_path, "[other]\nx = 1\n")) == Section()


def test_sets_override_the_file_in_both_key_forms(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[demo]\nvoxel_m = 0.02\nlevels = 4\n")
    got = load_config(
        Section,
        "demo",
        cfg,
        ["demo.voxel_m=0.05", "levels = 5", "iterations=[2, 1]", "method=point_to_plane"],
    )
    assert got.voxel_m == 0.05
    assert got.levels == 5
    assert got.iterations == (2, 1)
    assert got.method == "point_to_plane"


def test_set_accepts_quoted_text_exponents_and_integers_for_floats() -> None:
    got = load_config(Section, "demo", sets=['mode="exact"', "voxel_m=1e-2", "fitness=0"])
    assert got.mode == "exact"
    assert got.voxel_m == 0.01
    assert got.fitness == 0.0 and isinstance(got.fitness, float)


def test_later_sets_win() -> None:
    assert load_config(Section, "demo", sets=["levels=2", "levels=6"]).levels == 6


# --------------------------------------------------------------------------- errors


@pytest.mark.parametrize(
    ("assignment", "pattern"),
    [
        ("voxel_m='big'", r"demo\.voxel_m: expected a number in \(0, 0\.5\] \(m\), got \"big\""),
        ("voxel_m=0", r"demo\.voxel_m: expected a number in \(0, 0\.5\] \(m\), got 0"),
        ("voxel_m=0.6", r"demo\.voxel_m: .*got 0\.6"),
        ("voxel_m=nan", r"demo\.voxel_m: .*got nan"),
        ("voxel_m=true", r"demo\.voxel_m: expected a number .*got true"),
        ("levels=2.5", r"demo\.levels: expected an integer in \[1, 8\], got 2\.5"),
        ("levels=true", r"demo\.levels: expected an integer .*got true"),
        ("levels=0", r"demo\.levels: expected an integer in \[1, 8\], got 0"),
        ("levels=9", r"demo\.levels: .*got 9"),
        ("fitness=1", r"demo\.fitness: expected a number in \[0, 1\), got 1"),
        ("fitness=-0.1", r"demo\.fitness: .*got -0\.1"),
        ("colour=1", r"demo\.colour: expected true or false, got 1"),
        (
            "method=icp",
            r"demo\.method: expected one of \"hybrid\", \"point_to_plane\", got \"icp\"",
        ),
        ("method=3", r"demo\.method: expected one of .*got 3"),
        ("mode=slow", r"demo\.mode: expected one of \"fast\", \"exact\", got \"slow\""),
        ("iterations=3", r"demo\.iterations: expected a list of integers >= 1, got 3"),
        ("iterations=[3, 0]", r"demo\.iterations: .*got \[3, 0\]"),
        ("iterations=[3, 1.5]", r"demo\.iterations: .*got \[3, 1\.5\]"),
        ("origin=[1, 2]", r"demo\.origin: expected a list of 3 values .*got \[1, 2\]"),
        ("depth_factor=-1", r"demo\.depth_factor: expected a number > 0, got -1"),
        ("note=[1]", r"demo\.note: expected a string, got \[1\]"),
    ],
)
def test_bad_values_name_the_dotted_key_value_and_range(assignment: str, pattern: str) -> None:
    with pytest.raises(ConfigError, match=f"^--set {pattern}$"):
        load_config(Section, "demo", sets=[assignment])


def test_check_settings_names_the_option_and_takes_the_docstring_as_hint() -> None:
    ok = Section(depth_factor=None, iterations=(4, 2))
    assert check_settings(ok) is ok
    with pytest.raises(
        ConfigError, match=r"^--voxel: expected a number in \(0, 0\.5\] \(m\), got 0$"
    ):
        check_settings(Section(voxel_m=0), {"voxel_m": "--voxel"})
    with pytest.raises(
        ConfigError, match=r"^iterations: expected a list of integers >= 1, got \[3, 0\]$"
    ):
        check_settings(Section(iterations=(3, 0)))
    with pytest.raises(ConfigError, match=r"^voxel_m: .*got nan$") as info:
        check_settings(Section(voxel_m=float("nan")))
    assert info.value.hint == "TSDF voxel edge"
    with pytest.raises(ConfigError, match=r"^note: expected a string, got 3$") as info:
        check_settings(Section(note=3))  # type: ignore[arg-type]
    assert info.value.hint == "free text, described only in this docstring."


def test_bad_value_in_file_names_the_file_and_key(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[demo]\nlevels = 12\n")
    with pytest.raises(ConfigError, match=r"cfg\.toml: demo\.levels: expected an integer in") as e:
        load_config(Section, "demo", cfg)
    assert e.value.hint == "pyramid levels"


def test_unknown_key_in_file_lists_the_keys_and_suggests(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[demo]\nvoxel = 0.02\n")
    with pytest.raises(
        ConfigError, match=r"cfg\.toml: demo\.voxel: unknown setting; \[demo\] has"
    ) as e:
        load_config(Section, "demo", cfg)
    assert e.value.hint is not None and "did you mean demo.voxel_m?" in e.value.hint


def test_unknown_key_in_set() -> None:
    with pytest.raises(ConfigError, match=r"^--set demo\.levelz: unknown setting") as e:
        load_config(Section, "demo", sets=["demo.levelz=2"])
    assert e.value.hint is not None and "demo.levels" in e.value.hint


def test_nested_table_in_section_is_an_unknown_key(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[demo.inner]\nx = 1\n")
    with pytest.raises(ConfigError, match=r"demo\.inner: unknown setting"):
        load_config(Section, "demo", cfg)


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        ("levels", r"^--set 'levels': expected KEY=VALUE$"),
        ("=3", r"^--set '=3': expected KEY=VALUE$"),
        ("levels=", r"^--set demo\.levels: no value after '='$"),
        ("other.levels=2", r"^--set other\.levels: section 'other' does not apply here"),
        ("levels=abc", r"^--set demo\.levels=abc: not a TOML value; expected an integer"),
        ("iterations=[1,", r"^--set demo\.iterations=\[1,: not a TOML value"),
    ],
)
def test_malformed_sets(text: str, pattern: str) -> None:
    with pytest.raises(ConfigError, match=pattern):
        load_config(Section, "demo", sets=[text])


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"missing\.toml: config file not found"):
        load_config(Section, "demo", tmp_path / "missing.toml")


def test_invalid_toml_names_the_line(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[demo]\nlevels = 3\nvoxel_m = = 1\n")
    with pytest.raises(FormatError, match=r"cfg\.toml:3: not valid TOML: .* at column 11$") as e:
        load_config(Section, "demo", cfg)
    assert e.value.line == 3


def test_key_outside_any_section(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "levels = 3\n[demo]\n")
    with pytest.raises(ConfigError, match=r"key 'levels' is outside any \[section\]") as e:
        load_config(Section, "demo", cfg)
    assert e.value.hint is not None and "put it under [demo]" in e.value.hint


# --------------------------------------------------------------------------- dumping


def test_dump_has_header_comments_and_values() -> None:
    text = dump_config(Section(), "demo")
    lines = text.splitlines()
    assert lines[0] == "# Settings of a made-up pipeline. Lengths in metres."
    assert lines[1] == "[demo]"
    assert "# TSDF voxel edge (m, in (0, 0.5])" in lines
    assert "voxel_m = 0.01" in lines
    assert "# pyramid levels (in [1, 8])" in lines
    assert '# loss (one of "hybrid", "point_to_plane")' in lines
    assert "iterations = [10, 5, 3]" in lines
    assert "# per level (>= 1)" in lines
    assert "# depth_factor = (unset)" in lines
    assert "# free text, described only in this docstring." in lines
    assert 'note = "plain"' in lines


@pytest.mark.parametrize(
    "instance",
    [
        Section(),
        Section(
            voxel_m=0.1 + 0.2,
            levels=8,
            fitness=1e-7,
            colour=False,
            method="point_to_plane",
            mode="exact",
            iterations=(1,),
            origin=(-1.5, 2.0, 1e-300),
            depth_factor=5000.0,
            note='quote " and \\ backslash \t tab \x7f del, ünïcode',
        ),
    ],
)
def test_dump_then_load_gives_the_same_instance(tmp_path: Path, instance: Section) -> None:
    text = dump_config(instance, "demo")
    assert tomllib.loads(text)["demo"]["voxel_m"] == instance.voxel_m
    assert load_config(Section, "demo", _write(tmp_path, text)) == instance


@pytest.mark.parametrize("name", sorted(PIPELINES))
def test_every_pipeline_config_round_trips(tmp_path: Path, name: str) -> None:
    cls = get_pipeline(name).config_class
    text = dump_config(cls(), name)
    assert load_config(cls, name, _write(tmp_path, text)) == cls()
    for f in dataclasses.fields(cls):
        assert f.name in tomllib.loads(text)[name] or getattr(cls(), f.name) is None


def test_dump_rejects_a_non_dataclass() -> None:
    with pytest.raises(TypeError):
        dump_config(object(), "demo")


# --------------------------------------------------------------------------- CLI


def test_cli_config_dump_odometry_prints_the_defaults() -> None:
    res = runner.invoke(app, ["config", "dump", "odometry"])
    assert res.exit_code == 0, res.output
    cls = get_pipeline("odometry").config_class
    parsed = tomllib.loads(res.stdout)["odometry"]
    assert cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in parsed.items()}) == cls()


def test_cli_config_dump_dense_when_registered() -> None:
    if "dense" not in PIPELINES:
        pytest.skip("no dense pipeline registered yet")
    res = runner.invoke(app, ["config", "dump", "dense"])
    assert res.exit_code == 0, res.output
    assert "[dense]" in res.stdout.splitlines()
    cls = get_pipeline("dense").config_class
    defaults = cls()
    assert set(tomllib.loads(res.stdout)["dense"]) == {
        f.name for f in dataclasses.fields(cls) if getattr(defaults, f.name) is not None
    }


def test_cli_config_dump_dense_gives_every_setting_a_range() -> None:
    res = runner.invoke(app, ["config", "dump", "dense"])
    assert res.exit_code == 0, res.output
    comment: list[str] = []
    keys = 0
    for line in res.stdout.splitlines()[2:]:
        if line.startswith("# "):
            comment.append(line[2:])
            continue
        key = line.split(" = ")[0]
        text = " ".join(comment)
        assert re.search(r"(in [\[(]|>=? |<=? |one of )[^()]*\)$", text), (key, text)
        comment = []
        keys += 1
    assert keys == len(dataclasses.fields(get_pipeline("dense").config_class))


@pytest.mark.parametrize("key", ["dense.match_ratio", "match_ratio"])
def test_cli_run_dense_refuses_a_setting_out_of_range(tmp_path: Path, key: str) -> None:
    res = runner.invoke(
        app, ["run", "dense", str(tmp_path), "--out", str(tmp_path / "out"), "--set", f"{key}=-1"]
    )
    assert res.exit_code == 1, res.output
    assert "dense.match_ratio: expected a number in (0, 1], got -1" in res.output
    assert not (tmp_path / "out").exists()


def test_cli_config_dump_applies_config_and_sets(tmp_path: Path) -> None:
    cfg = _write(tmp_path, "[odometry]\nmax_step_m = 0.5\n")
    res = runner.invoke(
        app,
        ["config", "dump", "odometry", "--config", str(cfg), "--set", "iterations=[4, 2]"],
    )
    assert res.exit_code == 0, res.output
    parsed = tomllib.loads(res.stdout)["odometry"]
    assert parsed["max_step_m"] == 0.5
    assert parsed["iterations"] == [4, 2]


def test_cli_config_dump_unknown_pipeline() -> None:
    res = runner.invoke(app, ["config", "dump", "nope"])
    assert res.exit_code == 1
    assert "unknown pipeline 'nope'" in res.output
    assert "odometry" in res.output
    assert "Traceback" not in res.output


def test_cli_config_dump_bad_set() -> None:
    res = runner.invoke(app, ["config", "dump", "odometry", "--set", "max_step_m=fast"])
    assert res.exit_code == 1
    assert "odometry.max_step_m" in res.output
