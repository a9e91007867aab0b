"""Edge-conditioned GNN encoder with adaptive edge gates and a GRU memory (paper §III-C).

Inputs are padded local graphs, one per (batch element, robot), flattened into one disjoint
PyG-style batch of G graphs so that a single forward serves every robot of every environment:
node i of graph g becomes node g·V + i and edge indices are offset accordingly. Padding edges
carry a zero mask and contribute neither messages nor degree.

Every pose-graph edge e = (p → q) (tail p, head q) is used in both directions: the paper's message
m_pq = W_pq h_q is routed to the tail p, and the reverse message m_qp = W_qp h_p to the head q,
with a direction flag appended to a_pq so that φ_edge can tell them apart (otherwise information
would only ever flow backwards along a trajectory). The gate is one scalar z_e per pose-graph edge,
computed from the mean of the two directed messages, and it masks both (eq. mask).

Edge-attribute layout: envs.features.EDGE (kind one-hot, log-information diagonal, timestep gap,
‖t̃‖, sin θ̃, cos θ̃), declared once there.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn
from torch_geometric.nn import MessagePassing

from agents.config import ModelConfig
from envs.features import EDGE_COLUMN

# the edge-feature columns the gate reads, from the observation's declaration (envs.features)
LOG_INFO_COLUMNS = slice(EDGE_COLUMN["log_info_x"], EDGE_COLUMN["log_info_theta"] + 1)
INTER_LOOP_COLUMN = EDGE_COLUMN["inter_loop"]
HARD_CONCRETE_STRETCH = (-0.1, 1.1)  # (a, b) of eq. minmax
RESIDUAL_FEATURES = 3  # symlog(r) of an edge in its embedding (edge_embeddings)


@dataclass
class GraphBatch:
    """G padded local graphs (G = batch × robots, flattened).

    Attributes:
        node_features: [G, V, d_v] float.
        edge_index: [G, 2, E] long, local vertex indices (row 0 tail p, row 1 head q).
        edge_attr: [G, E, d_e] float (layout in the module docstring).
        edge_mask: [G, E] bool, True for real (non-padding) edges.
        node_mask: [G, V] bool, True for real vertices.
        residuals: [G, E, 3] float, log-map residual of the current estimate (x, y, θ).
        processed: [G, E] bool, True for edges already corrected in this episode.
        action_mask: [G, E + 1] bool, the edges the actor may pick: unprocessed real edges, and
            the no-op slot E, which the environment allows only when none is left.
        base_step: [G, E, 3] float, the Gauss–Newton base step of every edge in action units,
            and base_model: [G, E, 9] its quadratic model relative to the local F
            (envs.basestep.observed_model); None in an environment without the base step.
    """

    node_features: Tensor
    edge_index: Tensor
    edge_attr: Tensor
    edge_mask: Tensor
    node_mask: Tensor
    residuals: Tensor
    processed: Tensor
    action_mask: Tensor
    base_step: Tensor | None = None
    base_model: Tensor | None = None

    @property
    def num_graphs(self) -> int:
        return self.node_features.shape[0]

    @classmethod
    def from_observation(cls, observation: TensorDictBase, action_mask: Tensor) -> GraphBatch:
        """Flatten an env observation with leading dims [*] (e.g. [B, n]) into G = prod(*) graphs.

        Args:
            observation: the env's ("agents", "observation") sub-tensordict (envs.torchrl_env).
            action_mask: [*, E + 1] bool, ("agents", "action_mask").
        """
        lead = action_mask.shape[:-1]

        def flat(key: str, event_dims: int) -> Tensor | None:
            value = observation.get(key, None)
            if value is None:
                return None
            return value.reshape(-1, *value.shape[len(lead) : len(lead) + event_dims])

        return cls(
            node_features=flat("node_features", 2),
            edge_index=flat("edge_index", 2),
            edge_attr=flat("edge_attr", 2),
            edge_mask=flat("edge_mask", 1),
            node_mask=flat("node_mask", 1),
            residuals=flat("residuals", 2),
            processed=flat("processed", 1),
            action_mask=action_mask.reshape(-1, action_mask.shape[-1]),
            base_step=flat("base_step", 2),
            base_model=flat("base_model", 2),
        )


@dataclass
class Encoding:
    """Output of `GraphEncoder`.

    Attributes:
        nodes: [G, V, d] final node embeddings h^(L).
        pooled: [G, d] masked mean of `nodes` over real vertices (the graph latent).
        gates: [L, G, E] gate value z per layer and edge (0 on padding).
        gate_l1: scalar, mean of z over layers and real edges (the L1 sparsity term).
        gate_logits: [L, G, E] the gates' noise-free logits α/τ (σ of it is the relaxation u
            the evaluation gate is made of; the supervised gate loss regresses it).
    """

    nodes: Tensor
    pooled: Tensor
    gates: Tensor
    gate_l1: Tensor
    gate_logits: Tensor

    def inliers(self, threshold: float = 0.5) -> Tensor:
        """[G, E] bool: edges whose layer-averaged gate exceeds `threshold` (kept, not pruned)."""
        return self.gates.mean(dim=0) > threshold


def symlog(x: Tensor) -> Tensor:
    """sign(x)·log(1 + |x|): compresses outlier-sized residuals while keeping small ones linear."""
    return torch.sign(x) * torch.log1p(torch.abs(x))


def make_activation(name: str) -> nn.Module:
    """The node-update non-linearity; "sigmoid" is the paper's σ (eq. node_update)."""
    table = {"sigmoid": nn.Sigmoid, "relu": nn.ReLU, "elu": nn.ELU, "tanh": nn.Tanh}
    if name not in table:
        raise ValueError(f"unknown activation {name!r}; choose one of {sorted(table)}")
    return table[name]()


