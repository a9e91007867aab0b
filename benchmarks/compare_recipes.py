"""Two training recipes on the same held-out problems, each over its seeds: one learned row of
``popbench run heldout`` tables, one table per seed, paired problem by problem.

For each recipe, each seed's median F, robots' local F and ATE; then recipe B − recipe A on
each problem, where a recipe's value on a problem is the median over its seeds (so a seed that
fails on one problem does not decide it), with the paired statistics of
``popbench.harness.heldout.paired`` (bootstrap 95 % CIs that resample whole problems).

    python benchmarks/compare_recipes.py --row ga-sac \\
        --a v2=runs/v2-s0/heldout.csv,runs/v2-s1/heldout.csv --b slam=runs/slam-s1/heldout.csv

Used for the choice of prop-v1's default recipe (docs/training.md).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from popbench.harness.heldout import PAIRED_METRICS, paired


def recipe_frame(name: str, tables: list[Path], row: str) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``(per_seed, per_problem)``: the row's medians per seed table, and its per-problem
    median over the seed tables (row renamed ``name``; problems every table holds)."""
    frames = []
    for seed, path in enumerate(tables):
        frame = pd.read_csv(path)
        frames.append(frame[frame["row"] == row].assign(seed=seed, table=str(path)))
    joined = pd.concat(frames)
    metrics = [metric for metric in PAIRED_METRICS if metric in joined]
    per_seed = joined.groupby("table", sort=False)[metrics].median().reset_index()
    counts = joined.groupby("problem_seed")["seed"].nunique()
    complete = joined[joined["problem_seed"].isin(counts[counts == len(tables)].index)]
    keys = ["noise", "robots", "problem_seed"]
    per_problem = complete.groupby(keys)[metrics].median().reset_index().assign(row=name)
    return per_seed.assign(recipe=name), per_problem


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--row", default="ga-sac", help="the learned row to compare")
    parser.add_argument("--a", required=True, help="NAME=table.csv,table.csv,… (one per seed)")
    parser.add_argument("--b", required=True, help="NAME=table.csv,… (one per seed)")
    args = parser.parse_args()
    seeds, problems = [], []
    for spec in (args.a, args.b):
        name, paths = spec.split("=", 1)
        per_seed, per_problem = recipe_frame(name, [Path(p) for p in paths.split(",")], args.row)
        seeds.append(per_seed)
        problems.append(per_problem)
    (name_a, name_b) = (spec.split("=", 1)[0] for spec in (args.a, args.b))
    table = paired(pd.concat(problems), ((name_b, name_a),))
    with pd.option_context("display.width", 200, "display.max_columns", 30):
        print(f"row {args.row}: medians per seed table")
        print(pd.concat(seeds).to_string(index=False, float_format=lambda v: f"{v:.4g}"))
        print(f"\n{name_b} - {name_a}, per problem (each recipe: the median over its seeds)")
        print(table.to_string(index=False, float_format=lambda value: f"{value:.4g}"))


if __name__ == "__main__":
    main()
