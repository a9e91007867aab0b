"""MAPPO and IPPO on TorchRL: the GA-SAC actor trained with `ClipPPOLoss` and `GAE`.

The session (`build_ppo_session`) holds the training env of agents.session (the same task,
reward and frames), the shared HybridActor behind `PPOPolicy` (agents.ppo_actor, its hybrid
distribution in agents.hybrid_distribution), a `ValueOperator` (agents.value: centralised for
"mappo", per robot for "ippo"), the loss and one Adam optimiser over actor and value function.
`MAPPO` and `IPPO` are its agents.learner.Learner records: agents.trainer.train runs them with the
collector, checkpoints, metrics, held-out evaluation and resuming it runs GA-SAC with.

Per collected batch [num_envs, T] (`PPOBatches.learn`): rewards scaled by c (1 / std of the
first batch's rewards that vary, or 1 where the task fixes its scale, kept for the run;
agents.reward_scale.run_scale), the root done flags expanded to the robots, V(s) and V(s') by
the value function, GAE advantages and value targets (per robot, normalised over the batch),
then `epochs` passes of shuffled minibatches of `minibatch_size` joint transitions.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.envs import TransformedEnv
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from agents.actor import AGENTS, HybridActor
from agents.checkpoint import training_state
from agents.config import TrainConfig
from agents.learner import Learner
from agents.metrics import PPO_METRIC_FIELDS
from agents.ppo_actor import ACTION_KEY, SAMPLE_LOG_PROB_KEY, PPOPolicy
from agents.reward_scale import SCALE_UNSET, applied, run_scale
from agents.session import training_env
from agents.value import VALUE_KEY, TeamValue, ValueOperator

KEYS = {  # the explicit tensordict keys of ClipPPOLoss and GAE
    "action": ACTION_KEY,
    "sample_log_prob": SAMPLE_LOG_PROB_KEY,
    "value": VALUE_KEY,
    "advantage": (AGENTS, "advantage"),
    "value_target": (AGENTS, "value_target"),
    "reward": (AGENTS, "scaled_reward"),
    "done": (AGENTS, "done"),
    "terminated": (AGENTS, "terminated"),
}
GAE_KEYS = ("value", "advantage", "value_target", "reward", "done", "terminated")


@dataclasses.dataclass
class PPOSession:
    """Everything a MAPPO / IPPO run holds (built by `build_ppo_session`)."""

    config: TrainConfig
    env: TransformedEnv
    actor: HybridActor
    policy: PPOPolicy
    value: ValueOperator
    loss: ClipPPOLoss
    advantage: GAE
    optimiser: torch.optim.Optimizer
    dims: dict[str, int]
    frames: int = 0
    updates: int = 0
    reward_scale: float = SCALE_UNSET  # c, set on the first batch whose rewards vary


def build_ppo_session(config: TrainConfig, central_value: bool) -> PPOSession:
    """The training env (+ recurrent-state primer), actor, value function, loss, GAE, optimiser;
    ``central_value``: MAPPO's value function of the whole team, else IPPO's per agent."""
    experiment, ppo = config.experiment, config.ppo
    torch.manual_seed(experiment.seed)
    base_env, config, dims = training_env(config)
    device = experiment.device
    actor = HybridActor(dims["node"], dims["edge"], config.model).to(device)
    policy = PPOPolicy(actor)
    env = TransformedEnv(base_env, policy.primer(dims["agents"], dims["choices"]))
    network = TeamValue(dims["node"], dims["edge"], dims["agents"], config.model, central_value)
    value = ValueOperator(network.to(device))
    loss = ClipPPOLoss(
        policy,
        value,
        clip_epsilon=ppo.clip_epsilon,
        entropy_coeff=ppo.entropy_coeff,
        critic_coeff=ppo.critic_coeff,
        loss_critic_type="l2",
        normalize_advantage=False,  # done over the whole batch in PPOBatches.prepare
        functional=False,
    )
    loss.set_keys(**KEYS)
    advantage = GAE(gamma=ppo.gamma, lmbda=ppo.lmbda, value_network=None)
    advantage.set_keys(**{name: KEYS[name] for name in GAE_KEYS})
    optimiser = torch.optim.Adam(loss.parameters(), lr=ppo.lr)
    return PPOSession(config, env, actor, policy, value, loss, advantage, optimiser, dims)


def ppo_session_state(session: PPOSession) -> dict[str, Any]:
    """The checkpoint (agents.checkpoint's layout: "config", "dims", "actor" as GA-SAC's)."""
    optimisers = {"ppo": session.optimiser}
    return training_state(session, optimisers, reward_scale=session.reward_scale)


def restore_ppo(session: PPOSession, state: dict[str, Any]) -> None:
    """Load networks, optimiser, reward scale and progress from a read checkpoint."""
    session.loss.load_state_dict(state["loss"])
    session.optimiser.load_state_dict(state["optimisers"]["ppo"])
    session.frames, session.updates = int(state["frames"]), int(state["updates"])
    session.reward_scale = float(state["reward_scale"])


def optimise_ppo(session: PPOSession, minibatch: TensorDictBase) -> dict[str, float]:
    """One Adam step on loss_objective + loss_critic + loss_entropy; the loss's logs (means)."""
    out = session.loss(minibatch)
    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
    session.optimiser.zero_grad(set_to_none=True)
    total.backward()
    torch.nn.utils.clip_grad_norm_(session.loss.parameters(), session.config.ppo.max_grad_norm)
    session.optimiser.step()
    session.updates += 1
    return {key: float(value.detach().float().mean()) for key, value in out.items()}