def mix_bases(coefficients: Tensor, basis_products: Tensor, out_dim: int) -> Tensor:
    """[M, d_out] messages Σ_k φ̂_k B_k h_q of each edge from its coefficients φ̂ [M, K+1] and its
    source's basis products [M, (K+1)·d_out] (eq. ecc_message), as K+1 fused multiply-adds
    (several times faster than a batched [1, K+1] × [K+1, d_out] product on the CPU)."""
    products = basis_products.view(basis_products.shape[0], -1, out_dim)
    mixed = products[:, 0] * coefficients[:, :1]
    for k in range(1, products.shape[1]):
        mixed = mixed.addcmul(products[:, k], coefficients[:, k : k + 1])
    return mixed


def edge_conditioned_messages(
    features: Tensor, sources: Tensor, bases_weight: Tensor, out_dim: int
) -> Tensor:
    """[M, d_out] messages B_0 h_q + Σ_k φ_k B_k h_q (eq. ecc_message) from the edge features
    φ [M, K], the sources' embeddings h_q [M, d_in] and the bases' weight [(K+1)·d_out, d_in]
    (`EdgeConditionedConv.bases`), as K + 1 GEMMs of the scaled sources φ_k h_q [M, d_in].

    The same function as `mix_bases` of the per-node products B_k h, in another order of
    summation. This order keeps every intermediate d_in wide: no [M, (K+1)·d] tensor is made,
    and the backward pass scatters d_in-wide rows to the nodes and reduces φ's gradient over
    d_in-wide products only. Measured on one layer, forward + backward (docs/algorithms.md,
    "Cost"): 41–45 ms against 76 ms for one GEMM over the outer product φ̂ ⊗ h_q.
    """
    bases = bases_weight.view(-1, out_dim, sources.shape[1])
    messages = sources @ bases[0].T
    for k in range(1, bases.shape[0]):
        messages = messages + (sources * features[:, k - 1 : k]) @ bases[k].T
    return messages


