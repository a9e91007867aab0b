"""The PPO policy: the GA-SAC actor (agents.actor.HybridActor) as a TorchRL probabilistic actor.

`get_dist` gives the hybrid distribution (agents.hybrid_distribution) of the stored action's
edge, which ClipPPOLoss reads the log-probability and entropy from; `forward` samples an action
and writes its log-probability at ("agents", "sample_log_prob"), and the recurrent state as
GASACPolicy does. The distribution is that of the actor with noise-free gates
(`deterministic=True` in the encoder): the hard-concrete gate noise is a regulariser of GA-SAC,
but under PPO a log-probability that changes between the rollout and the update would add noise
to every importance ratio. Sampling takes one actor pass (the edge is drawn inside it, then the
correction of that edge is read); evaluating a stored action one.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from torch.distributions import Categorical

from agents.actor import (
    ACTION_MASK_KEY,
    AGENTS,
    DELTA_ACTION_KEY,
    EDGE_ACTION_KEY,
    MEMORY_KEY,
    OBSERVATION_KEY,
    PREV_DELTA_KEY,
    PREV_EDGE_KEY,
    RECURRENT_KEYS,
    ActorOutput,
    GASACPolicy,
    HybridActor,
    recurrent_inputs,
    resolve_deterministic,
)
from agents.encoder import GraphBatch
from agents.hybrid_distribution import HybridActionDistribution

ACTION_KEY = (AGENTS, "action")
SAMPLE_LOG_PROB_KEY = (AGENTS, "sample_log_prob")


def sample_edge(log_probs: torch.Tensor) -> torch.Tensor:
    """[G] edges drawn from π(e | s), given as its log-probabilities [G, E + 1]."""
    return Categorical(logits=log_probs).sample()


class PPOPolicy(GASACPolicy):
    """Reads what GASACPolicy reads; writes ("agents", "action", "edge" | "delta"),
    ("agents", "sample_log_prob") [*, n] and the next recurrent state under ("next", "agents")."""

    def __init__(self, actor: HybridActor) -> None:
        super().__init__(actor)
        self.out_keys = [
            EDGE_ACTION_KEY,
            DELTA_ACTION_KEY,
            SAMPLE_LOG_PROB_KEY,
            *(("next",) + key for key in RECURRENT_KEYS),
        ]

    def _act(self, tensordict: TensorDictBase, edge: torch.Tensor | Callable | None) -> ActorOutput:
        """One actor pass with noise-free gates over the [*, n] robots of `tensordict`; `edge`
        [G] long takes that edge, a function of the log-probabilities draws it (None: the
        arg-max)."""
        action_mask = tensordict.get(ACTION_MASK_KEY)
        lead, choices = action_mask.shape[:-1], action_mask.shape[-1]
        graphs = GraphBatch.from_observation(tensordict.get(OBSERVATION_KEY), action_mask)
        memory, prev_edge, prev_delta = recurrent_inputs(
            tensordict, self.actor, lead, choices, next_=False
        )
        return self.actor(graphs, memory, prev_edge, prev_delta, deterministic=True, edge=edge)

    def _distribution(self, out: ActorOutput, lead: torch.Size) -> HybridActionDistribution:
        def shaped(value: torch.Tensor) -> torch.Tensor:
            return value.reshape(*lead, *value.shape[1:])

        return HybridActionDistribution(
            shaped(out.edge_log_probs),
            shaped(out.action_mask),
            shaped(out.delta_mean),
            shaped(out.delta_log_std),
            self.actor.delta_max,
        )

    def get_dist(self, tensordict: TensorDictBase) -> HybridActionDistribution:
        """π(· | s) with the correction's Gaussian on the stored edge ("agents", "action",
        "edge"), batch shape [*, n]: what ClipPPOLoss evaluates the stored action under."""
        edge = tensordict.get(EDGE_ACTION_KEY)
        out = self._act(tensordict, edge.reshape(-1))
        return self._distribution(out, edge.shape)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        lead = tensordict.get(ACTION_MASK_KEY).shape[:-1]
        if resolve_deterministic(None):
            out = self._act(tensordict, None)
        else:  # sample the edge, then the correction of that edge, in one pass
            out = self._act(tensordict, sample_edge)
            noise = torch.randn_like(out.delta_mean)
            pre_tanh = out.delta_mean + out.delta_log_std.exp() * noise
            out.delta = self.actor.delta_max * torch.tanh(pre_tanh)
        action = TensorDict(
            {"edge": out.edge.reshape(lead), "delta": out.delta.reshape(*lead, 3)}, lead
        )
        values = {  # [G, ...] per robot
            EDGE_ACTION_KEY: out.edge,
            DELTA_ACTION_KEY: out.delta,
            ("next",) + MEMORY_KEY: out.memory,
            ("next",) + PREV_EDGE_KEY: out.edge_weights.to(out.delta.dtype),
            ("next",) + PREV_DELTA_KEY: out.delta,
        }
        for key, value in values.items():
            tensordict.set(key, value.detach().reshape(*lead, *value.shape[1:]))
        log_prob = self._distribution(out, lead).log_prob(action)
        tensordict.set(SAMPLE_LOG_PROB_KEY, log_prob.detach())
        return tensordict
