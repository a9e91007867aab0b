"""GA-SAC loss (paper §III-D, eq. sac): soft actor-critic for a hybrid (edge, correction) policy.

TorchRL's SACLoss handles one continuous action and DiscreteSACLoss one categorical action, so
this is a `LossModule` of its own that reuses TorchRL's functional-parameter machinery
(`convert_to_functional`, target parameters updated by `SoftUpdate`) and `set_keys`.

Per agent i (rewards are per agent; the critic gives one Q_i per agent, MAAC-style):

  policy π_i(e, δ | s) = π(e | s) · π(δ | s, e)
  soft value V_i(s) = min_k Q̄_k,i(s, a) + α_e H[π(· | s)] − α_δ log π(δ | s, e),  a ~ π
  critic:  L_Q = Σ_k E[ρ(Q_k,i(s, a) − y_i)],  y_i = c·r_i + γ (1 − terminated_i) V_i(s′),
           ρ = Huber(d) (½ δ² inside |δ| ≤ d; ½ δ², SAC's, when huber_delta is None)
  actor:   L_π = E[−α_e H[π(· | s)] + α_δ log π(δ | s, e) − min_k Q_k,i(s, ã)] + λ_gate · mean z,
           with Q_i differentiated through agent i's own action ã_i only (the others' enter
           Q_i as constants: CentralCritic's own_action_only, as in MADDPG / MAAC)
  α_e:     L = E[log α_e · (H[π(· | s)] − H̄_e(s))],   H̄_e(s) = ratio · log |allowed edges|
  α_δ:     L = −E[log α_δ · (log π(δ | s, e) + H̄_δ)],  H̄_δ = −3

Reward scale c (`AlgorithmConfig.reward_scale`; SAC's, Haarnoja et al. 2018 §5) acts only inside
this loss: it makes the reward part of the soft Q target O(1) beside the entropy bonus. The
Huber critic loss (`AlgorithmConfig.huber_delta`) bounds the gradient of the rare large TD errors.
Both are departures from the paper; their reasons and measurements: docs/training.md.

Supervised terms (beyond the paper; agents.loss_terms, docs/training.md): behaviour cloning,
the supervised gate loss and the fine-tuning anchor, each only when its weight is > 0, so the
paper's GA-SAC is unchanged by default (their definitions: :meth:`GASACLoss.forward`).

Gate L1: only the actor's gates carry the L1 penalty. The critic is a value estimator whose gates
flag nothing (prop-v1's inlier flags are the actor's); penalising them only biases the value
fit. λ_gate multiplies the mean of z over real edges and layers (a per-edge normalisation).

The edge entropy is exact (a sum over the masked categorical) rather than a sampled −log π(e),
which removes one source of variance. Q̄ uses the target critic parameters. The actor
differentiates through the edge choice with the straight-through Gumbel-softmax one-hot and
through δ with the reparameterised tanh-Gaussian; the critic parameters are detached there.
Correction terms are masked out for agents whose only choice is the no-op (their δ is ignored
by the environment). Each of the four losses reaches only its own parameter group, so they may
be summed and back-propagated once.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.objectives import LossModule

from agents.actor import (
    ACTION_MASK_KEY,
    DELTA_ACTION_KEY,
    EDGE_ACTION_KEY,
    OBSERVATION_KEY,
    ActorOutput,
    HybridActor,
    recurrent_inputs,
)
from agents.config import AlgorithmConfig
from agents.critic import CentralCritic
from agents.encoder import Encoding, GraphBatch
from agents.loss_terms import actor_imitation_losses, gate_supervision_loss

LABELS = ("agents", "labels")


def critic_regression(td_error: Tensor, huber_delta: float | None) -> Tensor:
    """Elementwise critic loss: ½ δ² (SAC) when `huber_delta` is None, else the Huber loss,
    ½ δ² for |δ| ≤ d and d (|δ| − ½ d) beyond (same value and slope at |δ| = d)."""
    if huber_delta is None:
        return 0.5 * td_error.pow(2)
    return F.huber_loss(td_error, torch.zeros_like(td_error), reduction="none", delta=huber_delta)


class GASACLoss(LossModule):
    """GA-SAC losses for a shared `HybridActor` and a `CentralCritic` (fixed n).

    Args:
        actor: the shared actor (its parameters are the ones the collector's policy uses).
        critic: the central critic; target parameters are a copy updated by `SoftUpdate`.
        config: γ, initial temperatures, target entropies, the gate L1 weight and the
            weights of the supervised terms (bc_weight, gate_weight).
    """

    @dataclass
    class _AcceptedKeys:
        """Tensordict keys (set with `set_keys`); "next" versions are read under ("next", …)."""

        observation: tuple = OBSERVATION_KEY
        action_mask: tuple = ACTION_MASK_KEY
        action_edge: tuple = EDGE_ACTION_KEY
        action_delta: tuple = DELTA_ACTION_KEY
        reward: tuple = ("agents", "reward")
        done: tuple = ("agents", "done")
        terminated: tuple = ("agents", "terminated")
        right_edges: tuple = LABELS + ("right",)
        expert_edge: tuple = LABELS + ("expert_edge",)
        expert_delta: tuple = LABELS + ("expert_delta",)
        outlier: tuple = LABELS + ("outlier",)

    actor_network: TensorDictModule
    critic_network: TensorDictModule
    actor_network_params: TensorDictParams
    critic_network_params: TensorDictParams
    target_actor_network_params: TensorDictParams
    target_critic_network_params: TensorDictParams

    def __init__(self, actor: HybridActor, critic: CentralCritic, config: AlgorithmConfig) -> None:
        super().__init__()
        # the start policy π₀, frozen (set_anchor copies the start weights in)
        anchor = copy.deepcopy(actor).requires_grad_(False) if config.anchor_weight > 0 else None
        self.convert_to_functional(actor, "actor_network")
        self.convert_to_functional(critic, "critic_network", create_target_params=True)
        self.gamma = config.gamma
        self.edge_entropy_ratio = config.edge_entropy_ratio
        self.gate_l1 = config.gate_l1
        # set by the trainer at the end of the warm-up when auto_* (saved with the loss)
        self.register_buffer("reward_scale", torch.tensor(float(config.reward_scale)))
        self.register_buffer("delta_target_entropy", torch.tensor(config.delta_target_entropy))
        self.anchor_weight = config.anchor_weight
        self.register_buffer("anchor_scale", torch.tensor(1.0))  # λ_k / λ₀, set per update
        self.anchor = anchor
        self.huber_delta = config.huber_delta
        self.bc_weight = config.bc_weight
        self.gate_weight = config.gate_weight
        self.log_alpha_edge = nn.Parameter(torch.tensor(math.log(config.init_alpha_edge)))
        self.log_alpha_delta = nn.Parameter(torch.tensor(math.log(config.init_alpha_delta)))

    # -- parameter groups (one optimiser each: lr 3e-4 actor, 3e-5 critic) ----------------------

    def set_anchor(self, actor: HybridActor) -> None:
        """Freeze a copy of `actor`'s current weights as the anchor policy π₀."""
        if self.anchor is not None:
            self.anchor.load_state_dict(actor.state_dict())

    def actor_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.actor_network_params.values(True, True) if p.requires_grad]

    def critic_parameters(self) -> list[nn.Parameter]:
        return [p for p in self.critic_network_params.values(True, True) if p.requires_grad]

    def alpha_parameters(self) -> list[nn.Parameter]:
        return [self.log_alpha_edge, self.log_alpha_delta]

    # -- pieces --------------------------------------------------------------------------------

    def _graphs(self, tensordict: TensorDictBase, next_: bool) -> GraphBatch:
        prefix = ("next",) if next_ else ()
        return GraphBatch.from_observation(
            tensordict.get(prefix + self.tensor_keys.observation),
            tensordict.get(prefix + self.tensor_keys.action_mask),
        )

    def _act(self, tensordict: TensorDictBase, graphs: GraphBatch, next_: bool) -> ActorOutput:
        """A fresh (sampled) actor pass from the stored recurrent state."""
        lead = tensordict.get(self.tensor_keys.action_mask).shape[:-1]
        memory, prev_edge, prev_delta = recurrent_inputs(
            tensordict, self.actor_network, lead, graphs.action_mask.shape[-1], next_
        )
        with self.actor_network_params.to_module(self.actor_network):
            return self.actor_network(graphs, memory, prev_edge, prev_delta, deterministic=False)

    def _agent_flag(self, tensordict: TensorDictBase, key: tuple, shape: torch.Size) -> Tensor:
        """("next", key) as float [B, n]; a root-level (B, 1) flag is broadcast to the agents."""
        value = tensordict.get(("next",) + key, None)
        if value is None:
            value = tensordict.get(("next", key[-1]))
        return value.to(torch.float32).reshape(shape[0], -1).expand(shape).contiguous()

    def _alphas(self) -> tuple[Tensor, Tensor]:
        return self.log_alpha_edge.exp().detach(), self.log_alpha_delta.exp().detach()

    @staticmethod
    def _acting(out: ActorOutput) -> Tensor:
        """[G] float: 1 where the chosen edge is a real edge (not the forced no-op)."""
        return (out.edge < out.action_mask.shape[-1] - 1).to(out.delta.dtype)

    # -- the four losses (each reaches only its own parameter group) ---------------------------

    @torch.no_grad()
    def soft_target(
        self, tensordict: TensorDictBase, next_graphs: GraphBatch, alphas: tuple[Tensor, Tensor]
    ) -> Tensor:
        """[B, n] critic target y_i = c·r_i + γ (1 − terminated_i) V_i(s′), with
        V_i(s′) = min_k Q̄_k,i(s′, a′) + α_e H[π(· | s′)] − α_δ log π(δ′ | s′, e′),  a′ ~ π
        (Q̄: the target critic; the δ term only for agents that act)."""
        keys = self.tensor_keys
        batch, agents = tensordict.get(keys.action_mask).shape[:2]
        alpha_edge, alpha_delta = alphas
        next_out = self._act(tensordict, next_graphs, next_=True)
        with self.target_critic_network_params.to_module(self.critic_network):
            next_q, _ = self.critic_network(next_graphs, next_out.edge_weights, next_out.delta)
        entropy_bonus = (
            alpha_edge * next_out.edge_entropy
            - alpha_delta * self._acting(next_out) * next_out.delta_log_prob
        )
        soft_value = next_q.min(-1).values + entropy_bonus.view(batch, agents)
        reward = self.reward_scale * tensordict.get(("next",) + keys.reward).reshape(batch, agents)
        terminated = self._agent_flag(tensordict, keys.terminated, (batch, agents))
        return reward + self.gamma * (1.0 - terminated) * soft_value

    def qvalue_loss(
        self, tensordict: TensorDictBase, graphs: GraphBatch, target: Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        """L_Q = mean_{B,n} Σ_k ρ(Q_k,i(s, a) − y_i) on the stored actions a (ρ:
        `critic_regression`); returns (L_Q, [B, n, 2] Q of the taken actions, [B, n, 2] TD
        errors)."""
        keys = self.tensor_keys
        choices = graphs.action_mask.shape[-1]
        taken_edge = F.one_hot(tensordict.get(keys.action_edge).reshape(-1), choices)
        taken_delta = tensordict.get(keys.action_delta).reshape(-1, 3)
        q_taken, _ = self.critic_network_apply(graphs, taken_edge, taken_delta)
        td_error = q_taken - target.unsqueeze(-1)
        loss = critic_regression(td_error, self.huber_delta).sum(-1).mean()
        return loss, q_taken, td_error

    def actor_loss(
        self, tensordict: TensorDictBase, graphs: GraphBatch, alphas: tuple[Tensor, Tensor]
    ) -> tuple[Tensor, ActorOutput, Tensor, Tensor]:
        """L_π = mean[−α_e H[π(· | s)] + α_δ log π(δ | s, e) − min_k Q_k,i(s, ã)] + λ_gate·mean z,
        ã ~ π reparameterised, the critic detached and differentiated through agent i's own
        action only; returns (L_π, the actor pass, [G] acting flags, [G] masked log π(δ))."""
        alpha_edge, alpha_delta = alphas
        out = self._act(tensordict, graphs, next_=False)
        with self.critic_network_params.detach().to_module(self.critic_network):
            q_policy, _ = self.critic_network(
                graphs, out.edge_weights, out.delta, own_action_only=True
            )
        acting = self._acting(out)
        delta_log_prob = acting * out.delta_log_prob
        loss = (
            -alpha_edge * out.edge_entropy
            + alpha_delta * delta_log_prob
            - q_policy.min(-1).values.reshape(-1)
        ).mean() + self.gate_l1 * out.encoding.gate_l1
        return loss, out, acting, delta_log_prob

    def alpha_edge_loss(self, out: ActorOutput, graphs: GraphBatch) -> tuple[Tensor, Tensor]:
        """L(α_e) = mean[log α_e · (H[π(· | s)] − H̄_e(s))], H̄_e(s) = ratio · log |allowed edges|;
        returns (the loss, [G] H̄_e)."""
        allowed = graphs.action_mask.sum(-1).to(out.delta.dtype)
        edge_target = self.edge_entropy_ratio * torch.log(allowed)
        loss = (self.log_alpha_edge * (out.edge_entropy - edge_target).detach()).mean()
        return loss, edge_target

    def alpha_delta_loss(self, out: ActorOutput, acting: Tensor) -> Tensor:
        """L(α_δ) = −mean over acting agents of log α_δ · (log π(δ | s, e) + H̄_δ)."""
        delta_gap = (out.delta_log_prob + self.delta_target_entropy).detach()
        return -(self.log_alpha_delta * acting * delta_gap).sum() / acting.sum().clamp(min=1.0)

    @torch.no_grad()
    def _anchor_pass(
        self, tensordict: TensorDictBase, graphs: GraphBatch, edge: Tensor
    ) -> ActorOutput:
        """π₀'s deterministic pass on the same state, teacher-forced on the actor's edge."""
        lead = tensordict.get(self.tensor_keys.action_mask).shape[:-1]
        memory, prev_edge, prev_delta = recurrent_inputs(
            tensordict, self.anchor, lead, graphs.action_mask.shape[-1], False
        )
        return self.anchor(graphs, memory, prev_edge, prev_delta, deterministic=True, edge=edge)

    def anchor_loss(
        self, tensordict: TensorDictBase, graphs: GraphBatch, out: ActorOutput, acting: Tensor
    ) -> Tensor:
        """λ_k · mean[KL(π(·|s) ‖ π₀(·|s)) + KL(N(μ, σ²) ‖ N(μ₀, σ₀²)) on the chosen edge]
        (AlgorithmConfig.anchor_weight; the correction's KL only where the agent acts)."""
        start = self._anchor_pass(tensordict, graphs, out.edge)
        finite = torch.where(
            out.action_mask, out.edge_log_probs, torch.zeros_like(out.edge_log_probs)
        )
        finite_start = torch.where(
            out.action_mask, start.edge_log_probs, torch.zeros_like(start.edge_log_probs)
        )
        edge_kl = (finite.exp() * (finite - finite_start) * out.action_mask).sum(-1)
        log_ratio = start.delta_log_std - out.delta_log_std
        variance = (2 * out.delta_log_std).exp() + (out.delta_mean - start.delta_mean) ** 2
        delta_kl = (log_ratio + variance / (2 * (2 * start.delta_log_std).exp()) - 0.5).sum(-1)
        return self.anchor_weight * self.anchor_scale * (edge_kl + acting * delta_kl).mean()

    def bc_loss(self, tensordict: TensorDictBase, graphs: GraphBatch) -> Tensor:
        """λ_bc · (L_edge + L_delta) on the stored labels (module docstring): one deterministic
        actor pass from the stored recurrent state, teacher-forced on the expert's edge."""
        keys = self.tensor_keys
        lead = tensordict.get(keys.action_mask).shape[:-1]
        choices = graphs.action_mask.shape[-1]
        memory, prev_edge, prev_delta = recurrent_inputs(
            tensordict, self.actor_network, lead, choices, False
        )
        expert_edge = tensordict.get(keys.expert_edge).reshape(-1)
        with self.actor_network_params.to_module(self.actor_network):
            out = self.actor_network(
                graphs, memory, prev_edge, prev_delta, deterministic=True, edge=expert_edge
            )
            bound = self.actor_network.delta_max.clone()
        right = tensordict.get(keys.right_edges).reshape(-1, choices)
        label = tensordict.get(keys.expert_delta).reshape(-1, 3)
        acting = expert_edge < choices - 1
        edge_loss, delta_loss = actor_imitation_losses(out, right, label, acting, bound)
        return self.bc_weight * (edge_loss + delta_loss)

    def gate_loss(self, tensordict: TensorDictBase, out: ActorOutput, graphs: GraphBatch) -> Tensor:
        """λ_gate_sup · L_gate of the actor pass's gates against the stored outlier labels."""
        outlier = tensordict.get(self.tensor_keys.outlier)
        outlier = outlier.reshape(-1, outlier.shape[-1])
        logits = out.encoding.gate_logits
        return self.gate_weight * gate_supervision_loss(logits, outlier, graphs.edge_mask)

    # -- forward -------------------------------------------------------------------------------

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """Losses for a batch [B] of transitions; returns loss_* scalars and diagnostics
        (loss_bc / loss_gate only when their weights are > 0).

        The order of the parts is fixed (target, critic, actor, temperatures, supervised
        terms): the target and the actor each sample an action, so reordering them changes the
        random stream (the supervised terms sample nothing).

        Supervised terms, each under its own key and only when its weight is > 0:

        * ``loss_bc = λ_bc · (L_edge + L_delta)``: behaviour cloning of the expert on the
          replayed states, from the labels stored with each transition at collection time (the
          env's ``labels=True``: ("agents", "labels", "right" | "expert_edge" |
          "expert_delta"), the labels of the transition's state s). ``L_edge = −log Σ_{e right}
          π(e | s)``; ``L_delta`` is the squared error of the actor's deterministic correction
          on the expert's edge (teacher forcing: one more actor pass, no sampling) against the
          expert's, in units of the action bound.
        * ``loss_gate = λ_gate_sup · L_gate``: the supervised gate loss of the actor pass's gate
          logits against ("agents", "labels", "outlier"), the injected outliers.
        * ``loss_anchor = λ_k · E[KL(π(·|s) ‖ π₀(·|s)) + KL(N(μ, σ²) ‖ N(μ₀, σ₀²))]``: the
          fine-tuning anchor toward the start policy π₀ (a frozen copy of the imitation actor;
          the correction's KL on the actor's chosen edge, in the pre-tanh space), its weight
          decaying linearly to 0 (AlgorithmConfig.anchor_weight / anchor_updates).

        They reach only the actor's parameters and do not depend on the critic, so they act
        during the critic warm-up too (agents.gasac_trainer.optimise leaves out loss_actor only).
        Reward scale and target entropy are buffers: with AlgorithmConfig.auto_reward_scale /
        auto_delta_entropy the trainer sets them from the warm-up data (agents.trainer).
        """
        alphas = self._alphas()
        graphs = self._graphs(tensordict, next_=False)
        next_graphs = self._graphs(tensordict, next_=True)
        target = self.soft_target(tensordict, next_graphs, alphas)
        loss_qvalue, q_taken, td_error = self.qvalue_loss(tensordict, graphs, target)
        loss_actor, out, acting, delta_log_prob = self.actor_loss(tensordict, graphs, alphas)
        loss_alpha_edge, edge_target = self.alpha_edge_loss(out, graphs)
        loss_alpha_delta = self.alpha_delta_loss(out, acting)
        supervised = {}
        if self.anchor is not None:
            supervised["loss_anchor"] = self.anchor_loss(tensordict, graphs, out, acting)
        if self.bc_weight > 0:
            supervised["loss_bc"] = self.bc_loss(tensordict, graphs)
        if self.gate_weight > 0:
            supervised["loss_gate"] = self.gate_loss(tensordict, out, graphs)
        return TensorDict(
            {
                **supervised,
                "loss_actor": loss_actor,
                "loss_qvalue": loss_qvalue,
                "loss_alpha_edge": loss_alpha_edge,
                "loss_alpha_delta": loss_alpha_delta,
                "alpha_edge": alphas[0],
                "alpha_delta": alphas[1],
                "entropy_edge": out.edge_entropy.mean().detach(),
                "target_entropy_edge": edge_target.mean().detach(),
                "log_prob_delta": (delta_log_prob.sum() / acting.sum().clamp(min=1.0)).detach(),
                "gate_mean": out.encoding.gate_l1.detach(),
                "q_mean": q_taken.mean().detach(),
                "td_error": td_error.abs().mean().detach(),
            },
            batch_size=[],
        )

    def critic_network_apply(
        self, graphs: GraphBatch, edge_weights: Tensor, delta: Tensor
    ) -> tuple[Tensor, Encoding]:
        """The critic with its trainable parameters: ([B, n, 2] Q, its encoding)."""
        with self.critic_network_params.to_module(self.critic_network):
            return self.critic_network(graphs, edge_weights, delta)
