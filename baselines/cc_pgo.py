"""CC-PGO: distributed certifiably-correct PGO by RBCD++ (Tian et al., mit-acl/dpgo).

Rank-``r`` Burer–Monteiro relaxation (``r = 5``), the problem's start (dpgo's example uses the
centralised chordal initialisation: ``--init chordal``) lifted by a seeded random ``St(2, r)``
matrix, Nesterov-accelerated Riemannian block-coordinate descent with a
**fixed restart every 30 iterations**, greedy block selection and rounding to SE(2) (dpgo;
SE-Sync's SVD rounding by default, dpgo's anchor rounding with ``rounding="anchor"``, see
:mod:`baselines.rbcd`). The blocks are the problem's own vertex → robot assignment
(``problem.graph.robots``). One iteration = one colour class of non-adjacent robots updating in
parallel (see :mod:`baselines.rbcd`).

Known property: with 35 robots the fixed restart limits the acceleration (measured, and the
causes ruled out: docs/rbcd.md, "cc-pgo's fixed restart with many robots").
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baselines.rbcd import MethodOptions
from popbench.methods import Budget, Result
from popbench.problems.distributed import DistributedProblem


@dataclasses.dataclass(frozen=True)
class Options(MethodOptions):
    """CC-PGO's options (its record's ``options``): the RBCD methods' and ``accelerated``,
    RBCD++ (default) or plain RBCD."""

    accelerated: bool = True


def solve(problem: DistributedProblem, budget: Budget | None = None, **options: object) -> Result:
    """CC-PGO on ``problem``, whose robot assignment gives the blocks, with :class:`Options`
    named in ``options`` (other keys are ignored)."""
    graph = problem.graph
    robots = np.zeros(graph.num_poses, np.int64) if graph.robots is None else graph.robots
    chosen = Options.of(options)
    return chosen.solve(graph, robots, budget or Budget(), chosen.accelerated, "fixed")
