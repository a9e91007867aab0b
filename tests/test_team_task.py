"""The team task (envs.team, envs.tasks "team"): every robot is paid, at the episode's end, the
drop in F after the consensus, checked against `popbench.consensus.reconcile` and `objective`
called here directly; with shaping, the local-F rewards on top; trained on and scored like any
checkpoint."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs, step_mdp

import envs
from agents.checkpoint import snapshot_identity
from agents.config import PRESETS, with_task
from agents.trainer import train
from envs.tasks import ACTORS, get_task
from popbench import objective
from popbench.consensus.reconcile import reconcile
from popbench.errors import ValueRangeError

SMALL = {"robots": 3, "poses_per_robot": 12}


def consensus_f(core, element: int) -> float:
    problem = core.problems[element]
    return float(
        objective.objective(problem.graph, reconcile(problem, core.local_poses(element)).poses)
    )


def zero_delta_episode(team_reward: str, seed: int = 3):
    """One episode of 2 problems: every robot takes its lowest unprocessed edge with δ = 0 (the
    Gauss–Newton base step alone, which lowers F). Returns (rewards [T, B, n], F_c start, end)."""
    env = envs.make_torchrl_env(
        task="team", batch_size=2, seed=seed, team_reward=team_reward, **SMALL
    )
    tensordict = env.reset()
    start = [consensus_f(env.core, element) for element in range(2)]
    rewards = []
    while True:
        mask = tensordict["agents", "action_mask"]
        edge = mask.to(torch.int8).argmax(-1)
        action = TensorDict({"edge": edge, "delta": torch.zeros(*edge.shape, 3)}, edge.shape)
        tensordict["agents", "action"] = action
        tensordict = env.step(tensordict)
        rewards.append(tensordict["next", "agents", "reward"].squeeze(-1))
        if bool(tensordict["next", "done"].all()):
            break
        tensordict = step_mdp(tensordict)
    end = [consensus_f(env.core, element) for element in range(2)]
    return torch.stack(rewards), start, end, env


def test_the_team_task_is_the_actors_task_with_the_team_reward() -> None:
    team = get_task("team")
    assert team.modes.team_reward == "consensus"
    modes = team.modes.replace(team_reward="none")
    assert (
        dataclasses.replace(team, name=ACTORS.name, summary=ACTORS.summary, modes=modes) == ACTORS
    )
    env = envs.make_torchrl_env(task="team", batch_size=2, **SMALL)
    check_env_specs(env)
    with pytest.raises(ValueRangeError, match="team_reward"):
        envs.make_torchrl_env(task="team", batch_size=1, team_reward="shared", **SMALL)


def test_each_robot_gets_the_consensus_drop_at_the_end_and_nothing_before() -> None:
    rewards, start, end, _ = zero_delta_episode("consensus")  # [T, B, n]
    for element in range(2):  # each element is paid once, on the step its episode ends
        paid = rewards[:, element].abs().amax(-1) > 0
        assert int(paid.sum()) == 1
        expected = max(-1.0, 1.0 - end[element] / start[element])
        row = rewards[paid.nonzero()[0, 0], element]
        torch.testing.assert_close(row, torch.full_like(row, expected))
        assert end[element] < start[element]  # the base step lowers F after the consensus


def test_shaping_adds_the_local_rewards_of_the_actors_task() -> None:
    shaped, _, _, _ = zero_delta_episode("consensus+shaping")
    team, _, _, _ = zero_delta_episode("consensus")
    local, _, _, _ = zero_delta_episode("none")
    torch.testing.assert_close(shaped, team + local)
    assert float(local[:-1].abs().max()) > 0


def test_the_pettingzoo_env_pays_the_same_team_reward() -> None:
    env = envs.make_pettingzoo_env(task="team", seed=5, **SMALL)
    _, infos = env.reset(seed=5)
    start = consensus_f(env.core, 0)
    totals = dict.fromkeys(env.agents, 0.0)
    while env.agents:
        actions = {}
        for agent in env.agents:
            mask = infos[agent]["action_mask"]["edge"]
            actions[agent] = {"edge": int(mask.argmax()), "delta": [0.0, 0.0, 0.0]}
        _, rewards, _, _, infos = env.step(actions)
        for agent, reward in rewards.items():
            totals[agent] += float(reward)
    expected = max(-1.0, 1.0 - consensus_f(env.core, 0) / start)
    for total in totals.values():
        assert total == pytest.approx(expected, rel=1e-5)


def tiny_team_run(out_dir, frames: int, frames_per_batch: int, minibatch_size: int):
    """MAPPO on the team task from scratch at 3 robots × 12 poses, 2 envs, one epoch."""
    config = with_task(PRESETS["cpu-mappo"], get_task("team"))
    return dataclasses.replace(
        config,
        experiment=dataclasses.replace(
            config.experiment,
            robots=3,
            poses_per_robot=12,
            num_envs=2,
            frames=frames,
            frames_per_batch=frames_per_batch,
            eval_interval=10_000,
            checkpoint_interval=10_000,
            progress=False,
            out_dir=str(out_dir),
        ),
        imitation=dataclasses.replace(config.imitation, episodes=0),
        ppo=dataclasses.replace(config.ppo, minibatch_size=minibatch_size, epochs=1),
    )


def test_a_team_run_trains_and_is_labelled_by_its_reward(tmp_path) -> None:
    config = tiny_team_run(tmp_path, frames=32, frames_per_batch=16, minibatch_size=8)
    assert config.task.team_reward == "consensus"
    result = train(config)
    assert result.frames == 32 and result.updates > 0
    identity = snapshot_identity(tmp_path / "checkpoint.pt")
    assert identity["algorithm"] == "mappo-team"


def test_a_team_run_keeps_the_terminal_rewards_own_scale(tmp_path) -> None:
    """The team task's terminal reward (a share of F in [−1, 1]) declares c = 1; a batch of
    zeros or one small terminal reward must not set it (1 / std of zeros was 10⁶ and the
    critic's targets 10⁶ × the returns; one small terminal reward gave c = 102)."""
    import csv

    from agents.reward_scale import SCALE_UNSET, reward_scale, run_scale
    from envs.modes import TRAJECTORY_MODES

    assert reward_scale(torch.zeros(4, 3, 1)) == SCALE_UNSET
    assert reward_scale(torch.tensor([0.0, 0.0, 0.5, 0.0])) == pytest.approx(4.0)
    one_small = torch.tensor([0.0, 0.0, 0.01, 0.0])  # c = 200 under the std rule
    assert run_scale(TRAJECTORY_MODES, one_small) == reward_scale(one_small)  # per-step rewards
    shaped = TRAJECTORY_MODES.replace(team_reward="consensus+shaping")
    assert run_scale(shaped, one_small) == reward_scale(one_small)
    assert run_scale(TRAJECTORY_MODES.replace(team_reward="consensus"), one_small) == 1.0
    config = tiny_team_run(tmp_path, frames=64, frames_per_batch=8, minibatch_size=4)
    train(config)
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [float(row["reward_scale"]) for row in rows] == [1.0] * len(rows)
    assert all(float(row["loss_critic"]) < 1e4 for row in rows)  # 10⁸–10¹¹ before
