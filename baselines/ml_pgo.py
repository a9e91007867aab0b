"""ML-PGO: multilevel partitioning + accelerated RBCD with adaptive restart (Li et al. 2024).

What distinguishes ML-PGO from CC-PGO is (1) how the poses are split among the robots: a
multilevel graph partitioner (coarsen → partition → refine; the paper uses KaHIP presets, here
METIS via :func:`popbench.partition.partition`) giving balanced parts with few cut edges, and (2)
an accelerated RBCD whose momentum restarts **adaptively, whenever the objective increases**
(REFERENCES §4.1; by more than a relative 1e-9, ``rbcd.ADAPTIVE_RESTART_TOLERANCE``, so that
floating-point noise near convergence does not reset the momentum), instead of every 30
iterations. Everything else (relaxation, rank 5, lifting the problem's start, local trust-region
updates, rounding) is shared with CC-PGO in :mod:`baselines.rbcd`.

The problem's assignment: by default (``repartition=True``) ML-PGO re-partitions the graph with
METIS into the problem's number of robots ``n`` (seeded by ``seed``), whatever partitioner made
the problem's assignment; only ``n`` is taken from the problem. When the problem itself was split
by METIS with the same seed, this is the same assignment. ``repartition=False`` uses the problem's
assignment as given.
"""

from __future__ import annotations

from baselines.rbcd import RBCDOptions, solve_rbcd
from popbench.distributed import DistributedProblem
from popbench.methods import Budget, Result
from popbench.partition import partition


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    rank: int = 5,
    certify: bool = False,
    seed: int = 0,
    repartition: bool = True,
    selection: str = "greedy",
    rtr_iterations: int = 1,
    tcg_iterations: int = 10,
    rounding: str = "svd",
    **_: object,
) -> Result:
    """Solve ``problem`` with ML-PGO.

    Args:
        problem: the graph; its number of robots sets ``n``.
        budget: iterations (default 1000) and an optional wall-clock cap.
        rank: relaxation rank ``r``.
        certify: report ``λ_min`` of the optimality certificate in ``extras``.
        seed: seeds the METIS partition and the lifting matrix.
        repartition: split with METIS (default) or keep ``problem.graph.robots``.
        selection: ``"greedy"`` or ``"round-robin"`` colour-class selection.
        rtr_iterations: accepted trust-region steps per robot update (dpgo 3).
        tcg_iterations: truncated-CG iterations per trust-region step (dpgo 50).
        rounding: ``"svd"`` (SE-Sync's rounding, default) or ``"anchor"`` (dpgo's); see
            :func:`baselines.rbcd.rounding_basis`.
    """
    graph = problem.graph
    if repartition or graph.robots is None:
        robots = partition(graph, problem.num_robots, "metis", seed)
    else:
        robots = graph.robots
    options = RBCDOptions.with_local(
        rtr_iterations, tcg_iterations, rounding, selection, accelerated=True, restart="adaptive"
    )
    return solve_rbcd(graph, robots, budget or Budget(), options, rank, certify, seed)
