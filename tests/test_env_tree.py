"""The subtree correction mode, its spanning tree and separator placement, the invariant and
whitened observations, the expert and the Gauss–Newton sweep (docs/environment.md)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from envs import make_pettingzoo_env, make_torchrl_env
from envs.core import PGOCore
from envs.expert import Expert, local_optima
from envs.observation import Dimensions
from envs.sweep import GaussNewtonSweep
from envs.tree import place_separators, spanning_tree
from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind
from popbench.outliers import with_outliers
from popbench.problems.synthetic import make_problem
from popbench.solvers.lm import solve_graph

SMALL = {"robots": 3, "poses_per_robot": 16}
MODES = [
    {"correction": "subtree"},
    {"correction": "subtree", "observation": "invariant", "action_scale": "whitened"},
    {"correction": "pose", "observation": "invariant", "action_scale": "whitened"},
]


def make_core(problems, **modes) -> PGOCore:
    core = PGOCore(problems[0].num_robots, Dimensions.of(problems), len(problems), **modes)
    core.load(problems, range(len(problems)))
    return core


def relative_poses(core: PGOCore, element: int, agent: int, edges: np.ndarray) -> np.ndarray:
    poses = core.state.poses[element, agent].numpy()
    tails = core.state.tails[element, agent].numpy()[edges]
    heads = core.state.heads[element, agent].numpy()[edges]
    return se2.between(poses[tails], poses[heads])


def test_spanning_tree_is_odometry_first_and_ranges_are_subtrees() -> None:
    problem = make_problem(seed=4, **SMALL)
    for local in problem.local_graphs:
        graph = local.graph
        tree = spanning_tree(graph)
        n = graph.num_poses
        assert tree.parent[0] == -1 and tree.order[0] == 0 and tree.end[0] == n
        assert tree.tree_edge.sum() == n - 1  # connected local graph
        odometry = np.isin(graph.kinds, [EdgeKind.ODOMETRY, EdgeKind.INTER_RELATIVE])
        assert tree.tree_edge[odometry].all()  # chains have no cycle: every one is in the tree
        for vertex in range(n):  # the pre-order range of a vertex is exactly its descendants
            members = set(tree.order[tree.position[vertex] : tree.end[vertex]].tolist())
            descendants = {vertex}
            for other in range(n):
                walk = other
                while walk != -1:
                    if walk == vertex:
                        descendants.add(other)
                    walk = tree.parent[walk]
            assert members == descendants
        edges = np.flatnonzero(tree.tree_edge)
        movers = tree.mover[edges]
        assert np.all(
            tree.parent[movers]
            == np.where(movers == graph.heads[edges], graph.tails[edges], graph.heads[edges])
        )


def test_placement_puts_each_copy_on_a_measurement() -> None:
    problem = make_problem(seed=5, **SMALL)
    placed = place_separators(problem)
    for local, poses, start in zip(problem.local_graphs, placed, problem.split(), strict=True):
        graph, owned = local.graph, local.owned_count
        np.testing.assert_array_equal(poses[:owned], start[:owned])
        r = objective.residuals(graph, poses)
        for copy in range(owned, local.num_vertices):
            incident = np.flatnonzero((graph.tails == copy) | (graph.heads == copy))
            assert np.min(np.abs(r[incident]).max(axis=1)) < 1e-12  # one edge is exact
            kinds = graph.kinds[incident]
            exact = incident[np.abs(r[incident]).max(axis=1) < 1e-12]
            if np.any(kinds == EdgeKind.INTER_RELATIVE):
                assert EdgeKind.INTER_RELATIVE in graph.kinds[exact]  # odometry preferred


@pytest.mark.parametrize("reward", ["localisation", "F"])
def test_subtree_move_changes_one_tree_edge_and_state_stays_exact(reward: str) -> None:
    problems = [make_problem(seed=seed, **SMALL) for seed in range(2)]
    core = make_core(problems, correction="subtree", reward=reward)
    generator = torch.Generator().manual_seed(0)
    for _ in range(15):
        mask = core.action_mask().flatten(0, 1).to(torch.float64)
        edge = torch.multinomial(mask, 1, generator=generator).view(2, 3)
        delta = (torch.rand(2, 3, 3, generator=generator, dtype=torch.float64) - 0.5) * 0.4
        before = core.state.poses.clone()
        core.step(edge, delta)
        for element in range(2):
            for agent in range(3):
                chosen = int(edge[element, agent])
                if chosen == core.dims.edges:
                    continue
                tree = np.flatnonzero(core.state.tree_edge[element, agent].numpy())
                after = relative_poses(core, element, agent, tree)
                core.state.poses, moved = before, core.state.poses
                old = relative_poses(core, element, agent, tree)
                change = relative_poses(core, element, agent, np.array([chosen]))
                core.state.poses = moved
                change = relative_poses(core, element, agent, np.array([chosen])) - change
                change[:, 2] = se2.wrap(change[:, 2])
                np.testing.assert_allclose(change[0], delta[element, agent].numpy(), atol=1e-9)
                others = tree != chosen
                if chosen not in tree:  # a loop closure moves its mover's subtree: the mover's
                    mover = int(core.state.mover[element, agent, chosen])  # parent edge
                    parent_edge = spanning_tree(
                        problems[element].local_graph(agent).graph
                    ).parent_edge[mover]
                    others &= tree != parent_edge
                np.testing.assert_allclose(after[others], old[others], atol=1e-9)
    from test_envs import reference_losses

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
                atol=1e-9,
            )


def test_invariant_observation_changes_only_at_the_moved_subtree_boundary() -> None:
    problem = make_problem(seed=6, **SMALL)
    core = make_core([problem], correction="subtree", observation="invariant")
    before = core.observation()
    agent, local = 1, problem.local_graph(1)
    tree = spanning_tree(local.graph)
    edge = int(np.flatnonzero(tree.tree_edge & (local.graph.kinds == EdgeKind.ODOMETRY))[3])
    edges = torch.full((1, 3), core.dims.edges)
    edges[0, agent] = edge
    for other in (0, 2):  # the other agents process an edge with a zero correction
        edges[0, other] = 0
    delta = torch.zeros(1, 3, 3, dtype=torch.float64)
    delta[0, agent] = torch.tensor([0.2, -0.1, 0.15])
    core = make_core(
        [problem], correction="subtree", observation="invariant", invalid_edge="repair"
    )
    core.step(edges, delta)
    after = core.observation()
    mover = int(tree.mover[edge])
    inside = np.zeros(core.dims.vertices, bool)
    inside[tree.order[tree.position[mover] : tree.end[mover]]] = True
    features = (after["node_features"] - before["node_features"])[0, agent].abs().sum(-1)
    assert set(np.flatnonzero(features.numpy() > 1e-6)) == {mover}
    m = local.graph.num_edges
    crossing = inside[local.graph.tails] != inside[local.graph.heads]
    changed = (after["residuals"] - before["residuals"])[0, agent, :m].abs().sum(-1) > 1e-6
    assert np.all(~changed.numpy()[~crossing])  # interior and exterior edges: unchanged
    assert changed[edge]


def test_whitened_action_and_residuals() -> None:
    problem = make_problem(seed=7, **SMALL)
    metric = make_core([problem], correction="subtree")
    whitened = make_core([problem], correction="subtree", action_scale="whitened")
    root = whitened.state.sqrt_information[0, :, 0]  # edge 0 of every agent
    information = whitened.state.sqrt_information[0, 0, 0] @ root[0]
    np.testing.assert_allclose(
        information.numpy(), problem.local_graph(0).graph.information[0], rtol=1e-9
    )
    delta = torch.tensor([[[0.05, -0.03, 0.02]] * 3], dtype=torch.float64)
    white_delta = (root @ delta[0].unsqueeze(-1)).squeeze(-1).unsqueeze(0)
    metric.step(torch.zeros(1, 3, dtype=torch.int64), delta)
    whitened.step(torch.zeros(1, 3, dtype=torch.int64), white_delta)
    torch.testing.assert_close(whitened.state.poses, metric.state.poses)
    r = metric.observation()["residuals"].to(torch.float64)
    expected = (whitened.state.sqrt_information[..., :-1, :, :] @ r.unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(
        whitened.observation()["residuals"].to(torch.float64), expected, rtol=1e-5, atol=1e-5
    )


def run_episode(core: PGOCore, policy) -> None:
    for _ in range(int(core.state.num_edges.max())):
        core.step(*policy.act())


def test_expert_reaches_the_local_optimum_in_one_episode() -> None:
    """Subtree mode, measurement reward: after the expert's episode each agent's local F equals
    its LM optimum's (relative gap ≤ 1e-6) on every agent none of whose corrections was clipped."""
    problems = [make_problem(seed=seed, robots=3, poses_per_robot=20) for seed in (10, 11)]
    core = make_core(problems, correction="subtree", reward="F")
    expert = Expert(core)
    clipped = torch.zeros(2, 3, dtype=torch.bool)
    for _ in range(int(core.state.num_edges.max())):
        edge, delta = expert.act()
        clipped |= (delta.abs() > core.delta_max).any(-1)
        core.step(edge, delta)
    checked = 0
    for element, problem in enumerate(problems):
        optima = local_optima(problem, place_separators(problem))
        for agent, local in enumerate(problem.local_graphs):
            if clipped[element, agent]:
                continue
            best = objective.objective(local.graph, optima[agent])
            reached = float(core.state.loss[element, agent])
            assert abs(reached - best) <= 1e-6 * best + 1e-12  # a tree-like graph has F* = 0
            checked += best > 1.0

    assert checked >= 4


