"""mm-pgo's robust modes: outlier precision / recall per kernel, on Table II's problems or on
held-out synthetic problems (the rule that names Table II's kernel, docs/outliers.md).

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/bench_mm_pgo_robust.py
    (options: --problems datasets|synthetic --datasets intel,mit,csail --seeds 0 --rate 0.1
     --modes authors:huber,authors:gm,authors:welsch,project:gm --count 10)

``datasets``: Table II's cells (:func:`popbench.harness.outliers.corrupted_problem`: METIS split
into 7, outliers among the loop closures, odometry start), one line per (dataset, seed, mode),
and the number of outliers on inter-robot loop closures (the only ones the ``authors`` mode can
flag).
``synthetic``: ``--count`` held-out synthetic problems (V2, n = 7 robots × 60 poses, seeds
``HELDOUT_SEED_BASE + k``, none of Table II's cells), the same outlier model, odometry start;
per mode the pooled precision, recall and F1 = 2PR / (P + R) over all problems. Scores are over
the candidate set (the loop closures). Results go to ``docs/outliers.md`` by hand.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from baselines import mm_pgo
from popbench.graph import EdgeKind
from popbench.harness.heldout import HELDOUT_SEED_BASE
from popbench.harness.outliers import corrupted_problem
from popbench.methods import Budget
from popbench.outliers import candidate_mask, with_outliers
from popbench.problems.synthetic import make_problem


def counts(problem, mode: str, kernel: str, iterations: int) -> tuple[int, int, int, float]:
    """(true positives, flagged, true outliers) over the loop closures, and the wall time [s]."""
    result = mm_pgo.solve(problem, Budget(iterations=iterations), kernel=kernel, robust_mode=mode)
    among = candidate_mask(problem.graph, "loops")
    flagged, truth = ~result.inlier_mask & among, problem.outlier_mask & among
    return int((flagged & truth).sum()), int(flagged.sum()), int(truth.sum()), result.wall_s


def scores(hits: int, flagged: int, true: int) -> tuple[float, float, float]:
    """Precision, recall (1.0 for an empty denominator) and F1."""
    precision = hits / flagged if flagged else 1.0
    recall = hits / true if true else 1.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    return precision, recall, f1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", default="datasets", choices=("datasets", "synthetic"))
    parser.add_argument("--datasets", default="intel,mit,csail")
    parser.add_argument("--seeds", default="0")
    parser.add_argument("--count", type=int, default=10)
    parser.add_argument("--rate", type=float, default=0.1)
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--modes", default="authors:huber,authors:gm,authors:welsch,project:gm")
    args = parser.parse_args()
    modes = [tuple(item.split(":")) for item in args.modes.split(",")]
    if args.problems == "synthetic":
        problems = [
            with_outliers(make_problem(7, "V2", 60, seed=HELDOUT_SEED_BASE + k), args.rate, k)
            for k in range(args.count)
        ]
        for mode, kernel in modes:
            total = np.zeros(3, dtype=int)
            started = time.perf_counter()
            for problem in problems:
                total += counts(problem, mode, kernel, args.iterations)[:3]
            precision, recall, f1 = scores(*total)
            print(
                f"synthetic {mode:8s} {kernel:7s} P {precision:.3f} R {recall:.3f} F1 {f1:.3f} "
                f"(hits {total[0]}, flagged {total[1]}, outliers {total[2]}; "
                f"{time.perf_counter() - started:.1f} s)",
                flush=True,
            )
        return
    for dataset in args.datasets.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            problem = corrupted_problem(dataset, 7, args.rate, seed, "odometry")
            graph = problem.graph
            inter = int((problem.outlier_mask & (graph.kinds == EdgeKind.INTER_LOOP)).sum())
            print(
                f"{dataset:6s} seed {seed}: {inter} of the outliers are inter-robot loop closures"
            )
            for mode, kernel in modes:
                hits, flagged, true, wall = counts(problem, mode, kernel, args.iterations)
                precision, recall, _ = scores(hits, flagged, true)
                print(
                    f"{dataset:6s} seed {seed} {mode:8s} {kernel:7s} P {precision:.3f} "
                    f"R {recall:.3f} (hits {hits}, flagged {flagged}, outliers {true}; "
                    f"{wall:.1f} s)",
                    flush=True,
                )


if __name__ == "__main__":
    main()
