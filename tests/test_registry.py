"""Adding a method = one solve function + one record: a toy method, registered through the
registry only, runs in ``popbench solve`` and gets its row (and label) in a quick Table I."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from conftest import ring_g2o

from popbench import methods, objective
from popbench.cli import main
from popbench.harness.cache import cell_key, provenance
from popbench.harness.table1 import Table1Config


def solve_toy(problem, budget, seed: int = 0, step: float = 0.5, **_) -> methods.Result:
    """The toy method: one plain gradient-free move, halfway from the start to the odometry
    composition (a real method would iterate); it only has to honour the interface."""
    start = problem.graph.poses
    poses = start + step * (problem.graph.odometry_initial() - start)
    costs = objective.evaluate(problem.graph, poses)
    budget.round_done(1)
    history = np.array([objective.objective(problem.graph), costs.F])
    return methods.Result(
        poses, **costs._asdict(), wall_s=0.0, parallel_s=0.0, iterations=1, history=history
    )


@pytest.fixture
def toy(monkeypatch: pytest.MonkeyPatch, tmp_path):
    checkpoint = tmp_path / "toy.weights"
    checkpoint.write_bytes(b"toy weights")
    record = methods.MethodRecord(
        "toy", "test_registry:solve_toy", "Toy", checkpoint=str(checkpoint)
    )
    monkeypatch.setitem(methods.METHODS, "toy", record)
    return checkpoint


def test_a_registered_toy_method_gets_its_row_in_a_quick_table(toy, tmp_path, capsys) -> None:
    assert "toy" in Table1Config().methods  # a distributed method: in Table I by default
    assert methods.method_options("toy") == ("seed", "step")
    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    out = tmp_path / "table"
    # --jobs 1: in this process (spawned workers would not see a record added at run time)
    args = ["run", "table1", "--quick", "--datasets", str(graph), "--robots", "2", "--jobs", "1"]
    assert main([*args, "--methods", "toy,mm-pgo", "--iterations", "5", "--out", str(out)]) == 0
    frame = pd.read_csv(out / "table1.csv")
    assert list(frame["method"]) == ["toy", "mm-pgo"]
    row = frame.iloc[0]
    assert row["robots"] == 2 and row["init"] == "odometry" and row["iterations"] == 1
    assert row["gap"] == pytest.approx(row["F"] / row["F_star"] - 1.0)
    assert "n=2 Toy" in (out / "table1.md").read_text()  # the record's label
    assert "Toy" in (out / "table1.tex").read_text()
    # the checkpoint named by the record keys the cached cells
    before = cell_key(provenance(str(graph), "toy"))
    toy.write_bytes(b"toy weights, retrained")
    assert cell_key(provenance(str(graph), "toy")) != before


def test_a_registered_toy_method_solves_from_the_command_line(toy, tmp_path, capsys) -> None:
    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    assert main(["solve", str(graph), "--method", "toy", "-o", "step=1.0", "--json"]) == 0
    assert '"method": "toy"' in capsys.readouterr().out


def test_the_registered_records_say_what_table_i_and_table_ii_read() -> None:
    # Table I's defaults: the registered methods that are not centralised, local-lm included
    assert Table1Config().methods == (
        "cc-pgo",
        "ml-pgo",
        "mm-pgo",
        "prop-v1",
        "prop-v2",
        "local-lm",
    )
    gnc, local = methods.method_record("gnc"), methods.method_record("local-lm")
    assert gnc.centralised and gnc.has_inlier_mask and gnc.label == "GNC"
    assert not local.centralised and not local.learned and local.label == "local-lm"
    assert methods.get_method("local-lm").__module__ == "popbench.solvers.local_lm"
    assert "consensus" in methods.method_options("local-lm")
