"""The PettingZoo env in every mode: its spaces hold what it returns, PettingZoo's and TorchRL's
tools run on it, the action mask of its infos draws only valid edges, the global state lies in
``state_space`` and ``render()`` gives an RGB picture."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from envs import make_problem_source
from envs.modes import ACTION_SCALES, BASES, CORRECTIONS, OBSERVATIONS
from envs.pettingzoo_env import PGOParallelEnv
from popbench.errors import ValueRangeError

ROBOTS = 3
MODES = [
    dict(zip(("correction", "observation", "action_scale", "base"), values, strict=True))
    for values in itertools.product(CORRECTIONS, OBSERVATIONS, ACTION_SCALES, BASES)
]


def mode_id(modes: dict) -> str:
    return "-".join(modes.values())


@pytest.fixture(scope="module")
def source():
    problems, dims, _ = make_problem_source(ROBOTS, poses_per_robot=12)
    return problems, dims


def make(source, **options) -> PGOParallelEnv:
    problems, dims = source
    return PGOParallelEnv(problems, ROBOTS, dims, **options)


def masked_actions(env: PGOParallelEnv, infos: dict) -> dict:
    return {
        agent: env.action_space(agent).sample(mask=infos[agent]["action_mask"])
        for agent in env.agents
    }


@pytest.mark.parametrize("modes", MODES, ids=mode_id)
def test_spaces_hold_every_observation_and_the_state(source, modes: dict) -> None:
    env = make(source, **modes)
    observations, infos = env.reset(seed=1)
    for _ in range(6):
        for agent in env.possible_agents:
            assert env.observation_space(agent).contains(observations[agent]), agent
        assert env.state_space.contains(env.state())
        mask = infos["agent_0"]["action_mask"]["edge"]
        assert mask.shape == (env.dims.edges + 1,) and mask.dtype == np.int8
        observations, _, _, _, infos = env.step(masked_actions(env, infos))
    assert set(observations["agent_0"]) == set(env.observation_space("agent_0").spaces)


@pytest.mark.parametrize("modes", MODES, ids=mode_id)
def test_torchrl_wrapper_check_env_specs(source, modes: dict) -> None:
    from torchrl.envs import PettingZooWrapper
    from torchrl.envs.utils import check_env_specs

    # the wrapper reads an action_mask only for a Discrete action (docs/environment.md)
    env = make(source, action_mask=False, invalid_edge="repair", **modes)
    wrapped = PettingZooWrapper(env=env, return_state=True)
    check_env_specs(wrapped)
    data = wrapped.rollout(4)
    assert data["next", "state", "processed"].shape == (4, ROBOTS, env.dims.edges)


def test_masked_samples_play_a_whole_episode_unchanged(source) -> None:
    """Default options: sampling with the infos' mask never draws an invalid edge (an invalid
    one would raise), and the env executes exactly the drawn edge."""
    env = make(source, correction="subtree", base="gauss-newton")
    _, infos = env.reset(seed=4)
    steps = 0
    while env.agents:
        before = env.core.state.processed[0].clone()
        actions = masked_actions(env, infos)
        _, _, _, _, infos = env.step(actions)
        after = env.core.state.processed[0]
        for index, agent in enumerate(env.possible_agents):
            edge = int(actions[agent]["edge"])
            assert not before[index, edge] or edge == env.dims.edges
            assert after[index, edge]
        assert int((after & ~before).sum()) <= ROBOTS
        steps += 1
    assert steps == env.core.horizon


def test_pettingzoo_api_tests(source) -> None:
    from pettingzoo.test import api_test, parallel_api_test, parallel_seed_test
    from pettingzoo.utils import parallel_to_aec

    api_test(parallel_to_aec(make(source)), num_cycles=60)  # samples with the infos' mask
    # parallel_api_test samples a Dict action without a mask: it needs the repair option
    parallel_api_test(make(source, invalid_edge="repair"), num_cycles=60)
    parallel_seed_test(lambda: make(source, invalid_edge="repair"), num_cycles=20)


def test_invalid_edge_raises_by_default(source) -> None:
    env = make(source)
    env.reset(seed=0)
    actions = {agent: {"edge": env.dims.edges, "delta": np.zeros(3)} for agent in env.agents}
    with pytest.raises(ValueRangeError, match="invalid edge action"):
        env.step(actions)  # the no-op while edges remain
    repairing = make(source, invalid_edge="repair")
    repairing.reset(seed=0)
    *_, infos = repairing.step(actions)
    assert all(infos[agent]["repaired"] == 1 for agent in repairing.possible_agents)


def test_render_draws_one_colour_per_robot(source) -> None:
    env = make(source, render_mode="rgb_array")
    _, infos = env.reset(seed=2)
    env.step(masked_actions(env, infos))
    image = env.render()
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    colours = {tuple(int(c) for c in pixel) for pixel in image.reshape(-1, 3)[::7]}
    # matplotlib's first three cycle colours (C0, C1, C2) are all present
    for hex_colour in ("#1f77b4", "#ff7f0e", "#2ca02c"):
        rgb = tuple(int(hex_colour[i : i + 2], 16) for i in (1, 3, 5))
        assert any(np.abs(np.subtract(c, rgb)).max() <= 2 for c in colours), hex_colour
    assert make(source).render() is None
    with pytest.raises(ValueRangeError, match="render_mode"):
        make(source, render_mode="human")
