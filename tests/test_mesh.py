"""Mesh and point files (PLY, GLB) and mesh operations, on small hand-built meshes."""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from slamcli.errors import ConfigError, ExportError, FormatError, InputError
from slamcli.formats.mesh import (
    check_mesh,
    component_sizes,
    crop,
    export_mesh,
    mesh_to_glb,
    read_mesh,
    read_points_ply,
    remove_small_components,
    simplify,
    write_glb,
    write_ply,
    write_points_ply,
)
from slamcli.types import TriangleMesh

GLB_MAGIC = b"glTF"
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
COMPONENT_SIZE = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _colours(n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, size=(n, 3), dtype=np.uint8)


def _sphere(subdivisions: int = 3, colours: bool = True) -> TriangleMesh:
    ico = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = np.asarray(ico.vertices, dtype=np.float64)
    return TriangleMesh(
        v, np.asarray(ico.faces, dtype=np.int64), _colours(len(v)) if colours else None
    )


def _strip(n_triangles: int, x0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A strip of triangles along +x: vertices (n+2, 3), faces (n, 3), all sharing edges."""
    n = n_triangles + 2
    v = np.zeros((n, 3))
    v[:, 0] = x0 + np.arange(n) // 2
    v[:, 1] = np.arange(n) % 2
    f = np.stack(
        [np.arange(n_triangles), np.arange(n_triangles) + 1, np.arange(n_triangles) + 2], 1
    )
    return v, f.astype(np.int64)


def _assert_same(a: TriangleMesh, b: TriangleMesh) -> None:
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    if a.vertex_colors is None:
        assert b.vertex_colors is None
    else:
        assert b.vertex_colors is not None
        np.testing.assert_array_equal(a.vertex_colors, b.vertex_colors)


# --------------------------------------------------------------------------- PLY


@pytest.mark.parametrize("colours", [True, False])
def test_ply_round_trip_is_exact(tmp_path: Path, colours: bool) -> None:
    mesh = _sphere(2, colours)
    out = write_ply(tmp_path / "mesh.ply", mesh)
    assert out == tmp_path / "mesh.ply"
    back = read_mesh(out)
    assert back.vertices.dtype == np.float64 and back.faces.dtype == np.int64
    _assert_same(mesh, back)
    assert list(tmp_path.iterdir()) == [out]


def test_ply_header_is_binary_with_colour_properties(tmp_path: Path) -> None:
    mesh = _sphere(1)
    path = write_ply(tmp_path / "mesh.ply", mesh)
    data = path.read_bytes()
    header = data[: data.index(b"end_header\n")].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    assert f"element vertex {len(mesh.vertices)}" in header
    assert f"element face {len(mesh.faces)}" in header
    for prop in ("uchar red", "uchar green", "uchar blue", "list uchar int vertex_indices"):
        assert f"property {prop}" in header
    body = len(data) - data.index(b"end_header\n") - len(b"end_header\n")
    assert body == len(mesh.vertices) * (24 + 3) + len(mesh.faces) * 13


def test_ply_written_by_us_opens_in_open3d(tmp_path: Path) -> None:
    from slamcli.backends import import_open3d

    o3d = import_open3d()
    mesh = _sphere(2)
    loaded = o3d.io.read_triangle_mesh(str(write_ply(tmp_path / "m.ply", mesh)))
    np.testing.assert_allclose(np.asarray(loaded.vertices), mesh.vertices)
    np.testing.assert_array_equal(np.asarray(loaded.triangles), mesh.faces)
    assert mesh.vertex_colors is not None
    got = np.rint(np.asarray(loaded.vertex_colors) * 255).astype(np.uint8)
    np.testing.assert_array_equal(got, mesh.vertex_colors)


def test_read_mesh_reads_open3d_ply(tmp_path: Path) -> None:
    from slamcli.backends import import_open3d

    o3d = import_open3d()
    mesh = _sphere(2)
    assert mesh.vertex_colors is not None
    legacy = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(mesh.vertices), o3d.utility.Vector3iVector(mesh.faces)
    )
    legacy.vertex_colors = o3d.utility.Vector3dVector(mesh.vertex_colors / 255.0)
    path = tmp_path / "o3d.ply"
    assert o3d.io.write_triangle_mesh(str(path), legacy, write_ascii=False)
    _assert_same(mesh, read_mesh(path))


def test_points_ply_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    pts = rng.normal(size=(50, 3))
    rgba = np.concatenate([_colours(50), np.full((50, 1), 7, np.uint8)], axis=1)
    path = write_points_ply(tmp_path / "points.ply", pts, rgba)
    back, colours = read_points_ply(path)
    np.testing.assert_array_equal(back, pts)
    assert colours is not None
    np.testing.assert_array_equal(colours, rgba[:, :3])
    bare, none = read_points_ply(write_points_ply(tmp_path / "bare.ply", pts))
    np.testing.assert_array_equal(bare, pts)
    assert none is None


def test_points_ply_rejects_bad_shapes(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match=r"points must be \(N, 3\)"):
        write_points_ply(tmp_path / "p.ply", np.zeros((4, 2)))
    with pytest.raises(ExportError, match=r"point colours must be \(N, 3\)"):
        write_points_ply(tmp_path / "p.ply", np.zeros((4, 3)), np.zeros((3, 3), np.uint8))
    assert not list(tmp_path.iterdir())


def test_write_refuses_an_empty_mesh_and_leaves_nothing(tmp_path: Path) -> None:
    empty = TriangleMesh(np.zeros((3, 3)), np.zeros((0, 3), np.int64))
    with pytest.raises(ExportError, match="no triangles"):
        write_ply(tmp_path / "m.ply", empty)
    with pytest.raises(ExportError, match="no triangles"):
        write_glb(tmp_path / "m.glb", empty)
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("mesh", "pattern"),
    [
        (
            TriangleMesh(np.zeros((3, 3)), np.array([[0, 1, 3]])),
            r"face indices must lie in \[0, 3\)",
        ),
        (TriangleMesh(np.zeros((3, 3)), np.array([[0, -1, 2]])), r"face indices"),
        (TriangleMesh(np.zeros((3, 2)), np.array([[0, 1, 2]])), r"vertices must be \(V, 3\)"),
        (TriangleMesh(np.zeros((4, 3)), np.array([[0, 1, 2, 3]])), r"faces must be \(F, 3\)"),
        (
            TriangleMesh(np.full((3, 3), np.nan), np.array([[0, 1, 2]])),
            r"3 vertices are not finite",
        ),
        (
            TriangleMesh(np.zeros((3, 3)), np.array([[0, 1, 2]]), np.zeros((2, 3), np.uint8)),
            r"vertex_colors must be \(V, 3\)",
        ),
    ],
)
def test_write_rejects_malformed_meshes(tmp_path: Path, mesh: TriangleMesh, pattern: str) -> None:
    with pytest.raises(ExportError, match=pattern):
        write_ply(tmp_path / "m.ply", mesh)
    assert not list(tmp_path.iterdir())


def test_write_into_a_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="does not exist"):
        write_ply(tmp_path / "nope" / "m.ply", _sphere(0))


def test_read_mesh_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        read_mesh(tmp_path / "missing.ply")
    (tmp_path / "mesh.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match=r"expected a \.ply file"):
        read_mesh(tmp_path / "mesh.obj")
    (tmp_path / "junk.ply").write_bytes(b"this is not a ply file\n")
    with pytest.raises(FormatError, match=r"junk\.ply: cannot be read as PLY"):
        read_mesh(tmp_path / "junk.ply")
    points = write_points_ply(tmp_path / "points.ply", np.zeros((5, 3)))
    with pytest.raises(FormatError, match=r"points\.ply: has no faces"):
        read_mesh(points)


# --------------------------------------------------------------------------- GLB


def _parse_glb(data: bytes) -> tuple[dict[str, Any], bytes]:
    """The JSON chunk and the BIN chunk of a GLB, checking the container layout on the way."""
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    assert magic == GLB_MAGIC
    assert version == 2
    assert length == len(data)
    json_len, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == CHUNK_JSON
    assert json_len % 4 == 0
    doc = json.loads(data[20 : 20 + json_len].decode("utf-8"))
    offset = 20 + json_len
    bin_len, bin_type = struct.unpack_from("<II", data, offset)
    assert bin_type == CHUNK_BIN
    assert bin_len % 4 == 0
    assert offset + 8 + bin_len == len(data)
    return doc, data[offset + 8 : offset + 8 + bin_len]


def _accessor_array(doc: dict[str, Any], binary: bytes, index: int) -> np.ndarray:
    acc = doc["accessors"][index]
    view = doc["bufferViews"][acc["bufferView"]]
    dtype = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}[
        acc["componentType"]
    ]
    width = TYPE_WIDTH[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = view.get("byteStride", width * COMPONENT_SIZE[acc["componentType"]])
    assert stride == width * COMPONENT_SIZE[acc["componentType"]]
    return np.frombuffer(binary, dtype=dtype, count=acc["count"] * width, offset=start).reshape(
        acc["count"], width
    )


def test_glb_layout_and_required_fields(tmp_path: Path) -> None:
    mesh = _sphere(2)
    path = write_glb(tmp_path / "mesh.glb", mesh)
    doc, binary = _parse_glb(path.read_bytes())

    assert doc["asset"]["version"] == "2.0"
    prim = doc["meshes"][0]["primitives"][0]
    assert prim.get("mode", 4) == 4
    attrs = prim["attributes"]
    assert {"POSITION", "COLOR_0"} <= set(attrs)
    for acc in doc["accessors"]:
        assert {"count", "componentType", "type"} <= set(acc)
        assert acc["componentType"] in COMPONENT_SIZE
        assert acc["type"] in TYPE_WIDTH
    assert doc["buffers"][0]["byteLength"] <= len(binary)
    for view in doc["bufferViews"]:
        assert view["buffer"] == 0
        assert view.get("byteOffset", 0) + view["byteLength"] <= len(binary)
    for acc in doc["accessors"]:
        view = doc["bufferViews"][acc["bufferView"]]
        size = acc["count"] * TYPE_WIDTH[acc["type"]] * COMPONENT_SIZE[acc["componentType"]]
        assert acc.get("byteOffset", 0) + size <= view["byteLength"]

    position = doc["accessors"][attrs["POSITION"]]
    assert (position["count"], position["type"], position["componentType"]) == (
        len(mesh.vertices),
        "VEC3",
        5126,
    )
    assert "min" in position and "max" in position  # required for POSITION by the spec
    np.testing.assert_allclose(
        _accessor_array(doc, binary, attrs["POSITION"]), mesh.vertices, atol=1e-6
    )

    colour = doc["accessors"][attrs["COLOR_0"]]
    assert colour["count"] == len(mesh.vertices)
    assert colour["type"] in ("VEC3", "VEC4")
    assert colour["componentType"] in (5121, 5126)
    if colour["componentType"] == 5121:
        assert colour["normalized"] is True
        assert mesh.vertex_colors is not None
        got = _accessor_array(doc, binary, attrs["COLOR_0"])[:, :3]
        np.testing.assert_array_equal(got, mesh.vertex_colors)

    indices = doc["accessors"][prim["indices"]]
    assert (indices["count"], indices["type"]) == (3 * len(mesh.faces), "SCALAR")
    flat = _accessor_array(doc, binary, prim["indices"]).reshape(-1, 3)
    np.testing.assert_array_equal(flat, mesh.faces)


def test_glb_loads_back_in_trimesh_with_counts_and_colours(tmp_path: Path) -> None:
    mesh = _sphere(3)
    path = write_glb(tmp_path / "mesh.glb", mesh)
    scene = trimesh.load(str(path), file_type="glb", process=False)
    (geom,) = scene.geometry.values()
    assert len(geom.vertices) == len(mesh.vertices)
    assert len(geom.faces) == len(mesh.faces)
    assert geom.visual.kind == "vertex"
    assert mesh.vertex_colors is not None
    np.testing.assert_array_equal(np.asarray(geom.visual.vertex_colors)[:, :3], mesh.vertex_colors)
    np.testing.assert_allclose(geom.vertices, mesh.vertices, atol=1e-6)


def test_glb_without_colours_has_no_color_attribute() -> None:
    doc, _ = _parse_glb(mesh_to_glb(_sphere(1, colours=False)))
    assert "COLOR_0" not in doc["meshes"][0]["primitives"][0]["attributes"]
    scene = trimesh.load(io.BytesIO(mesh_to_glb(_sphere(1, colours=False))), file_type="glb")
    assert len(next(iter(scene.geometry.values())).faces) == 80


# --------------------------------------------------------------------------- operations


def test_crop_reindexes_vertices_correctly() -> None:
    # Vertex 0 lies outside; faces using it go, and every kept index shifts down by one.
    v = np.array(
        [[-5.0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [9, 9, 9]], dtype=np.float64
    )
    f = np.array([[0, 1, 3], [1, 2, 3], [2, 4, 3], [4, 5, 2]], dtype=np.int64)
    c = np.arange(18, dtype=np.uint8).reshape(6, 3)
    out = crop(TriangleMesh(v, f, c), (-1, -1, -1, 1, 1, 1))
    np.testing.assert_array_equal(out.vertices, v[1:5])
    np.testing.assert_array_equal(out.faces, [[0, 1, 2], [1, 3, 2]])
    assert out.vertex_colors is not None
    np.testing.assert_array_equal(out.vertex_colors, c[1:5])


def test_crop_bounds_are_inclusive_and_keep_only_whole_faces() -> None:
    v, f = _strip(4)  # x in 0..2, y in 0..1
    out = crop(TriangleMesh(v, f), (0, 0, 0, 1, 1, 0))
    np.testing.assert_array_equal(out.faces, [[0, 1, 2], [1, 2, 3]])
    assert len(out.vertices) == 4
    assert len(crop(TriangleMesh(v, f), (5, 5, 5, 6, 6, 6)).faces) == 0


@pytest.mark.parametrize(
    ("bounds", "pattern"),
    [
        ((0, 0, 0, 1, 1), "six finite numbers"),
        ((0, 0, 0, 1, 1, float("nan")), "six finite numbers"),
        ((0, 2, 0, 1, 1, 1), "ymin 2 is above ymax 1"),
    ],
)
def test_crop_rejects_bad_boxes(bounds: tuple[float, ...], pattern: str) -> None:
    v, f = _strip(2)
    with pytest.raises(ConfigError, match=pattern):
        crop(TriangleMesh(v, f), bounds)


def test_remove_small_components_known_answer() -> None:
    big_v, big_f = _strip(5)  # 5 triangles, 7 vertices
    small_v, small_f = _strip(2, x0=100.0)  # 2 triangles, 4 vertices
    lone = np.array([[50.0, 50, 50], [51, 50, 50], [50, 51, 50]])
    v = np.concatenate([small_v, big_v, lone])
    f = np.concatenate([small_f, big_f + 4, np.array([[11, 12, 13]])])
    c = _colours(len(v))
    mesh = TriangleMesh(v, f, c)

    labels, sizes = component_sizes(mesh)
    assert sorted(sizes.tolist()) == [1, 2, 5]
    assert len(set(labels[:2].tolist())) == 1 and labels[0] != labels[2]

    out = remove_small_components(mesh, 3)
    np.testing.assert_array_equal(out.vertices, big_v)
    np.testing.assert_array_equal(out.faces, big_f)
    assert out.vertex_colors is not None
    np.testing.assert_array_equal(out.vertex_colors, c[4:11])

    kept = remove_small_components(mesh, 2)
    assert len(kept.faces) == 7 and len(kept.vertices) == 11
    assert len(remove_small_components(mesh, 6).faces) == 0
    _assert_same(remove_small_components(mesh, 1), mesh)


def test_faces_sharing_only_a_vertex_are_one_component() -> None:
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    f = np.array([[0, 1, 2], [0, 3, 4]], dtype=np.int64)
    _, sizes = component_sizes(TriangleMesh(v, f))
    assert sizes.tolist() == [2]


def test_remove_small_components_rejects_zero() -> None:
    v, f = _strip(2)
    with pytest.raises(ConfigError, match=">= 1"):
        remove_small_components(TriangleMesh(v, f), 0)


def test_simplify_reaches_about_the_target_and_is_deterministic() -> None:
    mesh = _sphere(4)  # 5120 triangles
    a = simplify(mesh, 500)
    b = simplify(mesh, 500)
    _assert_same(a, b)
    assert 450 <= len(a.faces) <= 500
    assert a.vertex_colors is not None and a.vertex_colors.shape == a.vertices.shape
    used = np.zeros(len(a.vertices), bool)
    used[a.faces.ravel()] = True
    assert used.all()
    radius = np.linalg.norm(a.vertices, axis=1)
    assert np.all(np.abs(radius - 1.0) < 0.05)  # still a sphere
    check_mesh(a)


def test_simplify_leaves_small_meshes_alone_and_rejects_zero() -> None:
    mesh = _sphere(1)
    _assert_same(simplify(mesh, len(mesh.faces)), mesh)
    with pytest.raises(ConfigError, match=">= 1"):
        simplify(mesh, 0)


# --------------------------------------------------------------------------- export_mesh


def test_export_mesh_refuses_existing_output_and_wrong_extension(tmp_path: Path) -> None:
    src = write_ply(tmp_path / "mesh.ply", _sphere(1))
    (tmp_path / "mesh.glb").write_bytes(b"old")
    with pytest.raises(ExportError, match="already exists"):
        export_mesh(src, "glb")
    assert (tmp_path / "mesh.glb").read_bytes() == b"old"
    with pytest.raises(ConfigError, match=r"does not end in \.glb"):
        export_mesh(src, "glb", tmp_path / "x.ply")
    with pytest.raises(ConfigError, match="unknown mesh format 'obj'"):
        export_mesh(src, "obj")
    report = export_mesh(src, "glb", force=True)
    assert report.out == tmp_path / "mesh.glb"
    assert (tmp_path / "mesh.glb").read_bytes()[:4] == GLB_MAGIC
