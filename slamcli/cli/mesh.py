"""``slamcli mesh export``: convert and clean a run's mesh (PLY or GLB)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary
from slamcli.errors import ConfigError

mesh_app = typer.Typer(
    help="Convert and clean meshes built by a run: PLY or GLB, cropped, filtered, simplified.",
    no_args_is_help=True,
    rich_markup_mode="rich",
)

FORMATS = ("ply", "glb")

EXPORT_HELP = """Export a mesh as PLY or GLB, optionally cropped, filtered and simplified.

INPUT is a run folder (its mesh.ply is used) or a .ply mesh. Steps run in this order: \
--crop keeps the triangles whose three corners lie inside the box, --min-component drops \
connected pieces smaller than N triangles (floating noise), --simplify decimates to about N \
triangles (quadric edge collapse). Vertex colours are kept in both formats; a GLB is glTF 2.0 \
with colours as COLOR_0 and opens in Blender, three.js and Foxglove. The file is written to a \
temporary name and renamed into place when complete.

Exit codes: 0 ok; 1 a missing input, a run folder without mesh.ply, an unknown format, a bad \
--crop, a mesh left empty by --crop or --min-component, or --out exists without --force.

Examples:

[bold]slamcli mesh export runs/room_dense --format glb[/] (after the 'slamcli run dense' example)

[bold]slamcli mesh export runs/room_dense --out room.ply --min-component 200 --simplify 20000[/]

[bold]slamcli mesh export room.ply --format glb --crop=-2,-2,-0.5,2,2,2.5[/]
"""


def register(app: typer.Typer) -> None:
    app.add_typer(mesh_app, name="mesh", rich_help_panel="Export")


def parse_crop(text: str) -> tuple[float, float, float, float, float, float]:
    """``"xmin,ymin,zmin,xmax,ymax,zmax"`` (metres) -> six floats; ConfigError naming --crop."""
    parts = [p.strip() for p in text.split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ConfigError(
            f"--crop: expected six numbers xmin,ymin,zmin,xmax,ymax,zmax in metres, got {text!r}",
            hint="for example --crop=-2,-2,0,2,2,1.5 (write '=' when the first number is negative)",
        )
    for axis, low, high in zip("xyz", values[:3], values[3:], strict=True):
        if low > high:
            raise ConfigError(
                f"--crop: {axis}min {low:g} is above {axis}max {high:g} in {text!r}",
                hint="the order is xmin,ymin,zmin,xmax,ymax,zmax",
            )
    x0, y0, z0, x1, y1, z1 = values
    return x0, y0, z0, x1, y1, z1


def resolve_format(format: str | None, out: Path | None) -> str:
    """The output format: --format, else --out's extension, else glb."""
    if format is not None:
        fmt = format.lower().lstrip(".")
        if fmt not in FORMATS:
            raise ConfigError(
                f"--format: unknown mesh format {format!r}", hint=f"choose {' or '.join(FORMATS)}"
            )
        return fmt
    if out is not None:
        fmt = out.suffix.lower().lstrip(".")
        if fmt not in FORMATS:
            raise ConfigError(
                f"--out {out}: unknown mesh format {out.suffix or '(no extension)'}",
                hint=f"name the file *.ply or *.glb, or pass --format {' or '.join(FORMATS)}",
            )
        return fmt
    return "glb"


@mesh_app.command("export", help=EXPORT_HELP)
@boundary
def export(
    input: Annotated[
        Path,
        typer.Argument(
            help="A run folder (its mesh.ply is used) or a .ply mesh.", show_default=False
        ),
    ],
    format: Annotated[
        str | None,
        typer.Option(
            "--format",
            "-f",
            help="ply or glb. Default: --out's extension, else glb.",
            show_default=False,
        ),
    ] = None,
    out: Annotated[
        Path | None,
        typer.Option(
            "--out",
            "-o",
            help="File to write. Default: beside the input, named after it with the format's "
            "extension (mesh.ply -> mesh.glb; a .ply export of a .ply becomes NAME.export.ply).",
            show_default=False,
        ),
    ] = None,
    simplify: Annotated[
        int | None,
        typer.Option(
            "--simplify",
            min=1,
            help="Decimate to about this many triangles (quadric edge collapse).",
            show_default=False,
        ),
    ] = None,
    crop: Annotated[
        str | None,
        typer.Option(
            "--crop",
            help="Keep triangles inside the box xmin,ymin,zmin,xmax,ymax,zmax (metres).",
            show_default=False,
        ),
    ] = None,
    min_component: Annotated[
        int | None,
        typer.Option(
            "--min-component",
            min=1,
            help="Drop connected pieces with fewer triangles than this (floaters, noise).",
            show_default=False,
        ),
    ] = None,
    force: Annotated[bool, typer.Option("--force", help="Overwrite an existing --out.")] = False,
) -> None:
    """Export a mesh as PLY or GLB, optionally cropped, filtered and simplified."""
    from slamcli.atomic import check_writable_file
    from slamcli.formats.mesh import export_mesh

    fmt = resolve_format(format, out)
    box = parse_crop(crop) if crop is not None else None
    if out is not None:
        check_writable_file(out)
    result = export_mesh(
        input,
        fmt,
        out,
        simplify_to=simplify,
        crop_box=box,
        min_component=min_component,
        force=force,
    )
    rows: dict[str, str] = {
        "input": f"{result.source} ({result.input_vertices} vertices, {result.input_faces} faces)"
    }
    for step, detail, faces in result.steps:
        rows[step] = f"{detail}: {faces} faces left"
    rows["output"] = f"{result.format}: {result.vertices} vertices, {result.faces} faces"
    rows["colours"] = "per vertex" if result.colors else "none"
    render.key_values("Mesh", rows)
    render.written([result.out])
