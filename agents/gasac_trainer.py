"""GA-SAC's learner (paper §III-D): uniform replay → :class:`agents.loss.GASACLoss`, with the
critic warm-up, the calibration of the reward scale and target entropy at the end of the
warm-up, and ``updates_per_batch`` optimisation steps per collected batch. ``GASAC`` is its
:class:`agents.learner.Learner`; ``agents.trainer.train`` runs it with the collector,
checkpoints, metrics and resuming, as it runs PPO's (:mod:`agents.ppo_trainer`).
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, ReplayBuffer

from agents.diagnostics import critic_probe
from agents.learner import Learner
from agents.metrics import METRIC_FIELDS
from agents.reward_scale import applied, run_scale
from agents.session import Session, build_session, restore, session_state


def optimise(session: Session, batch: TensorDictBase) -> dict[str, float]:
    """One GA-SAC step on a minibatch: the summed losses reach disjoint parameter groups.

    Until the critic warm-up is over (`session.actor_learns`, set by the trainer: after
    `critic_warmup_updates` updates, or earlier by `critic_patience`) only the critic and the
    temperatures learn: the actor's loss is left out, so the actor does not follow the gradient
    of a critic that cannot yet tell one correction from another. The anchor's weight follows
    the actor's updates (AlgorithmConfig.anchor_updates).
    """
    algorithm = session.config.algorithm
    actor_learns = session.actor_learns or session.updates >= algorithm.critic_warmup_updates
    session.actor_learns = actor_learns
    decay = 1.0  # anchor_updates 0: the anchor's weight is held
    if algorithm.anchor_updates > 0:
        decay = max(0.0, 1.0 - session.actor_updates / algorithm.anchor_updates)
    session.loss.anchor_scale.fill_(decay)
    out = session.loss(batch)
    total = sum(
        out[key]
        for key in out.keys()
        if key.startswith("loss_") and (actor_learns or key != "loss_actor")
    )
    for optimiser in session.optimisers.values():
        optimiser.zero_grad(set_to_none=True)
    total.backward()
    clip = session.config.algorithm.max_grad_norm
    torch.nn.utils.clip_grad_norm_(session.loss.actor_parameters(), clip)
    torch.nn.utils.clip_grad_norm_(session.loss.critic_parameters(), clip)
    for optimiser in session.optimisers.values():
        optimiser.step()
    session.updater.step()
    session.updates += 1
    session.actor_updates += int(actor_learns)
    return {key: float(value.detach()) for key, value in out.items()}


@torch.no_grad()
def calibrate(session: Session, warmup: TensorDictBase) -> dict[str, float]:
    """At the end of the warm-up (before the first update): the reward scale c = 1 / std of the
    warm-up rewards (auto_reward_scale; 1 when they are all equal or the task fixes its c,
    agents.reward_scale.run_scale) and the correction's target entropy = the start policy's own
    on the warm-up states (auto_delta_entropy); returns what was set."""
    algorithm, loss = session.config.algorithm, session.loss
    values = {}
    if algorithm.auto_reward_scale:
        scale = run_scale(session.config.task, warmup["next", "agents", "reward"])
        loss.reward_scale.fill_(applied(scale))
        values["reward_scale"] = float(loss.reward_scale)
    if algorithm.auto_delta_entropy:
        graphs = loss._graphs(warmup, next_=False)
        out = loss._act(warmup, graphs, next_=False)
        acting = loss._acting(out)
        mean_log_prob = (acting * out.delta_log_prob).sum() / acting.sum().clamp(min=1.0)
        loss.delta_target_entropy.fill_(-float(mean_log_prob))
        values["delta_target_entropy"] = float(loss.delta_target_entropy)
    return values


@torch.no_grad()
def held_out_td_error(session: Session, transitions: TensorDictBase) -> float:
    """Mean |TD error| of the critic on `transitions` kept out of the replay buffer."""
    loss = session.loss
    graphs = loss._graphs(transitions, next_=False)
    target = loss.soft_target(transitions, loss._graphs(transitions, next_=True), loss._alphas())
    _, _, td_error = loss.qvalue_loss(transitions, graphs, target)
    return float(td_error.abs().mean())


class CriticWarmup:
    """The critic-only phase's stopping rule (AlgorithmConfig.critic_patience): the held-out TD
    error, checked every `every` updates, has not fallen by 1 % for `patience` checks."""

    def __init__(self, patience: int, every: int = 16) -> None:
        self.patience, self.every = patience, every
        self.best, self.stale = float("inf"), 0

    def over(self, session: Session, heldout: TensorDictBase | None) -> bool:
        if self.patience <= 0 or heldout is None or session.updates % self.every:
            return False
        error = held_out_td_error(session, heldout)
        if error < 0.99 * self.best:
            self.best, self.stale = error, 0
        else:
            self.stale += 1
        return self.stale >= self.patience


class GASACBatches:
    """GA-SAC's per-batch step: replay, warm-up (calibration, held-out transitions for the
    critic warm-up rule) and `updates_per_batch` optimisation steps."""

    def __init__(self, session: Session) -> None:
        experiment, algorithm = session.config.experiment, session.config.algorithm
        self.session = session
        self.buffer = ReplayBuffer(
            storage=LazyTensorStorage(algorithm.buffer_size, device=experiment.device),
            batch_size=algorithm.batch_size,
        )
        # A resumed run has lost its buffer: it needs only one minibatch before updating again.
        warmup = algorithm.warmup_frames if session.frames == 0 else algorithm.batch_size
        self.warmup_end = session.frames + warmup
        self.warmup_rule = CriticWarmup(algorithm.critic_patience)
        self.heldout: TensorDictBase | None = None  # transitions never replayed (warm-up rule)
        if session.frames == 0:  # the fine-tuning's start policy is the anchor's π₀
            session.loss.set_anchor(session.actor)

    def learn(self, data: TensorDictBase) -> dict[str, Any]:
        session, buffer = self.session, self.buffer
        row: dict[str, Any] = {}
        transitions = data.reshape(-1)
        if self.heldout is None and session.updates == 0 and session.frames >= self.warmup_end:
            self.heldout = transitions[: transitions.numel() // 4]  # a quarter, never replayed
            buffer.extend(transitions[transitions.numel() // 4 :])
            row.update(calibrate(session, buffer[:]))
        else:
            buffer.extend(transitions)
        algorithm = session.config.algorithm
        if session.frames >= self.warmup_end and len(buffer) >= algorithm.batch_size:
            for _ in range(algorithm.updates_per_batch):
                if not session.actor_learns and self.warmup_rule.over(session, self.heldout):
                    session.actor_learns = True
                logs = optimise(session, buffer.sample())
                row.update({k: v for k, v in logs.items() if k in METRIC_FIELDS})
        return row

    def evaluate(self, eval_env: Any) -> dict[str, Any]:
        if self.session.updates > 0:
            return {"critic_probe": critic_probe(self.session, eval_env)}
        return {}


GASAC = Learner("GA-SAC", build_session, restore, session_state, GASACBatches, METRIC_FIELDS)
