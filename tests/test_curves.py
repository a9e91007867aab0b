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


def test_marl_eval_layout_problems_as_tasks_steps_after_the_start() -> None:
    snapshots = [records({0: [1, 2, 3]}, frames=f) for f in (0, 64, 128)]
    layout = marl_eval_json(pd.concat(snapshots), problems=2)
    assert sorted(layout["popbench"]) == ["V2-n3-p0000", "V2-n3-p0001"]  # the first 2 problems
    run = layout["popbench"]["V2-n3-p0001"]["mappo-scratch"]["run_0"]
    assert list(run) == ["step_0", "step_1", "absolute_metrics"]
    assert run["step_0"] == {"step_count": 64, "neg_F": [-2.0], "neg_ATE": [-0.02]}
    assert run["absolute_metrics"] == {"neg_F": [-2.0], "neg_ATE": [-0.02]}
    # marl-eval's evaluation interval: the mean gap from 0 frames to each step_count; its
    # x-axis draws step i at i × interval, so the interval must be the snapshots' gap
    counts = [run[f"step_{i}"]["step_count"] for i in range(2)]
    assert np.mean(np.diff([0, *counts])) == 64
    final = marl_eval_json(snapshots[-1], frames=[128])  # every problem of the final actor
    assert len(final["popbench"]) == 3


def test_runs_scored_aggregated_and_exported(runs, tmp_path, capsys) -> None:
    from popbench.cli import main

    out, reference = tmp_path / "curves", tmp_path / "reference"
    reference.mkdir()
    # a gn-sweep row far above any F of these problems (the score's zero), and local-lm
    classical = pd.concat(
        [
            records({0: [1e4, 2e4]}).assign(row="gn-sweep"),
            records({0: [1e3, 1e3]}).assign(row="local-lm"),
        ]
    ).assign(noise="V2", robots=3)
    classical.to_csv(reference / "heldout.csv", index=False)
    args = ["--problems", "2", "--out", str(out), "--reference", str(reference)]
    code = main(["plot", "curves", *map(str, runs), *args])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert {Path(path).name for path in captured.out.split()} == {
        "curves.csv",
        "curves.md",
        "curves.marl-eval.json",
        "curves.learning.marl-eval.json",
        "curves.png",
        "curves.pdf",
        "curves-comparison.png",
        "curves-comparison.pdf",
    }
    scored = pd.read_csv(out.with_suffix(".csv"))
    assert sorted(scored["frames"].unique()) == [0, 32]  # the start and the end snapshot
    assert len(scored) == 2 * 2 * 2  # runs × snapshots × problems
    assert set(scored["seed"]) == {0, 1} and set(scored["start"]) == {"scratch"}
    assert np.isfinite(scored[["F", "ATE", "score"]].to_numpy()).all()
    assert (scored["F_optimum"] <= scored["F"]).all() and (scored["score"] < 1).all()
    zero = scored["problem_seed"].map({HELDOUT_SEED_BASE: 1e4, HELDOUT_SEED_BASE + 1: 2e4})
    gap = zero - scored["F_optimum"]
    assert np.allclose(scored["score"], (zero - scored["F"]) / gap)
    layout = json.loads(out.with_suffix(".marl-eval.json").read_text())
    assert set(layout["popbench"]["V2-n3-p0000"]["mappo-scratch"]) == {"run_0", "run_1"}
    table = out.with_suffix(".md").read_text()
    assert "| mappo | scratch | 32 | 2 |" in table
    assert "| gn-sweep | — | 1 | 15000.0 | 150.000 | 0.000 |" in table  # median F, ATE, score
    assert "| mappo | scratch | 2 | 2 |" in table  # the IQM table: 2 seeds, 2 problems

    # a second call reads RUN/curve.csv instead of scoring again
    cached = [pd.read_csv(run / "curve.csv") for run in runs]
    for run in runs:
        (run / "curve-cells").rename(run / "moved-away")
    again = pd.concat([score_run(run, 2) for run in runs], ignore_index=True)
    pd.testing.assert_frame_equal(again, pd.concat(cached, ignore_index=True))


def test_a_run_given_twice_is_a_one_line_error(runs, tmp_path, capsys) -> None:
    import shutil

    from popbench.cli import main

    copy = tmp_path / "copy"
    shutil.copytree(runs[0], copy)
    code = main(["plot", "curves", str(runs[0]), str(runs[1]), str(copy)])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"{runs[0]} and {copy}" in err and "mappo from scratch, seed 0" in err


def test_training_csvs_of_equal_names_are_lines_named_by_folder(runs, tmp_path, capsys) -> None:
    from popbench.cli import main
    from popbench.plotting import line_labels

    files = [run / "metrics.csv" for run in runs]
    assert line_labels(files) == [run.name for run in runs]
    assert line_labels([files[0], tmp_path / "other.csv"]) == ["metrics", "other"]
    code = main(["plot", "curves", *map(str, files), "--out", str(tmp_path / "ab")])
    assert code == 0 and (tmp_path / "ab.png").is_file()
    code = main(["plot", "curves", str(files[0]), str(files[0]), "--out", str(tmp_path / "a")])
    err = capsys.readouterr().err
    assert code == 2 and "each file once" in err and len(err.strip().splitlines()) == 1


def test_files_and_folders_together_are_a_one_line_error(runs, capsys) -> None:
    from popbench.cli import main

    code = main(["plot", "curves", str(runs[0]), str(runs[0] / "metrics.csv")])
    err = capsys.readouterr().err
    assert (
        code != 0 and "all CSV files or all folders" in err and len(err.strip().splitlines()) == 1
    )