class EdgeConditionedConv(MessagePassing):
    """One edge-conditioned layer, eqs. ecc_weight, ecc_message, mean_aggr, node_update.

    φ_edge is an MLP a ↦ L(ReLU(A a + c)) whose last linear layer L outputs vec(W) ∈ R^{d_out·d_in}.
    Writing L's weight as K+1 matrices B_k ∈ R^{d_out×d_in} (its bias as B_0) gives exactly
        W_pq = B_0 + Σ_k φ_k(a_pq) B_k,     φ(a) = ReLU(A a + c) ∈ R^K,
    so m_pq = W_pq h_q = Σ_k φ̂_k(a_pq) (B_k h_q) with φ̂ = [1, φ]. We therefore compute B_k h once
    per *node* and mix the K+1 products per edge: the same function as materialising the
    per-edge d_out×d_in matrix (NNConv), at O(K·d_out) instead of O(d_out·d_in) memory per edge.
    W_pq is still a full d_out×d_in matrix conditioned on a_pq (eq. 3); K bounds the rank of
    the map a ↦ W, exactly as the width of φ_edge's last hidden layer does in the paper's MLP.
    """

    def __init__(
        self, in_dim: int, out_dim: int, edge_dim: int, edge_hidden: int, activation: str
    ) -> None:
        super().__init__(aggr="sum", flow="source_to_target")
        self.out_dim = out_dim
        self.num_bases = edge_hidden + 1
        self.edge_net = nn.Sequential(nn.Linear(edge_dim, edge_hidden), nn.ReLU())
        self.bases = nn.Linear(in_dim, self.num_bases * out_dim, bias=False)
        nn.init.normal_(self.bases.weight, std=(in_dim * self.num_bases) ** -0.5)
        self.update_net = nn.Linear(in_dim + out_dim, out_dim)  # U of eq. node_update
        self.activation = make_activation(activation)

    def messages(self, x: Tensor, edge_index: Tensor, edge_attr: Tensor) -> Tensor:
        """Directed messages m = W_pq h_q (eqs. ecc_weight, ecc_message).

        Args:
            x: [N, d_in] node embeddings.
            edge_index: [2, M] (row 0 source q, row 1 target p).
            edge_attr: [M, d_e].
        Returns:
            [M, d_out].
        """
        sources = x.index_select(0, edge_index[0])
        return edge_conditioned_messages(
            self.edge_net(edge_attr), sources, self.bases.weight, self.out_dim
        )

    def forward(self, x: Tensor, edge_index: Tensor, messages: Tensor, degree: Tensor) -> Tensor:
        """Aggregate already-gated messages and update nodes (eqs. mean_aggr, node_update).

        Args:
            x: [N, d_in] node embeddings h^(ℓ).
            edge_index: [2, M] (source, target).
            messages: [M, d_out] gated messages z·m (zero for padding).
            degree: [N] number of real incident edges (|N(p)|, ≥ 1 to avoid 0/0).
        Returns:
            [N, d_out] h^(ℓ+1) = σ(U [h_p ‖ m̄_p]).
        """
        summed = self.propagate(edge_index, msg=messages, size=(x.shape[0], x.shape[0]))
        mean_message = summed / degree.unsqueeze(-1)
        # U [h_p ‖ m̄_p] as U_h h_p + U_m m̄_p: the same map without the [N, d_in + d_out] copy
        weight, in_dim = self.update_net.weight, x.shape[1]
        update = torch.addmm(self.update_net.bias, x, weight[:, :in_dim].T)
        return self.activation(update.addmm(mean_message, weight[:, in_dim:].T))

    def message(self, msg: Tensor) -> Tensor:
        return msg


class AdaptiveEdgeGate(nn.Module):
    """Hard-concrete edge gate, eqs. reliability_vector … mask (Louizos et al. 2018).

    s = [m ‖ symlog(r) ‖ c] → α = P_gate(s) + β·[inter-robot loop closure]
    training:  u = σ((α + log ε − log(1−ε))/τ),  ε ~ U(0, 1)
    eval:      u = σ(α/τ)   (the noise-free median of the same relaxation)
    z = min(1, max(0, (b − a)u + a)),  (a, b) = (−0.1, 1.1).
    """

    def __init__(
        self,
        message_dim: int,
        hidden: int,
        temperature: float,
        inter_loop_bias: float,
        init_logit: float,
    ) -> None:
        super().__init__()
        if temperature <= 0:
            raise ValueError(f"gate temperature must be > 0, got {temperature}")
        self.score = nn.Sequential(
            nn.Linear(message_dim + 6, hidden), nn.ReLU(), nn.Linear(hidden, 1)
        )
        nn.init.constant_(self.score[-1].bias, init_logit)
        self.temperature = temperature
        self.inter_loop_bias = inter_loop_bias

    def logits(self, messages: Tensor, residuals: Tensor, log_info: Tensor, inter_loop: Tensor):
        """α per edge (eqs. reliability_vector, logit). Shapes [M, d], [M, 3], [M, 3], [M] → [M]."""
        reliability = torch.cat([messages, symlog(residuals), log_info], dim=-1)
        return self.score(reliability).squeeze(-1) + self.inter_loop_bias * inter_loop

    def forward(
        self,
        messages: Tensor,
        residuals: Tensor,
        log_info: Tensor,
        inter_loop: Tensor,
        deterministic: bool,
    ) -> Tensor:
        """Gate z ∈ [0, 1] per edge, [M] (eqs. bernoulli, minmax)."""
        return self.relax(self.logits(messages, residuals, log_info, inter_loop), deterministic)

    def relax(self, alpha: Tensor, deterministic: bool) -> Tensor:
        """z ∈ [0, 1] of the logits α [M] (eqs. bernoulli, minmax), [M]."""
        if deterministic:
            u = torch.sigmoid(alpha / self.temperature)
        else:
            eps = torch.rand_like(alpha).clamp(1e-6, 1.0 - 1e-6)
            u = torch.sigmoid((alpha + torch.log(eps) - torch.log1p(-eps)) / self.temperature)
        a, b = HARD_CONCRETE_STRETCH
        return torch.clamp((b - a) * u + a, 0.0, 1.0)


