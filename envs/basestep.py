"""The Gauss–Newton base step of every candidate edge at once, from subtree sums (issue 26).

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
of two prefix sums: all candidates cost O(V + E) per step, one evaluation of every edge. Finally
``g_c = s_c P_cᵀ g_ξ``, ``H_c = P_cᵀ H_ξ P_c``; positions are taken relative to the agent's vertex
0 to keep the products well conditioned. The candidate edge itself crosses ``S_c`` and
contributes ``W_c²`` (``K_c P_c = I``). In the pose mode ``S_c = {q}``: the vertex sums
themselves, without ``ψ``.

In whitened action units (``Δ_metric = A Δ_w``, ``A = Λ^−½``) the model is ``g_w = Aᵀ g``,
``H_w = Aᵀ H A``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import torch

from envs.geometry import _gather_rows

if TYPE_CHECKING:
    from envs.core import PGOCore

DAMPING = 1e-9  # μ, relative to the largest diagonal entry of H (at least 1)


class BaseModel(NamedTuple):
    """The quadratic model of every agent's local F in each edge slot's action Δ.

    Attributes:
        gradient: ``(G, E+1, 3)`` g_c (F ≈ F₀ + 2 gᵀΔ + ΔᵀHΔ), action units (0 off the tree).
        hessian: ``(G, E+1, 3, 3)`` H_c, action units (0 off the tree).
        step: ``(G, E+1, 3)`` Δ_GN = −(H + μI)⁻¹ g, action units (0 off the tree).
        local_f: ``(G,)`` the agent's current local F = Σ ‖W r‖².
    """

    gradient: torch.Tensor
    hessian: torch.Tensor
    step: torch.Tensor
    local_f: torch.Tensor


MODEL_FEATURES = 9  # observed per edge: g / F (3) and the upper triangle of H / F (6)
UPPER = (0, 1, 2, 4, 5, 8)  # flat indices of a 3 × 3 matrix's upper triangle


def observed_model(model: BaseModel) -> torch.Tensor:
    """``(G, E+1, 9)`` the model as the actor observes it, relative to the agent's local F:
    ``[g / F, upper(H) / F]``, so that ``−(2 gᵀΔ + ΔᵀHΔ) / F`` is the predicted fraction of the
    local F a correction Δ removes (the step reward's argument, envs.core)."""
    scale = (model.local_f + 1e-12)[:, None, None]
    upper = model.hessian.flatten(-2)[..., list(UPPER)]
    return torch.cat([model.gradient, upper], -1) / scale


def _skew(xy: torch.Tensor) -> torch.Tensor:
    """``S t`` = (−y, x) of ``(..., 2)`` points."""
    return torch.stack([-xy[..., 1], xy[..., 0]], -1)


def _rotation_transpose(theta: torch.Tensor) -> torch.Tensor:
    """``(..., 2, 2)`` R(θ)ᵀ."""
    c, s = torch.cos(theta), torch.sin(theta)
    return torch.stack([torch.stack([c, s], -1), torch.stack([-s, c], -1)], -2)


def _twist_jacobian(rotation_t: torch.Tensor, lever: torch.Tensor) -> torch.Tensor:
    """``(..., 3, 3)`` [[Rᵀ, Rᵀ S t], [0, 0, 1]] for ``rotation_t (..., 2, 2)``, ``t (..., 2)``."""
    top = torch.cat([rotation_t, (rotation_t @ _skew(lever).unsqueeze(-1))], -1)
    bottom = torch.zeros_like(top[..., :1, :])
    bottom[..., 0, 2] = 1.0
    return torch.cat([top, bottom], -2)


def _inverse_twist_jacobian(jacobian: torch.Tensor) -> torch.Tensor:
    """The inverse [[R, −S t], [0, 0, 1]] of :func:`_twist_jacobian`'s [[Rᵀ, Rᵀ S t], [0, 0, 1]]."""
    rotation = jacobian[..., :2, :2].transpose(-1, -2)
    inverse = torch.zeros_like(jacobian)
    inverse[..., :2, :2] = rotation
    inverse[..., :2, 2:] = -(rotation @ jacobian[..., :2, 2:])
    inverse[..., 2, 2] = 1.0
    return inverse


def _subtree_sums(values: torch.Tensor, position: torch.Tensor, end: torch.Tensor) -> torch.Tensor:
    """``(G, V+1, k)`` Σ over each vertex's subtree of per-vertex ``values (G, V+1, k)``
    (positions form a permutation of 0..V, every subtree is ``[position, end)``)."""
    g, slots, k = values.shape
    ordered = torch.zeros_like(values).scatter_(1, position.unsqueeze(-1).expand(-1, -1, k), values)
    prefix = torch.cat([torch.zeros_like(ordered[:, :1]), ordered.cumsum(1)], 1)  # (G, V+2, k)
    upper = torch.gather(prefix, 1, end.unsqueeze(-1).expand(-1, -1, k))
    lower = torch.gather(prefix, 1, position.unsqueeze(-1).expand(-1, -1, k))
    return upper - lower


def base_model(core: PGOCore) -> BaseModel:
    """The quadratic model and Gauss–Newton step of every edge slot of every agent (module
    docstring), from the core's current poses and residuals."""
    t = core.tensors
    g = core.batch * core.num_agents
    slots = core.dims.vertices + 1
    poses = t["poses"].view(g, -1, 3)
    tails, heads = t["tails"].view(g, -1), t["heads"].view(g, -1)
    tau, kappa = t["tau"].view(g, -1), t["kappa"].view(g, -1)
    weight = torch.stack([tau, tau, kappa], -1)  # (G, E+1, 3): W²
    r = t["residuals"].view(g, -1, 3)
    local_f = (weight * r * r).sum((-1, -2))
    origin = poses[:, :1, :2]
    x_tail, x_head = _gather_rows(poses, tails), _gather_rows(poses, heads)
    k_edge = _twist_jacobian(_rotation_transpose(x_tail[..., 2]), x_head[..., :2] - origin)
    weighted = weight.unsqueeze(-1) * k_edge  # W² K
    u = (weighted * r.unsqueeze(-1)).sum(-2)  # Kᵀ W² r, (G, E+1, 3)
    h = (k_edge.transpose(-1, -2) @ weighted).flatten(-2)  # Kᵀ W² K, (G, E+1, 9)

    def scatter(index: torch.Tensor, values: torch.Tensor) -> torch.Tensor:
        k = values.shape[-1]
        out = values.new_zeros(g, slots, k)
        return out.scatter_add_(1, index.unsqueeze(-1).expand(-1, -1, k), values)

    phi = scatter(heads, u) - scatter(tails, u)
    chi = scatter(heads, h) + scatter(tails, h)
    if core.correction == "subtree":
        position, end = t["tree_position"].view(g, -1), t["tree_end"].view(g, -1)
        psi = scatter(t["lca"].view(g, -1), h)
        phi = _subtree_sums(phi, position, end)
        chi = _subtree_sums(chi, position, end) - 2.0 * _subtree_sums(psi, position, end)
        mover = t["mover"].view(g, -1)
        on_tree = t["tree_edge"].view(g, -1)
    else:
        mover = heads
        on_tree = torch.arange(tails.shape[1], device=core.device) < core.dims.edges
    g_twist = _gather_rows(phi, mover)  # (G, E+1, 3)
    h_twist = _gather_rows(chi, mover).view(g, -1, 3, 3)
    sign = torch.where(mover == heads, 1.0, -1.0).to(poses.dtype).unsqueeze(-1)
    p_c = _inverse_twist_jacobian(k_edge)  # [[R_p, −S t_q], [0, 1]] = K_c⁻¹
    gradient = sign * (p_c.transpose(-1, -2) @ g_twist.unsqueeze(-1)).squeeze(-1)
    hessian = p_c.transpose(-1, -2) @ h_twist @ p_c
    if core.action_scale == "whitened":
        inverse_root = t["inverse_sqrt_information"].view(g, -1, 3, 3)
        gradient = (inverse_root.transpose(-1, -2) @ gradient.unsqueeze(-1)).squeeze(-1)
        hessian = inverse_root.transpose(-1, -2) @ hessian @ inverse_root
    keep = on_tree.unsqueeze(-1)
    gradient = torch.where(keep, gradient, torch.zeros_like(gradient))
    hessian = torch.where(keep.unsqueeze(-1), hessian, torch.zeros_like(hessian))
    scale = hessian.diagonal(dim1=-2, dim2=-1).amax(-1).clamp_min(1.0)
    eye = torch.eye(3, dtype=poses.dtype, device=core.device)
    damped = hessian + DAMPING * scale[..., None, None] * eye
    step = -torch.linalg.solve(damped, gradient.unsqueeze(-1)).squeeze(-1)
    return BaseModel(gradient, hessian, torch.where(keep, step, torch.zeros_like(step)), local_f)
