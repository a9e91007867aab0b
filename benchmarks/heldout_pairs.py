"""Paired held-out differences of one row against another, across two held-out folders.

A ``popbench run heldout`` folder of a fine-tuned actor (``--rows ga-sac``) and the folder of its
start (``--rows ...,imitation,...``) hold the same problems; this prints the paired differences
(A − B per problem, bootstrap 95 % CIs; popbench.harness.heldout.paired) of F, ATE and the
robots' local F, without recomputing a cell.

    .venv/bin/python benchmarks/heldout_pairs.py results/heldout-residual-ft8k/anchor1-s0 \\
        results/heldout-residual-s0 [--a ga-sac] [--b imitation]
"""

from __future__ import annotations

import argparse

import pandas as pd

from popbench.harness.heldout import paired

METRICS = ("F", "ATE", "F_robots")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder_a", help="held-out folder holding row A")
    parser.add_argument("folder_b", help="held-out folder holding row B (the same problems)")
    parser.add_argument("--a", default="ga-sac", help="row A (read from folder_a)")
    parser.add_argument("--b", default="imitation", help="row B (read from folder_b)")
    args = parser.parse_args()
    rows_a = pd.read_csv(f"{args.folder_a}/heldout.csv")
    rows_b = pd.read_csv(f"{args.folder_b}/heldout.csv")
    frame = pd.concat([rows_a[rows_a.row == args.a], rows_b[rows_b.row == args.b]])
    table = paired(frame, pairs=((args.a, args.b),))
    print(f"{args.a} ({args.folder_a}) - {args.b} ({args.folder_b}), paired per problem:")
    for _, row in table[table.metric.isin(METRICS)].iterrows():
        low, high = row.diff_median_ci
        mean_low, mean_high = row.diff_mean_ci
        print(
            f"  {row.metric:9s} median {row.diff_median:+.4g} [{low:+.4g}, {high:+.4g}]"
            f"  mean {row.diff_mean:+.4g} [{mean_low:+.4g}, {mean_high:+.4g}]"
            f"  A lower on {100 * row.A_lower:.0f} % of {row.problems} problems"
        )


if __name__ == "__main__":
    main()
