"""Did training move each algorithm off its untrained actor? From a `popbench plot curves` CSV.

Per algorithm and seed, the mean over the held-out problems of the final snapshot's change
against the same run's 0-frame snapshot (the untrained actor, scored on the same problems):
the normalised score (higher is better) and log(F_final / F_0) (lower is better); then the mean
over seeds with its 95 % Student-t interval (t₀.₉₇₅,ₙ₋₁ · s/√n). A change is called real when
the interval excludes 0.

    .venv/bin/python benchmarks/scratch_gain.py results/algorithms-scratch/curves.csv
"""

from __future__ import annotations

import argparse

import numpy as np
import pandas as pd
from scipy import stats


def seed_changes(records: pd.DataFrame) -> pd.DataFrame:
    """One row per (algorithm, start, seed): final frames, mean Δscore, mean Δlog F."""
    rows = []
    for (algorithm, start, seed), run in records.groupby(["algorithm", "start", "seed"]):
        first, last = run["frames"].min(), run["frames"].max()
        begin = run[run["frames"] == first].set_index("problem_seed")
        end = run[run["frames"] == last].set_index("problem_seed").loc[begin.index]
        row = {"algorithm": algorithm, "start": start, "seed": seed, "frames": last}
        row["d_score"] = float((end["score"] - begin["score"]).mean())
        row["d_log_F"] = float(np.log(end["F"] / begin["F"]).mean())
        rows.append(row)
    return pd.DataFrame(rows)


def interval(values: np.ndarray) -> tuple[float, float, float]:
    """(mean, low, high): the 95 % Student-t interval of the mean."""
    mean = float(values.mean())
    if len(values) < 2:
        return mean, float("nan"), float("nan")
    half = stats.t.ppf(0.975, len(values) - 1) * values.std(ddof=1) / np.sqrt(len(values))
    return mean, mean - half, mean + half


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("curves_csv")
    args = parser.parse_args()
    changes = seed_changes(pd.read_csv(args.curves_csv))
    print("| algorithm | start | seeds | frames | Δ score [95 % t] | Δ log F [95 % t] | real |")
    print("|---|---|---:|---:|---|---|---|")
    for (algorithm, start), group in changes.groupby(["algorithm", "start"]):
        score, score_low, score_high = interval(group["d_score"].to_numpy())
        log_f, log_low, log_high = interval(group["d_log_F"].to_numpy())
        real = "yes" if score_low > 0 or score_high < 0 else "no"
        print(
            f"| {algorithm} | {start} | {len(group)} | {int(group['frames'].max())} | "
            f"{score:+.3f} [{score_low:+.3f}, {score_high:+.3f}] | "
            f"{log_f:+.4f} [{log_low:+.4f}, {log_high:+.4f}] | {real} |"
        )


if __name__ == "__main__":
    main()
