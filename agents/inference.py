"""Incremental deterministic inference of `HybridActor` over fixed-topology local graphs.

An episode of prop-v1 has one step per local edge, and a step moves one pose per robot (the head
of the chosen edge). A full GNN pass per step would make an episode O(E²). With L gated
edge-conditioned layers, a move of vertex q changes

* layer 0: q's node features and the residuals (hence gate inputs) of the edges incident to q;
* layer ℓ: the messages and gates of the edges incident to S_ℓ (the vertices whose input
  embedding changed) and the embeddings h^(ℓ+1) of S_{ℓ+1} = S_ℓ ∪ their neighbours,

so `IncrementalPolicy` caches, per layer, the node embeddings, the basis products B_k h of every
node (encoder.EdgeConditionedConv), both directed messages and the gate z of every edge, and
recomputes only the ℓ-hop rows (S grows by one hop per layer: O(D^L) rows, independent of the
graph size). In the subtree correction a step changes the residuals of every edge crossing the
moved subtree's boundary, and each feeds every layer's gate, so S is the L-hop neighbourhood of
that boundary (docs/prop_speed.md measures it). The edge embeddings (encoder.edge_embeddings:
[h_p ‖ h_q ‖ a_pq ‖ …]), the first layer of the edge-selection head applied to them, and the
masked sum behind the mean-pooled latent are cached the same way.

What stays O(unprocessed edges) per step, with a small constant: scoring every unprocessed edge
(the edge head's ReLU + last layer on cached first-layer outputs; the memory context changes
every step) and the arg-max over them, which is inherent to choosing among all edges. The cached
first-layer rows are kept *compacted*: each robot's unprocessed edges occupy the leading rows
(the chosen edge swaps places with the last unprocessed one, O(1) per step), so a step scores
only max_g(unprocessed edges of g) rows — on average half the edges over an episode. The
logits are scattered back to slot order and the choice is the actor's own arg-max of the masked
log-softmax: trained edge heads give many logits a few ulp apart, which the log-softmax's shift
rounds to ties (broken to the lowest slot), so an arg-max of the raw logits would choose
differently (measured on city10k: the 12th step already). Everything is batched over the G
robots (one disjoint graph of G·V vertices).

Exception: node features are poses in the frame of the robot's local vertex 0, so a step that
moves vertex 0 changes every node feature of that robot and refreshes that robot's whole graph
(a handful of steps per episode).

The output equals `HybridActor.forward(..., deterministic=True)` run on the full observation at
every step (tests/test_prop_methods.py checks this to float32 round-off).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from agents.actor import HybridActor, masked_log_softmax
from agents.encoder import (
    INTER_LOOP_COLUMN,
    LOG_INFO_COLUMNS,
    GraphBatch,
    base_inputs,
    edge_embeddings,
    mix_bases,
)


def _members(ids: Tensor, size: int) -> Tensor:
    """The ascending unique values of `ids` (any shape, long) below `size` (= torch.unique of
    them, by a membership mask: O(size) instead of a sort)."""
    member = torch.zeros(size + 1, dtype=torch.bool)
    member[ids.clamp(max=size).flatten()] = True
    return torch.nonzero(member[:size]).squeeze(-1)


class IncrementalPolicy:
    """Deterministic `HybridActor` with cached per-layer state over G fixed-topology graphs.

    Args:
        actor: the trained shared actor (eval mode; its weights are not changed).
        graphs: the G local graphs at the start of the episode (topology, attributes, features).
        incident: [G, V, D] long, local edge slots incident to each vertex, padded with E
            (envs.core's "incident" table without its trash row).
    """

    @torch.no_grad()
    def __init__(self, actor: HybridActor, graphs: GraphBatch, incident: Tensor) -> None:
        self.actor = actor
        encoder = actor.encoder
        g, v, _ = graphs.node_features.shape
        e = graphs.edge_index.shape[-1]
        self.shape = (g, v, e)
        n_nodes, n_edges = g * v, g * e
        offsets = torch.arange(g).view(-1, 1)
        local = graphs.edge_index.clamp(0, v - 1)
        sentinel_node = torch.tensor([n_nodes])
        self.tails = torch.cat([(local[:, 0] + offsets * v).reshape(-1), sentinel_node])
        self.heads = torch.cat([(local[:, 1] + offsets * v).reshape(-1), sentinel_node])
        self.valid = torch.cat([graphs.edge_mask.reshape(-1).float(), torch.zeros(1)])
        attr = graphs.edge_attr.reshape(n_edges, -1)
        self.attr = torch.cat([attr, torch.zeros(1, attr.shape[1])])
        self.log_info = self.attr[:, LOG_INFO_COLUMNS]
        self.inter_loop = self.attr[:, INTER_LOOP_COLUMN]
        flag = torch.zeros(n_edges + 1, 1)
        directed = (torch.cat([self.attr, flag], -1), torch.cat([self.attr, flag + 1.0], -1))
        # Static per-layer mixing coefficients φ̂(a) = [1, φ(a)] of both directions.
        self.coefficients = [
            tuple(torch.cat([torch.ones(n_edges + 1, 1), conv.edge_net(a)], -1) for a in directed)
            for conv in encoder.convs
        ]
        slots = incident[:, :v]
        self.incident = torch.where(slots < e, slots + offsets.view(-1, 1, 1) * e, n_edges)
        self.incident = self.incident.reshape(n_nodes, -1)
        degree = torch.zeros(n_nodes + 1).index_add(0, self.tails[:-1], self.valid[:-1])
        degree = degree.index_add(0, self.heads[:-1], self.valid[:-1])
        self.degree = degree[:n_nodes].clamp(min=1.0)
        self.node_weight = graphs.node_mask.reshape(-1).float()
        self.node_count = graphs.node_mask.sum(1).clamp(min=1).float()
        self.residuals = torch.cat([graphs.residuals.reshape(n_edges, 3), torch.zeros(1, 3)])

        dims = [graphs.node_features.shape[-1]] + [encoder.hidden] * len(encoder.convs)
        self.h = [torch.zeros(n_nodes + 1, d) for d in dims]  # row N: the sentinel vertex
        self.h[0][:n_nodes] = graphs.node_features.reshape(n_nodes, -1)
        self.bases = [
            torch.zeros(n_nodes + 1, conv.num_bases * conv.out_dim) for conv in encoder.convs
        ]
        self.messages = [
            (torch.zeros(n_edges + 1, encoder.hidden), torch.zeros(n_edges + 1, encoder.hidden))
            for _ in encoder.convs
        ]
        self.gates = [torch.zeros(n_edges + 1) for _ in encoder.convs]

        self.memory = actor.initial_memory(g)
        first = actor.edge_head[0]
        # The edge head reads [edge embedding ‖ memory context]: the rest of its input width.
        self.embedding_width = first.in_features - self.memory.shape[-1]
        self.head_embedding_weight = first.weight[:, : self.embedding_width]
        self.head_context_weight = first.weight[:, self.embedding_width :]
        self.embeddings = torch.zeros(g, e + 1, self.embedding_width)
        # Edge head's first layer on the embeddings, compacted (module docstring): row p of
        # graph g holds slot order[g, p]; rows [0, remaining[g]) are the unprocessed edges.
        unprocessed = graphs.action_mask[:, :e]
        self.remaining = unprocessed.sum(1)
        self.order = torch.argsort((~unprocessed).long() * e + torch.arange(e), dim=1)
        self.position = torch.empty(g, e, dtype=torch.long)
        self.position.scatter_(1, self.order, torch.arange(e).expand(g, e).contiguous())
        self.head_hidden = torch.zeros(g, e, first.out_features)
        self.hidden_buffer = torch.empty(g * e * first.out_features)  # act's scratch
        self.pooled_sum = torch.zeros(g, encoder.hidden)

        self.prev_edge = torch.full((g,), e, dtype=torch.long)  # E = "none" (zero embedding)
        self.prev_delta = torch.zeros(g, 3)
        self._propagate(torch.arange(n_nodes), torch.arange(n_edges))

    # -- cache maintenance -----------------------------------------------------------------------

    def _edges_at(self, vertices: Tensor) -> Tensor:
        """Ascending unique flat ids of the real edges incident to `vertices`."""
        return _members(self.incident[vertices], self.valid.shape[0] - 1)

    @torch.no_grad()
    def _propagate(self, changed: Tensor, first_edges: Tensor) -> None:
        """Recompute the caches after the features of `changed` vertices and the residuals of
        `first_edges` changed (both flat ids)."""
        n_nodes, n_edges = self.h[0].shape[0] - 1, self.valid.shape[0] - 1
        encoder = self.actor.encoder
        vertices = changed
        incident = self._edges_at(vertices)  # the real edges at `vertices`, kept in step with it
        for layer, (conv, gate) in enumerate(zip(encoder.convs, encoder.gates, strict=True)):
            # Residuals feed every layer's gate: the edges of `first_edges` are refreshed too.
            edges = _members(torch.cat([incident, first_edges]), n_edges)
            bases = self.bases[layer]
            bases.index_copy_(0, vertices, conv.bases(self.h[layer].index_select(0, vertices)))
            forward_coeff, reverse_coeff = self.coefficients[layer]
            tails, heads = self.tails.index_select(0, edges), self.heads.index_select(0, edges)
            # eq. ecc_message: the forward message goes head → tail, the reverse tail → head.
            m_forward = mix_bases(
                forward_coeff.index_select(0, edges), bases.index_select(0, heads), conv.out_dim
            )
            m_reverse = mix_bases(
                reverse_coeff.index_select(0, edges), bases.index_select(0, tails), conv.out_dim
            )
            self.messages[layer][0].index_copy_(0, edges, m_forward)
            self.messages[layer][1].index_copy_(0, edges, m_reverse)
            z = gate(
                0.5 * (m_forward + m_reverse),
                self.residuals.index_select(0, edges),
                self.log_info.index_select(0, edges),
                self.inter_loop.index_select(0, edges),
                deterministic=True,
            )
            self.gates[layer].index_copy_(0, edges, z * self.valid.index_select(0, edges))
            vertices = _members(torch.cat([vertices, tails, heads]), n_nodes)
            incident = self._edges_at(vertices)
            updated = self._node_update(layer, conv, vertices, incident)
            if layer == len(encoder.convs) - 1:  # masked sum behind the mean-pooled latent
                change = (updated - self.h[-1][vertices]) * self.node_weight[vertices, None]
                self.pooled_sum.index_add_(0, vertices // self.shape[1], change)
            self.h[layer + 1].index_copy_(0, vertices, updated)
        self._refresh_readout(incident)

    def _node_update(self, layer: int, conv, vertices: Tensor, edges: Tensor) -> Tensor:
        """h^(ℓ+1) of `vertices` (ascending flat ids) from cached gated messages (eqs. mean_aggr,
        node_update): the gated message of each of their real incident `edges` (ascending flat
        ids) is added at its endpoint's row (O(their count), not O(|vertices| · max degree))."""
        z = self.gates[layer].index_select(0, edges).unsqueeze(-1)
        forward, reverse = self.messages[layer]
        count = vertices.numel()
        summed = torch.zeros(count + 1, forward.shape[1])
        for ends, messages in ((self.tails, forward), (self.heads, reverse)):
            end = ends.index_select(0, edges)
            row = torch.searchsorted(vertices, end).clamp(max=count - 1)
            row = torch.where(vertices[row] == end, row, count)  # an end outside: the spare row
            summed.index_add_(0, row, z * messages.index_select(0, edges))
        mean = summed[:count] / self.degree.index_select(0, vertices).unsqueeze(-1)
        h = self.h[layer].index_select(0, vertices)
        return conv.activation(conv.update_net(torch.cat([h, mean], -1)))

    def _refresh_readout(self, edges: Tensor) -> None:
        """Edge embeddings and the edge head's first layer for `edges` (ascending flat ids), the
        edges touching the final-layer vertices whose h^(L) was just rewritten."""
        e = self.shape[2]
        final = self.h[-1]
        graph_of, slot = edges // e, edges % e
        # encoder.edge_embeddings on the refreshed edges, as one graph over the flat vertex ids.
        k = edges.numel()
        refreshed = GraphBatch(
            node_features=final.unsqueeze(0),
            edge_index=torch.stack([self.tails[edges], self.heads[edges]]).unsqueeze(0),
            edge_attr=self.attr[edges].unsqueeze(0),
            edge_mask=torch.ones(1, k, dtype=torch.bool),
            node_mask=torch.ones(1, final.shape[0], dtype=torch.bool),
            residuals=self.residuals[edges].unsqueeze(0),
            processed=torch.zeros(1, k, dtype=torch.bool),
            action_mask=torch.ones(1, k + 1, dtype=torch.bool),
        )
        embedding = edge_embeddings(final.unsqueeze(0), refreshed)[0, :k]
        width = self.embeddings.shape[-1]
        self.embeddings.view(-1, width).index_copy_(0, graph_of * (e + 1) + slot, embedding)
        real = torch.nonzero(slot < e).squeeze(-1)
        graph_of, slot = graph_of[real], slot[real]
        rows = graph_of * e + self.position.view(-1)[graph_of * e + slot]
        hidden = self.head_hidden.view(-1, self.head_hidden.shape[-1])
        hidden.index_copy_(0, rows, embedding[real] @ self.head_embedding_weight.T)

    # -- acting ----------------------------------------------------------------------------------

    @torch.no_grad()
    def act(
        self,
        action_mask: Tensor,
        base: Callable[[Tensor], tuple[Tensor, Tensor]] | None = None,
    ) -> tuple[Tensor, Tensor]:
        """One deterministic decision for every graph: (edge [G] long, delta [G, 3]).

        Args:
            action_mask: [G, E + 1] bool, the env's action mask; it must agree with the edges
                this policy chose so far (the environment processes exactly the chosen edge).
            base: for an actor with base features, the chosen edges' [G] (base_step [G, 3],
                base_model [G, 9]) at the current state (envs.readout.chosen_base_observation:
                the rows of envs.readout.base_observation, computed for the chosen edge only).
        """
        if not torch.equal(action_mask[:, : self.shape[2]].sum(1), self.remaining):
            raise RuntimeError("action mask out of step with the edges this policy chose")
        actor = self.actor
        g = self.shape[0]
        rows = torch.arange(g)
        pooled = self.pooled_sum / self.node_count.unsqueeze(-1)
        prev_embedding = self.embeddings[rows, self.prev_edge]
        memory_input = torch.cat([pooled, prev_embedding, self.prev_delta / actor.delta_max], -1)
        self.memory = actor.memory(memory_input, self.memory)
        context = self.memory[:, -1]
        first, last = actor.edge_head[0], actor.edge_head[2]
        context_term = context @ self.head_context_weight.T + first.bias
        edge = self._choose(context_term, last, action_mask)
        chosen = torch.cat([self.embeddings[rows, edge], context], -1)
        if actor.config.base_features:
            step, model = base(edge)
            chosen = torch.cat([chosen, base_inputs(step, model, actor.delta_max)], -1)
        mean, _ = actor.correction_head(chosen).chunk(2, dim=-1)
        delta = actor.delta_max * torch.tanh(mean)
        self.prev_edge, self.prev_delta = edge, delta
        self._mark_processed(edge)
        return edge, delta

    def _choose(self, context_term: Tensor, last: torch.nn.Linear, action_mask: Tensor) -> Tensor:
        """[G] deterministic edge choice: arg-max of the masked log-softmax of the logits, which
        are computed on the compacted unprocessed rows only and scattered back to slot order."""
        g, _, e = self.shape
        logits = torch.zeros(g, e + 1)  # unscored slots are processed: the mask removes them
        k = int(self.remaining.max())
        if k > 0:
            width = self.head_hidden.shape[-1]
            hidden = self.hidden_buffer[: g * k * width].view(g, k, width)
            torch.add(self.head_hidden[:, :k], context_term.unsqueeze(1), out=hidden)
            scores = (hidden.relu_() @ last.weight.T).squeeze(-1) + last.bias
            logits.scatter_(1, self.order[:, :k], scores)
        return masked_log_softmax(logits, action_mask).argmax(-1)

    def _mark_processed(self, edge: Tensor) -> None:
        """Move each graph's chosen `edge` [G] (E: none) out of the unprocessed rows."""
        graphs = torch.nonzero(edge < self.shape[2]).squeeze(-1)
        chosen = edge[graphs]
        p, q = self.position[graphs, chosen], self.remaining[graphs] - 1
        other = self.order[graphs, q]
        self.order[graphs, p], self.order[graphs, q] = other, chosen
        self.position[graphs, other], self.position[graphs, chosen] = p, q
        rows_p, rows_q = self.head_hidden[graphs, p], self.head_hidden[graphs, q]
        self.head_hidden[graphs, p], self.head_hidden[graphs, q] = rows_q, rows_p
        self.remaining[graphs] -= 1

    @torch.no_grad()
    def observe(self, moved: Tensor, features: Tensor, edges: Tensor, residuals: Tensor) -> None:
        """Apply the environment's change after a step.

        Args:
            moved: [S] flat vertex ids (graph · V + local id) whose node features changed.
            features: [S, d_v] their new node features.
            edges: [R] flat edge ids (graph · E + slot) whose residuals changed.
            residuals: [R, 3] their new residuals.
        """
        if moved.numel() == 0 and edges.numel() == 0:
            return
        self.h[0][moved] = features
        self.residuals[edges] = residuals
        self._propagate(moved, edges)

    def observe_update(
        self, vertices: Tensor, features: Tensor, edges: Tensor, residuals: Tensor
    ) -> None:
        """Apply what a step changed, given the entries it may have changed
        (envs.core.PGOCore.observation_update: ascending flat vertex ids [S] with their node
        features [S, d_v], ascending flat edge ids [R] with their residuals [R, 3]): only those
        that differ from the cached ones are propagated — right in every environment mode (one
        moved pose, a moved subtree whose boundary edges change, or a robot whose frame vertex
        moved)."""
        moved = (features != self.h[0][vertices]).any(-1)
        changed = (residuals != self.residuals[edges]).any(-1)
        self.observe(vertices[moved], features[moved], edges[changed], residuals[changed])

    def gate_means(self) -> Tensor:
        """[G, E] the layer-averaged gate of every edge slot (0 on padding)."""
        g, _, e = self.shape
        return torch.stack([z[:-1] for z in self.gates]).mean(0).view(g, e)

    def inliers(self, threshold: float = 0.5) -> Tensor:
        """[G, E] bool: layer-averaged gate > threshold (encoder.Encoding.inliers)."""
        return self.gate_means() > threshold