def test_expert_labels_any_state_and_skips_outliers() -> None:
    problem = make_problem(seed=12, robots=3, poses_per_robot=30)
    problem = with_outliers(problem, 0.3, seed=0)
    core = make_core([problem], correction="subtree", reward="F", invalid_edge="repair")
    expert = Expert(core)
    generator = torch.Generator().manual_seed(0)
    for _ in range(4):  # some other policy's steps first
        mask = core.action_mask().flatten(0, 1).to(torch.float64)
        core.step(
            torch.multinomial(mask, 1, generator=generator).view(1, 3),
            torch.rand(1, 3, 3, generator=generator, dtype=torch.float64) * 0.1,
        )
    edge = expert.edge()
    tree_left = core.state.tree_edge[0, :, :-1] & core.action_mask()[0, :, :-1]
    for agent in range(3):
        if tree_left[agent].any():
            assert bool(core.state.tree_edge[0, agent, edge[0, agent]])
    off_tree = ~core.state.tree_edge[0, :, :-1] & core.state.edge_mask[0]
    noop = torch.full((3,), core.dims.edges)
    non_tree = torch.where(off_tree.any(-1), off_tree.to(torch.int8).argmax(-1), noop)[None]
    assert torch.equal(expert.delta(non_tree), torch.zeros(1, 3, 3, dtype=torch.float64))
    counts = [int(problem.outlier_mask[local.edge_ids].sum()) for local in problem.local_graphs]
    agent = int(np.argmax(counts))
    assert counts[agent] > 0
    local = problem.local_graph(agent)
    kept = ~problem.outlier_mask[local.edge_ids]
    optimum = expert.optimum()[0, agent, : local.num_vertices].numpy()
    graph = local.graph
    clean = graph.edge_subset(kept)
    start = place_separators(problem)[agent]
    with_outliers_optimum = solve_graph(graph, start, 200).poses
    clean_optimum = solve_graph(clean, start, 200).poses
    reached = objective.objective(clean, optimum)
    assert reached < objective.objective(clean, with_outliers_optimum)
    assert abs(reached - objective.objective(clean, clean_optimum)) <= 1e-6 * reached


