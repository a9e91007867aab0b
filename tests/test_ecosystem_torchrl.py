"""TorchRL's own tools drive the PGO env with its default options: collectors with a random
policy, transforms, batched envs, an unbatched env, ``check_env_specs`` — in the paper's game
and in the actors' task. Every recorded transition is checked against the state it was drawn
in: the drawn edge was valid there (``("agents", "action_mask")`` of that state) and it is the
edge the env executed (the next state's processed flags are the old ones plus that edge)."""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector, RandomPolicy
from torchrl.envs import Compose, ParallelEnv, RewardSum, SerialEnv, StepCounter, TransformedEnv
from torchrl.envs.utils import check_env_specs

from agents.config import CPU_RESIDUAL
from envs import edge_mask_transform, make_torchrl_env
from envs.torchrl_env import ACTION_MASK_KEY, EDGE_ACTION_KEY
from popbench.errors import ValueRangeError

SMALL = {"robots": 3, "poses_per_robot": 12}
# The task the shipped algorithms train on (the cpu-residual preset and its MAPPO/IPPO twins).
ACTORS_TASK = {
    **CPU_RESIDUAL.task.core_options(),
    "reward": CPU_RESIDUAL.algorithm.reward,
    "terminal_bonus": CPU_RESIDUAL.algorithm.terminal_bonus,
}
TASKS = {"paper": {}, "actors": ACTORS_TASK}
FRAMES_PER_BATCH, BATCHES = 24, 3


def make(task: str, batch_size: int | tuple = 2, seed: int = 0):
    return make_torchrl_env(batch_size=batch_size, seed=seed, **SMALL, **TASKS[task])


def assert_drawn_valid_and_executed(data: TensorDictBase) -> int:
    """Every transition of ``data`` (any leading shape, then ``n``): the edge was in the mask of
    the state it was drawn in and the env executed it. Returns the number of agent-steps."""
    edge = data.get(EDGE_ACTION_KEY)
    mask = data.get(ACTION_MASK_KEY)
    assert mask.gather(-1, edge.unsqueeze(-1)).all(), "a drawn edge was not a valid choice"
    before = data.get(("agents", "observation", "processed"))
    after = data.get(("next", "agents", "observation", "processed"))
    e = before.shape[-1]
    chosen = torch.nn.functional.one_hot(edge, e + 1)[..., :e].bool()
    resets = data.get(("next", "done")).squeeze(-1)  # the next state is the episode's last
    assert torch.equal(after, before | chosen), "the env did not execute the drawn edge"
    assert not (before & chosen).any(), "a processed edge was drawn"
    assert resets.dtype == torch.bool
    return edge.numel()


def collect(env, policy=None) -> int:
    collector = Collector(
        env, policy, frames_per_batch=FRAMES_PER_BATCH, total_frames=FRAMES_PER_BATCH * BATCHES
    )
    steps = batches = 0
    for batch in collector:
        steps += assert_drawn_valid_and_executed(batch)
        batches += 1
    collector.shutdown()
    assert batches == BATCHES
    return steps


@pytest.mark.parametrize("task", sorted(TASKS))
def test_collector_with_default_random_policy_through_transforms(task: str) -> None:
    env = TransformedEnv(make(task), Compose(RewardSum(), StepCounter()))
    check_env_specs(env)
    steps = collect(env)  # Collector(env, None): RandomPolicy over a clone of the spec
    assert steps == FRAMES_PER_BATCH * BATCHES * SMALL["robots"]
    data = env.rollout(40, break_when_any_done=False)
    assert_drawn_valid_and_executed(data)
    assert (data["next", "step_count"] > 0).all()


def test_collector_with_an_explicit_random_policy() -> None:
    env = make("paper")
    policy = RandomPolicy(env.full_action_spec)  # a copy made before the first reset
    collect(env, policy)


@pytest.mark.parametrize("task", sorted(TASKS))
def test_parallel_env_with_the_edge_mask_transform(task: str) -> None:
    """A batched env's spec is a copy made from a throw-away instance: TorchRL's ``ActionMask``
    over it (``edge_mask_transform``) feeds it the workers' masks."""
    factory = functools.partial(make, task)
    env = TransformedEnv(
        ParallelEnv(2, factory, mp_start_method="spawn"),
        Compose(edge_mask_transform(), RewardSum(), StepCounter()),
    )
    assert_drawn_valid_and_executed(env.rollout(30, break_when_any_done=False))
    collect(env)  # the collector closes the env when it shuts down


def test_serial_env_with_the_edge_mask_transform() -> None:
    env = TransformedEnv(SerialEnv(2, functools.partial(make, "actors")), edge_mask_transform())
    check_env_specs(env)
    assert_drawn_valid_and_executed(env.rollout(30, break_when_any_done=False))


def test_invalid_edge_raises_by_default_and_repair_is_reported() -> None:
    env = make("paper")
    td = env.reset()
    td[EDGE_ACTION_KEY] = (~td[ACTION_MASK_KEY]).to(torch.int8).argmax(-1)  # padding edges
    td["agents", "action", "delta"] = torch.zeros(2, 3, 3)
    with pytest.raises(ValueRangeError, match="invalid edge action"):
        env.step(td.clone())
    assert "repaired" not in env.observation_spec["agents"].keys()
    repairing = make_torchrl_env(batch_size=2, seed=0, invalid_edge="repair", **SMALL)
    state = repairing.reset()
    state[EDGE_ACTION_KEY] = td[EDGE_ACTION_KEY]
    state["agents", "action", "delta"] = td["agents", "action", "delta"]
    out = repairing.step(state)
    assert out["next", "agents", "repaired"].all()
    check_env_specs(repairing)


def test_unbatched_env_and_group_map() -> None:
    env = make("actors", batch_size=())
    assert env.batch_size == torch.Size([])
    assert env.group_map == {"agents": ["agent_0", "agent_1", "agent_2"]}
    check_env_specs(env)
    data = env.rollout(200)
    assert data.batch_size[1:] == torch.Size([])  # (T,): no batch dimension
    assert data["next", "agents", "reward"].shape[1:] == (3, 1)
    assert_drawn_valid_and_executed(data)
    assert data["next", "done"][-1].all()
