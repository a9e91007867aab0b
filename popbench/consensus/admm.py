"""Information-weighted ADMM consensus over separator poses (paper §III-D, after Fung et al. 2019).

Every robot ``i`` holds local copies ``x^i`` of its local vertices (owned poses and separator
copies, :class:`popbench.problems.distributed.LocalGraph`). A separator ``s`` has one copy per
local graph it belongs to; ADMM drives the copies to a consensus value ``z_s``:

* local objective ``f_i``: eq. 1 over robot ``i``'s local edges, with every inter-robot edge at
  **half** its information (it is held by both robots), so that ``Σ_i f_i(x) = F(x)`` once the
  copies agree — ADMM's fixed points are stationary points of the global ``F``;
* ``Λ_s^i`` (3×3): the Gauss–Newton Hessian block ``2 Σ J_sᵀJ_s`` of ``f_i`` at copy ``s`` (the
  information that robot ``i``'s edges carry about that pose), evaluated once at the input local
  poses, plus ``1e-9 I``;
* z-update: ``z_s ← z_s ⊕ (Σ_i Λ_s^i)⁻¹ Σ_i Λ_s^i ((x_s^i + u_s^i) ⊖ z_s)`` — the
  information-weighted mean on the tangent space at the current ``z_s`` (translations subtract,
  angles subtract and wrap);
* x-update: ``x^i ← argmin f_i(x^i) + (ρ/2) Σ_s ‖(x_s^i ⊖ z_s) + u_s^i‖²_{Λ_s^i}`` by
  ``local_steps`` (1) damped Gauss–Newton steps (additive increments; system ``H + λ(diag H +
  1e-9)``, λ from 1e-4; a step that does not lower the robot's x-objective is retried with
  10λ up to 1e8, an accepted one divides λ by 10, floor 1e-9); the robot owning vertex 0 keeps
  it fixed (gauge); robots without separator copies are not coupled and keep their poses;
* dual update: ``u_s^i ← u_s^i + x_s^i ⊖ z_s`` (scaled form), from ``u = 0``; so even copies
  that already agree at the optimum first move apart (each robot's half-weighted local objective
  is not stationary there on its own) until the duals build up;
* stop when the copies agree: primal residual ``max_{s,i} ‖x_s^i ⊖ z_s‖_∞ < tol`` (m and rad
  alike). The dual residual ``max_s ‖z_s^{k+1} ⊖ z_s^k‖_∞`` is recorded, not used to stop:
  consensus reconciles the robots' estimates; it is not run to global optimality (ADMM's tail is
  slow); Prop-V2's LM refinement does that. The x-update systems are solved directly (exact up
  to round-off; why, and the measurements and variants not kept: docs/consensus.md).

``ρ`` is dimensionless: it scales the copies' own information, so ``ρ = 1`` makes the consensus
penalty on a copy as stiff as the robot's own edges on that pose. Default ``ρ = 3`` and one
damped Gauss–Newton step per x-update (how they were chosen: docs/consensus.md).

Messages: per iteration each non-owner copy sends ``x_s^i + u_s^i`` to the owner of ``s`` and
receives ``z_s`` back — two pose messages per non-owner copy.

Batched execution (all robots' x-updates as one block-diagonal team system): see
:class:`popbench.consensus.system._TeamSystem`. Accounting (``parallel_s``): see
:func:`admm_consensus`.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from popbench import se2
from popbench.consensus.system import _solve_blocks, _Team, _team, _TeamSystem
from popbench.errors import ValueRangeError
from popbench.objective import edge_costs, linearise, residuals
from popbench.problems.distributed import DistributedProblem

INFORMATION_FLOOR = 1e-9  # added to every Λ_s^i so that the weighted mean is always defined
INITIAL_DAMPING, MIN_DAMPING, MAX_DAMPING = 1e-4, 1e-9, 1e8


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
        parallel_s: simulated makespan [s] (module docstring, "Accounting").
        factorisations: sparse factorisations of robots' x-update systems (all robots).
    """

    poses: np.ndarray
    local_poses: list[np.ndarray]
    iterations: int
    primal_residuals: np.ndarray
    dual_residuals: np.ndarray
    converged: bool
    messages: int
    parallel_s: float
    factorisations: int = 0


