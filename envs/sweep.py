"""GaussNewtonSweep: the simple non-learned policy of the subtree mode (issue 14, item 6), and the
Gauss–Newton base step of the residual action (``base="gauss-newton"``).

In the pose mode the same sweep moves the head alone (the "subtree" is one vertex) and takes a
Gauss–Newton Δ on every edge: one block-coordinate pass, the pose mode's non-learned reference.

One root-outward pass over each agent's spanning-tree edges (the order of
:class:`envs.expert.Expert`, then the remaining edges with ``Δ = 0``). The Δ of a tree edge is one
Gauss–Newton step on the 3-vector Δ itself: the moved subtree is rigid, so only the edges that
cross its boundary change, and with the whitened residuals ``e = [√τ r_x, √τ r_y, √κ r_θ]``
of the agent's local edges against their measurements (``F = Σ ‖e‖²``) the step is
``Δ = −(N + μI)⁻¹ Jᵀ e``, ``N = JᵀJ``, with ``J = ∂e/∂Δ`` by forward differences (step
:data:`STEP`; rows of the non-crossing edges are zero) and a tiny damping μ (:data:`DAMPING`) for a
subtree whose boundary does not fix all three directions. A step longer than the action bound
(Δmax, and in the whitened action scale also ±:data:`~envs.core.WHITENED_DELTA_MAX` of the edge's
σ) is shortened along its own direction to fit (:func:`fit_bounds`): the core's componentwise clip
would turn it off the Gauss–Newton direction, and such steps can raise F (docs/never_worse.md).
Needs the problem's measurements only (no ground truth, no optimum).

The residual action (:func:`base_action`): the core executes the Gauss–Newton Δ plus the actor's
residual, in the whitened action scale a residual in units of the move's own standard deviation,
``N^−½`` (docs/never_worse.md has why and what it changed); :func:`base_residual` is its inverse,
the residual that executes a given action (the expert's imitation target).
"""

from __future__ import annotations

import torch

from envs.core import PGOCore
from envs.expert import Expert
from envs.geometry import _gather_rows, residuals

STEP = 1e-6  # forward-difference step of J [m, rad]
DAMPING = 1e-9  # μ, relative to the largest diagonal entry of JᵀJ