class GraphEncoder(nn.Module):
    """L edge-conditioned layers, each with an adaptive edge gate; a masked mean-pool latent."""

    def __init__(
        self,
        node_dim: int,
        edge_dim: int,
        hidden: int,
        layers: int,
        edge_hidden: int,
        activation: str,
        gate_hidden: int,
        gate_temperature: float,
        gate_inter_loop_bias: float,
        gate_init_logit: float,
    ) -> None:
        super().__init__()
        dims = [node_dim] + [hidden] * layers
        directed_edge_dim = edge_dim + 1
        self.convs = nn.ModuleList(
            EdgeConditionedConv(d_in, d_out, directed_edge_dim, edge_hidden, activation)
            for d_in, d_out in zip(dims[:-1], dims[1:], strict=True)
        )
        self.gates = nn.ModuleList(
            AdaptiveEdgeGate(
                hidden, gate_hidden, gate_temperature, gate_inter_loop_bias, gate_init_logit
            )
            for _ in range(layers)
        )
        self.hidden = hidden

    @classmethod
    def from_config(
        cls, node_dim: int, edge_dim: int, config: ModelConfig, hidden: int, layers: int
    ) -> GraphEncoder:
        """An encoder of width ``hidden`` and depth ``layers`` with ``config``'s edge-network,
        activation and gate settings (the actor and the critic differ only in width/depth)."""
        return cls(
            node_dim=node_dim,
            edge_dim=edge_dim,
            hidden=hidden,
            layers=layers,
            edge_hidden=config.edge_hidden,
            activation=config.activation,
            gate_hidden=config.gate_hidden,
            gate_temperature=config.gate_temperature,
            gate_inter_loop_bias=config.gate_inter_loop_bias,
            gate_init_logit=config.gate_init_logit,
        )

    def forward(self, graphs: GraphBatch, deterministic: bool) -> Encoding:
        """Encode the G graphs; messages, gates and node updates are computed on the real edges
        and vertices alone (packed: padding carries no message and is read by nothing, so
        dropping it changes nothing but the cost; padding rows of `nodes` are 0)."""
        num_graphs, num_vertices, _ = graphs.node_features.shape
        num_edges = graphs.edge_index.shape[-1]
        real_vertices = graphs.node_mask.reshape(-1).nonzero().squeeze(-1)  # [N] flat ids
        packed_id = torch.cumsum(graphs.node_mask.reshape(-1), 0) - 1  # flat id → packed row
        x = graphs.node_features.reshape(num_graphs * num_vertices, -1).index_select(
            0, real_vertices
        )
        real = graphs.edge_mask.reshape(-1).nonzero().squeeze(-1)  # [M] flat ids of real edges
        offsets = torch.arange(num_graphs, device=x.device).view(-1, 1) * num_vertices
        local = graphs.edge_index.clamp(0, num_vertices - 1)
        tails = packed_id[(local[:, 0] + offsets).reshape(-1).index_select(0, real)]
        heads = packed_id[(local[:, 1] + offsets).reshape(-1).index_select(0, real)]
        # Forward direction q → p carries m_pq to the tail; the reverse one m_qp to the head.
        directed_index = torch.stack([torch.cat([heads, tails]), torch.cat([tails, heads])])
        attr = graphs.edge_attr.reshape(num_graphs * num_edges, -1).index_select(0, real)
        flag = torch.zeros_like(attr[:, :1])
        directed_attr = torch.cat(
            [torch.cat([attr, flag], -1), torch.cat([attr, flag + 1.0], -1)], dim=0
        )
        degree = torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
        degree = degree.index_add(0, directed_index[1], torch.ones_like(directed_attr[:, 0]))
        degree = degree.clamp(min=1.0)
        residuals = graphs.residuals.reshape(-1, 3).index_select(0, real)
        log_info = attr[:, LOG_INFO_COLUMNS]
        inter_loop = attr[:, INTER_LOOP_COLUMN]

        gate_values, gate_logits = [], []
        h = x
        count = real.shape[0]
        for conv, gate in zip(self.convs, self.gates, strict=True):
            messages = conv.messages(h, directed_index, directed_attr)  # [2M, d]
            undirected = 0.5 * (messages[:count] + messages[count:])
            alpha = gate.logits(undirected, residuals, log_info, inter_loop)
            z = gate.relax(alpha, deterministic)
            gate_values.append(z)
            gate_logits.append(alpha / gate.temperature)
            h = conv(h, directed_index, messages * torch.cat([z, z]).unsqueeze(-1), degree)

        flat_nodes = h.new_zeros(num_graphs * num_vertices, self.hidden)
        nodes = flat_nodes.index_copy(0, real_vertices, h).view(num_graphs, num_vertices, -1)
        real_count = graphs.node_mask.sum(1, keepdim=True).clamp(min=1).to(h.dtype)
        pooled = nodes.sum(1) / real_count
        shape = (len(self.convs), num_graphs, num_edges)
        gates = unpack_edges(torch.stack(gate_values), real, shape)
        gate_l1 = gates.sum() / (max(count, 1) * len(self.convs))
        return Encoding(
            nodes=nodes,
            pooled=pooled,
            gates=gates,
            gate_l1=gate_l1,
            gate_logits=unpack_edges(torch.stack(gate_logits), real, shape),
        )


