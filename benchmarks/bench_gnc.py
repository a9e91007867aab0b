"""GNC benchmark: our ``gnc`` against GTSAM 4.3.0's GncLMOptimizer on Table II's cells, timed in
the same run (alternating which goes first), with the ratio of the times, the precision/recall
of both and the edges on which their flagged sets differ.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/bench_gnc.py
    (options: --datasets intel,csail,mit,m3500 --seeds 0,1,2 --rate 0.1 --surrogate tls
     --inner-start best --no-gtsam --before-tree DIR)

Each cell is Table II's problem (:func:`popbench.harness.outliers.corrupted_problem`: METIS
split into 7, outliers among the loop closures, odometry start). GTSAM gets the same start,
``BetweenFactor<Pose2>`` factors with diagonal sigmas ``(1/√τ, 1/√τ, 1/√κ)`` (so that its
whitened residual is eq. 1's up to Logmap), a prior with σ = 1e-6 on pose 0, the odometry edges
and the prior as known inliers, and the threshold at probability 0.99 (= ½χ²₃(0.99) on its
½‖e‖²); an edge is flagged when its final weight is < ½. Times are one run each: ours the whole
``gnc.solve`` (chordal start and sparse structure included), GTSAM's from the optimizer's
construction (its factor graph is built before the clock starts). ``ratio`` = ours / GTSAM.
A differing edge prints as ``id:kind:T|F`` (kind ``l`` loop / ``i`` inter-robot loop; T = an
injected outlier) followed by who flagged it (``ours`` or ``gtsam``).

``--before-tree DIR`` also times the ``gnc`` of another checkout (e.g. ``git worktree add DIR
<commit>``) on the same cells, in a subprocess per cell (its import not timed), and reports
whether its flagged set equals ours. Results go to ``docs/outliers.md`` by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from functools import partial

import numpy as np

from popbench import objective
from popbench.graph import EdgeKind, PoseGraph
from popbench.harness.outliers import corrupted_problem
from popbench.outliers import candidate_mask, precision_recall
from popbench.solvers import gnc

# Run by --before-tree's subprocess: time that checkout's gnc on one cell, print JSON.
_BEFORE = """
import json, sys, time
import numpy as np
from popbench.harness.outliers import corrupted_problem
from popbench.solvers import gnc
dataset, seed, rate, surrogate, start = sys.argv[1:]
problem = corrupted_problem(dataset, 7, float(rate), int(seed), "odometry")
began = time.perf_counter()
result = gnc.solve(problem, surrogate=surrogate, inner_start=start)
seconds = time.perf_counter() - began
print(json.dumps({"s": seconds, "flagged": np.flatnonzero(~result.inlier_mask).tolist()}))
"""


def gtsam_flags(graph: PoseGraph, surrogate: str) -> tuple[np.ndarray, float]:
    """GTSAM's flagged edges ``(M,)`` bool and its solve time [s] from ``graph.poses``."""
    import gtsam

    kappa, tau = objective.weights(graph.information)
    factors = gtsam.NonlinearFactorGraph()
    for k in range(graph.num_edges):
        sigmas = np.array([1.0 / np.sqrt(tau[k])] * 2 + [1.0 / np.sqrt(kappa[k])])
        factors.add(
            gtsam.BetweenFactorPose2(
                int(graph.tails[k]),
                int(graph.heads[k]),
                gtsam.Pose2(*graph.measurements[k]),
                gtsam.noiseModel.Diagonal.Sigmas(sigmas),
            )
        )
    prior = gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
    factors.add(gtsam.PriorFactorPose2(0, gtsam.Pose2(*graph.poses[0]), prior))
    values = gtsam.Values()
    for key, pose in enumerate(graph.poses):
        values.insert(key, gtsam.Pose2(*pose))
    params = gtsam.GncLMParams()
    params.setLossType(gtsam.GncLossType.TLS if surrogate == "tls" else gtsam.GncLossType.GM)
    known = np.flatnonzero(np.isin(graph.kinds, gnc.ODOMETRY_KINDS))
    params.setKnownInliers([*known.tolist(), graph.num_edges])
    started = time.perf_counter()
    optimizer = gtsam.GncLMOptimizer(factors, values, params)
    optimizer.setInlierCostThresholdsAtProbability(0.99)
    optimizer.optimize()
    seconds = time.perf_counter() - started
    return np.asarray(optimizer.getWeights())[: graph.num_edges] < 0.5, seconds


