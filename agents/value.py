"""The PPO value functions: V_i(s) per robot, centralised (MAPPO) or local (IPPO).

A shared, non-recurrent gated GNN (the critic's width and depth, ModelConfig.critic_hidden /
critic_layers, with deterministic gates) embeds every robot's local graph; robot i's features
are x_i = [graph latent ‖ episode progress (agents.critic.progress)]. One MLP shared by the
robots (critic_projection, *critic_mlp → 1) reads
    MAPPO: [x_i ‖ x_1 ‖ … ‖ x_n]   (agent i's own features first, then the whole team's, as
                                     CentralCritic without the actions)
    IPPO:  x_i                     (its own local graph only).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import Tensor, nn

from agents.actor import ACTION_MASK_KEY, AGENTS, OBSERVATION_FIELDS, OBSERVATION_KEY, mlp
from agents.config import ModelConfig
from agents.critic import PROGRESS_FEATURES, progress
from agents.encoder import GraphBatch, GraphEncoder

VALUE_KEY = (AGENTS, "state_value")


class TeamValue(nn.Module):
    """V(s) for n robots: `forward` maps B·n graphs (agent-major) to [B, n, 1]."""

    def __init__(
        self, node_dim: int, edge_dim: int, agents: int, config: ModelConfig, central: bool
    ) -> None:
        super().__init__()
        self.agents, self.central = agents, central
        self.encoder = GraphEncoder.from_config(
            node_dim, edge_dim, config, config.critic_hidden, config.critic_layers
        )
        own = config.critic_hidden + PROGRESS_FEATURES
        width = (agents + 1) * own if central else own
        self.head = mlp([width, config.critic_projection, *config.critic_mlp, 1])

    def forward(self, graphs: GraphBatch) -> Tensor:
        """[B, n, 1] values of B·n local graphs (graph b·n + i is robot i of element b)."""
        encoding = self.encoder(graphs, deterministic=True)
        own = torch.cat([encoding.pooled, progress(graphs)], dim=-1)
        own = own.reshape(-1, self.agents, own.shape[-1])  # [B, n, d]
        if self.central:
            batch, agents, width = own.shape
            team = own.reshape(batch, 1, agents * width).expand(batch, agents, agents * width)
            own = torch.cat([own, team], dim=-1)
        return self.head(own)


class ValueOperator(TensorDictModuleBase):
    """TensorDict wrapper of `TeamValue`: reads ("agents", "observation", …) and
    ("agents", "action_mask") with leading dims [*, n], writes ("agents", "state_value")
    [*, n, 1] (the key ClipPPOLoss and GAE are given)."""

    def __init__(self, network: TeamValue) -> None:
        super().__init__()
        self.network = network
        self.in_keys = [
            *(OBSERVATION_KEY + (name,) for name in OBSERVATION_FIELDS),
            ACTION_MASK_KEY,
        ]
        self.out_keys = [VALUE_KEY]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action_mask = tensordict.get(ACTION_MASK_KEY)
        graphs = GraphBatch.from_observation(tensordict.get(OBSERVATION_KEY), action_mask)
        value = self.network(graphs)
        tensordict.set(VALUE_KEY, value.reshape(*action_mask.shape[:-1], 1))
        return tensordict