def unpack_edges(packed: Tensor, real: Tensor, shape: tuple[int, int, int]) -> Tensor:
    """[L, G, E] per-edge values from their [L, M] values on the real edges, whose flat ids
    (g·E + e) are `real` [M]; 0 on padding."""
    layers, graphs, edges = shape
    full = packed.new_zeros(layers, graphs * edges)
    return full.index_copy(1, real, packed).view(shape)


def edge_embedding_width(hidden: int, edge_dim: int) -> int:
    """Width 2d + d_e + 3 of `edge_embeddings` rows."""
    return 2 * hidden + edge_dim + RESIDUAL_FEATURES


def edge_embeddings(nodes: Tensor, graphs: GraphBatch) -> Tensor:
    """[G, E + 1, 2d + d_e + 3] per-choice features [h_p ‖ h_q ‖ a_pq ‖ symlog(r_pq)] (tail,
    head, attributes, current residual of the edge).

    The residual r_pq = [R_pᵀ(t_q − t_p) − t̃, wrap(θ_q − θ_p − θ̃)] is expressed in the tail's
    frame, the frame in which the environment applies the correction Δ to the head (envs.core,
    eq. C): it is what a correction of this edge must see, and the critic must see it to value
    Δ. It is the same residual the gate's reliability vector uses (eq. reliability_vector); the
    GNN alone cannot recover it from the node poses to the needed precision (measured: see
    agents/checkpoints/README.md). Row E (the environment's no-op choice) is all zeros.
    """
    num_vertices = nodes.shape[1]
    local = graphs.edge_index.clamp(0, num_vertices - 1)
    tail = torch.gather(nodes, 1, local[:, 0].unsqueeze(-1).expand(-1, -1, nodes.shape[-1]))
    head = torch.gather(nodes, 1, local[:, 1].unsqueeze(-1).expand(-1, -1, nodes.shape[-1]))
    residual = symlog(graphs.residuals.to(nodes.dtype))
    embeddings = torch.cat([tail, head, graphs.edge_attr, residual], dim=-1)
    return torch.cat([embeddings, torch.zeros_like(embeddings[:, :1])], dim=1)