class PPOBatches:
    """The per-batch PPO step (agents.learner.BatchLearner; module docstring)."""

    def __init__(self, session: PPOSession) -> None:
        self.session = session

    @torch.no_grad()
    def prepare(self, data: TensorDictBase) -> TensorDictBase:
        """`data` [num_envs, T] with the scaled rewards, the robots' done flags, V(s), V(s'),
        advantages and value targets at the KEYS (in place)."""
        session, ppo = self.session, self.session.config.ppo
        reward = data.get(("next", AGENTS, "reward"))  # [B, T, n, 1]
        if session.reward_scale == SCALE_UNSET:
            session.reward_scale = run_scale(session.config.task, reward)
        data.set(("next",) + KEYS["reward"], reward * applied(session.reward_scale))
        for name in ("done", "terminated"):
            flag = data.get(("next", name)).unsqueeze(-2).expand_as(reward)  # [B, T, 1] → robots
            data.set(("next",) + KEYS[name], flag.clone())
        session.value(data)
        session.value(data.get("next"))
        session.advantage(data)
        if ppo.normalize_advantage:
            advantage = data.get(KEYS["advantage"])
            std = advantage.std().clamp(min=1e-6)
            data.set(KEYS["advantage"], (advantage - advantage.mean()) / std)
        return data

    def learn(self, data: TensorDictBase) -> dict[str, Any]:
        session, ppo = self.session, self.session.config.ppo
        transitions = self.prepare(data).reshape(-1)
        logs: list[dict[str, float]] = []
        for _ in range(ppo.epochs):
            for index in torch.randperm(transitions.numel()).split(ppo.minibatch_size):
                logs.append(optimise_ppo(session, transitions[index]))
        row: dict[str, Any] = {"reward_scale": session.reward_scale}
        for key in logs[0].keys() & set(PPO_METRIC_FIELDS):
            row[key] = sum(log[key] for log in logs) / len(logs)
        return row

    def evaluate(self, eval_env: Any) -> dict[str, Any]:  # noqa: ARG002 - no extra probes
        return {}


MAPPO = Learner(
    "MAPPO",
    functools.partial(build_ppo_session, central_value=True),
    restore_ppo,
    ppo_session_state,
    PPOBatches,
    PPO_METRIC_FIELDS,
    config_parts=("ppo",),
)
IPPO = dataclasses.replace(
    MAPPO, name="IPPO", build=functools.partial(build_ppo_session, central_value=False)
)
