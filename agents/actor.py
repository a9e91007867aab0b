"""The GA-SAC actor: one recurrent gated GNN with two heads, shared by every robot (paper §III-D).

Per decision step and robot:
1. the encoder embeds the robot's local graph (nodes h, latent = masked mean of h, gates z);
2. the memory (K GRUs) is refreshed with [latent ‖ embedding of the previously chosen edge ‖
   previous correction / Δmax];
3. the edge head scores every edge from [h_p ‖ h_q ‖ a_pq ‖ symlog r_pq ‖ memory] (→ 200 → 1),
   masked by the environment's action mask (unprocessed real edges; the no-op slot E only once
   none is left); an edge is drawn with a straight-through Gumbel-softmax (arg-max when
   deterministic); r_pq is the edge's current residual in its tail's frame, the frame of Δ
   (encoder.edge_embeddings);
4. the correction head (2 × 512 MLP) maps the chosen edge's embedding to a tanh-squashed
   Gaussian on (−1, 1)³, scaled by Δmax. Its mean outputs start at zero, so the untrained
   deterministic policy is the no-op (Δ = 0), and its log-std at `correction_init_log_std`.

Parameters are shared across robots (actor replication): a team of any size runs the same module.
Log-probabilities of the correction are those of δ/Δmax (the constant log-Jacobian of the scaling
is dropped), so the continuous target entropy is independent of Δmax.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModuleBase
from tensordict.nn.probabilistic import interaction_type
from torch import Tensor, nn
from torchrl.data import Composite, Unbounded
from torchrl.envs import TensorDictPrimer

from agents.config import ModelConfig
from agents.encoder import (
    BASE_INPUTS,
    RESIDUAL_FEATURES,
    Encoding,
    GraphBatch,
    GraphEncoder,
    Memory,
    base_inputs,
    chosen_base,
    chosen_edge_embedding,
    edge_embedding_width,
    symlog,
)

DETERMINISTIC_INTERACTIONS = (
    InteractionType.DETERMINISTIC,
    InteractionType.MODE,
    InteractionType.MEAN,
)


def mlp(sizes: Sequence[int], activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """Linear layers of the given widths with `activation` between them (none after the last)."""
    layers: list[nn.Module] = []
    for k, (d_in, d_out) in enumerate(zip(sizes[:-1], sizes[1:], strict=True)):
        layers.append(nn.Linear(d_in, d_out))
        if k < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


def resolve_deterministic(deterministic: bool | None) -> bool:
    """`deterministic` if given, else from tensordict's interaction type (RANDOM/None → sample)."""
    if deterministic is not None:
        return deterministic
    return interaction_type() in DETERMINISTIC_INTERACTIONS


def tanh_gaussian_log_prob(pre_tanh: Tensor, mean: Tensor, log_std: Tensor) -> Tensor:
    """log-density of y = tanh(u), u ~ N(mean, exp(log_std)²), summed over the last dim.

    Uses log(1 − tanh²u) = 2(log 2 − u − softplus(−2u)), exact and stable for large |u|.
    """
    gaussian = (
        -0.5 * ((pre_tanh - mean) / log_std.exp()) ** 2 - log_std - 0.5 * math.log(2 * math.pi)
    )
    log_jacobian = 2.0 * (math.log(2.0) - pre_tanh - F.softplus(-2.0 * pre_tanh))
    return (gaussian - log_jacobian).sum(-1)


def masked_log_softmax(logits: Tensor, mask: Tensor) -> Tensor:
    """log_softmax over the last dim with masked-out entries at −inf."""
    return torch.log_softmax(logits.masked_fill(~mask, float("-inf")), dim=-1)


def categorical_entropy(log_probs: Tensor, mask: Tensor) -> Tensor:
    """−Σ p log p over allowed entries (masked entries contribute 0 and a zero gradient, not NaN:
    the −inf is replaced before the product, since where() would still back-propagate 0·∞)."""
    finite = torch.where(mask, log_probs, torch.zeros_like(log_probs))
    return -(finite.exp() * finite * mask).sum(-1)


