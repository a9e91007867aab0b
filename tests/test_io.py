"""g2o / TORO reading and writing: exact round trips, the TORO conversion against SE-Sync's g2o
form of the same data, the real files' quirks, and one-line errors for malformed files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import require_dataset

from popbench import se2
from popbench.errors import DataFormatError
from popbench.graph import odometry_composition
from popbench.io import detect_format, read_graph, read_vertices, write_g2o, write_toro

EDGE = "EDGE_SE2 0 1 1.0 0.0 0.1 10 0 0 10 0 10"
VERTICES = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0.1\n"


def write(tmp_path: Path, text: str, name: str = "graph.g2o") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def assert_same_graph(a, b) -> None:
    for field in ("poses", "tails", "heads", "measurements", "information", "kinds"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


def test_round_trip_is_exact(small_graph, tmp_path: Path) -> None:
    path = tmp_path / "loop.g2o"
    write_g2o(small_graph, path)
    assert_same_graph(read_graph(path), small_graph)


def test_round_trip_with_other_poses(small_graph, tmp_path: Path) -> None:
    path = tmp_path / "truth.g2o"
    write_g2o(small_graph, path, poses=small_graph.ground_truth)
    np.testing.assert_array_equal(read_graph(path).poses, small_graph.ground_truth)


@pytest.mark.dataset
def test_round_trip_of_real_file_keeps_reversed_edges(tmp_path: Path) -> None:
    mit = require_dataset("mit")
    path = tmp_path / "mit.g2o"
    write_g2o(mit, path)
    assert_same_graph(read_graph(path), mit)


@pytest.mark.dataset
def test_mit_reversed_edges_are_kept_as_written() -> None:
    mit = require_dataset("mit")
    reversed_edges = np.flatnonzero(mit.tails > mit.heads)
    assert reversed_edges.size == 20  # data README: 20 loop closures written i > j
    # Independent reference: the raw text of the first such line.
    from popbench.datasets import dataset_path

    raw = [
        line.split()
        for line in dataset_path("mit").read_text().splitlines()
        if line.startswith("EDGE_SE2")
    ]
    first = reversed_edges[0]
    tokens = raw[first]
    assert (int(tokens[1]), int(tokens[2])) == (mit.tails[first], mit.heads[first])
    values = [float(token) for token in tokens[3:]]
    np.testing.assert_array_equal(mit.measurements[first], values[:3])  # not inverted
    np.testing.assert_array_equal(mit.information[first][np.triu_indices(3)], values[3:])


@pytest.mark.dataset
def test_toro_file_equals_sesync_g2o_form() -> None:
    toro = require_dataset("csail_toro")
    g2o = require_dataset("csail")
    np.testing.assert_array_equal(toro.tails, g2o.tails)
    np.testing.assert_array_equal(toro.heads, g2o.heads)
    np.testing.assert_allclose(toro.measurements, g2o.measurements, rtol=1e-9, atol=1e-9)
    # Data README: the converted TORO information matches csail.g2o to print precision (8e-10).
    scale = np.abs(g2o.information).max(axis=(1, 2), keepdims=True)
    relative = np.abs(toro.information - g2o.information) / scale
    assert relative.max() < 2e-9


@pytest.mark.dataset
def test_csail_without_vertices_gets_odometry_composition() -> None:
    csail = require_dataset("csail")
    toro = require_dataset("csail_toro")
    assert csail.num_poses == 1045
    np.testing.assert_array_equal(csail.poses[0], [0.0, 0.0, 0.0])
    # Independent reference: Carlone's TORO vertices are the odometry composition (README: 5e-7).
    difference = csail.poses - toro.poses
    difference[:, 2] = se2.wrap(difference[:, 2])
    assert np.abs(difference).max() < 1e-5


def test_spanning_tree_composition_of_a_broken_chain(rng: np.random.Generator) -> None:
    truth = np.column_stack([rng.uniform(-5, 5, (7, 2)), rng.uniform(-np.pi, np.pi, 7)])
    truth = se2.compose(se2.inverse(truth[:1]), truth)  # vertex 0 at the origin
    # No chain edge 2 → 3 and 4 → 5; 3 is reached through a reversed edge 4 → 3 and 5 from 0;
    # vertex 6 is unreachable.
    tails = np.array([0, 1, 2, 4, 0])
    heads = np.array([1, 2, 4, 3, 5])
    measurements = se2.between(truth[tails], truth[heads])
    poses = odometry_composition(7, tails, heads, measurements)
    np.testing.assert_allclose(poses[:6], truth[:6], atol=1e-12)
    np.testing.assert_array_equal(poses[6], [0.0, 0.0, 0.0])


def test_file_without_vertices_and_broken_chain(tmp_path: Path) -> None:
    text = "EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nEDGE_SE2 2 1 1 0 1.5707963267948966 1 0 0 1 0 1\n"
    graph = read_graph(write(tmp_path, text))
    # Edge 2 → 1: vertex 1 is 1 m ahead of vertex 2 and turned +90°, so x_2 = x_1 ∘ z⁻¹.
    np.testing.assert_allclose(graph.poses, [[0, 0, 0], [1, 0, 0], [1, 1, -np.pi / 2]], atol=1e-12)


def test_format_detection(tmp_path: Path) -> None:
    assert detect_format(write(tmp_path, "EDGE2 0 1 1 0 0 1 0 1 1 0 0", "a.g2o")) == "toro"
    assert detect_format(write(tmp_path, "", "b.graph")) == "toro"
    assert detect_format(write(tmp_path, "# c\n" + EDGE)) == "g2o"


def test_toro_information_is_rotated_into_the_measurement_frame(tmp_path: Path) -> None:
    # TORO order I11 I12 I22 I33 I13 I23; measurement heading 90°: x and y swap roles.
    path = write(tmp_path, "EDGE2 0 1 1 2 1.5707963267948966 4 0 1 9 0 0\n", "e.graph")
    np.testing.assert_allclose(
        read_graph(path).information[0], np.diag([1.0, 4.0, 9.0]), atol=1e-12
    )


def test_read_vertices_matches_read_graph(small_graph, tmp_path: Path) -> None:
    path = tmp_path / "loop.g2o"
    write_g2o(small_graph, path)
    np.testing.assert_array_equal(read_vertices(path), small_graph.poses)


@pytest.mark.parametrize(
    ("text", "line", "phrase"),
    [
        (VERTICES + "EDGE_SE2 0 1 1.0 0.0 0.1 10 0 0 10 0\n", 3, "needs 11 values"),
        (
            VERTICES + "EDGE_SE2 0 1 1.0 zero 0.1 10 0 0 10 0 10\n",
            3,
            "EDGE_SE2 field dy (value 4 of 11) is 'zero': expected a number",
        ),
        ("VERTEX_SE2 0 0 abc 0\n" + EDGE + "\n", 1, "field y (value 3 of 4) is 'abc'"),
        (VERTICES + EDGE + "\nEDGE2 0 1 1 0 0 1 0 1 1 0 0\n", 4, "unknown tag 'EDGE2' in a g2o"),
        (VERTICES + "\n" + EDGE.replace("10 0 10", "10 0 -1") + "\n", 4, "not positive definite"),
        (VERTICES + EDGE.replace("1.0", "nan") + "\n", 3, "field dx (value 3 of 11) is non-finite"),
        (VERTICES + EDGE[:-2] + "inf" + "\n", 3, "field I33 (value 11 of 11) is non"),
        # An edge to a vertex without a VERTEX line is reported on the edge's line.
        (
            VERTICES + "VERTEX_SE2 2 2 0 0\n" + EDGE + "\nEDGE_SE2 1 2 1 0 0 1 0 0 1 0 1\n"
            "EDGE_SE2 0 7 1 0 0 1 0 0 1 0 1\n",
            6,
            "EDGE_SE2 references vertex 7, which has no VERTEX_SE2 line (ids 0–2)",
        ),
        (VERTICES + "EDGE_SE2 9 0 1 0 0 1 0 0 1 0 1\n", 3, "references vertex 9, which has no"),
        # Ids are 64-bit integers written in digits: beyond 2⁶⁴ − 1 a range error.
        (VERTICES + "VERTEX_SE2 1e12 0 0 0\n" + EDGE + "\n", 3, "'1e12' is not an integer"),
        (
            VERTICES + EDGE.replace("0 1 1.0", "0 18446744073709551616 1.0") + "\n",
            3,
            "field j: vertex id '18446744073709551616' is out of range (0 to 184467440737095516",
        ),
        # A valid id whose pose no edge reaches: named by its id.
        (
            VERTICES + "VERTEX_SE2 2000000000 0 0 0\n" + EDGE + "\n",
            3,
            "1 of 3 poses (ids 2000000000) are not connected to vertex 0",
        ),
        (VERTICES + EDGE.replace("0 1 1.0", "1 1 1.0") + "\n", 3, "joins vertex 1 to itself"),
        (VERTICES + EDGE.replace("0 1 1.0", "0 -1 1.0") + "\n", 3, "not an integer"),
        (VERTICES + EDGE.replace("0 1 1.0", "0 1.5 1.0") + "\n", 3, "not an integer"),
        ("VERTEX_SE2 0 0 0\n" + EDGE + "\n", 1, "needs 4 values"),
        (VERTICES + "VERTEX_SE2 1 2 0 0\n" + EDGE + "\n", 3, "vertex id 1 repeated"),
        (
            "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 2 0 0 0\n" + EDGE + "\n",
            3,
            "EDGE_SE2 references vertex 1, which has no VERTEX_SE2 line (2 ids from 0 to 2)",
        ),
        ("", 0, "no EDGE_SE2 lines"),
        ("# only a comment\n" + VERTICES, 0, "no EDGE_SE2 lines"),
        # Value ranges (io.COORDINATE_LIMIT, INFORMATION_RANGE, INFORMATION_SPREAD): beyond
        # them cc-pgo's Cholesky, LM's factor or the F sums failed (tests/test_fuzz.py).
        ("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 -2e9 0\n" + EDGE + "\n", 2, "pose coordinate -2e+09"),
        (VERTICES + EDGE.replace("1.0", "1e150") + "\n", 3, "translation 1e+150 m is out of"),
        (VERTICES + EDGE.replace("10 0 0 10 0 10", "1e-120 0 0 1 0 1") + "\n", 3, "1e-120 is"),
        (VERTICES + EDGE.replace("10 0 0 10 0 10", "1e200 0 0 1e200 0 1e200") + "\n", 3, "1e+200"),
        (
            VERTICES + EDGE + "\n" + EDGE.replace("10 0 0 10 0 10", "1e17 0 0 1 0 1") + "\n",
            4,
            "information spans 1e+17 (eigenvalue 1e+17 here, 1 on line 4); allowed at most 1e+15",
        ),
    ],
)
def test_malformed_files_name_the_line(tmp_path: Path, text: str, line: int, phrase: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(DataFormatError) as caught:
        read_graph(path)
    assert caught.value.line == line
    assert str(caught.value).startswith(f"{path}:{line}: ")
    assert phrase in str(caught.value)
    assert "\n" not in str(caught.value)


def test_toro_information_that_overflows_is_refused(tmp_path: Path) -> None:
    # Rotating 1e308 entries into the measurement frame overflows: refused, not NaN.
    edge = "EDGE2 0 1 1 0 0.7 1e308 1e308 1e308 1 0 0"
    path = write(tmp_path, f"VERTEX2 0 0 0 0\nVERTEX2 1 1 0 0\n{edge}\n", "t.graph")
    with pytest.raises(DataFormatError, match=r"t\.graph:3: information matrix overflows"):
        read_graph(path)


def test_malformed_toro_line(tmp_path: Path) -> None:
    path = write(tmp_path, "VERTEX2 0 0 0 0\nEDGE2 0 1 1 0 0 1 0 1 1 0\n", "t.graph")
    with pytest.raises(DataFormatError, match=r"t\.graph:2: EDGE2 needs 11 values"):
        read_graph(path)


def test_binary_file_is_a_format_error(tmp_path: Path) -> None:
    path = tmp_path / "blob.g2o"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe\x00binary")
    with pytest.raises(DataFormatError, match="not a text file"):
        read_graph(path)


def test_information_is_symmetric_and_ordered(tmp_path: Path) -> None:
    text = VERTICES + "EDGE_SE2 0 1 1 0 0.1 11 12 13 22 23 33\n"
    info = read_graph(write(tmp_path, text)).information[0]
    np.testing.assert_array_equal(info, [[11, 12, 13], [12, 22, 23], [13, 23, 33]])


def test_ground_truth_vertices_only(tmp_path: Path) -> None:
    # Edges of a ground-truth file are not parsed (their information may be placeholders).
    text = VERTICES + "EDGE_SE2 0 1 not numbers at all\n"
    np.testing.assert_array_equal(read_vertices(write(tmp_path, text)), [[0, 0, 0], [1, 0, 0.1]])
    with pytest.raises(DataFormatError, match="no VERTEX_SE2 lines"):
        read_vertices(write(tmp_path, EDGE + "\n", "edges.g2o"))


# TORO EQUIV: vertices 1 and 3 are one pose (chained with 3 ≡ 4); edges redirected, self-loops
# dropped, internal indices renumbered in order.
EQUIV_TORO = """VERTEX2 0 0 0 0
VERTEX2 1 1 0 0
VERTEX2 2 2 0 0
VERTEX2 3 1.5 0 0
VERTEX2 4 1.6 0 0
VERTEX2 5 3 0 0
EDGE2 0 1 1 0 0 1 0 1 1 0 0
EDGE2 1 2 1 0 0 2 0 2 2 0 0
EDGE2 2 3 -1 0 0 3 0 3 3 0 0
EDGE2 3 4 0 0 0 4 0 4 4 0 0
EDGE2 4 5 2 0 0 5 0 5 5 0 0
EQUIV 1 3
EQUIV 4 3
"""


def test_toro_equiv_merges_vertices_and_redirects_edges(tmp_path: Path) -> None:
    path = write(tmp_path, EQUIV_TORO, "w.graph")
    with pytest.warns(UserWarning, match=r"w\.graph: EQUIV merged 2 .*dropped 1 edge"):
        graph = read_graph(path)
    # Classes {0}, {1, 3, 4}, {2}, {5} → new ids 0, 1, 2, 3; vertex 1's pose is kept.
    np.testing.assert_array_equal(graph.poses, [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    np.testing.assert_array_equal(graph.tails, [0, 1, 2, 1])
    np.testing.assert_array_equal(graph.heads, [1, 2, 1, 3])
    np.testing.assert_array_equal(graph.measurements[:, 0], [1, 1, -1, 2])
    # The dropped edge 3–4 (information 4) is gone; the others keep their own information.
    np.testing.assert_array_equal(graph.information[:, 2, 2], [1, 2, 3, 5])
    np.testing.assert_array_equal(read_vertices(path), graph.poses)
    # Written back with each class's kept (smallest) file id: 0, 1, 2, 5.
    np.testing.assert_array_equal(graph.vertex_ids, [0, 1, 2, 5])
    out = tmp_path / "merged.graph"
    write_toro(graph, out)
    ids = [line.split()[1 : 3 if "EDGE" in line else 2] for line in out.read_text().splitlines()]
    assert ids == [["0"], ["1"], ["2"], ["5"], ["0", "1"], ["1", "2"], ["2", "1"], ["1", "5"]]


def test_toro_equiv_without_vertex_lines_or_self_loops(tmp_path: Path) -> None:
    text = "EDGE2 0 1 1 0 0 1 0 1 1 0 0\nEDGE2 2 3 1 0 0 1 0 1 1 0 0\nEQUIV 1 2\n"
    graph = read_graph(write(tmp_path, text, "n.graph"))
    np.testing.assert_array_equal(graph.tails, [0, 1])
    np.testing.assert_array_equal(graph.heads, [1, 2])
    np.testing.assert_allclose(graph.poses, [[0, 0, 0], [1, 0, 0], [2, 0, 0]])


@pytest.mark.parametrize(
    ("equiv", "phrase"),
    [
        ("EQUIV 1", "EQUIV needs 2 values after the tag, found 1"),
        ("EQUIV 1 x", "EQUIV field j: vertex id 'x' is not an integer"),
        ("EQUIV 1 1.5", "vertex id '1.5' is not an integer"),
        ("EQUIV 2 2", "EQUIV joins vertex 2 to itself"),
        ("EQUIV 1 9", "EQUIV references vertex 9, which is not in the graph (ids 0–5)"),
    ],
)
def test_malformed_equiv_line_names_file_and_line(tmp_path: Path, equiv: str, phrase: str) -> None:
    path = write(tmp_path, EQUIV_TORO.replace("EQUIV 4 3", equiv), "bad.graph")
    with pytest.raises(DataFormatError) as caught:
        read_graph(path)
    assert str(caught.value).startswith(f"{path}:13: ")
    assert phrase in str(caught.value)
    assert "\n" not in str(caught.value)


def test_equiv_is_not_a_g2o_tag(tmp_path: Path) -> None:
    with pytest.raises(DataFormatError, match="unknown tag 'EQUIV'"):
        read_graph(write(tmp_path, VERTICES + "EQUIV 0 1\n"))
