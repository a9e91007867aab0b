"""Information-weighted ADMM consensus over separator poses (paper §III-D, after Fung et al. 2019;
REFERENCES.md §8).

Every robot ``i`` holds local copies ``x^i`` of its local vertices (owned poses and separator
copies, :class:`popbench.distributed.LocalGraph`). A separator ``s`` has one copy per local graph
it belongs to; ADMM drives the copies to a consensus value ``z_s``:

* local objective ``f_i``: eq. 1 over robot ``i``'s local edges, with every inter-robot edge at
  **half** its information (it is held by both robots), so that ``Σ_i f_i(x) = F(x)`` once the
  copies agree — ADMM's fixed points are stationary points of the global ``F``;
* ``Λ_s^i`` (3×3): the Gauss–Newton Hessian block ``2 Σ J_sᵀJ_s`` of ``f_i`` at copy ``s`` (the
  information that robot ``i``'s edges carry about that pose), evaluated once at the input local
  poses, plus ``1e-9 I``;
* z-update: ``z_s ← z_s ⊕ (Σ_i Λ_s^i)⁻¹ Σ_i Λ_s^i ((x_s^i + u_s^i) ⊖ z_s)`` — the
  information-weighted mean on the tangent space at the current ``z_s`` (translations subtract,
  angles subtract and wrap);
* x-update: ``x^i ← argmin f_i(x^i) + (ρ/2) Σ_s ‖(x_s^i ⊖ z_s) + u_s^i‖²_{Λ_s^i}`` by a few damped
  Gauss–Newton steps (one sparse solve each); the robot owning vertex 0 keeps it fixed (gauge);
* dual update: ``u_s^i ← u_s^i + x_s^i ⊖ z_s`` (scaled form), from ``u = 0``; so even copies
  that already agree at the optimum first move apart (each robot's half-weighted local objective
  is not stationary there on its own) until the duals build up;
* stop when the copies agree: primal residual ``max_{s,i} ‖x_s^i ⊖ z_s‖_∞ < tol`` (m and rad
  alike). The dual residual ``max_s ‖z_s^{k+1} ⊖ z_s^k‖_∞`` is recorded, not used to stop:
  consensus reconciles the robots' estimates; it is not run to global optimality (ADMM's tail is
  slow — on a 7×60 synthetic problem the dual residual still shrinks by only ~0.2 % per
  iteration after 300 iterations); Prop-V2's LM refinement does that.

``ρ`` is dimensionless: it scales the copies' own information, so ``ρ = 1`` makes the consensus
penalty on a copy as stiff as the robot's own edges on that pose. Default ``ρ = 3``: of
``ρ ∈ {1, 3, 10, 30}`` it reached agreement (residuals < 1e-3) in the fewest iterations on
synthetic V2 problems (3×30 and 7×60 poses, copies = optimum + N(0, 0.05²) noise); one damped
Gauss–Newton step per x-update converged as fast as three.

Messages: per iteration each non-owner copy sends ``x_s^i + u_s^i`` to the owner of ``s`` and
receives ``z_s`` back — two pose messages per non-owner copy.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import scipy.sparse
import scipy.sparse.linalg

from popbench import se2
from popbench.distributed import DistributedProblem, LocalGraph
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.objective import linearise, objective

INFORMATION_FLOOR = 1e-9  # added to every Λ_s^i so that the weighted mean is always defined


@dataclasses.dataclass(frozen=True, eq=False)
class ConsensusOutcome:
    """Result of :func:`admm_consensus`.

    Attributes:
        poses: ``(N, 3)`` global estimate: separators at their consensus value ``z``, every other
            vertex from its owner's copy.
        local_poses: final ``[(n_r, 3)]`` local copies, rows in ``local_vertices(r)`` order.
        iterations: ADMM iterations run.
        primal_residuals: ``(iterations,)`` max copy disagreement ``‖x_s^i ⊖ z_s‖_∞`` per iteration.
        dual_residuals: ``(iterations,)`` max consensus change ``‖z^{k+1} ⊖ z^k‖_∞``.
        converged: the primal residual fell below ``tol``.
        messages: pose messages exchanged (see the module docstring).
        parallel_s: simulated makespan: Σ over iterations of the slowest robot's x-update [s].
    """

    poses: np.ndarray
    local_poses: list[np.ndarray]
    iterations: int
    primal_residuals: np.ndarray
    dual_residuals: np.ndarray
    converged: bool
    messages: int
    parallel_s: float


def minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Tangent difference ``a ⊖ b`` of poses ``(..., 3)``: translations subtract, angles wrap."""
    return np.concatenate([a[..., :2] - b[..., :2], se2.wrap(a[..., 2:] - b[..., 2:])], -1)


