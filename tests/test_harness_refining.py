"""A refining method's cell (prop-v2) starts from the refined method's cached cell (prop-v1):
one prop-v1 solve per cell, computed on demand when missing, the same columns as the direct
computation; the runner's dependency order and the cached Result round trip."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from popbench.harness.cache import CellCache
from popbench.harness.executors import Execution, Run
from popbench.harness.runner import run_cells
from popbench.methods import Result
from popbench.threads import limited_threads

# ----- the layer itself (no dataset) --------------------------------------------------------------


def _result(n: int = 4) -> Result:
    rng = np.random.default_rng(0)
    return Result(
        poses=rng.normal(size=(n, 3)),
        F=1.25,
        F_chordal=1.0,
        chi2=2.5,
        wall_s=0.5,
        parallel_s=0.25,
        iterations=7,
        history=rng.normal(size=8),
        inlier_mask=np.array([True, False, True]),
        messages=11,
        extras={"actor_s": 0.125, "consensus_converged": True},
    )


def test_cached_result_round_trips_exactly_and_is_discarded(tmp_path):
    cache = CellCache(tmp_path)
    spec = {"dataset": "d", "method": "prop-v1"}
    assert cache.result(spec) is None
    stored = _result()
    cache.put_result(spec, stored)
    cache.put(spec, {"F": stored.F})
    loaded = cache.result(spec)
    assert loaded is not None
    np.testing.assert_array_equal(loaded.poses, stored.poses)
    np.testing.assert_array_equal(loaded.history, stored.history)
    np.testing.assert_array_equal(loaded.inlier_mask, stored.inlier_mask)
    assert (loaded.F, loaded.iterations, loaded.messages) == (1.25, 7, 11)
    assert loaded.extras == stored.extras
    cache.discard(spec)
    assert cache.result(spec) is None and cache.get(spec) is None


def stamped(spec):
    """A module-level cell (sent to worker processes): when it started and ended [s]."""
    started = time.time()
    time.sleep(0.3 if spec["name"] == "a" else 0.05)
    return {"name": spec["name"], "start": started, "end": time.time(), "pid": os.getpid()}


def _after_a(spec):
    return {"name": "a"} if spec["name"] == "b" else None


@pytest.mark.parametrize("execution", [Execution.serial(), Execution(jobs=2)])
def test_a_dependent_cell_waits_for_its_dependency(tmp_path, execution):
    specs = [{"name": "b"}, {"name": "c"}, {"name": "a"}]  # b starts from a, listed first
    rows = run_cells(
        specs,
        stamped,
        CellCache(tmp_path),
        execution=execution,
        progress=False,
        depends=_after_a,
    )
    by_name = {row["name"]: row for row in rows}
    assert [row["name"] for row in rows] == ["b", "c", "a"]  # rows in spec order
    assert by_name["b"]["start"] >= by_name["a"]["end"]


def stamped_method(spec):
    """A module-level cell of a method spec: prop-v1's is the slow one."""
    started = time.time()
    time.sleep(0.3 if spec["method"] == "prop-v1" else 0.05)
    return {"method": spec["method"], "start": started, "end": time.time()}


def test_every_experiment_orders_a_refiner_after_its_refined_cell(tmp_path):
    # scalability's cells, prop-v2 listed first: by default the runner waits for prop-v1's cell
    # (before, scalability ran them at once and prop-v2's worker computed prop-v1 again)
    from conftest import ring_g2o

    from popbench.harness.runner import run_experiment
    from popbench.harness.scalability import ScalabilityConfig, cell_specs

    graph = ring_g2o(tmp_path / "ring.g2o", n=12)
    config = ScalabilityConfig(dataset=str(graph), robots=(2,), methods=("prop-v2", "prop-v1"))
    run = Run(execution=Execution(jobs=2), progress=False)
    rows = run_experiment(tmp_path / "out", lambda: cell_specs(config), stamped_method, list, run)
    by_method = {row["method"]: row for row in rows}
    assert by_method["prop-v2"]["start"] >= by_method["prop-v1"]["end"]


def test_fresh_discards_a_cached_dependency_outside_the_run(tmp_path):
    cache = CellCache(tmp_path)
    cache.put({"name": "a"}, {"name": "a"})
    cache.put_result({"name": "a"}, _result())
    run_cells([{"name": "b"}], stamped, cache, progress=False, fresh=True, depends=_after_a)
    assert cache.get({"name": "a"}) is None and cache.result({"name": "a"}) is None


# ----- prop-v2 from prop-v1's cell (the mit quick table) ------------------------------------------

NON_TIME = ["F", "F_chordal", "chi2", "iterations", "messages"]


@pytest.fixture()
def counted_prop_v1(monkeypatch):
    """Count the prop-v1 solves of this process."""
    import agents.methods as prop

    calls: list[int] = []
    solve = prop.solve_prop_v1

    def counting(*args, **kwargs):
        calls.append(1)
        return solve(*args, **kwargs)

    monkeypatch.setattr(prop, "solve_prop_v1", counting)
    return calls


def _table(out, methods: tuple[str, ...]) -> dict[str, dict]:
    """The quick table's cached rows (exact, not the CSV's 10 digits) by method."""
    from popbench.harness.table1 import Table1Config, cell_specs, run_table1

    config = Table1Config.quick(out=out, methods=methods)
    run_table1(config, Run(fresh=True, progress=False))
    cache = CellCache(out / "cells")
    return {spec["method"]: cache.get(spec) for spec in cell_specs(config)}


@pytest.mark.dataset
@pytest.mark.slow
def test_prop_v2_starts_from_prop_v1s_cell(tmp_path, counted_prop_v1):
    from tests.conftest import require_dataset

    require_dataset("mit")
    from agents.methods import solve_prop_v2
    from popbench.harness import problems
    from popbench.harness.table1 import QUICK
    from popbench.methods import Budget

    both = _table(tmp_path / "both", ("prop-v1", "prop-v2"))
    assert len(counted_prop_v1) == 1  # prop-v2 read prop-v1's cached cell
    alone = _table(tmp_path / "alone", ("prop-v2",))
    assert len(counted_prop_v1) == 2  # computed on demand, once
    cells = tmp_path / "alone" / "cells"
    assert len(list(cells.glob("*.result.npz"))) == 1  # prop-v1's, cached for the next run
    assert len(list(cells.glob("*.json"))) == 3  # the optimum, prop-v2 and prop-v1

    problem = problems.distributed_problem("mit", QUICK["robots"][0], "odometry")
    with limited_threads(1):  # as the cells ran
        direct = solve_prop_v2(problem, Budget(iterations=QUICK["iterations"]))  # prop-v1 inside
    assert len(counted_prop_v1) == 3
    row = both["prop-v2"]
    assert [row[column] for column in NON_TIME] == [getattr(direct, c) for c in NON_TIME]
    assert [alone["prop-v2"][column] for column in NON_TIME] == [row[c] for c in NON_TIME]
    # its time is prop-v1's plus the LM's
    assert row["wall_s"] > both["prop-v1"]["wall_s"]
    assert row["parallel_s"] > both["prop-v1"]["parallel_s"]
