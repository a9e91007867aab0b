"""The hybrid action's distribution: a masked categorical edge × a squashed Gaussian correction.

π(e, δ | s) = π(e | s) · π(δ | s, e) (paper §III-B): the edge e ∈ {0..E} is drawn from a masked
softmax (E, the last choice, is the no-op, the only one allowed once every edge is processed),
then the correction from the Gaussian *of that edge*, squashed by tanh and scaled by Δmax. The
log-probability of an action is the sum of the parts', the entropy H(e | s) + E_e[H(δ | s, e)].
TorchRL's ``CompositeDistribution`` would treat e and δ as independent; here δ's Gaussian is
chosen by e (docs/algorithms.md, "Bring your own algorithm").

Public API (``from agents import HybridActionDistribution``): it works as the
``distribution_class`` of ``torchrl.modules.ProbabilisticActor`` (samples are ``(edge, delta)``
tuples, written to two out_keys; ``deterministic_sample`` is the arg-max edge and
Δmax·tanh(mean) of its Gaussian) and as the distribution ``torchrl.objectives.ClipPPOLoss``
evaluates (``log_prob`` of the action sub-tensordict {"edge", "delta"}).

The correction's density is that of δ/Δmax (the constant log-Jacobian of the scaling is dropped,
as agents.actor's). On the no-op the environment ignores δ: its part is left out of both sums.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor
from torch.distributions import Distribution

from agents.actor import categorical_entropy, masked_log_softmax, tanh_gaussian_log_prob

# Gauss–Hermite rule of the squashed Gaussian's entropy term E[log(1 − tanh² u)]
_HERMITE_NODES, _HERMITE_WEIGHTS = np.polynomial.hermite.hermgauss(24)
_TANH_LIMIT = 1.0 - 1e-6  # |δ/Δmax| is clamped to it before atanh


def log_one_minus_tanh_squared(u: Tensor) -> Tensor:
    """log(1 − tanh² u) = 2(log 2 − u − softplus(−2u)), exact and stable for large |u|."""
    return 2.0 * (math.log(2.0) - u - torch.nn.functional.softplus(-2.0 * u))


class HybridActionDistribution(Distribution):
    """π(e, δ | s) = π(e | s) · π(δ | s, e) of a batch of robots (batch shape [*]).

    Args:
        edge_logits: [*, E + 1] scores of the edge choices (normalised here over
            ``action_mask``; log-probabilities are accepted as they are).
        action_mask: [*, E + 1] bool, the edge choices allowed (the env's
            ("agents", "action_mask")); the last one is the no-op.
        delta_mean, delta_log_std: the pre-tanh Gaussian of the correction (units of δ/Δmax),
            either [*, E + 1, 3], one per edge choice (a policy that scores every edge; what
            sampling needs), or [*, 3], that of the one edge the action takes (evaluating a
            stored action, as agents.ppo_actor does; sampling then uses it for every edge).
        delta_max: [3] (or broadcastable to [*, 3]) Δmax, the bound of δ (the env's action
            spec's ``high``: m, m, rad, or whitened units).

    Example:
        >>> import torch
        >>> from agents import HybridActionDistribution
        >>> mask = torch.tensor([[True, True, False, False], [False, False, False, True]])
        >>> dist = HybridActionDistribution(
        ...     torch.zeros(2, 4), mask, torch.zeros(2, 4, 3), torch.zeros(2, 4, 3),
        ...     delta_max=torch.tensor([0.5, 0.5, 0.2]))
        >>> edge, delta = dist.sample()
        >>> edge.shape, delta.shape, bool(mask.gather(-1, edge[:, None]).all())
        (torch.Size([2]), torch.Size([2, 3]), True)
        >>> dist.log_prob(edge, delta).shape
        torch.Size([2])
        >>> dist.deterministic_sample[1]  # arg-max edge's Δmax·tanh(mean) = 0
        tensor([[0., 0., 0.],
                [0., 0., 0.]])
    """

    arg_constraints: dict = {}
    has_rsample = False

    def __init__(
        self,
        edge_logits: Tensor,
        action_mask: Tensor,
        delta_mean: Tensor,
        delta_log_std: Tensor,
        delta_max: Tensor,
    ) -> None:
        self.action_mask = action_mask.to(torch.bool)
        self.edge_log_probs = masked_log_softmax(edge_logits, self.action_mask)
        self.per_edge = delta_mean.dim() == edge_logits.dim() + 1
        self.delta_mean, self.delta_log_std = delta_mean, delta_log_std
        self.delta_max = torch.as_tensor(
            delta_max, dtype=delta_mean.dtype, device=delta_mean.device
        )
        super().__init__(batch_shape=edge_logits.shape[:-1], validate_args=False)

    def acting(self, edge: Tensor) -> Tensor:
        """[*] bool: `edge` is a real edge (its correction is executed), not the no-op."""
        return edge < self.edge_log_probs.shape[-1] - 1

    def edge_log_prob(self, edge: Tensor) -> Tensor:
        """[S, *] log π(e | s) of the edges `edge` [S, *] (long; S: any sample shape)."""
        log_probs = self.edge_log_probs.expand(*edge.shape, -1)
        return log_probs.gather(-1, edge.unsqueeze(-1)).squeeze(-1)

    def gaussian(self, edge: Tensor) -> tuple[Tensor, Tensor]:
        """(mean, log_std) [S, *, 3] of the correction's Gaussian on the edges `edge` [S, *]."""
        if not self.per_edge:
            shape = (*edge.shape, 3)
            return self.delta_mean.expand(shape), self.delta_log_std.expand(shape)
        index = edge[..., None, None].expand(*edge.shape, 1, 3)
        choices = self.delta_mean.shape[-2]

        def chosen(value: Tensor) -> Tensor:
            return value.expand(*edge.shape, choices, 3).gather(-2, index).squeeze(-2)

        return chosen(self.delta_mean), chosen(self.delta_log_std)

    def delta_log_prob(self, delta: Tensor, edge: Tensor) -> Tensor:
        """[S, *] log-density of δ/Δmax under the squashed Gaussian of `edge` [S, *]; `delta`
        [S, *, 3] in Δmax's units."""
        mean, log_std = self.gaussian(edge)
        squashed = (delta / self.delta_max).clamp(-_TANH_LIMIT, _TANH_LIMIT)
        return tanh_gaussian_log_prob(torch.atanh(squashed), mean, log_std)

    def log_prob(self, action: TensorDictBase | Tensor, delta: Tensor | None = None) -> Tensor:
        """[S, *] log π(e | s) + log π(δ | s, e) (the second term 0 on the no-op).

        Args:
            action: the env's action entry {"edge": [S, *] long, "delta": [S, *, 3]} (what
                ClipPPOLoss passes), or the edges [S, *] with `delta` (what ProbabilisticActor
                passes: its two sampled out_keys).
            delta: [S, *, 3] when `action` is the edges.
        """
        edge = action if delta is not None else action.get("edge")
        delta = delta if delta is not None else action.get("delta")
        correction = self.delta_log_prob(delta, edge)
        return self.edge_log_prob(edge) + torch.where(self.acting(edge), correction, 0.0)

    def sample(self, sample_shape: torch.Size | tuple = ()) -> tuple[Tensor, Tensor]:
        """(edge [S, *] long, delta [S, *, 3]): e ~ π(e | s), then δ from e's squashed Gaussian."""
        with torch.no_grad():
            probs = self.edge_log_probs.exp()
            flat = probs.reshape(-1, probs.shape[-1])
            draws = torch.multinomial(flat, math.prod(sample_shape), replacement=True)
            edge = draws.T.reshape(*sample_shape, *self.batch_shape)
            mean, log_std = self.gaussian(edge)
            pre_tanh = mean + log_std.exp() * torch.randn_like(mean)
            return edge, self.delta_max * torch.tanh(pre_tanh)

    @property
    def deterministic_sample(self) -> tuple[Tensor, Tensor]:
        """(arg-max edge [*], Δmax·tanh(mean) of its Gaussian [*, 3]): the policy the held-out
        protocol scores (TorchRL's DETERMINISTIC exploration type)."""
        edge = self.edge_log_probs.argmax(-1)
        return edge, self.delta_max * torch.tanh(self.gaussian(edge)[0])

    @property
    def mode(self) -> tuple[Tensor, Tensor]:
        """:attr:`deterministic_sample` (the arg-max edge and the squashed mean)."""
        return self.deterministic_sample

    def delta_entropy(self) -> Tensor:
        """[*] (or [*, E + 1] per edge) entropy of δ/Δmax = tanh(u): H(u) + E[log(1 − tanh² u)]
        summed over the 3 axes, the expectation by a 24-node Gauss–Hermite rule (exact to ~1e-6
        for |mean| ≲ 10)."""
        std = self.delta_log_std.exp()
        nodes = torch.as_tensor(_HERMITE_NODES, dtype=std.dtype, device=std.device)
        weights = torch.as_tensor(_HERMITE_WEIGHTS, dtype=std.dtype, device=std.device)
        u = self.delta_mean.unsqueeze(-1) + math.sqrt(2.0) * std.unsqueeze(-1) * nodes
        jacobian = (log_one_minus_tanh_squared(u) * weights).sum(-1) / math.sqrt(math.pi)
        gaussian = 0.5 * math.log(2.0 * math.pi * math.e) + self.delta_log_std
        return (gaussian + jacobian).sum(-1)

    def entropy(self) -> Tensor:
        """[*] H(e | s) + Σ_{e < E} π(e | s) H(δ | s, e). With one Gaussian ([*, 3]) the second
        term is its entropy where a real edge is allowed, 0 where only the no-op is (the env
        allows the no-op only then): on on-policy data, the taken edge's entropy is an
        unbiased one-sample estimate of the sum."""
        edge_entropy = categorical_entropy(self.edge_log_probs, self.action_mask)
        if self.per_edge:
            probs = self.edge_log_probs.exp()[..., :-1]
            return edge_entropy + (probs * self.delta_entropy()[..., :-1]).sum(-1)
        acting = self.action_mask[..., :-1].any(-1)
        return edge_entropy + torch.where(acting, self.delta_entropy(), 0.0)
