"""Information-weighted ADMM consensus over separator poses."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse
import scipy.sparse.linalg

from popbench.consensus import admm_consensus, minus
from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.objective import linearise, objective
from popbench.synthetic import make_problem


def gauss_newton(graph, poses: np.ndarray, iterations: int = 15) -> np.ndarray:
    """Reference centralised Gauss–Newton on F (pose 0 fixed), written independently of the
    consensus module: stacks the full sparse Jacobian and solves the normal equations."""
    m, n = graph.num_edges, graph.num_poses
    rows = np.repeat(np.arange(3 * m).reshape(m, 3, 1), 3, axis=2)
    cols_tail = np.broadcast_to((3 * graph.tails)[:, None, None] + np.arange(3), (m, 3, 3))
    cols_head = np.broadcast_to((3 * graph.heads)[:, None, None] + np.arange(3), (m, 3, 3))
    for _ in range(iterations):
        lin = linearise(graph, poses)
        jacobian = scipy.sparse.csr_matrix(
            (
                np.concatenate([lin.jac_tail.ravel(), lin.jac_head.ravel()]),
                (
                    np.concatenate([rows.ravel()] * 2),
                    np.concatenate([cols_tail.ravel(), cols_head.ravel()]),
                ),
            ),
            shape=(3 * m, 3 * n),
        )[:, 3:]
        step = scipy.sparse.linalg.spsolve(
            (jacobian.T @ jacobian).tocsc(), -(jacobian.T @ lin.errors.ravel())
        )
        poses = poses.copy()
        poses[1:] += step.reshape(n - 1, 3)
    return poses


@pytest.fixture(scope="module")
def problem_and_optimum():
    problem = make_problem(robots=3, poses_per_robot=30, noise="V2", seed=2)
    optimum = gauss_newton(problem.graph, problem.graph.ground_truth)
    return problem, optimum


def copy_disagreement(problem: DistributedProblem, outcome) -> float:
    """Largest ‖copy ⊖ global estimate‖_∞ over all local copies of all separators."""
    worst = 0.0
    for local, poses in zip(problem.local_graphs, outcome.local_poses, strict=True):
        shared = np.isin(local.global_ids, problem.separators)
        difference = minus(poses[shared], outcome.poses[local.global_ids[shared]])
        worst = max(worst, float(np.abs(difference).max(initial=0.0)))
    return worst


def test_reference_optimum_is_stationary(problem_and_optimum):
    problem, optimum = problem_and_optimum
    from popbench.objective import gradient

    assert np.abs(gradient(problem.graph, optimum)[1:]).max() < 1e-6
    assert objective(problem.graph, optimum) < objective(problem.graph, problem.graph.ground_truth)


def test_consensus_from_perturbed_local_solutions(problem_and_optimum):
    """Copies = optimum + N(0, 0.05²) noise, each copy perturbed independently. After ADMM:
    (1) the run reports convergence and every copy agrees with the global estimate to ``tol``;
    (2) F(after) ≤ F(assembled from owners before) — measured 226.7 → 40.59;
    (3) F(after) is within 0.5 % of the reference optimum F* = 40.54 (the local objectives
        count inter-robot edges at half information, so ADMM's fixed points are stationary
        points of F; with full information it would settle elsewhere);
    (4) the gauge (vertex 0, robot 0's copy) does not move."""
    problem, optimum = problem_and_optimum
    graph = problem.graph
    rng = np.random.default_rng(0)
    local_poses = [x + rng.normal(0.0, 0.05, x.shape) for x in problem.split(optimum)]
    tol = 1e-4
    outcome = admm_consensus(problem, local_poses, rho=3.0, iterations=300, tol=tol)
    assert outcome.converged and outcome.iterations < 300
    assert outcome.primal_residuals[-1] < tol <= outcome.primal_residuals[0]
    assert copy_disagreement(problem, outcome) < tol
    before = objective(graph, problem.assemble(local_poses))
    after = objective(graph, outcome.poses)
    optimum_cost = objective(graph, optimum)
    assert after <= before
    assert optimum_cost - 1e-9 <= after <= optimum_cost * 1.005
    np.testing.assert_allclose(outcome.poses[0], local_poses[0][0], atol=1e-12)
    # the inputs were not modified
    assert not np.allclose(local_poses[0], outcome.local_poses[0])


def test_messages_and_history(problem_and_optimum):
    problem, optimum = problem_and_optimum
    outcome = admm_consensus(problem, problem.split(optimum), iterations=4, tol=0.0)
    non_owner_copies = sum(local.separator_ids.size for local in problem.local_graphs)
    assert outcome.iterations == 4 and not outcome.converged
    assert outcome.messages == 2 * non_owner_copies * 4
    assert outcome.primal_residuals.shape == outcome.dual_residuals.shape == (4,)
    # u starts at 0, so even consistent optimal copies first move apart (each robot's half-weighted
    # local objective is not stationary there on its own), then the disagreement shrinks
    assert np.all(np.diff(outcome.primal_residuals) < 0)


def test_single_robot_problem_needs_no_consensus(small_graph):
    problem = DistributedProblem.single_robot(small_graph)
    outcome = admm_consensus(problem, problem.split())
    assert outcome.converged and outcome.iterations == 1 and outcome.messages == 0
    np.testing.assert_array_equal(outcome.poses, small_graph.poses)


def test_invalid_arguments(problem_and_optimum):
    problem, optimum = problem_and_optimum
    local_poses = problem.split(optimum)
    with pytest.raises(ValueRangeError):
        admm_consensus(problem, local_poses, rho=0.0)
    with pytest.raises(ValueRangeError, match="local_poses"):
        admm_consensus(problem, [x[:-1] for x in local_poses])


def test_team_system_is_block_diagonal_by_robot(problem_and_optimum):
    """The batched x-update system couples no two robots: every stored entry joins unknowns of
    one robot, each robot's unknowns are one contiguous range, and the gauge row is absent."""
    from popbench.consensus import _team, _TeamSystem

    problem, optimum = problem_and_optimum
    team = _team(problem, problem.split(optimum))
    system = _TeamSystem(team)
    columns = np.repeat(np.arange(system.size), np.diff(system.indptr))
    robot = system.dof_robot
    assert np.array_equal(robot[system.indices], robot[columns])
    assert np.all(np.diff(robot) >= 0)
    assert np.array_equal(system.bounds, np.searchsorted(robot, np.arange(problem.num_robots + 1)))
    assert system.size == 3 * (team.graph.num_poses - 1)
    assert team.fixed_row not in system.free_dof // 3