@dataclass
class ActorOutput:
    """Everything the environment, the critic and the loss need from one actor pass (G graphs).

    Attributes:
        edge: [G] long, chosen local edge index (E = the no-op, forced when no edge is left).
        edge_weights: [G, E + 1] one-hot of `edge`; straight-through Gumbel-softmax gradient when
            sampled (feed it to the critic to differentiate through the discrete choice).
        edge_log_probs: [G, E + 1] log π(e | s) (−inf outside the action mask).
        edge_entropy: [G] exact entropy of the edge distribution.
        action_mask: [G, E + 1] bool, the support of the edge distribution.
        delta: [G, 3] correction (δx, δy, δθ), |·| ≤ Δmax.
        delta_log_prob: [G] log π(δ/Δmax | s, e).
        memory: [G, K, H] refreshed memory state (the next step's input).
        encoding: the encoder output (gates, latent) for the gate penalty and inlier flags.
        delta_mean, delta_log_std: [G, 3] the pre-tanh Gaussian of the correction (its
            likelihood of a labelled action: imitation's NLL, the fine-tuning anchor).
    """

    edge: Tensor
    edge_weights: Tensor
    edge_log_probs: Tensor
    edge_entropy: Tensor
    action_mask: Tensor
    delta: Tensor
    delta_log_prob: Tensor
    memory: Tensor
    encoding: Encoding
    delta_mean: Tensor
    delta_log_std: Tensor


