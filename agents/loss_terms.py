"""Supervised loss terms shared by the imitation phase (agents.imitation) and GA-SAC
(agents.loss): behaviour cloning of the expert and the supervised gate loss. Both are beyond
the paper (docs/training.md).

Behaviour cloning (the expert of envs.expert labels a state s):

    L_edge  = −log Σ_{e ∈ right(s)} π(e | s)
    L_delta = Σ_k huber((u*_k − μ_k) / s_u) + Σ_k ½ min(((u*_k − sg(μ_k)) / σ_k)², 9) + log σ_k,
              u* = atanh(clip(δ*(s, e)) / bound)

with ``bound`` the action bound (Δmax, or the whitened bound), δ* the actor output that makes
the environment execute the expert's Δ on e, (μ, σ) the correction head's pre-tanh Gaussian
(δ = bound · tanh(u), u ~ N(μ, σ²)) and sg the stop-gradient. The mean regresses the label in
units of the batch's own label scale s_u (1.4826 × the median absolute deviation of u*,
robust to the heavy tail of labels near outliers), where a squared error in units of the ±5σ
bound left the head a constant. The second term is the Gaussian likelihood of the
label under σ with the mean held fixed and the standardised error capped at 3: σ learns the
head's real error (the exploration width GA-SAC starts from) without the 1/σ² weight that made
a full NLL's mean gradient explode on rare large labels (measured in a pilot: delta loss spikes
of 10³ and an episode whose local F rose).

Supervised gate loss (beyond the paper; docs/training.md): every layer's gate logit α_ℓ/τ of an
edge is regressed on the injected label "keep" (1 for an inlier, 0 for an injected outlier) by
binary cross-entropy, σ(α/τ) being the noise-free relaxation u of the hard-concrete gate (the
evaluation gate is z = clamp(1.2 u − 0.1, 0, 1), so u > ½ ⇔ z > ½). Outliers are rare (a few per
cent of a local graph's edges), so the two classes are weighted equally: L_gate = ½ (mean BCE over
the outlier edges + mean BCE over the inlier edges), a class absent from the batch contributing 0.
The gate keeps its hard-concrete form and its L1 penalty; this term only adds a label."""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F  # noqa: N812

if TYPE_CHECKING:
    from agents.actor import ActorOutput

LABEL_MARGIN = 1e-3  # |δ*| / bound ≤ 1 − margin before the atanh


def pre_tanh_label(label: torch.Tensor, bound: torch.Tensor) -> torch.Tensor:
    """(G, 3) u* = atanh(δ* / bound) of a label δ* clipped to the bound (less a margin)."""
    return torch.atanh(torch.clamp(label / bound, -1.0 + LABEL_MARGIN, 1.0 - LABEL_MARGIN))


def imitation_losses(
    log_probs: torch.Tensor,
    right: torch.Tensor,
    mean: torch.Tensor,
    log_std: torch.Tensor,
    label: torch.Tensor,
    acting: torch.Tensor,
    bound: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(L_edge, L_delta) of the module docstring, averaged over the G graphs (L_delta over the
    acting ones).

    Args:
        log_probs: (G, E + 1) log π(e | s); right: (G, E + 1) bool right choices.
        mean, log_std: (G, 3) the learner's pre-tanh Gaussian on an edge; label: (G, 3) the
            expert's action on it.
        acting: (G,) bool, the edge is a real edge (not the no-op).
        bound: (3,) the action bound.
    """
    right_log_prob = torch.logsumexp(log_probs.masked_fill(~right, float("-inf")), -1)
    edge_loss = -right_log_prob.mean()
    target = pre_tanh_label(label, bound)
    scale = label_scale(target[acting]) if bool(acting.any()) else target.new_ones(3)
    fit = F.huber_loss(mean / scale, target / scale, reduction="none", delta=1.0)
    standardised = ((target - mean.detach()) / log_std.exp()) ** 2
    width = 0.5 * standardised.clamp(max=STANDARDISED_CAP**2) + log_std
    per_graph = (fit + width).sum(-1)
    delta_loss = (per_graph * acting).sum() / acting.sum().clamp(min=1)
    return edge_loss, delta_loss


def actor_imitation_losses(
    out: ActorOutput,
    right: torch.Tensor,
    label: torch.Tensor,
    acting: torch.Tensor,
    bound: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """:func:`imitation_losses` of an actor pass ``out``: its edge log-probabilities and the
    Gaussian on its edge, against the right edges and the label (arguments as there)."""
    mean, log_std = out.delta_mean, out.delta_log_std
    return imitation_losses(out.edge_log_probs, right, mean, log_std, label, acting, bound)


STANDARDISED_CAP = 3.0  # |u* − μ| / σ beyond which the width term stops growing
MIN_LABEL_SCALE = 1e-3  # floor of s_u (pre-tanh units)


def label_scale(target: torch.Tensor) -> torch.Tensor:
    """(3,) s_u = 1.4826 · median |u* − median u*| of the labels ``target (K, 3)``, floored."""
    median = target.median(0).values
    spread = 1.4826 * (target - median).abs().median(0).values
    return spread.clamp(min=MIN_LABEL_SCALE).detach()


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
