"""Rigid alignment of the robots' frames before the consensus (popbench.consensus.alignment)."""

from __future__ import annotations

import numpy as np
import pytest

from popbench import se2
from popbench.consensus.alignment import align_frames, frame_jacobians, inter_robot_graph, moved
from popbench.objective import linearise, objective
from popbench.problems.distributed import DistributedProblem
from popbench.problems.synthetic import make_problem
from popbench.solvers.chordal import chordal_initialisation
from popbench.solvers.lm import solve_graph


@pytest.fixture(scope="module")
def problem() -> DistributedProblem:
    return make_problem(robots=4, poses_per_robot=30, noise="V2", seed=5)


@pytest.fixture(scope="module")
def optimum(problem) -> np.ndarray:
    graph = problem.graph
    return solve_graph(graph, chordal_initialisation(graph), iterations=200).poses


def random_frames(problem: DistributedProblem, seed: int) -> np.ndarray:
    """A frame per robot (translations ~10 m, headings up to ±2 rad), the gauge robot's zero."""
    rng = np.random.default_rng(seed)
    frames = np.column_stack(
        [rng.normal(0, 10, (problem.num_robots, 2)), rng.uniform(-2, 2, problem.num_robots)]
    )
    frames[problem.graph.robots[0]] = 0.0
    return frames


def test_undoes_rigid_motions_of_the_optimal_maps(problem, optimum) -> None:
    """Every robot's copies of the optimum moved by its own random frame: the alignment puts
    them back (the optimum is also the least F over the robots' rigid motions)."""
    frames = random_frames(problem, seed=1)
    shuffled = [
        se2.compose(np.broadcast_to(frames[r], copies.shape), copies)
        for r, copies in enumerate(problem.split(optimum))
    ]
    assert objective(problem.graph, problem.assemble(shuffled)) > 100 * objective(
        problem.graph, optimum
    )
    outcome = align_frames(problem, shuffled)
    for aligned, expected in zip(outcome.local_poses, problem.split(optimum), strict=True):
        np.testing.assert_allclose(aligned[:, :2], expected[:, :2], atol=1e-5)
        np.testing.assert_allclose(se2.wrap(aligned[:, 2] - expected[:, 2]), 0.0, atol=1e-6)
    inverse = se2.inverse(frames)
    np.testing.assert_allclose(outcome.frames[:, :2], inverse[:, :2], atol=1e-5)
    assert outcome.inter_cost_after == pytest.approx(
        objective(inter_robot_graph(problem), optimum), rel=1e-8
    )


def test_lowers_only_the_inter_robot_edges(problem) -> None:
    """From perturbed copies: the assembled F never rises, it falls by exactly the inter-robot
    edges' cost change, and every intra-robot edge keeps its cost (rigid-motion invariance)."""
    rng = np.random.default_rng(2)
    copies = [c + rng.normal(0, [0.3, 0.3, 0.05], c.shape) for c in problem.split()]
    outcome = align_frames(problem, copies)
    graph = problem.graph
    before, after = problem.assemble(copies), problem.assemble(outcome.local_poses)
    assert outcome.inter_cost_after < outcome.inter_cost_before
    drop = objective(graph, before) - objective(graph, after)
    assert drop == pytest.approx(outcome.inter_cost_before - outcome.inter_cost_after, rel=1e-9)
    intra = graph.robots[graph.tails] == graph.robots[graph.heads]
    costs = [(linearise(graph, poses).errors[intra] ** 2).sum(1) for poses in (before, after)]
    np.testing.assert_allclose(costs[1], costs[0], rtol=1e-9, atol=1e-12)
    assert outcome.frames[graph.robots[0]] == pytest.approx(np.zeros(3))
    assert outcome.messages == problem.separators.size + problem.num_robots - 1


def test_frame_jacobians_match_central_differences(problem, optimum) -> None:
    frames = random_frames(problem, seed=3)
    inter = inter_robot_graph(problem)
    errors, jac_tail, jac_head = frame_jacobians(inter, optimum, frames)
    robots = problem.graph.robots
    tail_robot, head_robot = robots[inter.tails], robots[inter.heads]
    step = 1e-6
    for robot in range(problem.num_robots):
        for k in range(3):
            shift = np.zeros_like(frames)
            shift[robot, k] = step
            plus_ = linearise(inter, moved(frames + shift, optimum, robots)).errors
            minus_ = linearise(inter, moved(frames - shift, optimum, robots)).errors
            numeric = (plus_ - minus_) / (2 * step)
            analytic = np.where((tail_robot == robot)[:, None], jac_tail[:, :, k], 0.0)
            analytic += np.where((head_robot == robot)[:, None], jac_head[:, :, k], 0.0)
            np.testing.assert_allclose(analytic, numeric, atol=1e-5)
    assert errors.shape == (inter.num_edges, 3)


def test_single_robot_is_left_as_it_is() -> None:
    problem = make_problem(robots=1, poses_per_robot=20, noise="V2", seed=0)
    copies = problem.split()
    outcome = align_frames(problem, copies)
    np.testing.assert_array_equal(outcome.local_poses[0], copies[0])
    assert outcome.messages == 0 and outcome.iterations == 0
