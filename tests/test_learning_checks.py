"""Checks that the learned parts can learn and do not drift (docs/training.md): the null-critic test
(a flat critic must not move the correction), the critic probe, and the sanity task (GA-SAC
from scratch must learn a state-dependent correction, measured by the correction probe)."""

from __future__ import annotations

import copy
import dataclasses

import pytest
import torch
from conftest import tiny_model

from agents.config import AlgorithmConfig, ExperimentConfig, ImitationConfig
from envs.modes import TRAJECTORY_MODES
from popbench.threads import limited_threads

ROBOTS, POSES = 3, 10
TASK = TRAJECTORY_MODES
EXPERIMENT = ExperimentConfig(robots=ROBOTS, poses_per_robot=POSES, seed=4)


def make_env(batch: int = 2, seed: int = 0):
    from envs import make_torchrl_env

    return make_torchrl_env(
        robots=ROBOTS,
        batch_size=batch,
        seed=seed,
        poses_per_robot=POSES,
        reward="F",
        terminal_bonus=False,
        **TASK.core_options(),
    )


def imitation_actor(env):
    """A tiny base-feature actor after a short imitation phase (its correction is not zero)."""
    from agents.actor import HybridActor
    from agents.imitation import imitate

    observation = env.observation_spec["agents", "observation"]
    bound = tuple(float(v) for v in env.core.action_bound)
    model = dataclasses.replace(tiny_model(), delta_max=bound, base_features=True)
    torch.manual_seed(0)
    actor = HybridActor(
        observation["node_features"].shape[-1], observation["edge_attr"].shape[-1], model
    )
    imitate(actor, TASK, EXPERIMENT, ImitationConfig(episodes=4, num_envs=2, lr=3e-3))
    return actor


@pytest.fixture(scope="module")
def trained():
    """(env, imitation actor, its rollout [B, T] in the F-rewarded env)."""
    from torchrl.envs import TransformedEnv

    from agents.actor import GASACPolicy

    env = make_env()
    actor = imitation_actor(env)
    policy = GASACPolicy(actor)
    wrapped = TransformedEnv(env, policy.primer(ROBOTS, env.dims.edges + 1))
    torch.manual_seed(1)
    return env, actor, wrapped.rollout(12, policy, break_when_any_done=False)


def deterministic_corrections(actor, batch) -> torch.Tensor:
    """[G, 3] the actor's deterministic correction on each stored state's taken edge."""
    from agents.actor import recurrent_inputs
    from agents.encoder import GraphBatch

    graphs = GraphBatch.from_observation(
        batch["agents", "observation"], batch["agents", "action_mask"]
    )
    lead = batch["agents", "action_mask"].shape[:-1]
    state = recurrent_inputs(batch, actor, lead, graphs.action_mask.shape[-1], False)
    edge = batch["agents", "action", "edge"].reshape(-1)
    with torch.no_grad():
        return actor(graphs, *state, deterministic=True, edge=edge).delta


