"""The robots' local update: Riemannian trust-region Newton with truncated CG on each robot's
problem with its neighbours fixed, vectorised over a colour class (dpgo ``PGOAgent::updateX``;
Absil, Mahony & Sepulchre 2008, Alg. 11 for the tCG).

With neighbours fixed, robot α minimises ``f_α(Z) = ½⟨Z, Q_αα Z⟩ + ⟨Z, G_α⟩`` over
``(St(2, r) × R^r)^{n_α}``; the robots of a class are independent, so every trust-region and tCG
scalar is kept per robot (``(k,)`` arrays) and each robot follows the iteration it would run
alone. The settings and their measurements: :class:`LocalOptions`, docs/rbcd.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from baselines.rbcd.blocks import PRECONDITIONER_SHIFT, ClassBlock, PerRobot
from baselines.rbcd.relaxation import flat
from baselines.rbcd.stiefel import (
    multipliers,
    project_tangent,
    retract,
    riemannian_gradient,
    riemannian_hessian,
)

MAX_REJECTIONS = 10  # trust-region rejections allowed in one robot update (dpgo)


@dataclasses.dataclass(frozen=True)
class LocalOptions:
    """Riemannian trust-region settings of one robot update (dpgo ``ROptParameters``).

    The defaults (1 accepted step, ≤ 10 tCG iterations) are cheaper than dpgo's (3, 50) and
    converge in as many rounds (measured: docs/rbcd.md, "Local solver settings").

    Attributes:
        rtr_iterations: accepted trust-region steps per update (dpgo 3).
        tcg_iterations: truncated-CG iterations per trust-region step (dpgo 50).
        gradient_tolerance: stop the update when ``‖grad f_α‖ <`` this (dpgo 1e-2), or below
            ``relative_gradient_tolerance`` × the team's ``‖grad f‖`` at the start when that is
            smaller (:func:`scaled_local_options`).
        relative_gradient_tolerance: the scale-aware bound above: residuals ``s×`` smaller give
            gradients ``s×`` smaller, and with the absolute 1e-2 alone every robot stopped
            updating on a graph of tiny residuals (``docs/rbcd.md``); 2e-3 keeps 1e-2 on every
            Table I start.
        preconditioner_shift: ``λ`` of the preconditioner ``Q_αα + λI`` (dpgo 0.1).
    """

    rtr_iterations: int = 1
    tcg_iterations: int = 10
    gradient_tolerance: float = 1e-2
    relative_gradient_tolerance: float = 2e-3
    preconditioner_shift: float = PRECONDITIONER_SHIFT


def truncated_cg(
    gradient: np.ndarray,
    preconditioned_gradient: np.ndarray,
    hessian: Callable[[np.ndarray], np.ndarray],
    precondition: Callable[[np.ndarray], np.ndarray],
    radius: np.ndarray,
    max_iterations: int,
    active: np.ndarray,
    robots: PerRobot,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Preconditioned Steihaug–Toint truncated CG for ``min ⟨g,η⟩ + ½⟨η,Hη⟩``, ``‖η‖_P ≤ Δ``
    (Absil, Mahony & Sepulchre 2008, Alg. 11; the trust region in the preconditioner's norm),
    run for every robot of a class at once: all scalars (step, radius, stopping) are per robot
    ``(k,)``; ``H`` and ``P`` are block diagonal over the robots, so the robots' iterations are
    independent and each stops on its own test (a stopped robot's iterate is frozen).

    Args:
        gradient: ``g`` ``(n_c, 3, r)``; preconditioned_gradient: ``P⁻¹g`` (projected).
        radius: ``Δ`` per robot ``(k,)``.
        active: ``(k,)`` robots that run; the others return ``η = 0``.

    Returns:
        ``(η, Hη, hit_boundary (k,), hessian_products (k,))``.
    """
    eta = np.zeros_like(gradient)
    h_eta = np.zeros_like(gradient)
    residual = gradient.copy()
    r_z = robots.inner(residual, preconditioned_gradient)
    delta = -preconditioned_gradient
    e_pe, e_pd, d_pd = np.zeros_like(r_z), np.zeros_like(r_z), r_z  # ‖η‖²_P, ⟨η,δ⟩_P, ‖δ‖²_P
    initial_norm = np.sqrt(robots.inner(residual, residual))
    stop_norm = initial_norm * np.minimum(initial_norm, 0.1)  # ‖r₀‖ min(‖r₀‖^θ, κ), θ=1, κ=0.1
    running = active.copy()
    hit_boundary = np.zeros_like(active)
    products = np.zeros(active.shape, dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for iteration in range(max_iterations):
            h_delta = hessian(delta)
            products += running
            curvature = robots.inner(delta, h_delta)
            alpha = np.where(curvature > 0, r_z / curvature, np.inf)
            e_pe_next = e_pe + 2.0 * alpha * e_pd + alpha**2 * d_pd
            boundary = running & ((curvature <= 0) | ~(e_pe_next < radius**2))
            tau = (-e_pd + np.sqrt(e_pd**2 + d_pd * (radius**2 - e_pe))) / d_pd
            running &= ~boundary
            hit_boundary |= boundary
            step = np.where(boundary, tau, np.where(running, alpha, 0.0))
            eta += robots.spread(step) * delta
            h_eta += robots.spread(step) * h_delta
            if iteration == max_iterations - 1:  # η is final: no next residual or direction
                break
            residual += robots.spread(np.where(running, alpha, 0.0)) * h_delta
            e_pe = np.where(running, e_pe_next, e_pe)
            running &= np.sqrt(robots.inner(residual, residual)) > stop_norm
            if not running.any():
                break
            z = precondition(residual)
            r_z_next = robots.inner(residual, z)
            beta = np.where(running, r_z_next / r_z, 0.0)
            r_z = np.where(running, r_z_next, r_z)
            delta = -z + robots.spread(beta) * delta
            e_pd = np.where(running, beta * (e_pd + alpha * d_pd), e_pd)
            d_pd = np.where(running, r_z + beta**2 * d_pd, d_pd)
    return eta, h_eta, hit_boundary, products


class LocalStep(NamedTuple):
    """The outcome of :func:`local_update`: the new ``Z`` ``(n_c, 3, r)``, the change of ``QX``
    on the class's ``reach_rows`` ``(m, r)``, and each robot's Hessian–vector products ``(k,)``
    (its work)."""

    z: np.ndarray
    q_change: np.ndarray
    products: np.ndarray


def local_update(
    block: ClassBlock, z: np.ndarray, euclidean: np.ndarray, options: LocalOptions
) -> LocalStep:
    """Every robot α of the class runs RTR on ``f_α(Z) = ½⟨Z, Q_αα Z⟩ + ⟨Z, G_α⟩`` from ``z``
    ``(n_c, 3, r)``, given its Euclidean gradient there, ``euclidean = Q_αα Z + G_α`` (the
    class's rows of ``QY``), ``(n_c, 3, r)``; vectorised over the class with per-robot trust
    regions, acceptance and stopping (the robots are independent).

    **Local update** (dpgo ``PGOAgent::updateX``): with neighbours fixed, robot α minimises
    ``f_α(Z) = ½⟨Z, Q_αα Z⟩ + ⟨Z, G_α⟩`` over ``(St(2, r) × R^r)^{n_α}`` by Riemannian
    trust-region Newton steps with truncated (Steihaug–Toint) CG, preconditioned by a cached sparse
    Cholesky factor of ``Q_αα + λI`` (dpgo's preconditioner); by default one accepted step with ≤ 10
    tCG iterations (dpgo: 3 steps, ≤ 50; see :class:`LocalOptions`). The linear term ``G_α`` only
    needs the neighbours' separator poses, and is never formed: the update starts from the gradient
    ``∇f_α(Z) = (QY)_α`` the round already has, and a candidate step ``Δ`` is judged by
    ``f_α(Z + Δ) − f_α(Z) = ⟨Δ, ∇f_α(Z)⟩ + ½⟨Δ, Q_αα Δ⟩`` from one sparse product with the class's
    columns of ``Q`` (which also gives the change of the neighbours' ``QX``), so a robot update
    costs its tCG iterations (one Hessian product and one preconditioner solve each, none after the
    last) plus one product per trust-region step.

    Costs are tracked relative to ``f_α(z)``: a step ``Δ`` costs
    ``f_α(Z + Δ) − f_α(Z) = ⟨Δ, ∇f_α(Z)⟩ + ½⟨Δ, Q_αα Δ⟩`` and moves the gradient by ``Q_αα Δ``,
    so each candidate needs one sparse product, ``reach · Δ``, whose own rows are ``Q_αα Δ`` and
    whose other rows are the change of the neighbours' ``QX`` (neither ``G_α`` nor ``f_α``
    itself is ever formed).

    Each robot runs until ``options.rtr_iterations`` steps were accepted, its gradient norm
    falls below ``options.gradient_tolerance``, or ``MAX_REJECTIONS`` steps were rejected (each
    rejection shrinks its radius ×¼, as dpgo does). Its first radius is 10 × the P-norm of its
    preconditioned gradient.
    """
    robots = block.per_robot
    rank = z.shape[-1]

    def precondition(point: np.ndarray, v: np.ndarray) -> np.ndarray:
        return project_tangent(point, block.preconditioner.solve(v))

    q_change = np.zeros((block.reach_rows.size, rank))
    radius = np.full(block.num_robots, np.inf)
    accepted = np.zeros(block.num_robots, dtype=np.int64)
    rejected = np.zeros_like(accepted)
    products = np.zeros_like(accepted)
    pending = np.ones(block.num_robots, dtype=bool)
    moved = pending
    while True:
        if moved.any():  # the gradient, its preconditioned version and Λ at the new point
            gradient = riemannian_gradient(z, euclidean)
            pending &= np.sqrt(robots.inner(gradient, gradient)) >= options.gradient_tolerance
            if not pending.any():
                break
            preconditioned = precondition(z, gradient)
            first = ~np.isfinite(radius)
            p_norm = np.sqrt(np.maximum(robots.inner(preconditioned, gradient), 0.0))
            radius[first] = 10.0 * p_norm[first]
            lam = multipliers(z, euclidean)
            point = z
        eta, h_eta, hit_boundary, used = truncated_cg(
            gradient,
            preconditioned,
            lambda v, point=point, lam=lam: riemannian_hessian(block.hessian, point, lam, v),
            lambda v, point=point: precondition(point, v),
            radius,
            options.tcg_iterations,
            pending,
            robots,
        )
        products += used
        model_decrease = -(robots.inner(gradient, eta) + 0.5 * robots.inner(eta, h_eta))
        step = np.where(robots.spread(pending), retract(z, eta) - z, 0.0)
        reach_step = block.reach @ flat(step)
        q_step = reach_step[block.own_in_reach].reshape(step.shape)  # Q_cc Δ
        decrease = -robots.inner(step, euclidean + 0.5 * q_step)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(model_decrease > 0, decrease / model_decrease, -np.inf)
        radius = np.where(pending & (rho < 0.25), radius / 4.0, radius)
        radius = np.where(pending & (rho > 0.75) & hit_boundary, radius * 2.0, radius)
        moved = pending & (rho > 1e-4) & (decrease > 0)
        if np.array_equal(moved, pending):  # every robot that stepped moved
            q_change += reach_step
        else:
            step = np.where(robots.spread(moved), step, 0.0)
            reach_step = block.reach @ flat(step)
            q_step = reach_step[block.own_in_reach].reshape(step.shape)
            q_change += reach_step
        z = z + step
        euclidean = euclidean + q_step
        accepted += moved
        rejected += pending & ~moved
        pending &= (accepted < options.rtr_iterations) & (rejected < MAX_REJECTIONS)
        if not pending.any():
            break
    return LocalStep(z, q_change, products)
