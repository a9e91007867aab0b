"""Supervised loss terms shared by the imitation phase (agents.imitation) and GA-SAC
(agents.loss): behaviour cloning of the expert and the supervised gate loss. Both are beyond
the paper (docs/training.md).

Behaviour cloning (the expert of envs.expert labels a state s):

    L_edge  = −log Σ_{e ∈ right(s)} π(e | s)
    L_delta = ‖(δ_θ(s, e) − clip(δ*(s, e))) / bound‖²

with ``bound`` the action bound (Δmax, or the whitened bound) and δ* the actor output that makes
the environment execute the expert's Δ on e.

Supervised gate loss (issue 15, item 4): every layer's gate logit α_ℓ/τ of an edge is regressed
on the injected label "keep" (1 for an inlier, 0 for an injected outlier) by binary cross-entropy,
σ(α/τ) being the noise-free relaxation u of the hard-concrete gate (the evaluation gate is
z = clamp(1.2 u − 0.1, 0, 1), so u > ½ ⇔ z > ½). Outliers are rare (a few per cent of a local
graph's edges), so the two classes are weighted equally: L_gate = ½ (mean BCE over the outlier
edges + mean BCE over the inlier edges), a class absent from the batch contributing 0. The gate
keeps its hard-concrete form and its L1 penalty; this term only adds a label.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F  # noqa: N812


def imitation_losses(
    log_probs: torch.Tensor,
    right: torch.Tensor,
    delta: torch.Tensor,
    label: torch.Tensor,
    acting: torch.Tensor,
    bound: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_edge, L_delta) of the module docstring, averaged over the G graphs (L_delta over the
    acting ones).

    Args:
        log_probs: (G, E + 1) log π(e | s); right: (G, E + 1) bool right choices.
        delta: (G, 3) the learner's correction on an edge; label: (G, 3) the expert's on it.
        acting: (G,) bool, the edge is a real edge (not the no-op).
        bound: (3,) the action bound.
    """
    right_log_prob = torch.logsumexp(log_probs.masked_fill(~right, float("-inf")), -1)
    edge_loss = -right_log_prob.mean()
    target = torch.maximum(torch.minimum(label, bound), -bound)
    squared = (((delta - target) / bound) ** 2).sum(-1)
    delta_loss = (squared * acting).sum() / acting.sum().clamp(min=1)
    return edge_loss, delta_loss


def gate_supervision_loss(
    logits: torch.Tensor, outlier: torch.Tensor, edge_mask: torch.Tensor
) -> torch.Tensor:
    """L_gate of the module docstring (a scalar).

    Args:
        logits: (L, G, E) the gates' noise-free logits α/τ (encoder.Encoding.gate_logits).
        outlier: (G, E) bool, the edge is an injected outlier.
        edge_mask: (G, E) bool, real (non-padding) edges.
    """
    keep = (~outlier).to(logits.dtype).expand_as(logits)
    bce = F.binary_cross_entropy_with_logits(logits, keep, reduction="none")
    loss = logits.new_zeros(())
    for members in (outlier & edge_mask, ~outlier & edge_mask):
        weight = members.to(logits.dtype).expand_as(logits)
        count = weight.sum()
        if count > 0:
            loss = loss + 0.5 * (bce * weight).sum() / count
    return loss
