"""Rigid alignment of the robots' local frames before the consensus (our addition to §III-D).

After the local refinement every robot's map is consistent in itself but placed in the frame it
started from, so the inter-robot edges, which tie the maps together, carry the accumulated
disagreement. Before the ADMM consensus (popbench.consensus.admm) each robot's whole local estimate
(owned poses and separator copies) is moved rigidly by one frame ``T_r ∈ SE(2)``:

    y_v = T_r ∘ x_v   for every local vertex v of robot r,

with the frames chosen to minimise eq. 1 of the assembled estimate (each vertex from its owner).
A rigid motion of a robot's map leaves the costs of its intra-robot edges unchanged, so this is
the minimisation of the inter-robot edges' cost over ``3(n − 1)`` unknowns (the robot owning
vertex 0 keeps ``T = I``, the gauge) — a tiny nonlinear least-squares problem, solved by
Levenberg–Marquardt from ``T = I`` with additive frame increments, so the assembled ``F`` never
increases. Jacobians by the chain rule through ``y = T ∘ x``: ``∂y_t/∂t_T = I``,
``∂y_t/∂θ_T = J (y_t − t_T)``, ``∂y_θ/∂θ_T = 1`` (``J = R(π/2)``), times the edge Jacobians of
:func:`popbench.objective.linearise`.

Cost: a dense ``3(n − 1)`` system per step, against seconds for the ADMM. Measurements (effect
on F and ATE, where it is used, timings): docs/alignment.md.

Messages (a model, for the reports): the owners send the gauge robot the poses at their
inter-robot edges (one message per separator), and it sends every other robot its frame
(``n − 1``).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from popbench import se2
from popbench.graph import PoseGraph
from popbench.objective import linearise, objective
from popbench.problems.distributed import DistributedProblem

INITIAL_DAMPING, MIN_DAMPING, MAX_DAMPING = 1e-4, 1e-9, 1e8


@dataclasses.dataclass(frozen=True, eq=False)
class FrameAlignment:
    """Result of :func:`align_frames`.

    Attributes:
        local_poses: ``[(n_r, 3)]`` every robot's local estimate moved by its frame.
        frames: ``(n, 3)`` the frames ``T_r = (x [m], y [m], θ [rad])``; the gauge robot's is 0.
        inter_cost_before, inter_cost_after: eq. 1 of the inter-robot edges at the owners' poses
            before and after (the assembled ``F`` changes by exactly their difference).
        iterations: LM steps tried (accepted or rejected).
        messages: see the module docstring.
    """

    local_poses: list[np.ndarray]
    frames: np.ndarray
    inter_cost_before: float
    inter_cost_after: float
    iterations: int
    messages: int


def moved(frames: np.ndarray, poses: np.ndarray, robots: np.ndarray) -> np.ndarray:
    """``T_{robots[v]} ∘ x_v``: poses ``(V, 3)`` moved by their robot's frame, ``frames``
    ``(n, 3)``."""
    return se2.compose(frames[robots], poses)


def inter_robot_graph(problem: DistributedProblem) -> PoseGraph:
    """The global graph restricted to its inter-robot edges (all vertices kept)."""
    return problem.graph.edge_subset(problem.inter_robot_edges)


def frame_jacobians(
    inter: PoseGraph, poses: np.ndarray, frames: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened residuals ``(m, 3)`` of the inter-robot graph ``inter``
    (:func:`inter_robot_graph`) at ``T ∘ x`` and their Jacobians with respect to the tail's and
    the head's robot frame (each ``(m, 3, 3)``); ``poses``: the owners' ``(N, 3)``."""
    y = moved(frames, poses, inter.robots)
    lin = linearise(inter, y)

    def chain(vertices: np.ndarray) -> np.ndarray:  # ∂(T ∘ x_v)/∂T at each vertex
        origin = frames[inter.robots[vertices], :2]
        d = np.broadcast_to(np.eye(3), (vertices.size, 3, 3)).copy()
        d[:, 0, 2] = -(y[vertices, 1] - origin[:, 1])
        d[:, 1, 2] = y[vertices, 0] - origin[:, 0]
        return d

    return lin.errors, lin.jac_tail @ chain(inter.tails), lin.jac_head @ chain(inter.heads)


def align_frames(
    problem: DistributedProblem,
    local_poses: list[np.ndarray],
    iterations: int = 50,
    relative_tolerance: float = 1e-10,
) -> FrameAlignment:
    """Move every robot's local estimate rigidly so that the assembled ``F`` is least (module
    docstring).

    Args:
        problem: the distributed problem.
        local_poses: one ``(n_r, 3)`` estimate per robot, rows in ``local_vertices(r)`` order.
        iterations: LM steps at most (accepted or rejected).
        relative_tolerance: stop after an accepted step that lowers the cost by at most this
            fraction.
    """
    n = problem.num_robots
    poses = problem.assemble(local_poses)
    inter = inter_robot_graph(problem)
    robots = inter.robots
    frames = np.zeros((n, 3))
    cost = before = objective(inter, moved(frames, poses, robots))
    gauge = int(robots[0])
    free = np.setdiff1d(np.arange(3 * n), 3 * gauge + np.arange(3))
    tail_robot, head_robot = robots[inter.tails], robots[inter.heads]
    damping, tried = INITIAL_DAMPING, 0
    while inter.num_edges and tried < iterations and damping < MAX_DAMPING:
        errors, jac_tail, jac_head = frame_jacobians(inter, poses, frames)
        hessian = np.zeros((n, 3, n, 3))
        gradient = np.zeros((n, 3))
        for rows, jac_rows in ((tail_robot, jac_tail), (head_robot, jac_head)):
            np.add.at(gradient, rows, np.einsum("mki,mk->mi", jac_rows, errors))
            for cols, jac_cols in ((tail_robot, jac_tail), (head_robot, jac_head)):
                block = np.einsum("mki,mkj->mij", jac_rows, jac_cols)
                np.add.at(hessian, (rows, slice(None), cols), block)
        hessian = hessian.reshape(3 * n, 3 * n)[np.ix_(free, free)]
        gradient = gradient.reshape(-1)[free]
        converged = False
        while tried < iterations and damping < MAX_DAMPING:
            tried += 1
            system = hessian + damping * np.diag(np.diag(hessian) + 1e-9)
            trial = frames.copy()
            trial.reshape(-1)[free] += np.linalg.solve(system, -gradient)
            trial[:, 2] = se2.wrap(trial[:, 2])
            trial_cost = objective(inter, moved(trial, poses, robots))
            if trial_cost <= cost:
                converged = cost - trial_cost <= relative_tolerance * cost
                frames, cost = trial, trial_cost
                damping = max(damping / 10.0, MIN_DAMPING)
                break
            damping *= 10.0
        if converged:
            break
    aligned = [
        se2.compose(np.broadcast_to(frames[r], estimate.shape), estimate)
        for r, estimate in enumerate(local_poses)
    ]
    messages = problem.separators.size + n - 1 if inter.num_edges else 0
    return FrameAlignment(aligned, frames, before, cost, tried, messages)
