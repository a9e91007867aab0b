"""CC-PGO and ML-PGO (RBCD on the rank-5 relaxation) against the published optima and GTSAM.

Prints, for each dataset × number of robots × method, after ``--iterations`` rounds (one round =
one colour class of non-adjacent robots updating in parallel, see ``baselines/rbcd/``):
F_chordal of the rounded estimate, its gap to the published certified optimum
(Dataset.chordal_optimum; SE-Sync, IJRR 2019, Table 1), the first round whose relaxed cost
(2f) was within 1e-3 of it, wall_s and parallel_s. Then:

* each baseline's wall time on m3500 and city10k (n = 7) divided by GTSAM 4.3 Levenberg–Marquardt's
  time on the same graph (default parameters, from the file's odometry estimate, pose 0 fixed by
  a tight prior; the best of 3 runs timed just before and 3 just after that dataset's runs, since
  the shared machine's load drifts), and beside it the *sparse-kernel floor*: the part of the same
  run spent inside its compiled sparse kernels (every CSR × multivector product — the tCG
  Hessian products, the candidate steps' products, the rounds' ``QY`` — and every Cholesky
  preconditioner solve), divided by the same GTSAM time. That is what 1000 rounds of this
  algorithm would cost with no interpreter overhead at all, so a floor ratio above the target
  means no rewrite of the Python glue can meet it;
* parallel_s of city10k at n = 3, 7, 35 (it should fall with n);
* F and F_chordal after the same number of rounds from the odometry start.

    .venv/bin/python benchmarks/bench_rbcd.py [--iterations 1000] [--datasets mit csail ...]
        [--robots 3 7 35] [--odometry intel mit m3500]

BLAS is pinned to one thread (the machine is shared; GTSAM runs single-threaded too).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import time  # noqa: E402
from collections.abc import Iterator  # noqa: E402

import numpy as np  # noqa: E402
from reference import (  # noqa: E402
    PUBLISHED_OPTIMA,
    TOLERANCE,
    first_within,
    gtsam_lm_seconds,
    relative_gap,
    split_problem,
)
from scipy.sparse import _sparsetools  # noqa: E402

from baselines.rbcd import blocks  # noqa: E402
from popbench.methods import Budget, Result, get_method  # noqa: E402

METHODS = ("cc-pgo", "ml-pgo")
RATIO_DATASETS = ("m3500", "city10k")  # wall time compared with GTSAM LM at n = 7


def best_gtsam_lm_seconds(name: str, repeats: int = 3) -> float:
    """Best of ``repeats`` wall times [s] of GTSAM LM on the dataset's file."""
    return min(gtsam_lm_seconds(name)[0] for _ in range(repeats))


@contextlib.contextmanager
def sparse_kernel_clock() -> Iterator[list[float]]:
    """Accumulate, in the yielded one-element list, the wall seconds spent in scipy's CSR ×
    multivector kernel (``csr_matvecs``, which every ``csr_matrix @ (n, r) array`` calls) and in
    RBCD's Cholesky preconditioner solves, while the block runs. Each call is timed whole; the
    clock adds two ``perf_counter`` reads per call (≈ 0.1 µs against ≥ 10 µs per kernel)."""
    total = [0.0]
    matvecs, solve = _sparsetools.csr_matvecs, blocks.CholeskyPreconditioner.solve

    def timed(kernel):
        def call(*args):
            start = time.perf_counter()
            out = kernel(*args)
            total[0] += time.perf_counter() - start
            return out

        return call

    _sparsetools.csr_matvecs = timed(matvecs)
    blocks.CholeskyPreconditioner.solve = timed(solve)
    try:
        yield total
    finally:
        _sparsetools.csr_matvecs, blocks.CholeskyPreconditioner.solve = matvecs, solve


def run(name: str, robots: int, method: str, iterations: int, init: str) -> Result:
    return get_method(method)(split_problem(name, robots, init), Budget(iterations=iterations))


def row(name: str, robots: int, method: str, result: Result) -> str:
    gap = relative_gap(name, result.F_chordal)
    reached = first_within(name, result.history)
    return (
        f"| {name} | {robots} | {method} | {result.F_chordal:.4f} | {gap:+.2e} | "
        f"{'yes' if gap < TOLERANCE else 'NO'} | {reached if reached is not None else '-'} | "
        f"{result.iterations} | {result.wall_s:.1f} | {result.parallel_s:.1f} |"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=1000)
    parser.add_argument("--datasets", nargs="+", default=list(PUBLISHED_OPTIMA))
    parser.add_argument("--robots", nargs="+", type=int, default=[3, 7, 35])
    parser.add_argument("--odometry", nargs="*", default=["intel", "mit", "m3500"])
    args = parser.parse_args()

    print(f"## chordal start, {args.iterations} rounds\n")
    print(
        "| dataset | n | method | F_chordal | rel gap | <1e-3 | first round <1e-3 (2f) "
        "| rounds | wall_s | parallel_s |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    results: dict[tuple[str, int, str], Result] = {}
    kernel_s: dict[tuple[str, str], float] = {}  # sparse-kernel seconds of the n = 7 ratio runs
    references: dict[str, float] = {}  # GTSAM LM, best of the timings before and after
    for name in args.datasets:
        timed = name in RATIO_DATASETS
        before = best_gtsam_lm_seconds(name) if timed else np.inf
        for robots in args.robots:
            for method in METHODS:
                with sparse_kernel_clock() as kernels:
                    result = run(name, robots, method, args.iterations, "chordal")
                if timed and robots == 7:
                    kernel_s[name, method] = kernels[0]
                results[name, robots, method] = result
                print(row(name, robots, method, result), flush=True)
        if timed:
            references[name] = min(before, best_gtsam_lm_seconds(name))

    print("\n## wall time / GTSAM LM time (n = 7)\n")
    print("| dataset | GTSAM LM s | method | wall_s | ratio | sparse kernels s | floor ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, reference in references.items():
        if (name, 7, METHODS[0]) not in results:
            continue
        for method in METHODS:
            wall, kernels = results[name, 7, method].wall_s, kernel_s[name, method]
            print(
                f"| {name} | {reference:.3f} | {method} | {wall:.1f} | {wall / reference:.1f}× "
                f"| {kernels:.2f} | {kernels / reference:.1f}× |"
            )

    print("\n## parallel_s on city10k against n\n")
    print("| method | " + " | ".join(f"n = {n}" for n in args.robots) + " |")
    print("|---|" + "---|" * len(args.robots))
    for method in METHODS:
        cells = [results.get(("city10k", n, method)) for n in args.robots]
        print(
            f"| {method} | " + " | ".join(f"{c.parallel_s:.1f}" if c else "-" for c in cells) + " |"
        )

    print(f"\n## odometry start, {args.iterations} rounds, n = 7\n")
    print("| dataset | method | F_chordal start (relaxed) | F | F_chordal | rel gap | wall_s |")
    print("|---|---|---|---|---|---|---|")
    for name in args.odometry:
        for method in METHODS:
            result = run(name, 7, method, args.iterations, "odometry")
            gap = relative_gap(name, result.F_chordal)
            print(
                f"| {name} | {method} | {result.history[0]:.4g} | {result.F:.4f} | "
                f"{result.F_chordal:.4f} | "
                f"{gap:+.2e} | {result.wall_s:.1f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
