"""GaussNewtonSweep: the simple non-learned policy of the subtree mode (issue 14, item 6).

In the pose mode the same sweep moves the head alone (the "subtree" is one vertex) and takes a
Gauss–Newton Δ on every edge: one block-coordinate pass, the pose mode's non-learned reference.

One root-outward pass over each agent's spanning-tree edges (the order of
:class:`envs.expert.Expert`, then the remaining edges with ``Δ = 0``). The Δ of a tree edge is one
Gauss–Newton step on the 3-vector Δ itself: the moved subtree is rigid, so only the edges that
cross its boundary change, and with the whitened residuals ``e = [√τ r_x, √τ r_y, √κ r_θ]``
of the agent's local edges against their measurements (``F = Σ ‖e‖²``) the step is
``Δ = −(JᵀJ + μI)⁻¹ Jᵀ e`` with ``J = ∂e/∂Δ`` by forward differences (step :data:`STEP`; rows of
the non-crossing edges are zero) and a tiny damping μ (:data:`DAMPING`) for a subtree whose
boundary does not fix all three directions. The core then clips Δ to Δmax. Needs the problem's
measurements only (no ground truth, no optimum).
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
    """``(B, n, 3)`` one Gauss–Newton Δ per agent on ``edge (B, n)`` (0 off the tree), in
    the core's action units."""
    t = core.tensors
    g = core.batch * core.num_agents
    flat_edge = edge.to(core.device, torch.int64).reshape(g, 1)
    poses = t["poses"].view(g, -1, 3)
    probes = torch.cat(
        [torch.zeros(1, 3, dtype=core.dtype), STEP * torch.eye(3, dtype=core.dtype)]
    ).to(core.device)  # (4, 3): Δ = 0 and the three unit steps
    whitening = _whitening(core)
    errors = []
    for probe in probes:  # four evaluations, each vectorised over every agent and edge
        moved, _ = core.subtree_move(poses, flat_edge, probe.expand(g, 1, 3))
        errors.append(_whitened_errors(core, moved, whitening).flatten(1))
    e0 = errors[0]
    jacobian = torch.stack([(value - e0) / STEP for value in errors[1:]], -1)  # (G, 3E', 3)
    normal = jacobian.transpose(1, 2) @ jacobian
    scale = normal.diagonal(dim1=1, dim2=2).amax(-1).clamp_min(1.0)
    eye = torch.eye(3, dtype=core.dtype, device=core.device)
    normal = normal + DAMPING * scale[:, None, None] * eye
    step = -torch.linalg.solve(normal, (jacobian.transpose(1, 2) @ e0.unsqueeze(-1)))
    step = step.squeeze(-1)
    on_tree = torch.gather(t["tree_edge"].view(g, -1), 1, flat_edge)
    if core.correction == "pose":
        on_tree = flat_edge < core.dims.edges
    step = torch.where(on_tree, step, torch.zeros_like(step))
    if core.action_scale == "whitened":
        root = _gather_rows(t["sqrt_information"].view(g, -1, 3, 3), flat_edge)
        step = (root @ step.view(g, 1, 3, 1)).view(g, 3)
    return step.view(core.batch, core.num_agents, 3)


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
