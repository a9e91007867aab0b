"""The Gauss–Newton base step of every candidate edge at once, from subtree sums, and of
one chosen edge from its boundary.

A correction Δ on edge ``c = (p → q)`` of an agent's spanning tree moves the subtree ``S_c`` of
its mover rigidly (:meth:`envs.core.PGOCore.subtree_move`). With the whitened errors
``e_m = W_m r_m``, ``W_m² = diag(τ_m, τ_m, κ_m)`` (``F = Σ ‖e_m‖²``, eq. 1), the local quadratic
model of the agent's F in Δ is

    F(Δ) ≈ F + 2 g_cᵀ Δ + Δᵀ H_c Δ,         Δ_GN = −(H_c + μI)⁻¹ g_c,

summed over the edges that cross the boundary of ``S_c``. Write the subtree's motion as a world
twist ξ = (a, ω) about the origin, ``δt_v = a + ω S t_v``, ``δθ_v = ω`` (``S`` the 90° rotation).
Then ``ξ = s_c P_c Δ`` with ``P_c = [[R_p, −S t_q], [0, 1]]`` and ``s_c = +1`` when the head
moves, ``−1`` when the tail does, and an edge ``m = (a → b)`` with one endpoint in ``S_c`` has
``∂r_m/∂ξ = σ_m K_m``, ``K_m = [[R_aᵀ, R_aᵀ S t_b], [0, 1]]``, ``σ_m = 1[b ∈ S_c] − 1[a ∈ S_c]``.
So, with ``u_m = K_mᵀ W_m² r_m`` and ``h_m = K_mᵀ W_m² K_m`` (candidate-free),

    g_ξ(c) = Σ_m (1[b ∈ S_c] − 1[a ∈ S_c]) u_m = Σ_{v ∈ S_c} φ_v,
    H_ξ(c) = Σ_m crossing h_m = Σ_{v ∈ S_c} χ_v − 2 Σ_{v ∈ S_c} ψ_v,

with ``φ_v = Σ_{head m = v} u_m − Σ_{tail m = v} u_m``, ``χ_v = Σ_{m ∋ v} h_m`` and
``ψ_v = Σ_{lca(m) = v} h_m`` (an edge lies inside ``S_c`` iff its endpoints' lowest common
ancestor does). Subtrees are contiguous pre-order ranges, so every subtree sum is a difference
of two prefix sums: all candidates cost O(V + E) per step, one evaluation of every edge
(:func:`base_model`, for the training observation, which shows every candidate's model). The
step the environment executes needs the chosen edge's model alone: :func:`chosen_model` takes the
same sums directly over the edges that cross ``S_c``'s boundary (:func:`boundary`),
O(boundary). Finally
``g_c = s_c P_cᵀ g_ξ``, ``H_c = P_cᵀ H_ξ P_c``; positions are taken relative to the agent's vertex
0 (the chosen edge's head in :func:`chosen_model`) to keep the products well conditioned. The
candidate edge itself crosses ``S_c`` and contributes ``W_c²`` (``K_c P_c = I``). In the pose
mode ``S_c = {q}``: the vertex sums themselves, without ``ψ``.

In whitened action units (``Δ_metric = A Δ_w``, ``A = Λ^−½``) the model is ``g_w = Aᵀ g``,
``H_w = Aᵀ H A``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import torch

from envs.features import BASE_MODEL
from envs.geometry import _gather_rows

if TYPE_CHECKING:
    from envs.state import CoreState

DAMPING = 1e-9  # μ, relative to the largest diagonal entry of H (at least 1)


class StepModes(NamedTuple):
    """What the base step needs of the core's modes.

    Attributes:
        correction: ``"pose"`` or ``"subtree"`` (what a correction moves, :mod:`envs.core`).
        delta_max: ``(3,)`` Δmax, metric (δx [m], δy [m], δθ [rad]).
        action_bound: ``(3,)`` the bound of the action's Δ (Δmax, or the whitened bound).
        whitened: the action is in units of the chosen edge's σ (``action_scale="whitened"``).
    """

    correction: str
    delta_max: torch.Tensor
    action_bound: torch.Tensor
    whitened: bool


class BaseModel(NamedTuple):
    """The quadratic model of every agent's local F in each edge slot's action Δ.

    Attributes:
        gradient: ``(G, E+1, 3)`` g_c (F ≈ F₀ + 2 gᵀΔ + ΔᵀHΔ), action units (0 off the tree).
        hessian: ``(G, E+1, 6)`` the upper triangle of H_c (xx, xy, xθ, yy, yθ, θθ), action
            units (0 off the tree).
        step: ``(G, E+1, 3)`` Δ_GN = −(H + μI)⁻¹ g, shortened along its direction where it
            exceeds the action bound or Δmax, action units (0 off the tree).
        local_f: ``(G,)`` the agent's current local F = Σ ‖W r‖².
    """

    gradient: torch.Tensor
    hessian: torch.Tensor
    step: torch.Tensor
    local_f: torch.Tensor


MODEL_FEATURES = BASE_MODEL  # observed per edge: g / F (3) and the upper triangle of H / F (6)
UPPER = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))  # the order of the upper triangle


def observed_model(model: BaseModel) -> torch.Tensor:
    """``(G, E+1, 9)`` the model as the actor observes it, relative to the agent's local F:
    ``[g / F, upper(H) / F]``, so that ``−(2 gᵀΔ + ΔᵀHΔ) / F`` is the predicted fraction of the
    local F a correction Δ removes (the step reward's argument, envs.core)."""
    scale = (model.local_f + 1e-12)[:, None, None]
    return torch.cat([model.gradient, model.hessian], -1) / scale


def upper_to_matrix(upper: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` the symmetric matrix of an ``(..., 6)`` upper triangle (:data:`UPPER`)."""
    xx, xy, xt, yy, yt, tt = upper.unbind(-1)
    rows = [[xx, xy, xt], [xy, yy, yt], [xt, yt, tt]]
    return torch.stack([torch.stack(row, -1) for row in rows], -2)


def _rotate(theta: torch.Tensor, xy: torch.Tensor, transpose: bool = False) -> torch.Tensor:
    """``R(θ) xy`` (or ``R(θ)ᵀ xy``) of ``(..., 2)`` vectors."""
    c, s = torch.cos(theta), torch.sin(theta)
    s = -s if transpose else s
    return torch.stack([c * xy[..., 0] - s * xy[..., 1], s * xy[..., 0] + c * xy[..., 1]], -1)


def _dot(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Dot product over a last axis of 2 (written out: a reduction over 2 entries is slower)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


def _apply(parts: torch.Tensor, vector: list, transpose: bool = False) -> list:
    """``M v`` (or ``Mᵀ v``) for matrices given by their components ``parts (3, 3, ...)``
    (:func:`envs.geometry.matrix_parts`) and a vector given as three component tensors, written
    out (batched 3 × 3 products on strided views are several times slower)."""
    if transpose:
        return [sum(parts[j, i] * vector[j] for j in range(3)) for i in range(3)]
    return [sum(parts[i, j] * vector[j] for j in range(3)) for i in range(3)]


def _congruence(parts: torch.Tensor, h: dict) -> list:
    """The upper triangle (:data:`UPPER`) of ``Aᵀ H A``, ``A`` by its components ``parts`` and the
    symmetric ``H`` by its entries ``h[(i, j)]`` (i ≤ j), written out."""

    def entry(i: int, j: int) -> torch.Tensor:
        return h[(min(i, j), max(i, j))]

    ha = [[sum(entry(i, j) * parts[j, k] for j in range(3)) for k in range(3)] for i in range(3)]
    return [sum(parts[j, i] * ha[j][k] for j in range(3)) for i, k in UPPER]


def _fit(vector: list, bound: torch.Tensor) -> torch.Tensor:
    """The largest factor ≤ 1 that brings every component of ``vector`` (three tensors) within
    ``±bound (3,)``."""
    ratios = [bound[i] / component.abs().clamp_min(1e-300) for i, component in enumerate(vector)]
    return torch.minimum(torch.minimum(ratios[0], ratios[1]), ratios[2]).clamp(max=1.0)


def _subtree_sums(values: torch.Tensor, position: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
    """``(G, V+1, k)`` Σ over each vertex's subtree of per-vertex ``values (G, V+1, k)``
    (positions form a permutation of 0..V, every subtree is ``[position, end)``)."""
    k = values.shape[-1]
    ordered = torch.zeros_like(values).scatter_(1, position.unsqueeze(-1).expand(-1, -1, k), values)
    prefix = torch.cat([torch.zeros_like(ordered[:, :1]), ordered.cumsum(1)], 1)  # (G, V+2, k)
    upper = torch.gather(prefix, 1, end.unsqueeze(-1).expand(-1, -1, k))
    lower = torch.gather(prefix, 1, position.unsqueeze(-1).expand(-1, -1, k))
    return upper - lower


def base_model(t: CoreState, modes: StepModes) -> BaseModel:
    """The quadratic model and Gauss–Newton step of every edge slot of every agent (module
    docstring), from the state's current poses and residuals, by subtree sums (the training
    observation shows every candidate's model)."""
    g = t.tails.shape[0] * t.tails.shape[1]
    slots = t.poses.shape[2]
    poses = t.poses.view(g, -1, 3)
    tails, heads = t.tails.view(g, -1), t.heads.view(g, -1)
    tau, kappa = t.tau.view(g, -1), t.kappa.view(g, -1)
    r = t.residuals.view(g, -1, 3)
    origin = poses[:, :1, :2]
    x_tail, x_head = _gather_rows(poses, tails), _gather_rows(poses, heads)
    head_xy = x_head[..., :2] - origin
    u, h = _edge_terms(x_tail[..., 2], head_xy, r, tau, kappa)

    def scatter(index: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        k = values.shape[-1]
        out = values.new_zeros(g, slots, k)
        return out.scatter_add_(1, index.unsqueeze(-1).expand(-1, -1, k), values)

    per_vertex = torch.cat([scatter(heads, u) - scatter(tails, u), scatter(heads, h)], -1)
    per_vertex[..., 3:] += scatter(tails, h)
    if modes.correction == "subtree":
        per_vertex[..., 3:] -= 2.0 * scatter(t.lca.view(g, -1), h)
        position, end = t.tree_position.view(g, -1), t.tree_end.view(g, -1)
        per_vertex = _subtree_sums(per_vertex, position, end)
        mover = t.mover.view(g, -1)
        on_tree = t.tree_edge.view(g, -1)
    else:
        mover = heads
        on_tree = torch.arange(tails.shape[1], device=tails.device) < t.edge_mask.shape[-1]
    sums = _gather_rows(per_vertex, mover)  # (G, E+1, 7): g_ξ (3), α, β (2), γ
    sign = torch.where(mover == heads, 1.0, -1.0).to(poses.dtype)
    lever = torch.stack([-head_xy[..., 1], head_xy[..., 0]], -1)
    parts = [part.view(3, 3, g, -1) for part in _whitening_parts(t)]
    gradient, hessian, step = _solve(modes, sums, x_tail[..., 2], sign, -lever, parts)
    keep = on_tree.to(poses.dtype).unsqueeze(-1)
    return BaseModel(gradient * keep, hessian * keep, step * keep, _local_f(r, tau, kappa))


class Boundary(NamedTuple):
    """The edges that cross a moved subtree's boundary, per agent (``G`` agents, ``V+1`` vertex
    and ``E+1`` edge slots): the only edges whose residual a subtree move changes.

    Attributes:
        crossing: ``(G, E+1)`` bool, the edge slot has exactly one endpoint in the subtree.
        slots: ``(K,)`` the crossing slots' flat ids ``agent·(E+1) + slot``, ascending.
        agent: ``(K,)`` the agent of each.
        head_inside: ``(K,)`` bool, its head is the endpoint in the subtree.
        tail_rows, head_rows: ``(K,)`` its endpoints' flat rows ``agent·(V+1) + vertex``.
    """

    crossing: torch.Tensor
    slots: torch.Tensor
    agent: torch.Tensor
    head_inside: torch.Tensor
    tail_rows: torch.Tensor
    head_rows: torch.Tensor


def boundary(t: CoreState, inside: torch.Tensor) -> Boundary:
    """The :class:`Boundary` of the vertices ``inside (G, V+1)`` (three comparisons per edge
    slot, then O(crossing edges))."""
    g = inside.shape[0]
    tails, heads = t.tails.view(g, -1), t.heads.view(g, -1)
    head_in = torch.gather(inside, 1, heads)
    crossing = torch.gather(inside, 1, tails) != head_in
    slots = crossing.flatten().nonzero().squeeze(-1)
    agent = slots // tails.shape[1]
    offset = agent * inside.shape[1]
    tail_rows = offset + tails.flatten()[slots]
    head_rows = offset + heads.flatten()[slots]
    return Boundary(crossing, slots, agent, head_in.flatten()[slots], tail_rows, head_rows)


def chosen_model(
    t: CoreState, modes: StepModes, edge: torch.Tensor, crossing: Boundary
) -> BaseModel:
    """The model and Gauss–Newton step of one edge slot per agent, ``edge (G, 1)``, whose
    correction moves a subtree with the boundary ``crossing`` (:func:`boundary`): the sums of the
    module docstring taken directly over the crossing edges, with positions relative to the
    chosen edge's head (so ``m = 0``), O(crossing edges); the local F, O(E). Fields as
    :class:`BaseModel` with the edge axis of length 1."""
    gradient, hessian, step = _chosen(t, modes, edge, crossing, model=True)
    g = edge.shape[0]
    r, tau, kappa = t.residuals.view(g, -1, 3), t.tau.view(g, -1), t.kappa.view(g, -1)
    return BaseModel(gradient, hessian, step, _local_f(r, tau, kappa))


def chosen_step(
    t: CoreState, modes: StepModes, edge: torch.Tensor, crossing: Boundary
) -> torch.Tensor:
    """``(G, 1, 3)`` the Gauss–Newton step Δ_GN of :func:`chosen_model` alone (what the
    environment executes), without the model's whitening and the local F."""
    return _chosen(t, modes, edge, crossing, model=False)[2]


def _chosen(
    t: CoreState, modes: StepModes, edge: torch.Tensor, crossing: Boundary, model: bool
) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
    """(gradient, hessian, step) of :func:`chosen_model`; gradient and Hessian None unless
    ``model``."""
    g = edge.shape[0]
    poses = t.poses.view(g, -1, 3)
    tails, heads = t.tails.view(g, -1), t.heads.view(g, -1)
    slots, agent = crossing.slots, crossing.agent
    flat_poses = poses.reshape(-1, 3)
    x_tail, x_head = flat_poses[crossing.tail_rows], flat_poses[crossing.head_rows]
    p, q = torch.gather(tails, 1, edge), torch.gather(heads, 1, edge)
    x_p, x_q = _gather_rows(poses, p).squeeze(1), _gather_rows(poses, q).squeeze(1)
    head_xy = x_head[:, :2] - x_q[agent, :2]
    r = t.residuals.view(-1, 3)[slots]
    u, h = _edge_terms(x_tail[:, 2], head_xy, r, t.tau.view(-1)[slots], t.kappa.view(-1)[slots])
    sigma = torch.where(crossing.head_inside, 1.0, -1.0).to(poses.dtype).unsqueeze(-1)
    sums = torch.zeros(g, 7, dtype=poses.dtype, device=poses.device)
    sums.index_add_(0, agent, torch.cat([sigma * u, h], -1))
    if modes.correction == "subtree":
        mover = torch.gather(t.mover.view(g, -1), 1, edge)
        on_tree = torch.gather(t.tree_edge.view(g, -1), 1, edge)
    else:
        mover, on_tree = q, edge < t.edge_mask.shape[-1]
    sign = torch.where(mover == q, 1.0, -1.0).to(poses.dtype)
    rows_g = torch.arange(g, device=edge.device)
    parts = [part.view(3, 3, g, -1)[:, :, rows_g, edge[:, 0], None] for part in _whitening_parts(t)]
    gradient, hessian, step = _solve(
        modes,
        sums.unsqueeze(1),
        x_p[:, None, 2],
        sign,
        torch.zeros_like(x_q[:, None, :2]),
        parts,
        model,
    )
    keep = on_tree.to(poses.dtype).unsqueeze(-1)
    if not model:
        return None, None, step * keep
    return gradient * keep, hessian * keep, step * keep


def _whitening_parts(t: CoreState) -> tuple[torch.Tensor, torch.Tensor]:
    """The components ``(3, 3, G, E+1)`` of Λ^½ and Λ^−½ (:func:`envs.geometry.matrix_parts`)."""
    return t.sqrt_information_parts, t.inverse_sqrt_information_parts


def _local_f(r: torch.Tensor, tau: torch.Tensor, kappa: torch.Tensor) -> torch.Tensor:
    """``(G,)`` the agent's local F = Σ ‖W r‖² of residuals ``r (G, E+1, 3)``."""
    return (tau * _dot(r, r) + kappa * r[..., 2] ** 2).sum(-1)


def _edge_terms(
    theta_tail: torch.Tensor,
    head_xy: torch.Tensor,
    r: torch.Tensor,
    tau: torch.Tensor,
    kappa: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The candidate-free terms of the edges ``m = (a → b)`` (module docstring):
    ``u_m (..., 3) = [τ R_a r_t, (S t_b)·(τ R_a r_t) + κ r_θ]`` and the four numbers
    ``h_m (..., 4) = [τ, τ S t_b, τ ‖t_b‖² + κ]`` of ``K_mᵀ W² K_m`` (``R_a`` orthonormal), from
    the tail's angle ``θ_a``, the head's position ``t_b`` relative to the chosen origin, the
    residuals and the weights."""
    lever = torch.stack([-head_xy[..., 1], head_xy[..., 0]], -1)  # S t_b
    pull = tau.unsqueeze(-1) * _rotate(theta_tail, r[..., :2])  # τ R_a r_t
    u = torch.cat([pull, (_dot(lever, pull) + kappa * r[..., 2]).unsqueeze(-1)], -1)
    h = torch.stack(
        [tau, tau * lever[..., 0], tau * lever[..., 1], tau * _dot(head_xy, head_xy) + kappa], -1
    )
    return u, h


def _solve(
    modes: StepModes,
    sums: torch.Tensor,
    theta_p: torch.Tensor,
    sign: torch.Tensor,
    m: torch.Tensor,
    parts: list[torch.Tensor],
    model: bool = True,
) -> tuple[torch.Tensor | None, torch.Tensor | None, torch.Tensor]:
    """(gradient ``(..., 3)``, upper Hessian ``(..., 6)``, step ``(..., 3)``) in action units of
    candidates with world-twist sums ``sums (..., 7)`` = [g_ξ (3), α, β (2), γ], tail angle
    ``θ_p``, sign ``s_c``, ``m = −S t_q`` (relative to the sums' origin) and the whitening
    ``parts`` [Λ^½, Λ^−½] by components ``(3, 3, ...)``; without ``model`` the step alone
    (gradient and Hessian None).

    Written out for the blocks: H_ξ is ``[[α I, β], [βᵀ, γ]]``, so
    ``H_c = [[α I, R_pᵀ(α m + β)], [·, α ‖m‖² + 2 β·m + γ]]`` and
    ``g_c = s_c [R_pᵀ g_t, m·g_t + g_θ]``, solved by its Schur complement."""
    alpha, beta, gamma = sums[..., 3], sums[..., 4:6], sums[..., 6]
    coupling = _rotate(theta_p, alpha.unsqueeze(-1) * m + beta, transpose=True)
    angular = alpha * _dot(m, m) + 2 * _dot(beta, m) + gamma
    g_t = sign.unsqueeze(-1) * _rotate(theta_p, sums[..., :2], transpose=True)
    g_theta = sign * (_dot(m, sums[..., :2]) + sums[..., 2])
    zero = torch.zeros_like(alpha)
    entries = [alpha, zero, coupling[..., 0], alpha, coupling[..., 1], angular]
    h_c = dict(zip(UPPER, entries, strict=True))
    # Gauss–Newton step (metric), damped by μ relative to the largest diagonal entry (at least 1)
    mu = DAMPING * torch.maximum(alpha, angular).clamp_min(1.0)
    a_damped, d_damped = alpha + mu, angular + mu
    step_theta = (-g_theta + _dot(coupling, g_t) / a_damped) / (
        d_damped - _dot(coupling, coupling) / a_damped
    )
    step_t = (-g_t - coupling * step_theta.unsqueeze(-1)) / a_damped.unsqueeze(-1)
    step = [step_t[..., 0], step_t[..., 1], step_theta]
    # shortened along its direction to fit Δmax (and below, the whitened bound): the core's
    # componentwise clip would turn an anisotropic step off its descent direction
    fit = _fit(step, modes.delta_max)
    gradient = [g_t[..., 0], g_t[..., 1], g_theta]
    hessian = [h_c[key] for key in UPPER]
    whitened = modes.whitened
    if whitened:  # Δ_w = Λ^½ Δ, g_w = Aᵀ g, H_w = Aᵀ H A (A = Λ^−½)
        root, inverse_root = parts
        step = _apply(root, step)
        fit = torch.minimum(fit, _fit(step, modes.action_bound))
    step = torch.stack([component * fit for component in step], -1)
    if not model:
        return None, None, step
    if whitened:
        gradient = _apply(inverse_root, gradient, transpose=True)
        hessian = _congruence(inverse_root, h_c)
    return torch.stack(gradient, -1), torch.stack(hessian, -1), step
