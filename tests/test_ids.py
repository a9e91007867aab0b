"""A user's own ids: files whose vertex ids start at 1, have gaps, come in any order or are
GTSAM ``Symbol`` keys (a robot letter in the top byte) solve exactly like their twin numbered
``0 … N−1`` and get their ids back in every output; FIX lines are read and written back; lines
of kinds popbench does not model are reported in one line. GTSAM (a test dependency) reads what
popbench writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from conftest import grid_g2o

from popbench import cli
from popbench.harness.solve import flagged_edges
from popbench.io import read_graph, write_g2o

GRID_POSES = 20  # conftest.grid_g2o
LETTER_SHIFT = 56  # gtsam.Symbol: the character in the top byte, the index below it


def symbol(letter: str, index: int) -> int:
    """``gtsam.symbol(letter, index)``, computed here (checked against gtsam below)."""
    return (ord(letter) << LETTER_SHIFT) | index


# Each map takes the twin's ids 0 … 19 to a file's ids, increasing (so the internal order, the
# ascending ids, is the twin's and the two solves do the same arithmetic).
ID_MAPS = {
    "from-1": [k + 1 for k in range(GRID_POSES)],
    "gaps": [7 + 3 * k + k * k for k in range(GRID_POSES)],
    "symbols": [symbol("a", k) for k in range(10)] + [symbol("b", k) for k in range(10)],
    "top-of-64-bits": [2**64 - 1 - 5 * (GRID_POSES - 1 - k) for k in range(GRID_POSES)],
}


def renumbered(text: str, ids: list[int], rng: np.random.Generator) -> str:
    """The g2o ``text`` with every vertex id ``k`` replaced by ``ids[k]`` and the VERTEX lines
    shuffled (ids in any order); edge lines keep their order."""
    vertices, others = [], []
    for line in text.splitlines():
        tokens = line.split()
        count = {"VERTEX_SE2": 1, "EDGE_SE2": 2, "FIX": len(tokens) - 1}.get(tokens[0], 0)
        tokens[1 : 1 + count] = [str(ids[int(t)]) for t in tokens[1 : 1 + count]]
        (vertices if tokens[0] == "VERTEX_SE2" else others).append(" ".join(tokens))
    vertices = [vertices[k] for k in rng.permutation(len(vertices))]
    return "\n".join(vertices + others) + "\n"


def solve(capsys, path: Path, out: Path, suffix: str, method: str = "lm") -> tuple[dict, str]:
    """``popbench solve`` on ``path`` writing ``out`` + ``suffix`` (graph), ``.tum``, ``.csv``;
    the JSON record and stderr."""
    args = ["solve", str(path), "--method", method, "--init", "chordal", "--json"]
    args += ["--output", f"{out}{suffix}", "--trajectory", f"{out}.tum", "--flags", f"{out}.csv"]
    code = cli.main(args)
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return json.loads(captured.out), captured.err


def tokens_with_ids(path: Path, ids: list[int] | None, columns: dict[str, tuple[int, int]]):
    """Every line of ``path`` (``#`` comments and a CSV header skipped) as tokens, its id
    columns mapped through ``ids`` (None: kept) and compared as integers; ``columns``: first
    token → (first id column, how many), ``"*"`` for every line."""
    rows = []
    for line in path.read_text().splitlines():
        tokens = line.replace(",", " ").split()
        if not tokens or tokens[0].startswith("#") or tokens[0] == "edge":
            continue
        start, count = columns.get("*", columns.get(tokens[0], (0, 0)))
        for k in range(start, start + count):
            tokens[k] = int(tokens[k]) if ids is None else ids[int(tokens[k])]
        rows.append(tokens)
    return rows


@pytest.mark.parametrize("name", ID_MAPS)
@pytest.mark.parametrize("suffix", [".g2o", ".graph"])
def test_ids_as_written_solve_like_their_twin_and_come_back(
    capsys: pytest.CaptureFixture, tmp_path: Path, name: str, suffix: str
) -> None:
    ids = ID_MAPS[name]
    twin = grid_g2o(tmp_path / "twin.g2o")
    mine = tmp_path / f"{name}.g2o"
    mine.write_text(renumbered(twin.read_text(), ids, np.random.default_rng(3)))
    twin_record, _ = solve(capsys, twin, tmp_path / "twin-out", suffix)
    record, err = solve(capsys, mine, tmp_path / "mine-out", suffix)
    assert record["F"] == twin_record["F"]  # the same graph, the same arithmetic
    assert record["F_init"] == twin_record["F_init"]
    # Every output equals the twin's with the twin's ids replaced by the file's, exactly.
    graph_ids = {"VERTEX_SE2": (1, 1), "EDGE_SE2": (1, 2), "VERTEX2": (1, 1), "EDGE2": (1, 2)}
    for ending, columns in [(suffix, graph_ids), (".tum", {"*": (0, 1)}), (".csv", {"*": (1, 2)})]:
        expected = tokens_with_ids(tmp_path / f"twin-out{ending}", ids, columns)
        written = tokens_with_ids(tmp_path / f"mine-out{ending}", None, columns)
        assert written == expected, ending
    # The written graph reads back to the file's ids and the solved F.
    back = read_graph(tmp_path / f"mine-out{suffix}")
    np.testing.assert_array_equal(back.vertex_ids, np.array(ids, dtype=np.uint64))
    # TUM timestamps above 2⁵³ that float64 readers (evo) would merge are reported.
    if name in ("symbols", "top-of-64-bits"):
        assert err.count("\n") == 1 and "20 of the 20 ids are above 2^53" in err, err
    else:
        assert err == ""


def test_gtsam_reads_the_written_symbol_keys(tmp_path: Path) -> None:
    gtsam = pytest.importorskip("gtsam")
    assert symbol("b", 7) == gtsam.symbol("b", 7)
    ids = ID_MAPS["symbols"]
    mine = tmp_path / "symbols.g2o"
    text = renumbered(grid_g2o(tmp_path / "twin.g2o").read_text(), ids, np.random.default_rng(0))
    mine.write_text(text + f"FIX {ids[3]}\n")
    graph = read_graph(mine)
    out = tmp_path / "out.g2o"
    write_g2o(graph, out)
    factors, values = gtsam.readG2o(str(out), False)
    assert sorted(values.keys()) == ids
    assert factors.size() == graph.num_edges
    keys = [tuple(factors.at(k).keys()) for k in range(factors.size())]
    file_ids = graph.vertex_ids
    assert keys == list(
        zip(file_ids[graph.tails].tolist(), file_ids[graph.heads].tolist(), strict=True)
    )
    pose = values.atPose2(ids[5])
    np.testing.assert_array_equal([pose.x(), pose.y(), pose.theta()], graph.poses[5])


def test_fix_lines_are_read_and_written_back(tmp_path: Path) -> None:
    ids = ID_MAPS["gaps"]
    text = renumbered(grid_g2o(tmp_path / "twin.g2o").read_text(), ids, np.random.default_rng(1))
    path = tmp_path / "fixed.g2o"
    path.write_text(f"FIX {ids[12]}\n{text}FIX {ids[5]} {ids[12]}\n")
    graph = read_graph(path)
    np.testing.assert_array_equal(graph.fixed, [5, 12])  # internal indices, once each
    out = tmp_path / "out.g2o"
    write_g2o(graph, out)
    assert out.read_text().splitlines()[-2:] == [f"FIX {ids[5]}", f"FIX {ids[12]}"]
    np.testing.assert_array_equal(read_graph(out).fixed, [5, 12])
    # On the solve path (robots assigned, a start applied) the ids and FIX poses stay.
    from popbench.harness.problems import distributed_problem

    problem = distributed_problem(str(path), 2, "chordal")
    np.testing.assert_array_equal(problem.graph.fixed, [5, 12])
    np.testing.assert_array_equal(problem.graph.vertex_ids, ids)


def test_unmodelled_lines_are_reported_in_one_line(
    capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    twin = grid_g2o(tmp_path / "twin.g2o")
    path = tmp_path / "landmarks.g2o"
    extra = [
        "VERTEX_XY 100 1.5 2.5",
        "EDGE_SE2_XY 0 100 1.5 2.5 10 0 10",
        "EDGE_SE2_XY 3 100 -1.5 2.5 10 0 10",
        "VERTEX_SE3:QUAT 101 0 0 0 0 0 0 1",
    ]
    path.write_text(twin.read_text() + "\n".join(extra) + "\n")
    args = ["solve", "--method", "lm", "--init", "chordal", "--json"]
    assert cli.main([args[0], str(twin), *args[1:]]) == 0
    clean = json.loads(capsys.readouterr().out)
    assert cli.main([args[0], str(path), *args[1:]]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["F"] == clean["F"]  # the pose graph alone is solved
    assert captured.err.count("\n") == 1
    assert captured.err.startswith(f"popbench: note: {path}: skipped 4 line(s) of kinds")
    assert "(VERTEX_XY ×1, EDGE_SE2_XY ×2, VERTEX_SE3:QUAT ×1)" in captured.err


def test_an_edge_to_a_missing_vertex_names_it(capsys: pytest.CaptureFixture, tmp_path: Path):
    ids = ID_MAPS["from-1"]
    text = renumbered(grid_g2o(tmp_path / "twin.g2o").read_text(), ids, np.random.default_rng(2))
    lines = [line for line in text.splitlines() if line.split()[1] != "16"]  # drop VERTEX 16
    path = tmp_path / "missing.g2o"
    path.write_text("\n".join(lines) + "\n")
    first = next(k for k, line in enumerate(lines, 1) if " 16 " in line and "EDGE" in line)
    assert cli.main(["solve", str(path), "--json"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"popbench: error: {path}:{first}: EDGE_SE2 references vertex 16, which has no "
        "VERTEX_SE2 line (19 ids from 1 to 20)\n"
    )


def test_tum_rounded_counts_the_ids_float64_merges() -> None:
    from popbench.io import tum_rounded

    assert tum_rounded(np.arange(5) + 2**53 - 4) == 0  # 2⁵³ − 4 … 2⁵³: all exact
    assert tum_rounded(np.array([2**53, 2**53 + 1, 7])) == 2  # 2⁵³ + 1 rounds to 2⁵³
    symbols = [symbol("a", k) for k in range(1030)] + [symbol("b", 0)]
    assert tum_rounded(np.array(symbols, dtype=np.uint64)) == 1030  # spacing 1024 at 2⁶²


def test_outliers_in_the_record_carry_the_file_ids(tmp_path: Path) -> None:
    ids = ID_MAPS["symbols"]
    path = tmp_path / "symbols.g2o"
    text = renumbered(grid_g2o(tmp_path / "twin.g2o").read_text(), ids, np.random.default_rng(4))
    path.write_text(text)
    graph = read_graph(path)
    mask = np.ones(graph.num_edges, dtype=bool)
    mask[[2, 25]] = False
    expected = [{"edge": e, "i": ids[graph.tails[e]], "j": ids[graph.heads[e]]} for e in (2, 25)]
    assert flagged_edges(graph, mask) == expected
    assert json.loads(json.dumps(expected)) == expected  # exact 64-bit integers in JSON
