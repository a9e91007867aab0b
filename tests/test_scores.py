"""The normalised per-problem score (popbench.harness.scores) and rliable's metrics on the export
(popbench.harness.stratified, popbench.harness.comparison), against rliable itself.

rliable's metrics module (IQM, probability of improvement) is the reference; its bootstrap
(rliable.library) cannot be imported next to pandas 3 (docs/algorithms.md), so the bootstrap
replicates are checked by applying rliable's metrics to the same resampled matrices.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from popbench.errors import ValueRangeError
from popbench.harness import comparison, stratified
from popbench.harness.curves import marl_eval_json
from popbench.harness.heldout import HELDOUT_SEED_BASE
from popbench.harness.scores import normalised, optimum

metrics = pytest.importorskip("rliable.metrics")

PROBLEMS = 40
SEEDS = 3


def problems(count: int) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "noise": "V2",
            "robots": 3,
            "poses_per_robot": 10,
            "problem_seed": HELDOUT_SEED_BASE + np.arange(count),
        }
    )


def test_optimum_is_lm_s_reference_and_the_score_runs_from_gn_sweep_to_it() -> None:
    from popbench.problems.synthetic import make_problem
    from popbench.solvers.lm import reference_optimum

    keys = problems(2)
    best = optimum(keys)
    assert (
        best.iloc[1]
        == reference_optimum(make_problem(3, "V2", 10, seed=keys.problem_seed[1]).graph).F
    )
    star = best.to_numpy()
    zero = keys.assign(F=star + 10.0)
    rows = pd.concat([keys.assign(F=star + 10.0), keys.assign(F=star), keys.assign(F=star + 12.5)])
    scored = normalised(rows, zero, best)
    assert np.allclose(scored["score"], [0, 0, 1, 1, -0.25, -0.25])
    assert np.allclose(scored["F_zero"] - scored["F_optimum"], 10.0)

    with pytest.raises(ValueRangeError, match="gn-sweep") as missing:
        normalised(rows, zero.iloc[:1], best)
    assert "\n" not in str(missing.value)
    with pytest.raises(ValueRangeError, match="below its optimum") as below:
        normalised(keys.assign(F=star - 1.0), zero, best)
    assert "\n" not in str(below.value)


def final_records(rng: np.random.Generator) -> pd.DataFrame:
    """Final scores of 3 algorithms × SEEDS seeds on PROBLEMS problems, one start."""
    shift = {"ga-sac": 0.0, "ippo": 0.05, "mappo": 0.3}
    difficulty = rng.normal(size=PROBLEMS)  # shared by the algorithms: problems as tasks
    frames = []
    for algorithm, offset in shift.items():
        for seed in range(SEEDS):
            score = difficulty + offset + rng.normal(scale=0.5, size=PROBLEMS)
            frames.append(
                pd.DataFrame(
                    {
                        "task": "V2-n3",
                        "algorithm": algorithm,
                        "start": "scratch",
                        "seed": seed,
                        "frames": 4096,
                        "problem_seed": HELDOUT_SEED_BASE + np.arange(PROBLEMS),
                        "F": 100 - score,
                        "ATE": 1.0,
                        "score": score,
                    }
                )
            )
    return pd.concat(frames, ignore_index=True)


def matrices_from_export(layout: dict) -> dict[str, np.ndarray]:
    """(runs × tasks) matrices of the absolute score, as marl-eval's create_matrices_for_rliable
    builds them from the JSON."""
    tasks = sorted(layout["popbench"])
    algorithms = layout["popbench"][tasks[0]]
    out = {}
    for algorithm in algorithms:
        runs = sorted(algorithms[algorithm])
        out[algorithm] = np.array(
            [
                [
                    np.mean(layout["popbench"][task][algorithm][run]["absolute_metrics"]["score"])
                    for task in tasks
                ]
                for run in runs
            ]
        )
    return out


def test_rliable_reads_the_export_with_problems_as_tasks() -> None:
    final = final_records(np.random.default_rng(3))
    exported = matrices_from_export(marl_eval_json(final, frames=[4096]))
    assert {m.shape for m in exported.values()} == {(SEEDS, PROBLEMS)}

    iqms = comparison.iqm_table(final).set_index("algorithm")
    improvements = comparison.improvement_table(final).set_index(["a", "b"])
    for algorithm, matrix in exported.items():
        name = algorithm.removesuffix("-scratch")
        assert iqms.loc[name, "value"] == pytest.approx(metrics.aggregate_iqm(matrix))
    for (a, b), row in improvements.iterrows():
        expected = metrics.probability_of_improvement(
            exported[f"{a}-scratch"], exported[f"{b}-scratch"]
        )
        assert row["value"] == pytest.approx(expected)
        assert row["lo_runs"] <= row["value"] <= row["hi_runs"]
        assert row["lo_seeds"] <= row["lo_runs"] and row["hi_runs"] <= row["hi_seeds"] + 0.05
    # a shift of 0.3 against noise 0.5 on 40 problems × 3 seeds is found; 0.05 is not
    assert improvements.loc[("mappo", "ga-sac"), "lo_runs"] > 0.5
    assert improvements.loc[("ippo", "ga-sac"), "lo_runs"] < 0.5


def test_bootstrap_replicates_are_rliable_s_metrics_of_stratified_resamples() -> None:
    rng = np.random.default_rng(5)
    x, y = rng.normal(size=(SEEDS, 12)), rng.normal(size=(4, 12))
    y[:, 0] = x[0, 0]  # ties count one half, as in rliable's Mann–Whitney U
    draws = np.random.default_rng(0)
    xs, ys = (stratified.resample(m, 20, draws) for m in (x, y))
    for column in range(12):  # runs drawn within each task: every column from its own column
        assert np.isin(xs[:, :, column], x[:, column]).all()
    expected = [metrics.probability_of_improvement(a, b) for a, b in zip(xs, ys, strict=True)]
    assert np.allclose(stratified.improvement(xs, ys), expected)
    assert np.allclose(stratified.iqm(xs), [metrics.aggregate_iqm(a) for a in xs])
    taus = np.array([-1.0, 0.0, 0.5])
    assert np.allclose(stratified.profile(x, taus), [np.mean(x > tau) for tau in taus])

    columns = draws.integers(0, 12, (20, 1, 12))
    shared = stratified.resample(x, 20, draws, columns)  # "seeds": one run draw for all tasks
    for copy, cols in zip(shared, columns[:, 0], strict=True):
        rows = [int(np.flatnonzero(x[:, cols[0]] == copy[i, 0])[0]) for i in range(SEEDS)]
        assert np.array_equal(copy, x[np.ix_(rows, cols)])
