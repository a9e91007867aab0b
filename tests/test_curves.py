"""Held-out learning curves over runs (popbench.harness.curves, `popbench plot curves RUN…`):
snapshots scored on held-out problems, seed aggregation, marl-eval's layout.

Two tiny MAPPO runs (3 robots × 10 poses, 32 frames) scored on 2 held-out problems; seconds.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy import stats
from test_ppo import tiny

from popbench.harness.curves import aggregate, marl_eval_json, score_run
from popbench.harness.heldout import HELDOUT_SEED_BASE


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> list:
    from agents.config import with_overrides
    from agents.trainer import train

    folders = []
    for seed in (0, 1):
        out = tmp_path_factory.mktemp(f"mappo-s{seed}")
        train(with_overrides(tiny(out, "mappo", 32), [f"experiment.seed={seed}"]))
        folders.append(out)
    return folders


def records(seeds: dict[int, list[float]], frames: int = 0) -> pd.DataFrame:
    """Curve records of one algorithm: per seed, F (and ATE = F / 100) on problems 0, 1, …"""
    return pd.DataFrame(
        [
            {
                "task": "V2-n3",
                "algorithm": "mappo",
                "start": "scratch",
                "seed": seed,
                "frames": frames,
                "problem_seed": HELDOUT_SEED_BASE + k,
                "F": f,
                "ATE": f / 100,
            }
            for seed, values in seeds.items()
            for k, f in enumerate(values)
        ]
    )


def test_seed_mean_and_t_interval_of_the_runs_statistics() -> None:
    # per-seed median F over the first 3 problems: 2, 5, 11 (the 4th problem is left out)
    table = aggregate(records({0: [1, 2, 3, 100], 1: [5, 4, 6, 100], 2: [11, 10, 12, -9]}), 3)
    (row,) = table.itertuples()
    medians = np.array([2.0, 5.0, 11.0])
    half = stats.t.ppf(0.975, 2) * medians.std(ddof=1) / np.sqrt(3)
    assert row.seeds == 3 and row.F == pytest.approx(6.0)
    assert (row.F_lo, row.F_hi) == pytest.approx((6.0 - half, 6.0 + half))
    means = np.array([2.0, 5.0, 11.0]) / 100  # mean ATE of (1, 2, 3)/100 etc.
    assert row.ATE == pytest.approx(means.mean())


def test_a_run_scored_on_fewer_problems_is_refused() -> None:
    with pytest.raises(Exception, match="at least --problems 3"):
        aggregate(records({0: [1, 2, 3], 1: [1, 2]}), 3)


def test_marl_eval_layout_negates_lower_is_better_metrics() -> None:
    both = pd.concat([records({0: [1, 2, 3]}), records({0: [4, 5, 6]}, frames=64)])
    layout = marl_eval_json(both, problems=2)
    run = layout["popbench"]["V2-n3"]["mappo-scratch"]["run_0"]
    assert run["step_0"] == {"step_count": 0, "neg_F": [-1, -2], "neg_ATE": [-0.01, -0.02]}
    assert run["step_1"]["step_count"] == 64
    assert run["absolute_metrics"]["neg_F"] == [-4, -5, -6]  # every problem of the final actor


def test_runs_scored_aggregated_and_exported(runs, tmp_path, capsys) -> None:
    from popbench.cli import main

    out, reference = tmp_path / "curves", tmp_path / "reference"
    reference.mkdir()
    classical = records({0: [7.0, 9.0]}).assign(row="gn-sweep", noise="V2", robots=3)
    classical.to_csv(reference / "heldout.csv", index=False)
    args = ["--problems", "2", "--out", str(out), "--reference", str(reference)]
    code = main(["plot", "curves", *map(str, runs), *args])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert {Path(path).name for path in captured.out.split()} == {
        "curves.csv",
        "curves.md",
        "curves.marl-eval.json",
        "curves.png",
        "curves.pdf",
    }
    scored = pd.read_csv(out.with_suffix(".csv"))
    assert sorted(scored["frames"].unique()) == [0, 32]  # the start and the end snapshot
    assert len(scored) == 2 * 2 * 2  # runs × snapshots × problems
    assert set(scored["seed"]) == {0, 1} and set(scored["start"]) == {"scratch"}
    assert np.isfinite(scored[["F", "ATE"]].to_numpy()).all()
    layout = json.loads(out.with_suffix(".marl-eval.json").read_text())
    assert set(layout["popbench"]["V2-n3"]["mappo-scratch"]) == {"run_0", "run_1"}
    table = out.with_suffix(".md").read_text()
    assert "| mappo | scratch | 32 | 2 |" in table
    assert "| gn-sweep | — | 1 | 8.0 | 0.080 |" in table  # median F, mean ATE of the reference

    # a second call reads RUN/curve.csv instead of scoring again
    cached = [pd.read_csv(run / "curve.csv") for run in runs]
    for run in runs:
        (run / "curve-cells").rename(run / "moved-away")
    again = pd.concat([score_run(run, 2) for run in runs], ignore_index=True)
    pd.testing.assert_frame_equal(again, pd.concat(cached, ignore_index=True))


def test_files_and_folders_together_are_a_one_line_error(runs, capsys) -> None:
    from popbench.cli import main

    code = main(["plot", "curves", str(runs[0]), str(runs[0] / "metrics.csv")])
    err = capsys.readouterr().err
    assert (
        code != 0 and "all CSV files or all folders" in err and len(err.strip().splitlines()) == 1
    )
