"""``slamcli mesh export``: files written, summaries, exit codes and one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import Result
from typer.testing import CliRunner

from slamcli.cli.app import app
from slamcli.formats.mesh import read_mesh, write_ply, write_points_ply
from slamcli.types import TriangleMesh

runner = CliRunner()


def invoke(*args: str | Path) -> Result:
    return runner.invoke(app, ["mesh", "export", *map(str, args)])


def one_line_error(res: Result, text: str) -> None:
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    lines = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and text in lines[0], res.stderr


def _scene() -> TriangleMesh:
    """A coloured sphere (radius 1 at the origin, 1280 triangles) and a 12-triangle box at x=3."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    box = trimesh.creation.box(extents=(0.5, 0.5, 0.5))
    box.apply_translation((3.0, 0.0, 0.0))
    v = np.concatenate([sphere.vertices, box.vertices]).astype(np.float64)
    f = np.concatenate([sphere.faces, box.faces + len(sphere.vertices)]).astype(np.int64)
    c = np.random.default_rng(0).integers(0, 256, size=(len(v), 3), dtype=np.uint8)
    return TriangleMesh(v, f, c)


@pytest.fixture
def run_dir(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}\n")
    write_ply(run / "mesh.ply", _scene())
    return run


def test_run_folder_to_glb(run_dir: Path) -> None:
    res = invoke(run_dir, "--format", "glb")
    assert res.exit_code == 0, res.output
    out = run_dir / "mesh.glb"
    mesh = _scene()
    scene = trimesh.load(str(out), file_type="glb", process=False)
    (geom,) = scene.geometry.values()
    assert (len(geom.vertices), len(geom.faces)) == (len(mesh.vertices), len(mesh.faces))
    assert mesh.vertex_colors is not None
    np.testing.assert_array_equal(np.asarray(geom.visual.vertex_colors)[:, :3], mesh.vertex_colors)
    for text in (
        f"{len(mesh.vertices)} vertices",
        f"{len(mesh.faces)} faces",
        "per vertex",
        str(out),
        str(out.stat().st_size),
    ):
        assert text in res.stdout, res.stdout


def test_format_defaults_to_glb_and_follows_out(run_dir: Path, tmp_path: Path) -> None:
    assert invoke(run_dir).exit_code == 0
    assert (run_dir / "mesh.glb").read_bytes()[:4] == b"glTF"
    res = invoke(run_dir, "--out", tmp_path / "copy.ply")
    assert res.exit_code == 0, res.output
    assert len(read_mesh(tmp_path / "copy.ply").faces) == len(_scene().faces)


def test_ply_to_ply_with_every_step(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "clean.ply"
    res = invoke(
        run_dir / "mesh.ply",
        "--format",
        "ply",
        "--out",
        out,
        "--crop",
        "-1.5,-1.5,-1.5,1.5,1.5,1.5",
        "--min-component",
        "20",
        "--simplify",
        "300",
    )
    assert res.exit_code == 0, res.output
    mesh = read_mesh(out)
    assert 270 <= len(mesh.faces) <= 300
    assert mesh.vertex_colors is not None
    assert np.abs(mesh.vertices).max() <= 1.0 + 1e-9  # the box at x=3 is gone
    for text in (
        "crop",
        "min-component",
        "simplify",
        "1280 faces left",
        f"{len(mesh.faces)} faces",
    ):
        assert text in res.stdout, res.stdout


def test_min_component_drops_the_box(run_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "big.ply"
    res = invoke(run_dir / "mesh.ply", "--out", out, "--min-component", "13")
    assert res.exit_code == 0, res.output
    assert len(read_mesh(out).faces) == 1280


def test_ply_default_out_does_not_overwrite_the_input(run_dir: Path) -> None:
    before = (run_dir / "mesh.ply").read_bytes()
    res = invoke(run_dir / "mesh.ply", "--format", "ply", "--simplify", "100")
    assert res.exit_code == 0, res.output
    assert (run_dir / "mesh.ply").read_bytes() == before
    assert len(read_mesh(run_dir / "mesh.export.ply").faces) <= 100


def test_existing_out_needs_force(run_dir: Path) -> None:
    (run_dir / "mesh.glb").write_bytes(b"old")
    res = invoke(run_dir, "--format", "glb")
    one_line_error(res, "mesh.glb: already exists")
    assert "--force" in res.stderr
    assert (run_dir / "mesh.glb").read_bytes() == b"old"
    res = invoke(run_dir, "--format", "glb", "--force")
    assert res.exit_code == 0, res.output
    assert (run_dir / "mesh.glb").read_bytes()[:4] == b"glTF"


def test_missing_run_folder(tmp_path: Path) -> None:
    one_line_error(invoke(tmp_path / "nope"), "nope: no such file or folder")


def test_run_folder_without_mesh(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "run.json").write_text("{}\n")
    res = invoke(run)
    one_line_error(res, "run: folder has no mesh.ply")
    assert "hint:" in res.stderr
    assert list(run.iterdir()) == [run / "run.json"]


@pytest.mark.parametrize(
    ("args", "text"),
    [
        (("--format", "obj"), "--format: unknown mesh format 'obj'"),
        (("--out", "mesh.stl"), "mesh.stl: unknown mesh format .stl"),
        (("--format", "glb", "--out", "mesh.ply"), "does not end in .glb"),
    ],
)
def test_unknown_or_contradictory_format(run_dir: Path, args: tuple[str, ...], text: str) -> None:
    fixed = [str(run_dir / a) if a.startswith("mesh.") else a for a in args]
    one_line_error(invoke(run_dir, *fixed), text)
    assert sorted(p.name for p in run_dir.iterdir()) == ["mesh.ply", "run.json"]


@pytest.mark.parametrize(
    ("crop", "text"),
    [
        ("1,2,3", "--crop: expected six numbers"),
        ("a,b,c,d,e,f", "--crop: expected six numbers"),
        ("0,0,0,1,1,inf", "--crop: expected six numbers"),
        ("0,0,2,1,1,1", "--crop: zmin 2 is above zmax 1"),
    ],
)
def test_bad_crop_text(run_dir: Path, crop: str, text: str) -> None:
    one_line_error(invoke(run_dir, "--crop", crop), text)
    assert not (run_dir / "mesh.glb").exists()


def test_crop_that_keeps_nothing(run_dir: Path) -> None:
    res = invoke(run_dir, "--crop", "10,10,10,11,11,11")
    one_line_error(res, "no triangle of")
    assert "the mesh spans" in res.stderr
    assert not (run_dir / "mesh.glb").exists()


def test_min_component_that_keeps_nothing(run_dir: Path) -> None:
    res = invoke(run_dir, "--min-component", "5000")
    one_line_error(res, "--min-component 5000: every component")
    assert "the largest has 1280 triangles" in res.stderr
    assert not (run_dir / "mesh.glb").exists()


def test_empty_mesh_file(tmp_path: Path) -> None:
    path = write_points_ply(tmp_path / "empty.ply", np.zeros((4, 3)))
    one_line_error(invoke(path), "empty.ply: has no faces")
    assert not (tmp_path / "empty.glb").exists()


def test_usage_errors_exit_2(run_dir: Path) -> None:
    assert invoke(run_dir, "--simplify", "0").exit_code == 2
    assert invoke().exit_code == 2


def test_help_teaches_with_examples() -> None:
    res = runner.invoke(app, ["mesh", "export", "--help"])
    assert res.exit_code == 0
    assert "slamcli mesh export runs/room_dense --format glb" in res.stdout
