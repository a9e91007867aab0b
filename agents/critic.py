"""The GA-SAC central critic (CTDE, paper §III-D): twin soft Q-values per agent.

A shared, non-recurrent gated GNN embeds every robot's local graph. For each robot the vector
[graph latent ‖ embedding of its chosen edge [h_p ‖ h_q ‖ a_pq] ‖ correction / Δmax] is formed;
the n vectors are concatenated, projected to 512, and an MLP (512, 256) returns, per twin head,
one Q-value per agent (MAAC-style Q_i(s, a_1..a_n), read against each agent's own reward).

The critic is built for a fixed team size n (training only); actors replicate to any n. The two
twin heads share the GNN trunk (one graph pass per batch); the heads themselves are independent.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from agents.actor import mlp
from agents.config import ModelConfig
from agents.encoder import Encoding, GraphBatch, GraphEncoder, edge_embeddings


class CentralCritic(nn.Module):
    """Q(s, a) for n agents; `forward` returns [B, n, 2] (twin heads on the last axis)."""

    def __init__(self, node_dim: int, edge_dim: int, agents: int, config: ModelConfig) -> None:
        super().__init__()
        self.agents = agents
        self.encoder = GraphEncoder.from_config(
            node_dim, edge_dim, config, config.critic_hidden, config.critic_layers
        )
        per_agent = config.critic_hidden + 2 * config.critic_hidden + edge_dim + 3
        self.heads = nn.ModuleList(
            nn.Sequential(
                nn.Linear(agents * per_agent, config.critic_projection),
                nn.ReLU(),
                mlp([config.critic_projection, *config.critic_mlp, agents]),
            )
            for _ in range(2)
        )
        self.register_buffer("delta_max", torch.tensor(config.delta_max, dtype=torch.float32))

    def forward(
        self,
        graphs: GraphBatch,
        edge_weights: Tensor,
        delta: Tensor,
        deterministic: bool = False,
    ) -> tuple[Tensor, Encoding]:
        """Twin Q-values.

        Args:
            graphs: B·n local graphs, agent-major inside each batch element (graph b·n + i).
            edge_weights: [B·n, E + 1] one-hot (or straight-through) choice of each agent's edge.
            delta: [B·n, 3] corrections in the environment's units.
            deterministic: noise-free gates (target evaluations use the same sampling as training).
        Returns:
            ([B, n, 2] Q-values, the critic encoder's output for its gate penalty).
        """
        encoding = self.encoder(graphs, deterministic)
        embeddings = edge_embeddings(encoding.nodes, graphs)
        chosen = torch.einsum("ge,ged->gd", edge_weights.to(embeddings.dtype), embeddings)
        per_agent = torch.cat([encoding.pooled, chosen, delta / self.delta_max], dim=-1)
        joint = per_agent.reshape(-1, self.agents * per_agent.shape[-1])
        q_values = torch.stack([head(joint) for head in self.heads], dim=-1)
        return q_values, encoding
