"""ML-PGO: multilevel partitioning + accelerated RBCD with adaptive restart (Li et al. 2024).

What distinguishes ML-PGO from CC-PGO is (1) how the poses are split among the robots: a
multilevel graph partitioner (coarsen → partition → refine; the paper uses KaHIP presets, here
METIS via :func:`popbench.problems.partition.partition`) giving balanced parts with few cut edges,
and (2) an accelerated RBCD whose momentum restarts **adaptively, whenever the objective increases**
(Li et al. 2024; by more than a relative 1e-9, ``driver.ADAPTIVE_RESTART_TOLERANCE``, so that
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

import dataclasses

from baselines.rbcd import MethodOptions
from popbench.methods import Budget, Result
from popbench.problems.distributed import DistributedProblem
from popbench.problems.partition import partition


@dataclasses.dataclass(frozen=True)
class Options(MethodOptions):
    """ML-PGO's options (its record's ``options``): the RBCD methods' (``seed`` also seeds the
    METIS partition) and ``repartition``: split with METIS (default) or keep
    ``problem.graph.robots``."""

    repartition: bool = True


def solve(problem: DistributedProblem, budget: Budget | None = None, **options: object) -> Result:
    """ML-PGO on ``problem``, whose number of robots sets ``n``, with :class:`Options` named in
    ``options`` (other keys are ignored)."""
    graph = problem.graph
    chosen = Options.of(options)
    if chosen.repartition or graph.robots is None:
        robots = partition(graph, problem.num_robots, "metis", chosen.seed)
    else:
        robots = graph.robots
    return chosen.solve(graph, robots, budget or Budget(), True, "adaptive")
