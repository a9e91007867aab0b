"""The GA-SAC central critic (CTDE, paper §III-D): twin soft Q-values per agent.

A shared, non-recurrent gated GNN embeds every robot's local graph. For each robot the vector
x_i = [graph latent ‖ embedding of its chosen edge [h_p ‖ h_q ‖ a_pq ‖ symlog r_pq] ‖
correction / Δmax ‖ symlog(r_pq + Δ) ‖ episode progress] is formed (with the base step,
`ModelConfig.base_features`, the correction is the *executed* one, clip(δ + Δ_GN), and x_i adds
tanh of its predicted gain and of Δ_GN's by the quadratic model of envs.basestep: the step
reward's argument to second order, so the critic sees what the reward depends on), and the n
vectors are concatenated (the paper's joint input). Each twin head is one MLP shared by the agents:
Q_i = MLP([x_i ‖ x_1 ‖ … ‖ x_n]) (projection to 512, then (512, 256) → 1), a MAAC-style
Q_i(s, a_1..a_n) read against agent i's own reward.

Agent i's own features come first, at the same place for every agent. `own_action_only` (the
actor loss) feeds Q_i agent i's features live and every other agent's detached, so that agent
j's action is moved only by its own Q_j (agent j's correction does not change agent i's reward).
symlog(r_pq + Δ) is the chosen edge's residual after the correction (exact: the environment
moves the head by Δ in the tail's frame): the action's known effect on the edge, not the value of
that effect. Why each input is there, with its measurements: docs/training.md, "The critic's
inputs".

The critic is built for a fixed team size n (training only); actors replicate to any n. The two
twin heads share the GNN trunk (one graph pass per batch); the heads themselves are independent.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from agents.actor import mlp
from agents.config import ModelConfig
from agents.encoder import (
    RESIDUAL_FEATURES,
    Encoding,
    GraphBatch,
    GraphEncoder,
    chosen_base,
    chosen_edge_embedding,
    edge_embedding_width,
    predicted_gain,
    symlog,
)


def corrected_residual(residuals: Tensor, edge_weights: Tensor, delta: Tensor) -> Tensor:
    """[G, 3] residual of each chosen edge after its correction: r + Δ.

    The environment moves the head q in the tail's frame by exactly Δ (envs.core, eq. C), so the
    chosen edge's residual [R_pᵀ(t_q − t_p) − t̃, θ_q − θ_p − θ̃] becomes r + Δ (in the action's
    units: metric, or whitened, where an angle is not wrapped at ±π). Args: residuals [G, E, 3];
    edge_weights [G, E + 1] (row E, the no-op, has a zero residual); delta [G, 3].
    """
    padded = torch.cat([residuals, torch.zeros_like(residuals[:, :1])], dim=1).to(delta.dtype)
    return torch.einsum("ge,ged->gd", edge_weights, padded) + delta


def progress(graphs: GraphBatch) -> Tensor:
    """[G, 2] episode progress of each agent: fraction of its real edges still unprocessed and
    log(1 + number of selectable choices).

    The soft value depends strongly on how many steps are left (future rewards, entropy bonuses,
    when the terminal bonus arrives), but nothing else in the critic's input says it: the GNN
    never reads the processed flags. Without it the TD error is dominated by this unexplained
    time dependence.
    """
    real = graphs.edge_mask.sum(-1).clamp(min=1).to(torch.float32)
    left = (graphs.edge_mask & ~graphs.processed).sum(-1).to(torch.float32)
    choices = graphs.action_mask.sum(-1).to(torch.float32)
    return torch.stack([left / real, torch.log1p(choices)], dim=-1)


PROGRESS_FEATURES = 2  # see progress()
BASE_GAIN_FEATURES = 2  # tanh of the predicted gain of the executed correction and of Δ_GN


class CentralCritic(nn.Module):
    """Q(s, a) for n agents; `forward` returns [B, n, 2] (twin heads on the last axis)."""

    def __init__(self, node_dim: int, edge_dim: int, agents: int, config: ModelConfig) -> None:
        super().__init__()
        self.agents = agents
        self.encoder = GraphEncoder.from_config(
            node_dim, edge_dim, config, config.critic_hidden, config.critic_layers
        )
        per_agent = (
            config.critic_hidden
            + edge_embedding_width(config.critic_hidden, edge_dim)
            + 3
            + RESIDUAL_FEATURES
            + PROGRESS_FEATURES
            + (BASE_GAIN_FEATURES if config.base_features else 0)
        )
        self.base_features = config.base_features
        self.heads = nn.ModuleList(
            nn.Sequential(
                nn.Linear((agents + 1) * per_agent, config.critic_projection),
                nn.ReLU(),
                mlp([config.critic_projection, *config.critic_mlp, 1]),
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
        own_action_only: bool = False,
    ) -> tuple[Tensor, Encoding]:
        """Twin Q-values.

        Args:
            graphs: B·n local graphs, agent-major inside each batch element (graph b·n + i).
            edge_weights: [B·n, E + 1] one-hot (or straight-through) choice of each agent's edge.
            delta: [B·n, 3] corrections in the environment's units.
            deterministic: noise-free gates (target evaluations use the same sampling as training).
            own_action_only: Q_i differentiable only through agent i's features (the actor
                loss; module docstring). The values are the same either way.
        Returns:
            ([B, n, 2] Q-values, the critic encoder's output for its gate penalty).
        """
        encoding = self.encoder(graphs, deterministic)
        weights = edge_weights.to(encoding.nodes.dtype)
        chosen = chosen_edge_embedding(encoding.nodes, graphs, weights)
        extra = []
        if self.base_features:  # what the environment executes: δ + Δ_GN, clipped
            step, model = chosen_base(graphs.base_step, graphs.base_model, weights)
            delta = torch.maximum(torch.minimum(delta + step, self.delta_max), -self.delta_max)
            gains = torch.stack([predicted_gain(model, delta), predicted_gain(model, step)], -1)
            extra = [torch.tanh(gains)]
        after = symlog(corrected_residual(graphs.residuals, weights, delta))
        per_agent = torch.cat(
            [encoding.pooled, chosen, delta / self.delta_max, after, progress(graphs), *extra],
            dim=-1,
        )
        own = per_agent.reshape(-1, self.agents, per_agent.shape[-1])  # [B, n, d]
        batch, agents, width = own.shape
        if own_action_only:  # row i: slot i live, every other slot detached
            diagonal = torch.eye(agents, dtype=torch.bool, device=own.device)[None, :, :, None]
            joint = torch.where(diagonal, own.unsqueeze(1), own.detach().unsqueeze(1))
        else:
            joint = own.unsqueeze(1).expand(batch, agents, agents, width)
        inputs = torch.cat([own, joint.reshape(batch, agents, agents * width)], dim=-1)
        q_values = torch.cat([head(inputs) for head in self.heads], dim=-1)  # [B, n, 2]
        return q_values, encoding