class HybridActor(nn.Module):
    """Recurrent gated GNN + edge selector + correction head (parameters shared by all robots)."""

    def __init__(self, node_dim: int, edge_dim: int, config: ModelConfig) -> None:
        super().__init__()
        self.config = config
        self.encoder = GraphEncoder.from_config(
            node_dim, edge_dim, config, config.hidden, config.layers
        )
        edge_dim_out = edge_embedding_width(config.hidden, edge_dim)
        self.memory = Memory(
            config.hidden + edge_dim_out + 3, config.memory_hidden, config.memory_layers
        )
        head_input = edge_dim_out + config.memory_hidden
        self.edge_head = mlp([head_input, config.edge_head_hidden, 1])
        correction_input = head_input + (BASE_INPUTS if config.base_features else 0)
        self.correction_head = mlp([correction_input, *config.correction_hidden, 6])
        self._init_correction_output()
        self.register_buffer("delta_max", torch.tensor(config.delta_max, dtype=torch.float32))

    def _init_correction_output(self) -> None:
        """Zero the last layer's mean rows and set its log-std bias to `correction_init_log_std`:
        the untrained deterministic policy is the no-op (Δ = tanh(0) = 0) instead of a random
        input-dependent shift, and exploration starts at a chosen width. A random mean made every
        untrained deterministic episode worse than doing nothing (held-out F −0.2 … −0.7 %).
        """
        last = self.correction_head[-1]
        with torch.no_grad():
            last.weight[:3].zero_()
            last.bias[:3].zero_()
            last.bias[3:].fill_(self.config.correction_init_log_std)

    def initial_memory(self, num_graphs: int, device: torch.device | str = "cpu") -> Tensor:
        """[G, K, H] zeros: the memory at the start of an episode."""
        return torch.zeros(num_graphs, self.memory.layers, self.memory.hidden, device=device)

    def forward(
        self,
        graphs: GraphBatch,
        memory: Tensor,
        prev_edge: Tensor,
        prev_delta: Tensor,
        deterministic: bool | None = None,
        edge: Tensor | Callable[[Tensor], Tensor] | None = None,
    ) -> ActorOutput:
        """One decision step for G robots.

        Args:
            graphs: the G local graphs.
            memory: [G, K, H] memory state from the previous step (zeros at reset).
            prev_edge: [G, E + 1] one-hot of the previously chosen edge (zeros at reset).
            prev_delta: [G, 3] previous correction in the environment's units (zeros at reset).
            deterministic: arg-max edge, tanh(mean) correction and noise-free gates; None reads
                tensordict's interaction type (sampling unless DETERMINISTIC/MODE/MEAN).
            edge: [G] long, an edge to take instead of choosing one (teacher forcing: the
                correction is then the one for this edge), or a function of the log π(e | s)
                [G, E + 1] that draws it (PPO's categorical sample: one pass, not two); None
                lets the edge head choose.
        """
        deterministic = resolve_deterministic(deterministic)
        encoding = self.encoder(graphs, deterministic)
        nodes = encoding.nodes
        prev_embedding = chosen_edge_embedding(nodes, graphs, prev_edge)
        memory_input = torch.cat(
            [encoding.pooled, prev_embedding, prev_delta / self.delta_max], dim=-1
        )
        memory = self.memory(memory_input, memory)
        context = memory[:, -1]
        log_probs = masked_log_softmax(self.edge_scores(nodes, graphs, context), graphs.action_mask)
        if edge is None:
            edge, edge_weights = self._choose_edge(log_probs, deterministic)
        else:
            edge = edge(log_probs) if callable(edge) else edge
            edge_weights = F.one_hot(edge, log_probs.shape[-1]).to(log_probs.dtype)
        # [embedding ‖ context] of the choice; Σ_e w_e = 1, and its gradient reaches every w_e
        chosen = torch.cat(
            [
                chosen_edge_embedding(nodes, graphs, edge_weights),
                edge_weights.sum(-1, keepdim=True) * context,
            ],
            dim=-1,
        )
        if self.config.base_features:
            base = base_inputs(
                *chosen_base(graphs.base_step, graphs.base_model, edge_weights), self.delta_max
            )
            chosen = torch.cat([chosen, base], -1)

        mean, log_std = self.correction_head(chosen).chunk(2, dim=-1)
        log_std = log_std.clamp(*self.config.log_std_bounds)
        if deterministic:
            pre_tanh = mean
        else:
            pre_tanh = mean + log_std.exp() * torch.randn_like(mean)
        return ActorOutput(
            edge=edge,
            edge_weights=edge_weights,
            edge_log_probs=log_probs,
            edge_entropy=categorical_entropy(log_probs, graphs.action_mask),
            action_mask=graphs.action_mask,
            delta=self.delta_max * torch.tanh(pre_tanh),
            delta_log_prob=tanh_gaussian_log_prob(pre_tanh, mean, log_std),
            memory=memory,
            encoding=encoding,
            delta_mean=mean,
            delta_log_std=log_std,
        )

    def edge_scores(self, nodes: Tensor, graphs: GraphBatch, context: Tensor) -> Tensor:
        """[G, E + 1] edge-head scores of the allowed choices (−inf elsewhere).

        The head's first layer on [h_p ‖ h_q ‖ a_pq ‖ symlog r_pq ‖ context] (the rows of
        `edge_embeddings` and the memory context) is split into two blocks: W_c·context once per
        graph, and W_e·[h_p ‖ h_q ‖ a_pq ‖ symlog r_pq] on the allowed rows alone
        (graphs.action_mask: the unprocessed real edges; on average a third of the padded slots).

        Args:
            nodes: [G, V, d] node embeddings; context: [G, H] the memory's output.
        """
        first, last = self.edge_head[0], self.edge_head[2]
        count, vertices, width = nodes.shape
        mask = graphs.action_mask
        allowed = mask.reshape(-1).nonzero().squeeze(-1)
        graph_of = torch.div(allowed, mask.shape[-1], rounding_mode="floor")
        slot = allowed - graph_of * mask.shape[-1]
        edges = graphs.edge_index.shape[-1]
        real = (slot < edges).to(nodes.dtype).unsqueeze(-1)  # the no-op row E has no edge part
        flat_slot = graph_of * edges + slot.clamp(max=edges - 1)
        weight = first.weight
        context_block = weight[:, 2 * width + graphs.edge_attr.shape[-1] + RESIDUAL_FEATURES :]
        hidden = F.linear(context, context_block, first.bias).index_select(0, graph_of)
        flat_nodes = nodes.reshape(count * vertices, width)
        local = graphs.edge_index.clamp(0, vertices - 1)
        ends = [  # h_p, h_q of the allowed rows' tails and heads, [A, d] each
            flat_nodes.index_select(0, graph_of * vertices + local[:, row].reshape(-1)[flat_slot])
            for row in (0, 1)
        ]
        features = torch.cat([graphs.edge_attr, symlog(graphs.residuals.to(nodes.dtype))], -1)
        rows = torch.cat([*ends, features.reshape(-1, features.shape[-1])[flat_slot]], -1)
        edge_part = F.linear(rows, weight[:, : rows.shape[-1]])
        hidden = torch.relu(hidden + real * edge_part)
        scores = torch.full_like(mask, float("-inf"), dtype=nodes.dtype)
        return scores.view(-1).index_copy(0, allowed, last(hidden).squeeze(-1)).view_as(scores)

    def _choose_edge(self, log_probs: Tensor, deterministic: bool) -> tuple[Tensor, Tensor]:
        """Arg-max, or a straight-through Gumbel-softmax sample: (index [G], weights [G, E])."""
        if deterministic:
            edge = log_probs.argmax(-1)
            return edge, F.one_hot(edge, log_probs.shape[-1]).to(log_probs.dtype)
        uniform = torch.rand_like(log_probs).clamp(1e-10, 1.0 - 1e-10)
        gumbel = -torch.log(-torch.log(uniform))
        soft = torch.softmax((log_probs + gumbel) / self.config.gumbel_temperature, dim=-1)
        edge = soft.argmax(-1)
        hard = F.one_hot(edge, log_probs.shape[-1]).to(soft.dtype)
        return edge, hard - soft.detach() + soft


AGENTS = "agents"
OBSERVATION_KEY = (AGENTS, "observation")
ACTION_MASK_KEY = (AGENTS, "action_mask")
EDGE_ACTION_KEY = (AGENTS, "action", "edge")
DELTA_ACTION_KEY = (AGENTS, "action", "delta")
MEMORY_KEY = (AGENTS, "memory")
PREV_EDGE_KEY = (AGENTS, "prev_edge")
PREV_DELTA_KEY = (AGENTS, "prev_delta")
OBSERVATION_FIELDS = (
    "node_features",
    "node_mask",
    "edge_index",
    "edge_attr",
    "edge_mask",
    "processed",
    "residuals",
)
BASE_FIELDS = ("base_step", "base_model")  # read when the actor has base features
RECURRENT_KEYS = (MEMORY_KEY, PREV_EDGE_KEY, PREV_DELTA_KEY)


