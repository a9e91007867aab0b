"""Adding a method = one solve function + one record: a toy method, registered through the
registry only, runs in ``popbench solve`` and gets its row (and label) in a quick Table I."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import ring_g2o

from popbench import methods, objective
from popbench.cli import main
from popbench.harness.cache import cell_key, provenance
from popbench.harness.reports import number
from popbench.harness.table1 import Table1Config
from popbench.metrics import mean_ci
from popbench.solvers.initial import with_start


def solve_toy(problem, budget, seed: int = 0, step: float = 0.5, **_) -> methods.Result:
    """The toy method: one plain gradient-free move, halfway from the start to the chordal
    estimate (a real method would iterate; a move that raised F would be replaced by the start,
    popbench.methods.never_worse); it only has to honour the interface."""
    start = problem.graph.poses
    poses = start + step * (with_start(problem.graph, "chordal").poses - start)
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


def solve_toy_learned(problem, budget, checkpoint: str | None = None, **_) -> methods.Result:
    """A toy learned method: the toy's move with the step its "actor" file holds (seed 0's,
    the record's own, unless the harness names another training seed's)."""
    actor = checkpoint or methods.method_record("toy-learned").checkpoint_path()
    return solve_toy(problem, budget, step=float(Path(actor).read_text()))


@pytest.fixture
def toy_learned(monkeypatch: pytest.MonkeyPatch, tmp_path) -> list[Path]:
    actors = [tmp_path / f"step-s{seed}.txt" for seed in range(3)]
    # steps whose estimates are all below the start's F on the test's ring (0.25 and 0.5 are
    # above it: the registry would return the start for both, popbench.methods.never_worse)
    for actor, step in zip(actors, ("0.9", "0.95", "0.75"), strict=True):
        actor.write_text(step)
    record = methods.MethodRecord(
        "toy-learned",
        "test_registry:solve_toy_learned",
        "ToyL",
        checkpoint=str(actors[0]),
        seed_checkpoints=tuple(map(str, actors[1:])),
        learned=True,
    )
    monkeypatch.setitem(methods.METHODS, "toy-learned", record)
    return actors


def test_a_learned_method_runs_once_per_training_seed_in_table_i(toy_learned, tmp_path) -> None:
    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    out = tmp_path / "table"
    args = ["run", "table1", "--datasets", str(graph), "--robots", "2", "--jobs", "1"]
    args += ["--methods", "toy-learned,mm-pgo", "--iterations", "5"]
    args += ["--out", str(out)]
    assert main([*args, "--training-seeds", "0,1,2"]) == 0
    frame = pd.read_csv(out / "table1.csv")
    assert list(frame["method"]) == ["toy-learned"] * 3 + ["mm-pgo"]
    assert list(frame["training_seed"].iloc[:3]) == [0, 1, 2]
    assert np.isnan(frame["training_seed"].iloc[3])  # not a learned method: one cell
    learned = frame.iloc[:3]["F"].to_numpy()
    assert len(set(learned)) == 3  # each seed's own actor ran (different steps)
    mean, half = mean_ci(learned)
    table = (out / "table1.md").read_text()
    assert f"{number(mean)} ± {number(half)}" in table
    mm_pgo = frame.iloc[3]["F"]
    assert f"{number(mm_pgo)} ±" not in table and f"{number(mm_pgo)}" in table
    # each seed's cell is keyed by its own actor
    toy_learned[2].write_text("0.8")
    assert main([*args, "--training-seeds", "0,1,2"]) == 0
    again = pd.read_csv(out / "table1.csv")
    assert list(again["F"].iloc[:2]) == list(frame["F"].iloc[:2])
    assert again["F"].iloc[2] != frame["F"].iloc[2]


def test_a_training_seed_without_an_actor_is_refused(toy_learned, tmp_path, capsys) -> None:
    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    args = ["run", "table1", "--datasets", str(graph), "--robots", "2", "--jobs", "1"]
    args += ["--methods", "toy-learned", "--out", str(tmp_path / "t")]
    assert main([*args, "--training-seeds", "0,3"]) != 0
    assert "training seed of toy-learned" in capsys.readouterr().err
    toy_learned[1].unlink()
    assert main([*args, "--training-seeds", "1"]) != 0
    assert "training seed 1" in capsys.readouterr().err


def test_a_registered_toy_method_solves_from_the_command_line(toy, tmp_path, capsys) -> None:
    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    assert main(["solve", str(graph), "--method", "toy", "-o", "step=1.0", "--json"]) == 0
    assert '"method": "toy"' in capsys.readouterr().out


def test_table_i_and_table_ii_follow_the_records(monkeypatch: pytest.MonkeyPatch) -> None:
    """A record decides where its method runs: a distributed one joins Table I's defaults, a
    centralised one does not; one with an inlier mask joins Table II's methods."""
    from popbench.harness.outliers import OutliersConfig

    before = Table1Config().methods
    assert before and not any(methods.method_record(name).centralised for name in before)
    for name, centralised in (("toy-distributed", False), ("toy-centralised", True)):
        record = methods.MethodRecord(
            name, "test_registry:solve_toy", name, centralised=centralised
        )
        monkeypatch.setitem(methods.METHODS, name, record)
    assert Table1Config().methods == (*before, "toy-distributed")
    for name in OutliersConfig().methods:
        assert methods.method_record(name).has_inlier_mask, f"{name} cannot score outliers"


@pytest.mark.parametrize("name", sorted(methods.METHODS))
def test_every_record_names_what_exists(name: str) -> None:
    """Each record's solve function and options class import, its options are unique and its
    checkpoints (learned methods) are files: a typo in a record fails here, not in a table run."""
    record = methods.method_record(name)
    assert callable(methods.get_method(name))
    options = methods.method_options(name)
    assert len(set(options)) == len(options), f"{name} declares an option twice: {options}"
    assert record.refines is None or record.refines in methods.METHODS
    for seed in record.training_seeds:
        path = record.checkpoint_path(seed)
        assert path is not None and path.is_file(), f"{name}: no actor of training seed {seed}"
    assert record.learned == (record.checkpoint is not None)
