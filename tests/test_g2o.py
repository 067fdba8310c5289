"""g2o pose graphs: the benchmark graphs' known sizes, and malformed lines named by file:line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import shared_path

from slamcli.errors import FormatError
from slamcli.formats.g2o import read_g2o


@pytest.mark.parametrize(
    ("name", "dim", "vertices", "ids", "edges"),
    [
        ("intel.g2o", 2, 1728, 1728, 2512),
        ("manhattan.g2o", 2, 0, 3500, 5453),
        ("sphere2500.g2o", 3, 2500, 2500, 4949),
    ],
)
def test_benchmark_graphs(name: str, dim: int, vertices: int, ids: int, edges: int) -> None:
    graph = read_g2o(shared_path("pose_graphs", name))
    summary = graph.summary()
    assert (graph.dim, summary["vertices"], summary["pose_ids"], summary["edges"]) == (
        dim,
        vertices,
        ids,
        edges,
    )
    size = 3 if dim == 2 else 6
    assert graph.information.shape == (edges, size, size)
    np.testing.assert_array_equal(graph.information, graph.information.transpose(0, 2, 1))


def test_information_is_the_upper_triangle_row_by_row(tmp_path: Path) -> None:
    f = tmp_path / "g.g2o"
    f.write_text("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\nEDGE_SE2 0 1 1 0 0 1 2 3 4 5 6\nFIX 0\n")
    graph = read_g2o(f)
    np.testing.assert_array_equal(graph.information[0], [[1, 2, 3], [2, 4, 5], [3, 5, 6]])
    np.testing.assert_array_equal(graph.measurements[0], [1, 0, 0])
    assert graph.fixed == (0,)
    assert graph.summary()["odometry_edges"] == 1


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("VERTEX_SE2 0 0 0\n", r"g\.g2o:1: VERTEX_SE2 has 1 id\(s\) and 3 values, found 3"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 x 0\n", r"g\.g2o:2: column 4: value 'x'"),
        ("VERTEX_SE2 a 0 0 0\n", r"g\.g2o:1: column 2: vertex id 'a'"),
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE3:QUAT 1 0 0 0 0 0 0 1\n", r"g\.g2o:2: .*mixed"),
        ("# only a comment\n", r"g\.g2o: no vertices or edges"),
        ("VERTEX_XY 0 1 2\n", r"g\.g2o:1: unsupported record 'VERTEX_XY'"),
    ],
)
def test_malformed_lines(tmp_path: Path, text: str, match: str) -> None:
    f = tmp_path / "g.g2o"
    f.write_text(text)
    with pytest.raises(FormatError, match=match):
        read_g2o(f)