def test_gauss_newton_sweep_lowers_local_F() -> None:
    problems = [make_problem(seed=seed, **SMALL) for seed in (13, 14)]
    for correction in ("subtree", "pose"):
        core = make_core(problems, correction=correction, reward="F", place_separators=True)
        start = core.state.loss.sum(-1).clone()
        run_episode(core, GaussNewtonSweep(core))
        assert bool((core.state.loss.sum(-1) < 0.8 * start).all())


def test_gauss_newton_base_adds_one_sweep_step_to_the_action() -> None:
    """base="gauss-newton": a zero action executes the sweep's Δ (the same episode as the sweep
    policy in a plain core); the expert's residual on top of it executes the expert's Δ."""
    problems = [make_problem(seed=seed, **SMALL) for seed in (15, 16)]
    modes = {"correction": "subtree", "action_scale": "whitened", "reward": "F"}
    plain, based = make_core(problems, **modes), make_core(problems, **modes, base="gauss-newton")
    sweep = GaussNewtonSweep(plain)
    for _ in range(int(plain.state.num_edges.max())):
        edge, delta = sweep.act()
        plain.step(edge, delta)
        based.step(edge, torch.zeros_like(delta))
    assert torch.allclose(plain.state.poses, based.state.poses, atol=1e-12)
    expert_core = make_core(problems, **modes)
    residual_core = make_core(problems, **modes, base="gauss-newton")
    expert, residual_expert = Expert(expert_core), Expert(residual_core)
    for _ in range(int(expert_core.state.num_edges.max())):
        edge, delta = expert.act()
        expert_core.step(edge, delta)
        residual = residual_expert.delta(edge) - residual_core.base_step(edge)
        residual_core.step(edge, residual)
    assert torch.allclose(expert_core.state.poses, residual_core.state.poses, atol=1e-9)
    with pytest.raises(ValueRangeError, match="gauss-newton"):
        make_core(problems, base="newton")