def recurrent_inputs(
    tensordict: TensorDictBase, actor: HybridActor, lead: torch.Size, choices: int, next_: bool
) -> tuple[Tensor, Tensor, Tensor]:
    """(memory [G, K, H], prev_edge [G, E + 1], prev_delta [G, 3]) read from `tensordict`
    (under "next" when `next_`), zeros where a key is missing (start of an episode)."""
    prefix = ("next",) if next_ else ()
    device = tensordict.device or actor.delta_max.device
    defaults = (
        torch.zeros(*lead, actor.memory.layers, actor.memory.hidden, device=device),
        torch.zeros(*lead, choices, device=device),
        torch.zeros(*lead, 3, device=device),
    )
    values = []
    for key, default in zip(RECURRENT_KEYS, defaults, strict=True):
        value = tensordict.get(prefix + key, None)
        value = default if value is None else value
        values.append(value.reshape(-1, *default.shape[len(lead) :]).to(torch.float32))
    return values[0], values[1], values[2]


class GASACPolicy(TensorDictModuleBase):
    """TensorDict wrapper of `HybridActor` for TorchRL collectors and evaluation.

    Reads ("agents", "observation", …), ("agents", "action_mask") and the recurrent state
    ("agents", "memory" | "prev_edge" | "prev_delta") (zeros when absent); writes the action
    ("agents", "action", "edge" | "delta"), the log-probabilities, the gate inlier flags
    ("agents", "inlier", [n, E]) and the next recurrent state under ("next", "agents", …),
    where TorchRL's step_mdp moves it to the next step's root (as for its GRU/LSTM modules).
    `primer()` makes the env reset the recurrent state to zeros.
    """

    def __init__(self, actor: HybridActor) -> None:
        super().__init__()
        self.actor = actor
        self.in_keys = [
            *(OBSERVATION_KEY + (name,) for name in self.observation_fields()),
            ACTION_MASK_KEY,
            *RECURRENT_KEYS,
        ]
        self.out_keys = [
            EDGE_ACTION_KEY,
            DELTA_ACTION_KEY,
            (AGENTS, "edge_log_prob"),
            (AGENTS, "delta_log_prob"),
            (AGENTS, "inlier"),
            *(("next",) + key for key in RECURRENT_KEYS),
        ]

    def observation_fields(self) -> tuple[str, ...]:
        """The observation entries the actor reads."""
        return OBSERVATION_FIELDS + (BASE_FIELDS if self.actor.config.base_features else ())

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        action_mask = tensordict.get(ACTION_MASK_KEY)
        lead, choices = action_mask.shape[:-1], action_mask.shape[-1]
        graphs = GraphBatch.from_observation(tensordict.get(OBSERVATION_KEY), action_mask)
        memory, prev_edge, prev_delta = recurrent_inputs(
            tensordict, self.actor, lead, choices, next_=False
        )
        out = self.actor(graphs, memory, prev_edge, prev_delta)
        chosen_log_prob = out.edge_log_probs.gather(-1, out.edge.unsqueeze(-1)).squeeze(-1)
        values = {
            EDGE_ACTION_KEY: out.edge,
            DELTA_ACTION_KEY: out.delta,
            (AGENTS, "edge_log_prob"): chosen_log_prob,
            (AGENTS, "delta_log_prob"): out.delta_log_prob,
            (AGENTS, "inlier"): out.encoding.inliers(),
            ("next",) + MEMORY_KEY: out.memory,
            ("next",) + PREV_EDGE_KEY: out.edge_weights,
            ("next",) + PREV_DELTA_KEY: out.delta,
        }
        for key, value in values.items():
            tensordict.set(key, value.detach().reshape(*lead, *value.shape[1:]))
        return tensordict

    def primer(self, num_agents: int, choices: int) -> TensorDictPrimer:
        """A `TensorDictPrimer` that adds the zero recurrent state at every reset.

        Args:
            num_agents: n.
            choices: E + 1, the size of the edge action.
        """
        shapes = {
            "memory": (num_agents, self.actor.memory.layers, self.actor.memory.hidden),
            "prev_edge": (num_agents, choices),
            "prev_delta": (num_agents, 3),
        }
        agents = Composite(
            {name: Unbounded(shape=shape) for name, shape in shapes.items()},
            shape=(num_agents,),
        )
        return TensorDictPrimer(Composite(agents=agents), reset_key="_reset", expand_specs=True)
