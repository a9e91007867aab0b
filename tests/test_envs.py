"""The multi-agent PGO environments: core dynamics against hand cases and popbench.objective, the
TorchRL spec/rollout contract, the PettingZoo API, seeding and the horizon."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from envs import make_pettingzoo_env, make_torchrl_env
from envs.core import EPSILON, PGOCore
from envs.observation import Dimensions, pack_problem
from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import make_graph
from popbench.problems.distributed import DistributedProblem
from popbench.problems.synthetic import make_problem

SMALL = {"robots": 3, "poses_per_robot": 16}


def hand_problem() -> DistributedProblem:
    """Six poses on two robots (0–2, 3–5): chain 0→…→5 and loops 0→2 and 1→4, with noise."""
    truth = np.array(
        [[0, 0, 0], [1, 0, 0.1], [2, 0.1, 0.3], [2.5, 1, 1.2], [2, 2, 2.0], [1, 2.2, 2.9]]
    )
    tails = np.array([0, 1, 2, 3, 4, 0, 1])
    heads = np.array([1, 2, 3, 4, 5, 2, 4])
    noise = np.random.default_rng(3).normal(0, 0.05, (tails.size, 3))
    z = se2.compose(se2.between(truth[tails], truth[heads]), noise)
    info = np.tile(np.diag([20.0, 30.0, 50.0]), (tails.size, 1, 1))
    graph = make_graph(np.zeros((6, 3)), tails, heads, z, info, ground_truth=truth, name="hand")
    graph = graph.replace(poses=graph.odometry_initial())
    return DistributedProblem.from_graph(graph, np.array([0, 0, 0, 1, 1, 1]))


def make_core(problems, reward="localisation", invalid_edge="raise") -> PGOCore:
    core = PGOCore(
        problems[0].num_robots,
        Dimensions.of(problems),
        len(problems),
        reward=reward,
        invalid_edge=invalid_edge,
    )
    core.load(problems, range(len(problems)))
    return core


def reference_losses(problem: DistributedProblem, local_poses, reward: str) -> np.ndarray:
    """L per agent from popbench.objective: F of the local graph, with ground-truth relative
    poses as measurements for the localisation reward."""
    losses = []
    for local, poses in zip(problem.local_graphs, local_poses, strict=True):
        graph = local.graph
        if reward == "localisation":
            truth = graph.ground_truth
            graph = graph.replace(measurements=se2.between(truth[graph.tails], truth[graph.heads]))
        losses.append(objective.objective(graph, poses))
    return np.array(losses)


def random_edges(mask: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """One valid edge per agent drawn uniformly from ``mask (B, n, E+1)``."""
    flat = mask.flatten(0, 1).to(torch.float64)
    return torch.multinomial(flat, 1, generator=generator).view(mask.shape[:2])


# ----- core dynamics ----------------------------------------------------------------------------


def test_torch_se2_matches_numpy(rng: np.random.Generator) -> None:
    from envs.geometry import between, compose, wrap

    angles = np.concatenate([rng.uniform(-20, 20, 200), [np.pi, -np.pi, 3 * np.pi, 0.0]])
    np.testing.assert_allclose(wrap(torch.tensor(angles)).numpy(), se2.wrap(angles), atol=1e-12)
    a, b = rng.normal(size=(50, 3)) * 3, rng.normal(size=(50, 3)) * 3
    ta, tb = torch.tensor(a), torch.tensor(b)
    np.testing.assert_allclose(between(ta, tb).numpy(), se2.between(a, b), atol=1e-12)
    np.testing.assert_allclose(compose(ta, tb).numpy(), se2.compose(a, b), atol=1e-12)


def test_correction_moves_head_in_tail_frame() -> None:
    problem = hand_problem()
    core = make_core([problem])
    local = problem.local_graph(0)
    edge = 0  # 0 → 1, both owned by robot 0: local ids 0 and 1
    assert (local.graph.tails[edge], local.graph.heads[edge]) == (0, 1)
    x_p, x_q = np.array([1.0, 2.0, np.pi / 2]), np.array([1.0, 3.0, np.pi / 2])
    core.state.poses[0, 0, 0] = torch.tensor(x_p)
    core.state.poses[0, 0, 1] = torch.tensor(x_q)
    delta = torch.zeros(1, 2, 3, dtype=torch.float64)
    delta[0, 0] = torch.tensor([0.1, 0.2, 0.05])
    edges = torch.tensor([[edge, 0]])
    core.step(edges, delta)
    # between(x_p, x_q) = (1, 0, 0); + Δ = (1.1, 0.2, 0.05); rotated by +90° about x_p:
    expected = np.array([1.0 - 0.2, 2.0 + 1.1, np.pi / 2 + 0.05])
    np.testing.assert_allclose(core.state.poses[0, 0, 1].numpy(), expected, atol=1e-12)
    np.testing.assert_allclose(core.state.poses[0, 0, 0].numpy(), x_p)  # tail unchanged
    # the other agent's copy of its own first pose moved by exactly its own zero correction
    np.testing.assert_allclose(
        core.state.poses[0, 1, 0].numpy(), problem.graph.poses[3], atol=1e-12
    )


def test_correction_is_clipped_and_wrapped() -> None:
    problem = hand_problem()
    core = make_core([problem])
    x_p = core.state.poses[0, 0, 0].clone()
    x_q = core.state.poses[0, 0, 1].clone()
    core.state.poses[0, 0, 1, 2] = torch.pi - 0.1 + x_p[2]
    before = se2.between(x_p.numpy(), core.state.poses[0, 0, 1].numpy())
    delta = torch.tensor([[[2.0, -2.0, 1.0], [0.0, 0.0, 0.0]]], dtype=torch.float64)
    core.step(torch.tensor([[0, 0]]), delta)
    after = se2.between(x_p.numpy(), core.state.poses[0, 0, 1].numpy())
    change = after - before
    change[2] = se2.wrap(change[2])
    np.testing.assert_allclose(change, [0.5, -0.5, 0.3], atol=1e-12)
    assert -np.pi <= core.state.poses[0, 0, 1, 2] < np.pi
    assert not torch.equal(x_q, core.state.poses[0, 0, 1])


@pytest.mark.parametrize("reward", ["localisation", "F"])
def test_incremental_state_matches_objective(reward: str) -> None:
    problems = [make_problem(seed=seed, **SMALL) for seed in range(2)]
    core = make_core(problems, reward)
    generator = torch.Generator().manual_seed(0)
    for _ in range(12):
        delta = (torch.rand(2, 3, 3, generator=generator, dtype=torch.float64) - 0.5) * 0.6
        core.step(random_edges(core.action_mask(), generator), delta)
    for element, problem in enumerate(problems):
        local_poses = core.local_poses(element)
        np.testing.assert_allclose(
            core.state.loss[element].numpy(),
            reference_losses(problem, local_poses, reward),
            rtol=1e-9,
        )
        for agent, local in enumerate(problem.local_graphs):
            m = local.graph.num_edges
            np.testing.assert_allclose(
                core.state.residuals[element, agent, :m].numpy(),
                objective.residuals(local.graph, local_poses[agent]),
                atol=1e-12,
            )


def test_reward_formula_hand_step() -> None:
    problem = hand_problem()
    core = make_core([problem])
    initial = reference_losses(problem, core.local_poses(0), "localisation")
    delta = torch.tensor([[[0.05, -0.1, 0.02], [-0.2, 0.1, -0.1]]], dtype=torch.float64)
    result = core.step(torch.tensor([[4, 2]]), delta)  # agent 0: loop 1→4; agent 1: 4→5
    after = reference_losses(problem, core.local_poses(0), "localisation")
    expected = np.tanh((initial - after) / (initial + EPSILON))
    np.testing.assert_allclose(result.reward[0].numpy(), expected, rtol=1e-9)
    assert not bool(result.done[0])


def test_terminal_bonus_and_horizon_on_hand_problem() -> None:
    problem = hand_problem()
    core = make_core([problem])
    counts = [local.graph.num_edges for local in problem.local_graphs]  # (5, 4): 1→4 is shared
    initial = reference_losses(problem, core.local_poses(0), "localisation")
    generator = torch.Generator().manual_seed(1)
    for step in range(1, max(counts) + 1):
        previous = reference_losses(problem, core.local_poses(0), "localisation")
        delta = torch.full((1, 2, 3), 0.01, dtype=torch.float64)
        result = core.step(random_edges(core.action_mask(), generator), delta)
        assert bool(result.done[0]) == (step == max(counts))
        np.testing.assert_array_equal(result.agent_done[0].numpy(), np.array(counts) <= step)
    final = reference_losses(problem, core.local_poses(0), "localisation")
    expected = np.tanh((previous - final) / (previous + EPSILON)) + np.log(
        (initial + EPSILON) / (final + EPSILON)
    )
    np.testing.assert_allclose(result.reward[0].numpy(), expected, rtol=1e-9)


def test_invalid_edge_raises_or_is_repaired() -> None:
    problem = hand_problem()
    core = make_core([problem])
    noop = core.dims.edges
    with pytest.raises(ValueRangeError, match="edge action"):
        core.step(torch.tensor([[noop, 0]]), torch.zeros(1, 2, 3))
    core = make_core([problem], invalid_edge="repair")
    core.step(torch.tensor([[0, 1]]), torch.zeros(1, 2, 3))
    result = core.step(torch.tensor([[0, noop]]), torch.zeros(1, 2, 3))  # both invalid
    assert result.repaired[0].tolist() == [True, True]
    processed = core.state.processed[0, :, :noop]
    assert processed[0, :2].all() and processed[1, [0, 1]].all()  # lowest unprocessed taken


def test_packing_rejects_oversized_problem_and_missing_truth() -> None:
    problem = hand_problem()
    small = Dimensions(vertices=3, edges=10, degree=10)
    with pytest.raises(ValueRangeError, match="max_vertices"):
        pack_problem(problem, small)
    without_truth = DistributedProblem(problem.graph.replace(ground_truth=None))
    with pytest.raises(ValueRangeError, match="no ground truth"):
        pack_problem(without_truth, Dimensions.of([without_truth]))
    assert pack_problem(without_truth, Dimensions.of([without_truth]), reward="F")


# ----- TorchRL ----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def torchrl_env():
    return make_torchrl_env(batch_size=4, seed=0, **SMALL)


def test_check_env_specs(torchrl_env) -> None:
    from torchrl.envs.utils import check_env_specs

    check_env_specs(torchrl_env)
    spec = torchrl_env.full_action_spec["agents", "action"]
    assert spec["edge"].shape == (4, 3) and spec["delta"].shape == (4, 3, 3)
    assert torchrl_env.full_reward_spec["agents", "reward"].shape == (4, 3, 1)
    assert torchrl_env.full_done_spec["done"].shape == (4, 1)
    assert torchrl_env.full_done_spec["agents", "done"].shape == (4, 3, 1)


def test_random_rollout_processes_every_edge_once(torchrl_env) -> None:
    from torchrl.envs.utils import step_mdp

    torch.manual_seed(0)
    td = torchrl_env.reset()
    core = torchrl_env.core
    edges = core.dims.edges
    horizon = core.state.num_edges.max(-1).values.tolist()
    counts = torch.zeros(4, 3, edges + 1, dtype=torch.int64)
    done_at = [None] * 4
    for step in range(1, max(horizon) + 1):
        td = torchrl_env.rand_step(td)
        counts.scatter_add_(
            2, td["agents", "action", "edge"].unsqueeze(-1), torch.ones(4, 3, 1, dtype=torch.int64)
        )
        for element, done in enumerate(td["next", "done"].flatten().tolist()):
            if done and done_at[element] is None:
                done_at[element] = step
        assert torch.equal(
            td["next", "agents", "done"].squeeze(-1).all(-1), td["next", "done"][:, 0]
        )
        td = step_mdp(td)
    assert done_at == horizon
    real = counts[..., :edges]
    assert torch.equal(real, core.state.edge_mask.to(torch.int64))  # once each, no padding
    noops = counts[..., edges]
    assert torch.equal(noops, max(horizon) - core.state.num_edges)  # no-op only when done


def test_seeding_makes_rollouts_identical() -> None:
    def rollout(seed: int):
        env = make_torchrl_env(batch_size=2, seed=0, **SMALL)
        env.set_seed(seed)
        torch.manual_seed(seed)
        return env.rollout(10, break_when_any_done=False)

    first, second, other = rollout(5), rollout(5), rollout(6)
    assert (first == second).all()
    assert not torch.equal(
        first["agents", "observation", "edge_attr"], other["agents", "observation", "edge_attr"]
    )


def test_partial_reset_restarts_only_flagged_elements(torchrl_env) -> None:
    td = torchrl_env.reset()
    td = torchrl_env.rand_step(td)
    before = torchrl_env.core.state.processed.clone()
    names = [problem.graph.name for problem in torchrl_env.core.problems]
    flags = torch.tensor([[False], [True], [False], [False]])
    out = torchrl_env.reset(td["next"].clone().set("_reset", flags))
    after = torchrl_env.core.state.processed
    assert torch.equal(after[[0, 2, 3]], before[[0, 2, 3]])
    assert not after[1, :, :-1].any()
    assert torchrl_env.core.problems[1].graph.name != names[1]
    assert not out["done"].any()


# ----- PettingZoo -------------------------------------------------------------------------------


def test_parallel_api_and_torchrl_wrapper() -> None:
    from pettingzoo.test import parallel_api_test
    from torchrl.envs import PettingZooWrapper

    # PettingZoo's parallel test samples the Dict action without a mask: the repair option
    env = make_pettingzoo_env(seed=0, invalid_edge="repair", **SMALL)
    parallel_api_test(env, num_cycles=200)
    observations, infos = env.reset(seed=1)
    assert sorted(observations) == ["agent_0", "agent_1", "agent_2"]
    assert env.observation_space("agent_0").contains(observations["agent_0"])
    assert infos["agent_0"]["action_mask"]["edge"].shape == (env.dims.edges + 1,)

    # the wrapper reads an action_mask only for a Discrete action (docs/environment.md)
    wrapped = PettingZooWrapper(
        env=make_pettingzoo_env(seed=0, invalid_edge="repair", action_mask=False, **SMALL)
    )
    td = wrapped.rollout(500)
    horizon = wrapped._env.core.state.num_edges.max().item()
    assert td.shape == (horizon,)
    assert td["next", "agent", "reward"].shape == (horizon, 3, 1)
    assert td["next", "done"][-1].all() and not td["next", "done"][:-1].any()


def test_pettingzoo_matches_torchrl_core() -> None:
    """Both envs run the same core: equal problems and actions give equal rewards."""
    pz = make_pettingzoo_env(seed=0, **SMALL)
    pz.reset(seed=3)
    core = make_core([pz.core.problems[0]])
    generator = torch.Generator().manual_seed(2)
    for _ in range(5):
        edges = random_edges(core.action_mask(), generator)
        delta = torch.rand(1, 3, 3, generator=generator) * 0.2
        expected = core.step(edges, delta.to(torch.float64)).reward[0].numpy()
        actions = {
            f"agent_{i}": {"edge": int(edges[0, i]), "delta": delta[0, i].numpy()} for i in range(3)
        }
        _, rewards, *_ = pz.step(actions)
        np.testing.assert_allclose([rewards[f"agent_{i}"] for i in range(3)], expected, rtol=1e-6)


@pytest.mark.dataset
def test_dataset_env_splits_the_graph() -> None:
    from conftest import require_dataset

    graph = require_dataset("intel")  # no ground truth: the reward falls back to F
    env = make_torchrl_env(robots=4, batch_size=1, dataset="intel")
    env.reset()
    problem = env.core.problems[0]
    assert env.core.reward_kind == "F"
    assert problem.graph.num_edges == graph.num_edges
    counts = env.core.state.num_edges[0]
    inter = problem.inter_robot_edges.size
    assert int(counts.sum()) == graph.num_edges + inter  # inter-robot edges held twice
    np.testing.assert_allclose(
        env.core.state.loss[0].numpy(),
        reference_losses(problem, env.core.local_poses(0), "F"),
        rtol=1e-9,
    )