def plus(a: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``a ⊕ δ``: additive pose increment with the angle wrapped."""
    return np.concatenate([a[..., :2] + delta[..., :2], se2.wrap(a[..., 2:] + delta[..., 2:])], -1)


@dataclasses.dataclass(frozen=True, eq=False)
class _Robot:
    """One robot's ADMM data: its half-weighted local graph and separator copies."""

    local: LocalGraph
    graph: PoseGraph  # inter-robot edges at half information
    copy_rows: np.ndarray  # (c_i,) local rows that are separator copies
    copy_ids: np.ndarray  # (c_i,) index of each copy into the global copy list
    fixed_row: int  # local row held fixed (vertex 0) or -1


def _hessian_blocks(graph: PoseGraph, poses: np.ndarray) -> tuple:
    lin = linearise(graph, poses)
    jt, jh = lin.jac_tail, lin.jac_head
    blocks = (
        2.0 * np.einsum("mki,mkj->mij", jt, jt),
        2.0 * np.einsum("mki,mkj->mij", jt, jh),
        2.0 * np.einsum("mki,mkj->mij", jh, jh),
    )
    gradients = (
        2.0 * np.einsum("mki,mk->mi", jt, lin.errors),
        2.0 * np.einsum("mki,mk->mi", jh, lin.errors),
    )
    return lin, blocks, gradients


def _diagonal_blocks(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    """``(n, 3, 3)`` Gauss–Newton Hessian diagonal blocks ``2 Σ JᵀJ`` of eq. 1."""
    _, (tt, _, hh), _ = _hessian_blocks(graph, poses)
    out = np.zeros((graph.num_poses, 3, 3))
    np.add.at(out, graph.tails, tt)
    np.add.at(out, graph.heads, hh)
    return out


def _cost(robot: _Robot, poses: np.ndarray, target: np.ndarray, weight: np.ndarray) -> float:
    d = minus(poses[robot.copy_rows], target)
    return objective(robot.graph, poses) + 0.5 * float(np.einsum("ci,cij,cj->", d, weight, d))


def _x_update(
    robot: _Robot,
    poses: np.ndarray,
    target: np.ndarray,
    weight: np.ndarray,
    steps: int,
    damping: float,
) -> tuple[np.ndarray, float]:
    """Damped Gauss–Newton on ``f_i(x) + ½ Σ (x_s ⊖ target_s)ᵀ W_s (x_s ⊖ target_s)``.

    ``target = z − u`` (so that ``x ⊖ target ≈ (x ⊖ z) + u``), ``weight = ρΛ``.
    """
    graph = robot.graph
    n = graph.num_poses
    index3 = np.arange(3)
    cost = _cost(robot, poses, target, weight)
    for _ in range(steps):
        _, (tt, th, hh), (g_tail, g_head) = _hessian_blocks(graph, poses)
        p3 = 3 * graph.tails[:, None] + index3  # (M, 3)
        q3 = 3 * graph.heads[:, None] + index3
        c3 = 3 * robot.copy_rows[:, None] + index3
        rows = np.concatenate(
            [np.broadcast_to(a[:, :, None], a.shape + (3,)).ravel() for a in (p3, p3, q3, q3, c3)]
        )
        cols = np.concatenate(
            [
                np.broadcast_to(b[:, None, :], b.shape[:1] + (3, 3)).ravel()
                for b in (p3, q3, p3, q3, c3)
            ]
        )
        values = np.concatenate(
            [tt.ravel(), th.ravel(), np.swapaxes(th, 1, 2).ravel(), hh.ravel(), weight.ravel()]
        )
        hessian = scipy.sparse.coo_matrix((values, (rows, cols)), shape=(3 * n, 3 * n)).tocsc()
        gradient = np.zeros(3 * n)
        np.add.at(gradient, p3.ravel(), g_tail.ravel())
        np.add.at(gradient, q3.ravel(), g_head.ravel())
        d = minus(poses[robot.copy_rows], target)
        np.add.at(gradient, c3.ravel(), np.einsum("cij,cj->ci", weight, d).ravel())
        diagonal = hessian.diagonal()
        free = np.ones(3 * n, dtype=bool)
        if robot.fixed_row >= 0:
            free[3 * robot.fixed_row : 3 * robot.fixed_row + 3] = False
        reduced = hessian[free][:, free]
        accepted = False
        while damping < 1e8:
            system = reduced + scipy.sparse.diags(damping * (diagonal[free] + 1e-9))
            step = np.zeros(3 * n)
            step[free] = -scipy.sparse.linalg.spsolve(system.tocsc(), gradient[free])
            trial = plus(poses, step.reshape(n, 3))
            trial_cost = _cost(robot, trial, target, weight)
            if trial_cost <= cost:
                poses, cost, accepted = trial, trial_cost, True
                damping = max(damping / 10.0, 1e-9)
                break
            damping *= 10.0
        if not accepted:
            break
    return poses, damping


def _prepare(problem: DistributedProblem, local_poses: list[np.ndarray]):
    """Robots' ADMM data, the copy → separator map and the initial copy information."""
    half = np.ones(problem.graph.num_edges)
    half[problem.inter_robot_edges] = 0.5
    separators = problem.separators
    robots, copy_separator, copy_information = [], [], []
    offset = 0
    for local, poses in zip(problem.local_graphs, local_poses, strict=True):
        factor = half[local.edge_ids][:, None, None]
        graph = local.graph.replace(information=local.graph.information * factor, poses=poses)
        rows = np.flatnonzero(np.isin(local.global_ids, separators))
        fixed = np.flatnonzero(local.owned_ids == 0)
        robot = _Robot(
            local, graph, rows, offset + np.arange(rows.size), int(fixed[0]) if fixed.size else -1
        )
        robots.append(robot)
        offset += rows.size
        copy_separator.append(np.searchsorted(separators, local.global_ids[rows]))
        copy_information.append(_diagonal_blocks(graph, poses)[rows])
    information = np.concatenate(copy_information) + INFORMATION_FLOOR * np.eye(3)
    return robots, np.concatenate(copy_separator), information


def _gather(robots: list[_Robot], local_poses: list[np.ndarray]) -> np.ndarray:
    """All separator copies ``(C, 3)``, robot by robot."""
    return np.concatenate([x[r.copy_rows] for r, x in zip(robots, local_poses, strict=True)])


def _weighted_mean(
    centre: np.ndarray, values: np.ndarray, separator_of: np.ndarray, information: np.ndarray
) -> np.ndarray:
    """Information-weighted tangent-space mean of copies ``values`` ``(C, 3)`` around ``centre``
    ``(S, 3)``."""
    s = centre.shape[0]
    delta = minus(values, centre[separator_of])
    total = np.zeros((s, 3, 3))
    np.add.at(total, separator_of, information)
    weighted = np.zeros((s, 3))
    np.add.at(weighted, separator_of, np.einsum("cij,cj->ci", information, delta))
    return plus(centre, np.linalg.solve(total, weighted[..., None])[..., 0])


def _pin_gauge(z: np.ndarray, copies: np.ndarray, gauge_copy: np.ndarray, separator_of: np.ndarray):
    """Hold a separating vertex 0 at its owner's fixed copy (the gauge)."""
    z[separator_of[gauge_copy]] = copies[gauge_copy]
    return z


def admm_consensus(
    problem: DistributedProblem,
    local_poses: list[np.ndarray],
    rho: float = 3.0,
    iterations: int = 200,
    tol: float = 1e-3,
    local_steps: int = 1,
) -> ConsensusOutcome:
    """Reconcile the robots' separator copies by information-weighted ADMM (module docstring).

    Args:
        problem: the distributed problem.
        local_poses: one ``(n_r, 3)`` estimate per robot, rows in ``local_vertices(r)`` order.
        rho: dimensionless penalty ``ρ > 0`` (multiplies each copy's information ``Λ_s^i``).
        iterations: maximum ADMM iterations (≥ 0).
        tol: stopping threshold on the primal residual (copy disagreement) [m, rad].
        local_steps: damped Gauss–Newton steps per x-update (≥ 1).

    Raises:
        ValueRangeError: a parameter outside its range or a local estimate of the wrong shape.
    """
    if not rho > 0:
        raise ValueRangeError("rho", rho, "> 0")
    if iterations < 0 or local_steps < 1:
        raise ValueRangeError("iterations/local_steps", (iterations, local_steps), "≥ 0 / ≥ 1")
    for local, poses in zip(problem.local_graphs, local_poses, strict=True):
        if np.shape(poses) != (local.num_vertices, 3):
            raise ValueRangeError(
                f"local_poses[{local.robot}] shape", np.shape(poses), f"({local.num_vertices}, 3)"
            )
    local_poses = [np.array(poses, dtype=np.float64) for poses in local_poses]
    robots, separator_of, information = _prepare(problem, local_poses)
    separators = problem.separators
    copies = _gather(robots, local_poses)
    owner_copy = problem.robots[separators][separator_of] == np.concatenate(
        [np.full(r.copy_rows.size, r.local.robot) for r in robots]
    )
    messages_per_iteration = 2 * int(np.count_nonzero(~owner_copy))

    gauge_copy = np.concatenate(
        [r.copy_ids[r.copy_rows == r.fixed_row] for r in robots]
    )  # the fixed copy of vertex 0, if vertex 0 is a separator
    first_copy = np.unique(separator_of, return_index=True)[1]
    z = _weighted_mean(copies[first_copy], copies, separator_of, information)
    z = _pin_gauge(z, copies, gauge_copy, separator_of)
    u = np.zeros_like(copies)
    weight = rho * information
    damping = [1e-4] * len(robots)
    primal, dual = [], []
    parallel_s = 0.0
    converged = False
    for _ in range(iterations):
        slowest = 0.0
        for k, robot in enumerate(robots):
            if robot.copy_rows.size == 0:
                continue  # no separator: nothing couples this robot
            start = time.perf_counter()
            target = minus(z[separator_of[robot.copy_ids]], u[robot.copy_ids])
            local_poses[k], damping[k] = _x_update(
                robot, local_poses[k], target, weight[robot.copy_ids], local_steps, damping[k]
            )
            slowest = max(slowest, time.perf_counter() - start)
        parallel_s += slowest
        copies = _gather(robots, local_poses)
        z_new = _weighted_mean(z, plus(copies, u), separator_of, information)
        z_new = _pin_gauge(z_new, copies, gauge_copy, separator_of)
        disagreement = minus(copies, z_new[separator_of])
        u = u + disagreement
        primal.append(float(np.abs(disagreement).max(initial=0.0)))
        dual.append(float(np.abs(minus(z_new, z)).max(initial=0.0)))
        z = z_new
        if primal[-1] < tol:
            converged = True
            break

    poses = problem.assemble(local_poses)
    poses[separators] = z
    return ConsensusOutcome(
        poses=poses,
        local_poses=local_poses,
        iterations=len(primal),
        primal_residuals=np.array(primal),
        dual_residuals=np.array(dual),
        converged=converged,
        messages=messages_per_iteration * len(primal),
        parallel_s=parallel_s,
    )
