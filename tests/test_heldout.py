"""popbench run heldout: rows, summary, JSON, cache."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pandas as pd
import pytest

from popbench.harness import heldout
from popbench.harness.executors import Run

ROWS = ("initial", "no-op", "random", "greedy", "expert", "gn-sweep", "local-lm", "ground-truth")
LADDER = ("gn-sweep", "learned-order", "imitation", "ga-sac")  # the learned parts, one by one


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("heldout")
    config = heldout.HeldoutConfig(robots=(3,), problems=3, poses_per_robot=12, rows=ROWS, out=out)
    return config, heldout.run_heldout(config, Run(progress=False))


def test_summary_rows_and_references(small_run):
    config, table = small_run
    assert list(table["row"]) == list(ROWS)
    by_row = table.set_index("row")
    assert by_row.loc["no-op", "median_ratio_to_noop"] == 1.0
    assert by_row.loc["no-op", "closed_F"] == 0.0
    assert by_row.loc["local-lm", "closed_F"] == pytest.approx(1.0)
    low, high = by_row.loc["no-op", "F_median_ci"]
    assert low <= by_row.loc["no-op", "F_median"] <= high
    # the ground truth through the consensus is far better than the odometry start
    assert by_row.loc["ground-truth", "F_median"] < by_row.loc["initial", "F_median"]
    # the expert brings every local graph to its optimum: the same copies as local-lm's
    frame = pd.read_csv(config.out / "heldout.csv").set_index(["problem_seed", "row"])
    expert, local = frame.xs("expert", level="row"), frame.xs("local-lm", level="row")
    assert np.allclose(expert["F_local"], local["F_local"], rtol=1e-4)
    for name in ("heldout.csv", "summary.csv", "heldout.md", "heldout.png", "manifest.json"):
        assert (config.out / name).is_file()


def test_json_summary_has_the_documented_fields(small_run):
    _, table = small_run
    rows = json.loads(heldout.summary_json(table))["rows"]
    assert [row["row"] for row in rows] == list(ROWS)
    for key in ("F_mean", "F_median", "F_median_ci", "ATE_mean", "median_ratio_to_noop"):
        assert key in rows[0]
    assert len(rows[0]["F_median_ci"]) == 2
    assert len(rows[0]["F_local_median_ci"]) == 2


def test_a_second_run_reuses_every_cell(small_run, monkeypatch):
    config, table = small_run
    monkeypatch.setattr(heldout, "compute_cell", lambda spec: pytest.fail("recomputed"))
    again = heldout.run_heldout(config, Run(progress=False))
    assert np.allclose(again["F_mean"], table["F_mean"])


def test_heldout_seeds_are_above_every_training_seed():
    config = heldout.HeldoutConfig(problems=2, rows=("initial",))
    seeds = [spec["problem_seed"] for spec in heldout.cell_specs(config)]
    assert min(seeds) >= 2**32  # envs.sampler.ProblemSampler draws 32-bit seeds


def test_the_consensus_budget_is_a_cell_option(tmp_path):
    base = heldout.HeldoutConfig(robots=(3,), problems=1, poses_per_robot=12, rows=("no-op",))
    assert "consensus_iterations" not in heldout.cell_specs(base)[0]  # earlier cells stay valid
    frames = {}
    for iterations in (1, 400):
        config = dataclasses.replace(
            base, consensus_iterations=iterations, out=tmp_path / str(iterations)
        )
        assert heldout.cell_specs(config)[0]["consensus_iterations"] == iterations
        heldout.run_heldout(config, Run(progress=False))
        frames[iterations] = pd.read_csv(config.out / "heldout.csv")
    assert frames[400]["F"].iloc[0] < frames[1]["F"].iloc[0]  # more ADMM iterations, lower F


def test_unknown_row_is_refused(tmp_path):
    from popbench.errors import ValueRangeError

    with pytest.raises(ValueRangeError, match="no-op"):
        heldout.run_heldout(heldout.HeldoutConfig(rows=("oracle",), out=tmp_path))


def test_outliers_add_the_gate_columns_to_the_learned_rows(tmp_path):
    config = heldout.HeldoutConfig(
        robots=(3,),
        problems=2,
        poses_per_robot=20,
        rows=("no-op", "imitation", "ga-sac"),
        out=tmp_path,
        outlier_rate=0.5,
    )
    specs = heldout.cell_specs(config)
    assert all(spec["outlier_rate"] == 0.5 for spec in specs)
    assert "outlier_rate" not in heldout.cell_specs(dataclasses.replace(config, outlier_rate=0))[0]
    table = heldout.run_heldout(config, Run(progress=False)).set_index("row")
    for row in ("imitation", "ga-sac"):
        assert 0.0 <= table.loc[row, "gate_auc"] <= 1.0
        assert 0.0 <= table.loc[row, "gate_precision"] <= 1.0
        assert 0.0 <= table.loc[row, "gate_recall"] <= 1.0
    assert np.isnan(table.loc["no-op", "gate_auc"])
    rows = json.loads(heldout.summary_json(table.reset_index()))["rows"]
    assert "gate_auc" in rows[-1] and len(rows[-1]["gate_auc_ci"]) == 2
    assert "ROC AUC" in (tmp_path / "heldout.md").read_text()


@pytest.fixture(scope="module")
def ladder_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ladder")
    config = heldout.HeldoutConfig(
        robots=(3,), problems=3, poses_per_robot=12, rows=LADDER, out=out
    )
    return config, heldout.run_heldout(config, Run(progress=False))


def test_learned_order_uses_the_imitation_actor_without_its_correction(ladder_run):
    config, table = ladder_run
    assert list(table["row"]) == list(LADDER)
    specs = {spec["row"]: spec for spec in heldout.cell_specs(config)}
    assert specs["learned-order"]["checkpoint"] == specs["imitation"]["checkpoint"]
    assert specs["ga-sac"]["checkpoint"] != specs["imitation"]["checkpoint"]
    frame = pd.read_csv(config.out / "heldout.csv").pivot(
        index="problem_seed", columns="row", values="F_local"
    )
    # the same actor's edges with and without its Δ, and the root-outward order: all differ
    assert not np.allclose(frame["learned-order"], frame["imitation"])
    assert not np.allclose(frame["learned-order"], frame["gn-sweep"])
    by_row = table.set_index("row")
    low, high = by_row.loc["learned-order", "F_local_median_ci"]
    assert low <= by_row.loc["learned-order", "F_local_median"] <= high
    assert "local F median" in (config.out / "heldout.md").read_text()


def test_paired_table_is_the_per_problem_difference(ladder_run):
    config, table = ladder_run
    pairs = pd.read_csv(config.out / "paired.csv")
    assert [tuple(p) for p in pairs[["A", "B"]].drop_duplicates().to_numpy()] == list(heldout.PAIRS)
    frame = pd.read_csv(config.out / "heldout.csv")
    wide = frame.pivot(index="problem_seed", columns="row", values="F_local")
    d = (wide["imitation"] - wide["learned-order"]).to_numpy()
    record = pairs.set_index(["A", "B", "metric"]).loc[("imitation", "learned-order", "F_local")]
    assert record["problems"] == 3
    assert record["diff_mean"] == pytest.approx(d.mean())
    assert record["diff_median"] == pytest.approx(np.median(d))
    assert record["A_lower"] == pytest.approx((d < 0).mean())
    json_pairs = json.loads(heldout.summary_json(table))["paired"]
    assert len(json_pairs) == len(pairs) and len(json_pairs[0]["diff_mean_ci"]) == 2
    assert "imitation − learned-order" in (config.out / "heldout.md").read_text()


def test_the_former_row_name_is_read_as_ga_sac(ladder_run):
    config, _ = ladder_run
    assert heldout.canonical_rows(("prop-v1", "imitation", "ga-sac")) == ("ga-sac", "imitation")
    frame = pd.read_csv(config.out / "heldout.csv").replace({"row": {"ga-sac": "prop-v1"}})
    assert "ga-sac" in set(heldout.summary(frame)["row"])  # a committed heldout.csv of before
    pairs = heldout.paired(frame)
    assert ("ga-sac", "imitation") in set(zip(pairs["A"], pairs["B"], strict=True))
