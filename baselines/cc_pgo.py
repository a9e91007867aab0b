"""CC-PGO: distributed certifiably-correct PGO by RBCD++ (Tian et al., mit-acl/dpgo).

Rank-``r`` Burer–Monteiro relaxation (``r = 5``), the problem's start (dpgo's example uses the
centralised chordal initialisation: ``--init chordal``) lifted by a seeded random ``St(2, r)``
matrix, Nesterov-accelerated Riemannian block-coordinate descent with a
**fixed restart every 30 iterations**, greedy block selection and rounding to SE(2) (dpgo;
SE-Sync's SVD rounding by default, dpgo's anchor rounding with ``rounding="anchor"``, see
:mod:`baselines.rbcd`). The blocks are the problem's own vertex → robot assignment
(``problem.graph.robots``). One iteration = one colour class of non-adjacent robots updating in
parallel (see :mod:`baselines.rbcd`).

Known property (measured, benchmarks/bench_rbcd.py): with 35 robots the fixed restart limits the
acceleration, and 1000 rounds from the chordal start end 3.7e-3 (mit) and 1.4e-3 (m3500) above
the certified optimum. The local solves are not the cause (dpgo's 3 RTR steps × 50 tCG give
3.6e-3 on mit and 1.36e-3 on m3500; near-exact local solves 3.4e-3 on mit), nor is the greedy
selection (round-robin 3.6e-3 on mit; greedy selection at ``X`` instead of the extrapolated ``Y``
3.67e-3, as at ``Y``), nor the restart round itself (a plain update from ``X`` with the momentum
reset, which is what dpgo's restart does after discarding that iteration's
accelerated step); plain RBCD ends at 8.4e-3 on mit, and the same partition with ML-PGO's
adaptive restart at 4.0e-4 (mit) and 2.4e-4 (m3500). No parameter is tuned for it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from baselines.rbcd import MethodOptions
from popbench.distributed import DistributedProblem
from popbench.methods import Budget, Result


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