def minus(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Tangent difference ``a ⊖ b`` of poses ``(..., 3)``: translations subtract, angles wrap."""
    return np.concatenate([a[..., :2] - b[..., :2], se2.wrap(a[..., 2:] - b[..., 2:])], -1)


def plus(a: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """``a ⊕ δ``: additive pose increment with the angle wrapped."""
    return np.concatenate([a[..., :2] + delta[..., :2], se2.wrap(a[..., 2:] + delta[..., 2:])], -1)


def _hessian_blocks(team: _Team, poses: np.ndarray) -> tuple:
    """Edge costs ``(M_T,)``, Gauss–Newton blocks ``2JᵀJ`` (tail-tail, tail-head, head-head,
    each ``(M_T, 3, 3)``) and gradients ``2Jᵀe`` (tail, head, each ``(M_T, 3)``) of eq. 1."""
    lin = linearise(team.graph, poses)
    jt, jh, e = lin.jac_tail, lin.jac_head, lin.errors
    jt_transposed = np.swapaxes(jt, 1, 2)
    # batched 3×3 products by matmul (≈ 5× faster than einsum here; equal to round-off)
    blocks = (
        2.0 * (jt_transposed @ jt),
        2.0 * (jt_transposed @ jh),
        2.0 * (np.swapaxes(jh, 1, 2) @ jh),
    )
    gradients = (2.0 * np.einsum("mki,mk->mi", jt, e), 2.0 * np.einsum("mki,mk->mi", jh, e))
    return np.einsum("mk,mk->m", e, e), blocks, gradients


def _information(team: _Team, poses: np.ndarray) -> np.ndarray:
    """``(C, 3, 3)`` copy information ``Λ_s^i``: the diagonal Gauss–Newton blocks at the copies,
    plus ``INFORMATION_FLOOR · I``."""
    _, (tt, _, hh), _ = _hessian_blocks(team, poses)
    v = team.graph.num_poses
    ends = np.concatenate([team.graph.tails, team.graph.heads])
    blocks = np.concatenate([tt, hh]).reshape(-1, 9)
    flat = np.stack([np.bincount(ends, blocks[:, k], v) for k in range(9)], -1)
    return flat.reshape(v, 3, 3)[team.copy_rows] + INFORMATION_FLOOR * np.eye(3)


# ----- ADMM ----------------------------------------------------------------------------------


def _robot_costs(
    team: _Team, edge_costs: np.ndarray, offsets: np.ndarray, weight: np.ndarray
) -> np.ndarray:
    """``(R,)`` every robot's x-update objective: its edges' eq. 1 costs (``edge_costs``
    ``(M_T,)``) plus ``½ Σ_s dᵀ W_s d`` over its copies (``offsets`` = ``x_s ⊖ target_s``)."""
    penalty = 0.5 * np.einsum("ci,cij,cj->c", offsets, weight, offsets)
    r = team.num_robots
    return np.bincount(team.edge_robot, edge_costs, r) + np.bincount(team.copy_robot, penalty, r)


def _x_update(
    team: _Team,
    system: _TeamSystem,
    poses: np.ndarray,
    target: np.ndarray,
    weight: np.ndarray,
    damping: np.ndarray,
    steps: int,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Damped Gauss–Newton on every robot's ``f_i(x) + ½ Σ_s (x_s ⊖ target_s)ᵀ W_s (…)`` at
    once (``poses`` ``(V, 3)``, ``target = z − u`` and ``weight = ρΛ`` per copy ``(C, …)``).

    Per robot, a step is accepted when it does not raise the robot's objective; its damping
    (``damping`` ``(R,)``, updated in place) is then divided by 10, else multiplied by 10 and
    the step retried, while below ``MAX_DAMPING``; a robot with no accepted step takes no
    further step. Robots without copies keep their poses.

    Returns:
        the new poses, each robot's factorise-and-solve time ``(R,)`` [s] and the number of
        factorisations.
    """
    robots = team.num_robots
    seconds = np.zeros(robots)
    factorisations = 0
    moving = np.bincount(team.copy_robot, minlength=robots) > 0
    for _ in range(steps):
        pending = moving & (damping < MAX_DAMPING)
        if not pending.any():
            break
        costs, blocks, (g_tail, g_head) = _hessian_blocks(team, poses)
        offsets = minus(poses[team.copy_rows], target)
        cost = _robot_costs(team, costs, offsets, weight)
        values = system.values(blocks, weight)
        gradient = system.gradient(g_tail, g_head, np.einsum("cij,cj->ci", weight, offsets))
        scale = values[system.diagonal_slots] + 1e-9
        accepted = np.zeros(robots, dtype=bool)
        while pending.any():
            matrix = system.matrix(values, damping[system.dof_robot] * scale)
            step = _solve_blocks(matrix, -gradient, pending, system.bounds, seconds)
            factorisations += int(pending.sum())
            trial = plus(poses, system.increments(step, team.graph.num_poses))
            trial_offsets = minus(trial[team.copy_rows], target)
            trial_cost = _robot_costs(
                team,
                edge_costs(residuals(team.graph, trial), team.kappa, team.tau),
                trial_offsets,
                weight,
            )
            better = pending & (trial_cost <= cost)
            poses = np.where(better[team.vertex_robot, None], trial, poses)
            damping[better] = np.maximum(damping[better] / 10.0, MIN_DAMPING)
            accepted |= better
            pending &= ~better
            damping[pending] *= 10.0
            pending &= damping < MAX_DAMPING
        moving &= accepted
    return poses, seconds, factorisations


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


def _slowest_share(team: _Team) -> float:
    """The largest robot's share of the team's work, work = local vertices + local edges."""
    r = team.num_robots
    work = np.bincount(team.vertex_robot, minlength=r) + np.bincount(team.edge_robot, minlength=r)
    return float(work.max() / work.sum())


def admm_consensus(
    problem: DistributedProblem,
    local_poses: list[np.ndarray],
    rho: float = 3.0,
    iterations: int = 200,
    tol: float = 1e-3,
    local_steps: int = 1,
) -> ConsensusOutcome:
    """Reconcile the robots' separator copies by information-weighted ADMM (module docstring).

    Accounting. ``parallel_s`` models the makespan: per ADMM iteration, the slowest robot's
    measured factorise-and-solve time plus the x-update's shared vectorised time times the largest
    robot's share of the work (local vertices + local edges). The z- and dual updates (cheap, done
    by the separators' owners) are not counted.

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
    local_poses = [np.asarray(poses, dtype=np.float64) for poses in local_poses]
    team = _team(problem, local_poses)
    poses = team.graph.poses.copy()
    separator_of = team.separator_of
    information = _information(team, poses)
    owner_copy = problem.robots[problem.separators][separator_of] == team.copy_robot
    messages_per_iteration = 2 * int(np.count_nonzero(~owner_copy))
    gauge_copy = np.flatnonzero(team.copy_rows == team.fixed_row)
    copies = poses[team.copy_rows]
    first_copy = np.unique(separator_of, return_index=True)[1]
    z = _weighted_mean(copies[first_copy], copies, separator_of, information)
    z = _pin_gauge(z, copies, gauge_copy, separator_of)
    u = np.zeros_like(copies)
    weight = rho * information
    damping = np.full(team.num_robots, INITIAL_DAMPING)
    system = _TeamSystem(team) if copies.size else None
    share = _slowest_share(team)
    primal, dual = [], []
    parallel_s = 0.0
    factorisations = 0
    converged = False
    for _ in range(iterations):
        if copies.size:
            start = time.perf_counter()
            target = minus(z[separator_of], u)
            poses, solve_s, count = _x_update(
                team, system, poses, target, weight, damping, local_steps
            )
            shared_s = time.perf_counter() - start - solve_s.sum()
            parallel_s += shared_s * share + solve_s.max()
            factorisations += count
        copies = poses[team.copy_rows]
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

    local_poses = np.split(poses, team.offsets[1:-1])
    result = problem.assemble(local_poses)
    result[problem.separators] = z
    return ConsensusOutcome(
        poses=result,
        local_poses=local_poses,
        iterations=len(primal),
        primal_residuals=np.array(primal),
        dual_residuals=np.array(dual),
        converged=converged,
        messages=messages_per_iteration * len(primal),
        parallel_s=parallel_s,
        factorisations=factorisations,
    )