class GaussNewtonSweep:
    """The one-pass Gauss–Newton policy over a :class:`PGOCore` (subtree or pose mode)."""

    def __init__(self, core: PGOCore) -> None:
        self.core = core
        self.order = Expert(core)  # only its edge order is used (no optimum is computed)

    def delta(self, edge: torch.Tensor) -> torch.Tensor:
        """``(B, n, 3)`` one Gauss–Newton Δ per agent on ``edge (B, n)`` (0 off the tree), in
        the core's action units (:func:`gauss_newton_delta`)."""
        return gauss_newton_delta(self.core, edge)

    def act(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The policy's joint action ``(edge (B, n), delta (B, n, 3))``."""
        edge = self.order.edge()
        return edge, self.delta(edge)


def gauss_newton_delta(core: PGOCore, edge: torch.Tensor) -> torch.Tensor:
    """``(B, n, 3)`` one Gauss–Newton Δ per agent on ``edge (B, n)`` (0 off the tree), within
    the action bound (:func:`fit_bounds`), in the core's action units."""
    flat_edge = _flat(core, edge)
    step = _base_step(core, flat_edge, *_normal_equations(core, flat_edge))
    return _action_units(core, flat_edge, step).view(core.batch, core.num_agents, 3)


def base_action(core: PGOCore, edge: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
    """``(B, n, 3)`` what the core executes with ``base="gauss-newton"`` on ``edge (B, n)``
    for the actor's ``residual (B, n, 3)``, in the core's action units (the core clips it
    afterwards): the Gauss–Newton Δ plus the residual.

    In the whitened action scale the residual ``a`` is in units of the move's own standard
    deviation, ``N^−½ a`` [m, m, rad] with ``N = JᵀJ`` (module docstring: every local edge that
    crosses the moved subtree's boundary, the chosen edge among them), so that ``a`` raises the
    linearised local F above the Gauss–Newton point by ``‖a‖²`` whatever the lever arms and the
    precision of the crossing edges. Where the chosen edge is the only crossing edge and its
    translation information is isotropic, ``N = Λ`` and the unit is the edge's own σ (that of
    the whitened scale without a base). In the metric scale ``a`` is in metres and radians.
    """
    flat_edge = _flat(core, edge)
    normal, gradient = _normal_equations(core, flat_edge)
    step = _base_step(core, flat_edge, normal, gradient)
    residual = residual.to(core.device, core.dtype).reshape(-1, 3)
    if core.action_scale == "whitened":
        residual = (_root(normal, -0.5) @ residual.unsqueeze(-1)).squeeze(-1)
        real = flat_edge < core.dims.edges  # the no-op moves nothing
        step = step + torch.where(real, residual, torch.zeros_like(residual))
        return _action_units(core, flat_edge, step).view(core.batch, core.num_agents, 3)
    return (step + residual).view(core.batch, core.num_agents, 3)


def base_residual(core: PGOCore, edge: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """``(B, n, 3)`` the residual for which :func:`base_action` on ``edge (B, n)`` is
    ``action (B, n, 3)`` (action units; neither clipped): the imitation target of an expert's
    action under ``base="gauss-newton"``."""
    flat_edge = _flat(core, edge)
    normal, gradient = _normal_equations(core, flat_edge)
    step = _base_step(core, flat_edge, normal, gradient)
    action = action.to(core.device, core.dtype).reshape(-1, 3)
    if core.action_scale == "metric":
        return (action - step).view(core.batch, core.num_agents, 3)
    root = _gather_rows(
        core.tensors["inverse_sqrt_information"].view(flat_edge.shape[0], -1, 3, 3), flat_edge
    )
    metric = (root @ action.view(-1, 1, 3, 1)).view(-1, 3)
    residual = (_root(normal, 0.5) @ (metric - step).unsqueeze(-1)).squeeze(-1)
    return residual.view(core.batch, core.num_agents, 3)


def fit_bounds(core: PGOCore, edge: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
    """``(G, 3)`` the metric ``step (G, 3)`` [m, m, rad] on the edge slots ``edge (G, 1)``
    shortened along its direction (scaled by one factor ≤ 1) so that the core's clip leaves it
    unchanged: ``|step| ≤ Δmax`` componentwise and, in the whitened action scale,
    ``|Λ^½ step| ≤`` the action bound."""
    ratio = (step.abs() / core.delta_max).amax(-1)
    if core.action_scale == "whitened":
        ratio = torch.maximum(
            ratio, (_action_units(core, edge, step).abs() / core.action_bound).amax(-1)
        )
    return step / ratio.clamp_min(1.0).unsqueeze(-1)


def _flat(core: PGOCore, edge: torch.Tensor) -> torch.Tensor:
    """``(G, 1)`` int64 edge slots of ``edge (B, n)``, ``G = B·n``."""
    return edge.to(core.device, torch.int64).reshape(core.batch * core.num_agents, 1)


def _normal_equations(core: PGOCore, edge: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(N + μI (G, 3, 3), Jᵀe (G, 3))`` of the move on the edge slots ``edge (G, 1)`` at the
    current poses (module docstring), J by forward differences."""
    t = core.tensors
    g = edge.shape[0]
    poses = t["poses"].view(g, -1, 3)
    probes = torch.cat(
        [torch.zeros(1, 3, dtype=core.dtype), STEP * torch.eye(3, dtype=core.dtype)]
    ).to(core.device)  # (4, 3): Δ = 0 and the three unit steps
    whitening = _whitening(core)
    errors = []
    for probe in probes:  # four evaluations, each vectorised over every agent and edge
        moved, _ = core.subtree_move(poses, edge, probe.expand(g, 1, 3))
        errors.append(_whitened_errors(core, moved, whitening).flatten(1))
    e0 = errors[0]
    jacobian = torch.stack([(value - e0) / STEP for value in errors[1:]], -1)  # (G, 3E', 3)
    normal = jacobian.transpose(1, 2) @ jacobian
    scale = normal.diagonal(dim1=1, dim2=2).amax(-1).clamp_min(1.0)
    eye = torch.eye(3, dtype=core.dtype, device=core.device)
    normal = normal + DAMPING * scale[:, None, None] * eye
    return normal, (jacobian.transpose(1, 2) @ e0.unsqueeze(-1)).squeeze(-1)


def _base_step(
    core: PGOCore, edge: torch.Tensor, normal: torch.Tensor, gradient: torch.Tensor
) -> torch.Tensor:
    """``(G, 3)`` metric Gauss–Newton step ``−N⁻¹Jᵀe`` on the edge slots ``edge (G, 1)`` (0 off
    the tree in the subtree mode, on the no-op in the pose mode), within the bound
    (:func:`fit_bounds`)."""
    step = -torch.linalg.solve(normal, gradient.unsqueeze(-1)).squeeze(-1)
    if core.correction == "pose":
        on_tree = edge < core.dims.edges
    else:
        on_tree = torch.gather(core.tensors["tree_edge"].view(edge.shape[0], -1), 1, edge)
    step = torch.where(on_tree, step, torch.zeros_like(step))
    return fit_bounds(core, edge, step)


def _root(normal: torch.Tensor, power: float) -> torch.Tensor:
    """``(G, 3, 3)`` ``N^power`` of symmetric positive definite ``normal (G, 3, 3)``."""
    values, vectors = torch.linalg.eigh(normal)
    return (vectors * values.pow(power).unsqueeze(-2)) @ vectors.transpose(1, 2)


def _action_units(core: PGOCore, edge: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
    """``(G, 3)`` the metric ``step (G, 3)`` in the core's action units on the edge slots
    ``edge (G, 1)``: ``Λ^½ step`` in the whitened scale, ``step`` in the metric one."""
    if core.action_scale != "whitened":
        return step
    root = _gather_rows(core.tensors["sqrt_information"].view(edge.shape[0], -1, 3, 3), edge)
    return (root @ step.view(-1, 1, 3, 1)).view(-1, 3)


def _whitening(core: PGOCore) -> torch.Tensor:
    """``(G, E+1, 3)`` ``[√τ, √τ, √κ]`` of every edge slot (the residuals' whitening)."""
    t = core.tensors
    g = core.batch * core.num_agents
    return torch.stack([t["tau"].view(g, -1).sqrt()] * 2 + [t["kappa"].view(g, -1).sqrt()], -1)


def _whitened_errors(core: PGOCore, poses: torch.Tensor, whitening: torch.Tensor) -> torch.Tensor:
    """``(G, E+1, 3)`` ``[√τ r_t, √κ r_θ]`` of every edge slot against the measurements
    (``whitening``: :func:`_whitening`)."""
    t = core.tensors
    g = poses.shape[0]
    tails, heads = t["tails"].view(g, -1), t["heads"].view(g, -1)
    r = residuals(
        _gather_rows(poses, tails), _gather_rows(poses, heads), t["measurements"].view(g, -1, 3)
    )
    return r * whitening
