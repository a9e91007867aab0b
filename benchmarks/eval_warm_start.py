"""mm-pgo from a one-pass estimate against mm-pgo from odometry (popbench.solvers.warm_start).

For each dataset (n robots, METIS seed 0, odometry start, one process, one cell at a time):
mm-pgo from odometry, local-lm, prop-v1 and the two warm-started rows, each with the relative
gap ``F / F* − 1`` at the end, the simulated parallel time [s], and the parallel times to a gap
of 1e-1 / 1e-2 / 1e-3 (Table I's columns, popbench.harness.profiles). The warm-started rows
reuse the one-pass row's Result (as the harness does from its cache), so their time is that
row's plus mm-pgo's.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/eval_warm_start.py \\
        --datasets m3500,intel --robots 7 --iterations 1000
"""

from __future__ import annotations

import argparse

import numpy as np

from popbench.harness import problems, profiles
from popbench.methods import Budget, get_method

FIRST = {"prop-v1+mm-pgo": "prop-v1", "local-lm+mm-pgo": "local-lm"}
ROWS = ("mm-pgo", "local-lm", "prop-v1", "local-lm+mm-pgo", "prop-v1+mm-pgo")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", default="m3500,intel")
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--iterations", type=int, default=1000)
    args = parser.parse_args()
    budget = Budget(iterations=args.iterations)
    header = "dataset  method             gap_end   parallel_s  t(1e-1)  t(1e-2)  t(1e-3)"
    print(header)
    for dataset in args.datasets.split(","):
        problem = problems.distributed_problem(dataset, args.robots, "odometry", "metis", 0)
        optima = {"F": problems.optimum(dataset), "F_chordal": problems.chordal_optimum(dataset)}
        results = {}
        for row in ROWS:
            refined = results.get(FIRST.get(row, ""))
            options = {"refined": refined} if row in FIRST else {}
            results[row] = result = get_method(row)(problem, budget, seed=0, **options)
            times = profiles.time_to_gap(
                result.history, result.history_s, optima[result.history_objective]
            )
            gap = result.F / optima["F"] - 1.0
            cells = "  ".join("    –  " if np.isnan(t) else f"{t:7.2f}" for t in times)
            print(f"{dataset:8s} {row:17s} {gap:9.4g} {result.parallel_s:11.2f}  {cells}")


if __name__ == "__main__":
    main()