def chosen_edge_embedding(nodes: Tensor, graphs: GraphBatch, weights: Tensor) -> Tensor:
    """[G, 2d + d_e + 3] Σ_e w_e · `edge_embeddings`(nodes, graphs)[:, e] for the choice weights
    `weights` [G, E + 1] (one-hot or straight-through; the no-op row E is zeros), without
    building the [G, E + 1, 2d + d_e + 3] embeddings: the weights are summed onto each edge's
    tail and head vertex and applied to the node embeddings by one batched product."""
    count, vertices, _ = nodes.shape
    edge_weights = weights[:, :-1].to(nodes.dtype)  # [G, E]
    local = graphs.edge_index.clamp(0, vertices - 1)
    ends = []
    for row in (0, 1):  # tail, head
        at_vertex = edge_weights.new_zeros(count, vertices).scatter_add(
            1, local[:, row], edge_weights
        )
        ends.append(torch.bmm(at_vertex.unsqueeze(1), nodes).squeeze(1))
    attr = torch.einsum("ge,ged->gd", edge_weights, graphs.edge_attr.to(nodes.dtype))
    residual = torch.einsum("ge,ged->gd", edge_weights, symlog(graphs.residuals.to(nodes.dtype)))
    return torch.cat([*ends, attr, residual], dim=-1)


class Memory(nn.Module):
    """K stacked GRU cells, refreshed once per decision step (paper §III-C, "memory").

    Input: [graph latent ‖ previous edge embedding ‖ previous correction / Δmax]. K = 2 by default:
    the paper does not give K; two layers is the smallest stack that is "stacked".
    """

    def __init__(self, input_dim: int, hidden: int, layers: int) -> None:
        super().__init__()
        if layers < 1:
            raise ValueError(f"memory needs at least one GRU layer, got {layers}")
        self.cells = nn.ModuleList(
            nn.GRUCell(input_dim if k == 0 else hidden, hidden) for k in range(layers)
        )
        self.hidden = hidden

    @property
    def layers(self) -> int:
        return len(self.cells)

    def forward(self, inputs: Tensor, state: Tensor) -> Tensor:
        """inputs [G, input_dim], state [G, K, H] → new state [G, K, H] (last layer = output)."""
        new_states = []
        x = inputs
        for k, cell in enumerate(self.cells):
            x = cell(x, state[:, k])
            new_states.append(x)
        return torch.stack(new_states, dim=1)


BASE_INPUTS = 13  # base_inputs(): Δ_GN / bound (3), symlog of its model (9), its predicted gain


def chosen_base(
    base_step: Tensor, base_model: Tensor, edge_weights: Tensor
) -> tuple[Tensor, Tensor]:
    """(Δ_GN [G, 3], model [G, 9]) of each graph's chosen edge, from every edge's `base_step`
    [G, E, 3] and `base_model` [G, E, 9] (GraphBatch) and the choice `edge_weights` [G, E + 1]
    (one-hot or straight-through; the no-op E has zeros)."""
    weights = edge_weights[:, :-1].to(base_step.dtype)
    step = torch.einsum("ge,ged->gd", weights, base_step)
    model = torch.einsum("ge,ged->gd", weights, base_model)
    return step, model


def predicted_gain(model: Tensor, delta: Tensor) -> Tensor:
    """[G] the fraction of the local F that a correction `delta` [G, 3] (action units) removes
    by the quadratic model [G, 9] (envs.basestep.observed_model): −(2 gᵀΔ + ΔᵀHΔ) / F."""
    g, upper = model[:, :3], model[:, 3:]
    xx, xy, xt, yy, yt, tt = upper.unbind(-1)
    x, y, t = delta.unbind(-1)
    quadratic = xx * x * x + yy * y * y + tt * t * t + 2 * (xy * x * y + xt * x * t + yt * y * t)
    return -(2.0 * (g * delta).sum(-1) + quadratic)


def base_inputs(step: Tensor, model: Tensor, bound: Tensor) -> Tensor:
    """[G, 13] what the correction head reads of the base step it corrects: Δ_GN / bound
    (clipped to ±1), symlog of the model and tanh of Δ_GN's predicted gain."""
    scaled = torch.clamp(step / bound, -1.0, 1.0)
    gain = torch.tanh(predicted_gain(model, step)).unsqueeze(-1)
    return torch.cat([scaled, symlog(model), gain], -1)