def drift_under_a_null_critic(env, actor, data, anchor_weight: float, updates: int = 60):
    """max |Δδ| (whitened σ) of the deterministic correction after `updates` actor updates of
    GA-SAC whose critic returns Q ≡ 0 (only the entropy terms and the anchor act)."""
    from agents.critic import CentralCritic
    from agents.loss import GASACLoss

    actor = copy.deepcopy(actor)
    observation = env.observation_spec["agents", "observation"]
    critic = CentralCritic(
        observation["node_features"].shape[-1],
        observation["edge_attr"].shape[-1],
        ROBOTS,
        actor.config,
    )
    config = AlgorithmConfig(anchor_weight=anchor_weight, anchor_updates=10**6)
    loss = GASACLoss(actor, critic, config)
    loss.set_anchor(actor)

    def null(graphs, edge_weights, delta, deterministic=False, own_action_only=False):
        return torch.zeros(edge_weights.shape[0] // ROBOTS, ROBOTS, 2), None

    loss.critic_network.forward = null
    batch = data.reshape(-1)
    before = deterministic_corrections(actor, batch)
    optimiser = torch.optim.Adam(loss.actor_parameters(), lr=config.actor_lr)
    torch.manual_seed(2)
    for _ in range(updates):
        out = loss(batch)
        total = out["loss_actor"] + out.get("loss_anchor", torch.zeros(()))
        optimiser.zero_grad()
        total.backward()
        optimiser.step()
    with loss.actor_network_params.to_module(loss.actor_network):
        after = deterministic_corrections(loss.actor_network, batch)
    return float((after - before).abs().max())


def test_a_null_critic_does_not_move_the_correction_with_the_anchor(trained) -> None:
    """Q ≡ 0: the entropy term alone pulls the squashed mean; the anchor holds it within 0.05σ
    (of a ±5σ action), where without it the same updates move it further."""
    env, actor, data = trained
    anchored = drift_under_a_null_critic(env, actor, data, anchor_weight=1.0)
    free = drift_under_a_null_critic(env, actor, data, anchor_weight=0.0)
    print(f"drift anchored {anchored:.4f} free {free:.4f}")
    assert anchored < 0.05
    assert free > 2 * anchored  # the check can fail: without the anchor δ drifts


def test_critic_probe_sees_a_critic_that_learned_the_one_step_reward(trained) -> None:
    """A critic regressed on the immediate reward (γ = 0) for a few hundred steps ranks the
    corrections of one state as the environment does; an untrained one does not."""
    from torchrl.envs import TransformedEnv

    from agents.actor import GASACPolicy
    from agents.config import TrainConfig
    from agents.diagnostics import critic_probe
    from agents.session import build_session

    env, actor, data = trained
    config = TrainConfig(
        model=dataclasses.replace(actor.config),
        algorithm=AlgorithmConfig(gamma=0.0, reward="F", terminal_bonus=False, critic_lr=3e-3),
        experiment=dataclasses.replace(
            EXPERIMENT, num_envs=2, eval_problems=2, progress=False, frames=64
        ),
        task=TASK,
    )
    session = build_session(config)
    session.actor.load_state_dict(actor.state_dict())
    eval_env = make_env(batch=2, seed=7)
    untrained = critic_probe(session, eval_env)
    # training data: the actor's states with wide corrections, so that rewards vary
    policy = GASACPolicy(session.actor)
    wide = TransformedEnv(make_env(batch=4, seed=3), policy.primer(ROBOTS, env.dims.edges + 1))
    torch.manual_seed(5)
    batch = wide.rollout(20, policy, break_when_any_done=False).reshape(-1)
    optimiser = torch.optim.Adam(session.loss.critic_parameters(), lr=3e-3)
    for _ in range(300):
        graphs = session.loss._graphs(batch, next_=False)
        reward = session.loss.reward_scale * batch["next", "agents", "reward"].reshape(-1, ROBOTS)
        q, _, _ = session.loss.qvalue_loss(batch, graphs, reward)
        optimiser.zero_grad()
        q.backward()
        optimiser.step()
    trained_score = critic_probe(session, copy.deepcopy(eval_env))
    print(f"probe untrained {untrained:.3f} trained {trained_score:.3f}")
    assert trained_score > 0.5 > untrained + 0.2


# The sanity task: one robot, a 10-pose chain with its loop closures, started off its odometry
# by 2 σ per measurement (popbench.problems.synthetic.perturbed_start), no base step: the best
# correction of each step undoes its perturbation, which the step's residual shows, and δ := 0
# changes nothing. GA-SAC from scratch (the tiny actor, ~1,000 updates, ~1 min of one core) must
# learn a state-dependent correction that follows the expert's and lowers F. Measured over training
# seeds 0, 1, 2 (docs/training.md): correlation with the expert 0.94 / 0.92 / 0.83, spread
# 1.5 / 1.4 / 1.8 σ, F reduction 0.78 / 0.82 / 0.70; at 4,096 frames seed 2 still raised F.
SANITY_TASK = dataclasses.replace(TASK, base="none")


def sanity_config(out_dir):
    from agents.config import TrainConfig

    algorithm = AlgorithmConfig(
        reward="F",
        terminal_bonus=False,
        auto_reward_scale=True,
        huber_delta=None,
        gamma=0.5,
        warmup_frames=128,
        batch_size=32,
        buffer_size=4_096,
        updates_per_batch=8,
        actor_lr=1e-3,
        critic_lr=1e-3,
        alpha_lr=3e-3,
        tau=0.02,
        critic_warmup_updates=32,
        gate_l1=0.0,
    )
    experiment = ExperimentConfig(
        robots=1,
        poses_per_robot=10,
        start_noise=2.0,
        num_envs=8,
        frames=8_192,
        frames_per_batch=64,
        checkpoint_interval=100_000,
        eval_interval=100_000,
        out_dir=str(out_dir),
        progress=False,
    )
    model = dataclasses.replace(tiny_model(), correction_hidden=(32, 32))
    return TrainConfig(model=model, algorithm=algorithm, experiment=experiment, task=SANITY_TASK)


def test_ga_sac_from_scratch_learns_the_sanity_task(tmp_path) -> None:
    from agents.checkpoint import load_actor
    from agents.diagnostics import correction_probe
    from agents.session import build_session
    from agents.trainer import train

    config = sanity_config(tmp_path)
    with limited_threads(1):  # as `popbench train` runs (a torch pool on a busy core: 4x slower)
        fresh = build_session(config).actor
        untrained = correction_probe(fresh, SANITY_TASK, config.experiment, problems=32)
        train(config, resume=False)
        actor, _ = load_actor(tmp_path / "checkpoint.pt")
        probe = correction_probe(actor, SANITY_TASK, config.experiment, problems=32)
    assert untrained["local_gain"] < 0.2  # the test can fail: the untrained actor does not pass
    assert abs(probe["local_gain_zero"]) < 1e-9  # δ := 0 is the no-op here
    assert probe["local_gain"] > 0.5, probe
    assert probe["corr_executed"] > 0.6, probe
    assert probe["delta_std"] > 0.5, probe
