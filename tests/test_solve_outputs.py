"""``popbench solve --output / --trajectory / --flags`` and their Python writers: the written
graph reads back to the solution's F, the TUM rows are the solved poses, the CSV carries each
edge's flag and weight; disconnected graphs are refused at load, naming the poses."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from conftest import grid_g2o, require_dataset

from popbench import cli, objective
from popbench.errors import DataFormatError, ValueRangeError
from popbench.io import read_graph, write_g2o, write_solution, write_toro, write_tum


def solve_json(capsys: pytest.CaptureFixture, *args: str) -> dict:
    assert cli.main(["solve", *args, "--json"]) == 0, capsys.readouterr().err
    return json.loads(capsys.readouterr().out)


def read_tum(path: Path) -> np.ndarray:
    """``(N, 8)`` rows of a TUM file (``#`` lines skipped), as evo reads them."""
    return np.loadtxt(path, comments="#", ndmin=2)


def read_flags(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


@pytest.mark.dataset
def test_intel_gnc_writes_three_files_that_reproduce_the_solution(
    capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    require_dataset("intel")
    out, tum, flags = tmp_path / "out.g2o", tmp_path / "out.tum", tmp_path / "out.csv"
    args = ["intel", "--method", "gnc", "--output", str(out), "--trajectory", str(tum)]
    record = solve_json(capsys, *args, "--flags", str(flags))
    solved = read_graph(out)
    assert (solved.num_poses, solved.num_edges) == (1228, 1483)
    # The written file, started at its own VERTEX lines, is the solution: F_init = F.
    again = solve_json(capsys, str(out), "--init", "given", "--iterations", "0")
    assert again["F_init"] == pytest.approx(record["F"], rel=1e-12)
    rows = read_tum(tum)
    np.testing.assert_array_equal(rows[:, 0], np.arange(1228))
    np.testing.assert_allclose(rows[:, 1:3], solved.poses[:, :2], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rows[:, [3, 4, 5]], 0.0)
    yaw = 2 * np.arctan2(rows[:, 6], rows[:, 7])
    np.testing.assert_allclose(np.angle(np.exp(1j * (yaw - solved.poses[:, 2]))), 0, atol=1e-12)
    table = read_flags(flags)
    assert len(table) == 1483 and list(table[0]) == ["edge", "i", "j", "kind", "weight", "flagged"]
    flagged = [(int(r["edge"]), int(r["i"]), int(r["j"])) for r in table if r["flagged"] == "1"]
    assert flagged == [(o["edge"], o["i"], o["j"]) for o in record["outliers"]]
    assert all(0.0 <= float(r["weight"]) <= 1.0 for r in table)
    assert {r["kind"] for r in table} == {"odometry", "loop"}


def test_distributed_solution_maps_back_to_the_file_ids(
    capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    # mm-pgo on 3 robots, TORO output: the robots own scattered vertex ids (METIS), and the
    # written file must hold each pose under its own id, so its F is the record's F.
    graph_file = grid_g2o(tmp_path / "grid.g2o")
    out, flags = tmp_path / "out.graph", tmp_path / "flags.csv"
    args = [str(graph_file), "--method", "mm-pgo", "--robots", "3", "--iterations", "30"]
    record = solve_json(
        capsys, *args, "-o", "kernel=huber", "--output", str(out), "--flags", str(flags)
    )
    solved, original = read_graph(out), read_graph(graph_file)
    np.testing.assert_array_equal(solved.tails, original.tails)
    np.testing.assert_allclose(solved.information, original.information, rtol=1e-12, atol=1e-12)
    assert objective.objective(solved) == pytest.approx(record["F"], rel=1e-9)
    assert record["F"] < 0.1 * record["F_init"]  # a solution, not the start
    table = read_flags(flags)
    assert {r["kind"] for r in table} >= {"odometry", "inter_relative"}  # the 3-robot labels
    assert all(r["weight"] != "" and r["flagged"] in ("0", "1") for r in table)


def test_method_without_mask_or_weights_leaves_the_columns_empty(
    capsys: pytest.CaptureFixture, tmp_path: Path
) -> None:
    flags = tmp_path / "flags.csv"
    record = solve_json(capsys, str(grid_g2o(tmp_path / "g.g2o")), "--flags", str(flags))
    assert record["outliers"] is None
    table = read_flags(flags)
    assert len(table) == 31 and all(r["weight"] == "" and r["flagged"] == "" for r in table)


@pytest.mark.parametrize(
    ("option", "path", "phrase"),
    [
        ("--output", "out.txt", "invalid --output"),
        ("--trajectory", "no/such/folder/out.tum", "invalid --trajectory"),
        ("--flags", ".", "invalid --flags"),
    ],
)
def test_bad_output_paths_are_refused_before_solving(
    capsys: pytest.CaptureFixture, option: str, path: str, phrase: str
) -> None:
    # no-such-dataset: the paths are checked before the dataset is read.
    assert cli.main(["solve", "no-such-dataset", option, path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and phrase in err, err


def test_toro_writer_round_trip(small_graph, tmp_path: Path) -> None:
    write_toro(small_graph, tmp_path / "loop.graph")
    back = read_graph(tmp_path / "loop.graph")
    np.testing.assert_array_equal(back.measurements, small_graph.measurements)
    np.testing.assert_allclose(back.information, small_graph.information, rtol=1e-13, atol=1e-12)
    np.testing.assert_array_equal(back.poses, small_graph.poses)


def test_write_solution_picks_the_format_and_checks_its_input(small_graph, tmp_path: Path) -> None:
    poses = small_graph.ground_truth
    write_solution(small_graph, poses, tmp_path / "a.g2o")
    write_solution(small_graph, poses, tmp_path / "a.graph")
    assert (tmp_path / "a.g2o").read_text().startswith("VERTEX_SE2 0 ")
    assert (tmp_path / "a.graph").read_text().startswith("VERTEX2 0 ")
    for name in ("a.g2o", "a.graph"):
        np.testing.assert_array_equal(read_graph(tmp_path / name).poses, poses)
    with pytest.raises(ValueRangeError, match="a path ending in .g2o or .graph"):
        write_solution(small_graph, poses, tmp_path / "a.txt")
    with pytest.raises(ValueRangeError, match=r"\(30, 3\)"):
        write_solution(small_graph, poses[:-1], tmp_path / "b.g2o")


def test_tum_quaternion_of_the_yaw(tmp_path: Path) -> None:
    poses = np.array([[1.0, 2.0, np.pi / 2], [3.0, -1.0, -np.pi / 3]])
    write_tum(poses, tmp_path / "t.tum", ids=np.array([4, 9]))
    rows = read_tum(tmp_path / "t.tum")
    half = np.sqrt(0.5)
    np.testing.assert_allclose(rows[0], [4, 1, 2, 0, 0, 0, half, half])
    np.testing.assert_allclose(rows[1], [9, 3, -1, 0, 0, 0, -0.5, np.sqrt(0.75)])


def test_disconnected_graph_is_refused_naming_the_poses(small_graph, tmp_path: Path) -> None:
    # Edges join 0…29 in a ring; add 7 VERTEX lines (30…36) with no edges.
    path = tmp_path / "island.g2o"
    write_g2o(small_graph, path)
    extra = "".join(f"VERTEX_SE2 {k} 0 0 0\n" for k in range(30, 37))
    path.write_text(path.read_text() + extra)
    first_line = len(path.read_text().splitlines()) - 6  # the VERTEX line of pose 30
    with pytest.raises(DataFormatError) as caught:
        read_graph(path)
    message = str(caught.value)
    assert message.startswith(f"{path}:{first_line}: 7 of 37 poses (ids 30, 31, 32, 33, 34, …)")
    assert "not connected to vertex 0" in message


def test_disconnected_toro_equiv_names_the_file_ids(tmp_path: Path) -> None:
    # EQUIV 1 2 merges 2 into 1; poses 4 and 5 form an island, reported by their file ids.
    path = tmp_path / "equiv.graph"
    lines = [f"VERTEX2 {k} 0 0 0" for k in range(6)]
    lines += ["EDGE2 0 1 1 0 0 1 0 1 1 0 0", "EDGE2 2 3 1 0 0 1 0 1 1 0 0"]
    lines += ["EDGE2 4 5 1 0 0 1 0 1 1 0 0", "EQUIV 1 2"]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r":5: 2 of 5 poses \(ids 4, 5\) are not connected"):
        read_graph(path)


@pytest.mark.parametrize("method", ["lm", "gnc", "prop-v1"])
def test_every_method_refuses_a_disconnected_graph_alike(
    capsys: pytest.CaptureFixture, tmp_path: Path, method: str
) -> None:
    # Before the check gnc and prop-v1 stopped with "internal error (RuntimeError: Factor is
    # exactly singular)", exit 1, while lm solved it.
    path = tmp_path / "two.g2o"
    lines = [f"VERTEX_SE2 {k} {k} 0 0" for k in range(10)]
    lines += [f"EDGE_SE2 {k} {k + 1} 1 0 0 1 0 0 1 0 1" for k in (0, 1, 2, 3, 4, 6, 7, 8)]
    path.write_text("\n".join(lines) + "\n")
    assert cli.main(["solve", str(path), "--method", method, "--robots", "2"]) == 2
    err = capsys.readouterr().err
    assert err == (
        f"popbench: error: {path}:7: 4 of 10 poses (ids 6, 7, 8, 9) are not connected to vertex "
        "0 by any path of edges, so the graph has no single gauge: remove them or add edges\n"
    )