@pytest.mark.parametrize("modes", MODES)
def test_conformance_in_every_mode(modes: dict) -> None:
    from pettingzoo.test import parallel_api_test
    from torchrl.envs.utils import check_env_specs

    env = make_torchrl_env(batch_size=2, seed=0, **SMALL, **modes)
    check_env_specs(env)
    td = env.rollout(40, break_when_any_done=False)
    assert torch.isfinite(td["next", "agents", "reward"]).all()
    pettingzoo_env = make_pettingzoo_env(seed=0, invalid_edge="repair", **SMALL, **modes)
    parallel_api_test(pettingzoo_env, num_cycles=100)  # it samples without a mask: repaired


@pytest.mark.parametrize("correction", ["subtree", "pose"])
def test_moved_rows_equal_a_rigid_motion_of_the_walked_subtree(correction: str) -> None:
    """The step moves only the mover's subtree (found here by walking parent pointers, not by
    pre-order ranges), by one rigid motion that changes the chosen edge's relative pose by Δ:
    every moved pose equals that motion applied to its old pose (numpy SE(2)) to 1e-9
    relative, every other pose is bitwise unchanged."""
    problems = [make_problem(seed=seed, **SMALL) for seed in range(2)]
    core = make_core(problems, correction=correction, reward="F")
    generator = torch.Generator().manual_seed(3)
    for _ in range(12):
        mask = core.action_mask().flatten(0, 1).to(torch.float64)
        edge = torch.multinomial(mask, 1, generator=generator).view(2, 3)
        delta = (torch.rand(2, 3, 3, generator=generator, dtype=torch.float64) - 0.5) * 0.4
        before = core.state.poses.clone().numpy()
        core.step(edge, delta)
        after = core.state.poses.numpy()
        for element in range(2):
            for agent in range(3):
                chosen = int(edge[element, agent])
                old, new = before[element, agent], after[element, agent]
                if chosen == core.dims.edges:  # the no-op moves nothing real
                    np.testing.assert_array_equal(new[:-1], old[:-1])
                    continue
                t = core.state
                tail = int(t.tails[element, agent, chosen])
                head = int(t.heads[element, agent, chosen])
                if correction == "pose":
                    mover, parent = head, None
                else:
                    mover = int(t.mover[element, agent, chosen])
                    parent = t.tree_parent[element, agent].numpy()
                count = problems[element].local_graphs[agent].num_vertices
                if parent is None:
                    subtree = np.arange(count) == mover
                else:  # v is inside iff walking up from v reaches the mover
                    subtree = np.zeros(count, bool)
                    for vertex in range(count):
                        walk = vertex
                        while walk != mover and parent[walk] != walk:
                            walk = parent[walk]
                        subtree[vertex] = walk == mover
                motion = se2.compose(new[mover], se2.inverse(old[mover]))
                np.testing.assert_allclose(
                    new[:count][subtree], se2.compose(motion, old[:count][subtree]), atol=1e-9
                )
                np.testing.assert_array_equal(new[:count][~subtree], old[:count][~subtree])
                relative = se2.between(new[tail], new[head]) - se2.between(old[tail], old[head])
                relative[2] = se2.wrap(relative[2])
                metric = core.metric_delta(
                    torch.tensor([[chosen]]), delta[element, agent].view(1, 1, 3)
                )
                np.testing.assert_allclose(relative, metric.view(3).numpy(), atol=1e-9)
