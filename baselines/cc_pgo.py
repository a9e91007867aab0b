"""CC-PGO: distributed certifiably-correct PGO by RBCD++ (Tian et al., mit-acl/dpgo).

Rank-``r`` Burer–Monteiro relaxation (``r = 5``), the problem's start (dpgo's example uses the
centralised chordal initialisation: ``--init chordal``) lifted by a seeded random ``St(2, r)``
matrix, Nesterov-accelerated Riemannian block-coordinate descent with a
**fixed restart every 30 iterations**, greedy block selection and rounding to SE(2) (REFERENCES
§2; SE-Sync's SVD rounding by default, dpgo's anchor rounding with ``rounding="anchor"``, see
:mod:`baselines.rbcd`). The blocks are the problem's own vertex → robot assignment
(``problem.graph.robots``). One iteration = one colour class of non-adjacent robots updating in
parallel (see :mod:`baselines.rbcd`).

Known property (measured, benchmarks/bench_rbcd.py): with 35 robots the fixed restart limits the
acceleration, and 1000 rounds from the chordal start end 3.7e-3 (mit) and 1.4e-3 (m3500) above
the certified optimum. The local solves are not the cause (dpgo's 3 RTR steps × 50 tCG give
3.6e-3 on mit and 1.36e-3 on m3500; near-exact local solves 3.4e-3 on mit), nor is the greedy
selection (round-robin 3.6e-3 on mit; greedy selection at ``X`` instead of the extrapolated ``Y``
3.67e-3, as at ``Y``), nor the restart round itself (a plain update from ``X`` with the momentum
reset, REFERENCES §2.4, which is what dpgo's restart does after discarding that iteration's
accelerated step); plain RBCD ends at 8.4e-3 on mit, and the same partition with ML-PGO's
adaptive restart at 4.0e-4 (mit) and 2.4e-4 (m3500). No parameter is tuned for it.
"""

from __future__ import annotations

import numpy as np

from baselines.rbcd import RBCDOptions, solve_rbcd
from popbench.distributed import DistributedProblem
from popbench.methods import Budget, Result


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    rank: int = 5,
    certify: bool = False,
    seed: int = 0,
    selection: str = "greedy",
    accelerated: bool = True,
    rtr_iterations: int = 1,
    tcg_iterations: int = 10,
    rounding: str = "svd",
    **_: object,
) -> Result:
    """Solve ``problem`` with CC-PGO.

    Args:
        problem: the graph and its robot assignment (the blocks).
        budget: iterations (default 1000) and an optional wall-clock cap.
        rank: relaxation rank ``r``.
        certify: report ``λ_min`` of the optimality certificate in ``extras``.
        seed: seeds the lifting matrix.
        selection: ``"greedy"`` or ``"round-robin"`` colour-class selection.
        accelerated: RBCD++ (default) or plain RBCD.
        rtr_iterations: accepted trust-region steps per robot update (dpgo 3).
        tcg_iterations: truncated-CG iterations per trust-region step (dpgo 50).
        rounding: ``"svd"`` (SE-Sync's rounding, default) or ``"anchor"`` (dpgo's); see
            :func:`baselines.rbcd.rounding_basis`.
    """
    graph = problem.graph
    robots = np.zeros(graph.num_poses, np.int64) if graph.robots is None else graph.robots
    options = RBCDOptions.with_local(
        rtr_iterations,
        tcg_iterations,
        rounding,
        selection,
        accelerated=accelerated,
        restart="fixed",
    )
    return solve_rbcd(graph, robots, budget or Budget(), options, rank, certify, seed)
