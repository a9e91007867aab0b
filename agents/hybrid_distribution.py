"""The hybrid action's distribution for PPO: a masked categorical edge × a squashed Gaussian Δ.

π(e, δ | s) = π(e | s) · π(δ | s, e): the edge e is drawn from the edge head's masked softmax,
the correction from the correction head's Gaussian on the chosen edge, squashed by tanh and
scaled by Δmax. The log-probability of an action is the sum of the parts' log-probabilities, and
the entropy the sum of the parts' entropies, so that `torchrl.objectives.ClipPPOLoss` takes the
distribution as it is: it calls the actor's `get_dist` and `log_prob` with the action entry
("agents", "action"), a sub-tensordict {"edge", "delta"} (docs/algorithms.md).

The correction's density is that of δ/Δmax (as agents.actor's: the constant log-Jacobian of the
scaling is dropped). On the forced no-op (the last choice, the only one left once every edge is
processed) the environment ignores δ: its part is left out of both sums there.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from tensordict import TensorDictBase
from torch import Tensor
from torch.distributions import Distribution

from agents.actor import categorical_entropy, tanh_gaussian_log_prob

# Gauss–Hermite rule of the squashed Gaussian's entropy term E[log(1 − tanh² u)]
_HERMITE_NODES, _HERMITE_WEIGHTS = np.polynomial.hermite.hermgauss(24)
_TANH_LIMIT = 1.0 - 1e-6  # |δ/Δmax| is clamped to it before atanh


def log_one_minus_tanh_squared(u: Tensor) -> Tensor:
    """log(1 − tanh² u) = 2(log 2 − u − softplus(−2u)), exact and stable for large |u|."""
    return 2.0 * (math.log(2.0) - u - torch.nn.functional.softplus(-2.0 * u))


class HybridActionDistribution(Distribution):
    """π(e, δ | s) of a batch of robots (batch shape [*]).

    Args:
        edge_log_probs: [*, E + 1] log π(e | s), −inf outside `action_mask`.
        action_mask: [*, E + 1] bool, the edge choices allowed; the last one is the no-op.
        delta_mean, delta_log_std: [*, 3] the pre-tanh Gaussian of the correction of the edge
            the action takes (the actor's correction head given that edge).
        delta_max: [3] Δmax, the correction's bound (m, m, rad or whitened units).
    """

    arg_constraints: dict = {}
    has_rsample = False

    def __init__(
        self,
        edge_log_probs: Tensor,
        action_mask: Tensor,
        delta_mean: Tensor,
        delta_log_std: Tensor,
        delta_max: Tensor,
    ) -> None:
        self.edge_log_probs, self.action_mask = edge_log_probs, action_mask
        self.delta_mean, self.delta_log_std, self.delta_max = delta_mean, delta_log_std, delta_max
        super().__init__(batch_shape=edge_log_probs.shape[:-1], validate_args=False)

    def acting(self, edge: Tensor) -> Tensor:
        """[*] bool: `edge` is a real edge (its correction is executed), not the no-op."""
        return edge < self.edge_log_probs.shape[-1] - 1

    def edge_log_prob(self, edge: Tensor) -> Tensor:
        """[*] log π(e | s) of the edges `edge` [*] (long)."""
        return self.edge_log_probs.gather(-1, edge.unsqueeze(-1)).squeeze(-1)

    def delta_log_prob(self, delta: Tensor) -> Tensor:
        """[*] log-density of δ/Δmax under the squashed Gaussian; `delta` [*, 3] in Δmax's units."""
        squashed = (delta / self.delta_max).clamp(-_TANH_LIMIT, _TANH_LIMIT)
        return tanh_gaussian_log_prob(torch.atanh(squashed), self.delta_mean, self.delta_log_std)

    def log_prob(self, action: TensorDictBase) -> Tensor:
        """[*] log π(e | s) + log π(δ | s, e) (the second term 0 on the no-op).

        Args:
            action: {"edge": [*] long, "delta": [*, 3]} (the env's action entry).
        """
        edge = action.get("edge")
        delta = self.delta_log_prob(action.get("delta"))
        return self.edge_log_prob(edge) + torch.where(self.acting(edge), delta, 0.0)

    def delta_entropy(self) -> Tensor:
        """[*] entropy of δ/Δmax = tanh(u): H(u) + E[log(1 − tanh² u)] summed over the 3 axes,
        the expectation by a 24-node Gauss–Hermite rule (exact to ~1e-6 for |mean| ≲ 10)."""
        std = self.delta_log_std.exp()
        nodes = torch.as_tensor(_HERMITE_NODES, dtype=std.dtype, device=std.device)
        weights = torch.as_tensor(_HERMITE_WEIGHTS, dtype=std.dtype, device=std.device)
        u = self.delta_mean.unsqueeze(-1) + math.sqrt(2.0) * std.unsqueeze(-1) * nodes
        jacobian = (log_one_minus_tanh_squared(u) * weights).sum(-1) / math.sqrt(math.pi)
        gaussian = 0.5 * math.log(2.0 * math.pi * math.e) + self.delta_log_std
        return (gaussian + jacobian).sum(-1)

    def entropy(self) -> Tensor:
        """[*] H(e | s) + H(δ | s, e) (the second term 0 where the no-op is the only choice: the
        environment allows the no-op only then, so that is where the action does not act)."""
        acting = self.action_mask[..., :-1].any(-1)
        edge_entropy = categorical_entropy(self.edge_log_probs, self.action_mask)
        return edge_entropy + torch.where(acting, self.delta_entropy(), 0.0)
