"""From the robots' local estimates to one global estimate: the consensus step shared by every
method that refines local graphs (prop-v1, prop-v2, local-lm).

``CONSENSUS_MODES`` names the ways to reconcile the separator copies:

* ``"admm"``: information-weighted ADMM over the separators (:mod:`popbench.consensus.admm`), the
  paper's §III-D step;
* ``"aligned-admm"`` (the default; not in the paper): first move every robot's local map
  rigidly by one SE(2) frame chosen to minimise the assembled eq. 1
  (:mod:`popbench.consensus.alignment`), then the same ADMM.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from popbench import objective
from popbench.consensus.admm import admm_consensus
from popbench.consensus.alignment import align_frames
from popbench.errors import ValueRangeError
from popbench.problems.distributed import DistributedProblem

CONSENSUS_MODES = ("admm", "aligned-admm")
DEFAULT_CONSENSUS = "aligned-admm"  # chosen by measurement: docs/consensus.md
DEFAULT_CONSENSUS_ITERATIONS = 200  # the ADMM's budget in every table (docs/consensus.md)


@dataclasses.dataclass(frozen=True, eq=False)
class Reconciled:
    """Result of :func:`reconcile`.

    Attributes:
        poses: ``(N, 3)`` the global estimate.
        F_before: eq. 1 of the assembled local estimates (each vertex from its owner).
        F_aligned: the same after the frame alignment (``F_before`` without it).
        iterations: ADMM iterations run; converged: whether the ADMM met its tolerance.
        messages: poses exchanged (alignment + ADMM).
        wall_s: the whole step [s]; parallel_s: its simulated makespan [s] (the alignment's
            wall time plus the ADMM's own ``parallel_s``).
    """

    poses: np.ndarray
    F_before: float
    F_aligned: float
    iterations: int
    converged: bool
    messages: int
    wall_s: float
    parallel_s: float


def check_consensus(mode: str) -> str:
    """``mode`` if it is one of :data:`CONSENSUS_MODES`, else a one-line error."""
    if mode not in CONSENSUS_MODES:
        raise ValueRangeError("consensus", mode, " | ".join(CONSENSUS_MODES))
    return mode


def reconcile(
    problem: DistributedProblem,
    local_poses: list[np.ndarray],
    mode: str = DEFAULT_CONSENSUS,
    iterations: int = DEFAULT_CONSENSUS_ITERATIONS,
) -> Reconciled:
    """Reconcile ``local_poses`` (one ``(n_r, 3)`` array per robot, rows in
    ``problem.local_vertices(r)`` order) into a global estimate by ``mode``.

    Args:
        problem: the distributed problem.
        local_poses: the robots' local estimates.
        mode: one of :data:`CONSENSUS_MODES`.
        iterations: ADMM iterations at most.
    """
    check_consensus(mode)
    started = time.perf_counter()
    graph = problem.graph
    f_before = objective.objective(graph, problem.assemble(local_poses))
    f_aligned, alignment_messages = f_before, 0
    if mode == "aligned-admm":
        alignment = align_frames(problem, local_poses)
        local_poses, alignment_messages = alignment.local_poses, alignment.messages
        f_aligned = objective.objective(graph, problem.assemble(local_poses))
    alignment_s = time.perf_counter() - started
    consensus = admm_consensus(problem, local_poses, iterations=iterations)
    return Reconciled(
        poses=consensus.poses,
        F_before=f_before,
        F_aligned=f_aligned,
        iterations=int(consensus.iterations),
        converged=bool(consensus.converged),
        messages=int(consensus.messages) + alignment_messages,
        wall_s=time.perf_counter() - started,
        parallel_s=alignment_s + consensus.parallel_s,
    )
