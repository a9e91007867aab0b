"""A GA-SAC training session: env, networks, loss, target updater and optimisers, built from a
`TrainConfig`, and its checkpoint state (save with `session_state`, load with `restore`)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import torch
from torchrl.envs import TransformedEnv
from torchrl.objectives import SoftUpdate

from agents.actor import GASACPolicy, HybridActor
from agents.checkpoint import read_checkpoint, training_state
from agents.config import TrainConfig
from agents.critic import CentralCritic
from agents.loss import GASACLoss


@dataclasses.dataclass
class Session:
    """Everything a run holds (built by `build_session`)."""

    config: TrainConfig
    env: TransformedEnv
    actor: HybridActor
    policy: GASACPolicy
    loss: GASACLoss
    updater: SoftUpdate
    optimisers: dict[str, torch.optim.Optimizer]
    dims: dict[str, int]
    frames: int = 0
    updates: int = 0
    actor_updates: int = 0  # updates that trained the actor (the anchor's schedule)
    actor_learns: bool = False  # the critic warm-up is over

    def dims_pair(self) -> tuple[int, int]:
        """(agents n, edge choices E + 1): the recurrent-state primer's arguments."""
        return self.dims["agents"], self.dims["choices"]


def make_env(config: TrainConfig, batch_size: int, seed: int, **options: Any):
    """The synthetic TorchRL env of the experiment (imported lazily: envs pulls torchrl)."""
    from envs import make_torchrl_env

    experiment = config.experiment
    return make_torchrl_env(
        robots=experiment.robots,
        batch_size=batch_size,
        noise=experiment.noise,
        seed=seed,
        device=experiment.device,
        poses_per_robot=experiment.poses_per_robot,
        start_noise=experiment.start_noise,
        **config.task.core_options(),
        **options,
    )


def training_env(
    config: TrainConfig, labels: bool = False
) -> tuple[Any, TrainConfig, dict[str, int]]:
    """The training env (the experiment's outliers, the algorithm's reward and terminal bonus;
    `labels`: the expert labels the supervised terms read), `config` with the actor's output
    bound set to the action's (Δmax, or the whitened bound: EnvModes), and the dimensions
    {"node", "edge": feature widths, "agents": n, "choices": E + 1}."""
    experiment, algorithm = config.experiment, config.algorithm
    training_options: dict[str, Any] = {
        "outlier_rate_max": experiment.outlier_rate_max,
        "reward": algorithm.reward,
        "terminal_bonus": algorithm.terminal_bonus,
    }
    if labels:
        training_options["labels"] = True
    base_env = make_env(config, experiment.num_envs, experiment.seed, **training_options)
    delta_max = tuple(float(v) for v in base_env.core.action_bound.cpu())
    config = dataclasses.replace(
        config, model=dataclasses.replace(config.model, delta_max=delta_max)
    )
    observation = base_env.observation_spec["agents", "observation"]
    dims = {
        "node": observation["node_features"].shape[-1],
        "edge": observation["edge_attr"].shape[-1],
        "agents": experiment.robots,
        "choices": base_env.dims.edges + 1,
    }
    return base_env, config, dims


def build_session(config: TrainConfig) -> Session:
    """Env (+ recurrent-state primer), actor, critic, loss, target updater and optimisers."""
    experiment, algorithm = config.experiment, config.algorithm
    torch.manual_seed(experiment.seed)
    supervised = algorithm.bc_weight > 0 or algorithm.gate_weight > 0
    base_env, config, dims = training_env(config, labels=supervised)
    actor = HybridActor(dims["node"], dims["edge"], config.model).to(experiment.device)
    critic = CentralCritic(dims["node"], dims["edge"], dims["agents"], config.model)
    policy = GASACPolicy(actor)
    env = TransformedEnv(base_env, policy.primer(dims["agents"], dims["choices"]))
    loss = GASACLoss(actor, critic.to(experiment.device), algorithm).to(experiment.device)
    updater = SoftUpdate(loss, tau=algorithm.tau)
    optimisers = {
        "actor": torch.optim.Adam(loss.actor_parameters(), lr=algorithm.actor_lr),
        "critic": torch.optim.Adam(loss.critic_parameters(), lr=algorithm.critic_lr),
        "alpha": torch.optim.Adam(loss.alpha_parameters(), lr=algorithm.alpha_lr),
    }
    return Session(config, env, actor, policy, loss, updater, optimisers, dims)


def session_state(session: Session) -> dict[str, Any]:
    """GA-SAC's checkpoint (agents.checkpoint.training_state, with the actor's progress)."""
    progress = {"actor_updates": session.actor_updates, "actor_learns": session.actor_learns}
    return training_state(session, session.optimisers, **progress)


def restore(session: Session, checkpoint: Path | dict[str, Any]) -> None:
    """Load networks, optimisers and progress from a checkpoint (path or read state)."""
    state = checkpoint
    if not isinstance(state, dict):
        state = read_checkpoint(checkpoint, session.config.experiment.device)
    session.loss.load_state_dict(state["loss"])
    for name, optimiser in session.optimisers.items():
        optimiser.load_state_dict(state["optimisers"][name])
    session.frames, session.updates = int(state["frames"]), int(state["updates"])
    session.actor_updates = int(state.get("actor_updates", 0))
    session.actor_learns = bool(state.get("actor_learns", False))