def before_flags(
    tree: str, dataset: str, seed: int, rate: float, surrogate: str, start: str, size: int
) -> tuple[np.ndarray, float]:
    """Flagged edges ``(size,)`` bool and solve time [s] of the ``gnc`` in checkout ``tree``."""
    env = {**os.environ, "PYTHONPATH": tree}
    args = [sys.executable, "-c", _BEFORE, dataset, str(seed), str(rate), surrogate, start]
    # cwd = tree: ``python -c`` puts the working directory first on sys.path
    done = subprocess.run(args, env=env, cwd=tree, capture_output=True, check=True)
    out = json.loads(done.stdout)
    flagged = np.zeros(size, dtype=bool)
    flagged[out["flagged"]] = True
    return flagged, out["s"]


def differing_edges(graph: PoseGraph, ours: np.ndarray, theirs: np.ndarray, truth: np.ndarray):
    """``id:kind:T|F:who`` for every edge flagged by exactly one of ``ours`` / ``theirs``."""
    letters = {EdgeKind.LOOP: "l", EdgeKind.INTER_LOOP: "i"}
    return [
        f"{k}:{letters.get(EdgeKind(graph.kinds[k]), '?')}:{'T' if truth[k] else 'F'}:"
        f"{'ours' if ours[k] else 'gtsam'}"
        for k in np.flatnonzero(ours != theirs)
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--datasets", default="intel,csail,mit,m3500")
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--rate", type=float, default=0.1)
    parser.add_argument("--surrogate", default="tls", choices=gnc.SURROGATES)
    parser.add_argument("--inner-start", default="best", choices=gnc.INNER_STARTS)
    parser.add_argument("--no-gtsam", action="store_true", help="Only our gnc.")
    parser.add_argument("--before-tree", help="Also time the gnc of this checkout.")
    args = parser.parse_args()
    print(
        "dataset seed outliers | ours: P R s rounds | gtsam: P R s | ratio | same flags"
        + (" | before: s same-as-ours" if args.before_tree else "")
    )
    totals: dict[str, list[float]] = {}
    for dataset in args.datasets.split(","):
        for index, seed in enumerate(int(s) for s in args.seeds.split(",")):
            problem = corrupted_problem(dataset, 7, args.rate, seed, "odometry")
            graph, truth, among = problem.graph, problem.outlier_mask, candidate_mask(problem.graph)
            runs = {
                "ours": partial(_ours, problem, args.surrogate, args.inner_start),
                "gtsam": partial(gtsam_flags, graph, args.surrogate),
            }
            if args.no_gtsam:
                runs.pop("gtsam")
            if args.before_tree:
                cell = (dataset, seed, args.rate, args.surrogate, args.inner_start)
                runs["before"] = partial(before_flags, args.before_tree, *cell, graph.num_edges)
            order = list(runs) if index % 2 == 0 else list(reversed(runs))  # alternate
            done = {name: runs[name]() for name in order}
            (ours, rounds), seconds = done["ours"]
            precision, recall = precision_recall(ours, truth, among)
            line = (
                f"{dataset} {seed} {int(truth.sum())} | {precision:.3f} {recall:.3f} "
                f"{seconds:.2f} {rounds}"
            )
            sums = totals.setdefault(dataset, [0.0, 0.0, 0.0, 0, 0])
            sums[0] += seconds
            sums[3] += 1
            if "gtsam" in done:
                theirs, their_seconds = done["gtsam"]
                precision, recall = precision_recall(theirs, truth, among)
                same = bool(np.array_equal(ours, theirs))
                line += (
                    f" | {precision:.3f} {recall:.3f} {their_seconds:.2f} | "
                    f"{seconds / their_seconds:.2f} | {same} "
                    + " ".join(differing_edges(graph, ours, theirs, truth))
                )
                sums[1] += their_seconds
                sums[4] += same
            if "before" in done:
                flagged, before_seconds = done["before"]
                line += f" | {before_seconds:.2f} {bool(np.array_equal(flagged, ours))}"
                sums[2] += before_seconds
            print(line, flush=True)
    if not args.no_gtsam:
        print("dataset: Σ ours s, Σ gtsam s, ratio of sums, same flags / cells, Σ before s")
        for dataset, (ours_s, gtsam_s, before_s, cells, same) in totals.items():
            print(
                f"{dataset}: {ours_s:.2f} {gtsam_s:.2f} {ours_s / gtsam_s:.2f} {same}/{cells} "
                f"{before_s:.2f}"
            )


def _ours(problem, surrogate: str, inner_start: str) -> tuple[tuple[np.ndarray, int], float]:
    """Our flagged edges, rounds and solve time [s] (``wall_s``)."""
    result = gnc.solve(problem, surrogate=surrogate, inner_start=inner_start)
    return (~result.inlier_mask, result.iterations), result.wall_s


if __name__ == "__main__":
    main()
