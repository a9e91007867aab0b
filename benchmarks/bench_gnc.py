"""GNC benchmark: our ``gnc`` against GTSAM 4.3.0's GncLMOptimizer on Table II's cells, in the
same run, and the precision/recall of both.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/bench_gnc.py
    (options: --datasets intel,csail,mit --seeds 0,1,2,3,4 --rate 0.1 --surrogate tls
     --no-gtsam)

Each cell is Table II's problem (:func:`popbench.harness.outliers.corrupted_problem`: METIS
split into 7, outliers among the loop closures, odometry start). GTSAM gets the same start,
``BetweenFactor<Pose2>`` factors with diagonal sigmas ``(1/√τ, 1/√τ, 1/√κ)`` (so that its
whitened residual is eq. 1's up to Logmap), a prior with σ = 1e-6 on pose 0, the odometry edges
and the prior as known inliers, and the threshold at probability 0.99 (= ½χ²₃(0.99) on its
½‖e‖²); an edge is flagged when its final weight is < ½. Times are one run each, whole solve
(ours includes building the sparse structure and the METIS ordering at every inner solve), on a
shared machine. Results go to ``docs/outliers.md`` by hand.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from popbench import objective
from popbench.graph import PoseGraph
from popbench.harness.outliers import corrupted_problem
from popbench.outliers import candidate_mask, precision_recall
from popbench.solvers import gnc


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--datasets", default="intel,csail,mit")
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--rate", type=float, default=0.1)
    parser.add_argument("--surrogate", default="tls", choices=gnc.SURROGATES)
    parser.add_argument("--no-gtsam", action="store_true", help="Only our gnc.")
    args = parser.parse_args()
    print("dataset seed outliers | ours: P R s rounds | gtsam: P R s | same flags")
    for dataset in args.datasets.split(","):
        for seed in (int(s) for s in args.seeds.split(",")):
            problem = corrupted_problem(dataset, 7, args.rate, seed, "odometry")
            truth, among = problem.outlier_mask, candidate_mask(problem.graph)
            result = gnc.solve(problem, surrogate=args.surrogate)
            ours = ~result.inlier_mask
            precision, recall = precision_recall(ours, truth, among)
            line = (
                f"{dataset} {seed} {int(truth.sum())} | {precision:.3f} {recall:.3f} "
                f"{result.wall_s:.1f} {result.iterations}"
            )
            if not args.no_gtsam:
                theirs, seconds = gtsam_flags(problem.graph, args.surrogate)
                precision, recall = precision_recall(theirs, truth, among)
                same = bool(np.array_equal(ours, theirs))
                line += f" | {precision:.3f} {recall:.3f} {seconds:.1f} | {same}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
