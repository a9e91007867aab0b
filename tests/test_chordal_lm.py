"""Chordal initialisation and the sparse LM reference solver.

Independent references: noise-free graphs (the truth is the exact answer), SciPy's
``least_squares`` (a different trust-region solver on the same residuals), the objective's own
gradient, and the published optima (F of eq. 1 with κ/τ weights).
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_dataset
from scipy.optimize import least_squares

from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import make_graph
from popbench.methods import Budget, get_method
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.chordal import chordal_initialisation
from popbench.solvers.initial import with_start
from popbench.solvers.lm import reference_optimum, solve, solve_graph

# Independent reference values of F (recomputed beside SE-Sync, IJRR 2019, Table 1).
REFERENCE_F = {
    "intel": 205.0502,
    "mit": 40.2451,
    "csail": 20.5362,
    "grid1000_3": 1772.67,
    "m3500": 137.9130,  # measured 137.912951
    "city10k": 511.9852,  # measured 511.985164
}


def in_frame_of_pose_zero(poses: np.ndarray) -> np.ndarray:
    """``x_0⁻¹ ∘ x_i`` for every pose: the gauge our solvers use (pose 0 at the origin)."""
    return se2.between(poses[:1], poses)


def pose_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Largest coordinate difference, headings compared modulo 2π."""
    diff = a - b
    diff[:, 2] = se2.wrap(diff[:, 2])
    return float(np.max(np.abs(diff)))


def noise_free(graph):
    truth = graph.ground_truth
    return graph.replace(measurements=se2.between(truth[graph.tails], truth[graph.heads]))


def synthetic_graph(rng: np.random.Generator, num_poses: int = 120, noise: float = 0.03):
    """A noisy Manhattan-like random walk with loop closures between nearby poses, with
    anisotropic, correlated information (different per edge)."""
    turns = rng.choice([0.0, np.pi / 2, -np.pi / 2], size=num_poses - 1, p=[0.6, 0.2, 0.2])
    steps = np.column_stack([np.ones(num_poses - 1), np.zeros(num_poses - 1), turns])
    truth = np.zeros((num_poses, 3))
    for k, step in enumerate(steps):  # test data only: a short sequential composition
        truth[k + 1] = se2.compose(truth[k], step)
    near = np.linalg.norm(truth[:, None, :2] - truth[None, :, :2], axis=-1) < 1.5
    far_in_time = np.abs(np.arange(num_poses)[:, None] - np.arange(num_poses)) > 3
    loop_tails, loop_heads = np.nonzero(np.triu(near & far_in_time))
    tails = np.concatenate([np.arange(num_poses - 1), loop_tails])
    heads = np.concatenate([np.arange(1, num_poses), loop_heads])
    exact = se2.between(truth[tails], truth[heads])
    measurements = se2.compose(exact, rng.normal(0.0, noise, exact.shape))
    factors = rng.normal(0.0, 0.3, (tails.size, 3, 3)) + np.eye(3)
    information = np.einsum("mji,mjk->mik", factors, factors) / noise**2
    graph = make_graph(np.zeros_like(truth), tails, heads, measurements, information)
    return graph.replace(poses=graph.odometry_initial(), ground_truth=truth)


def assert_stationary(graph, poses: np.ndarray, relative: float = 1e-7) -> None:
    """``‖∇F‖_∞`` over the free poses small compared with the gradient's natural scale
    (``‖∇F‖`` at the start of the run is typically 1e3–1e6 times larger)."""
    gradient = objective.gradient(graph, poses)[1:]
    scale = np.max(np.abs(objective.gradient(graph, graph.poses)[1:]))
    assert np.max(np.abs(gradient)) <= relative * scale


def test_chordal_initialisation_is_exact_without_noise(small_graph, rng) -> None:
    graph = noise_free(synthetic_graph(rng))
    estimate = chordal_initialisation(graph)
    assert pose_difference(estimate, in_frame_of_pose_zero(graph.ground_truth)) < 1e-9
    loop = noise_free(small_graph)
    estimate = chordal_initialisation(loop)
    assert pose_difference(estimate, in_frame_of_pose_zero(loop.ground_truth)) < 1e-9


def test_chordal_initialisation_is_much_better_than_odometry(rng) -> None:
    graph = synthetic_graph(rng, noise=0.05)
    chordal = objective.objective(graph, chordal_initialisation(graph))
    assert chordal < 0.1 * objective.objective(graph)
    assert np.all(chordal_initialisation(graph)[0] == 0.0)


def test_lm_recovers_the_truth_without_noise(rng) -> None:
    graph = noise_free(synthetic_graph(rng))
    start = in_frame_of_pose_zero(graph.ground_truth)
    start[1:] += rng.normal(0.0, 0.05, start[1:].shape)
    outcome = solve_graph(graph, start)
    assert outcome.converged
    assert outcome.F < 1e-16
    assert pose_difference(outcome.poses, in_frame_of_pose_zero(graph.ground_truth)) < 1e-8


def test_lm_converges_on_the_small_graph(small_graph) -> None:
    outcome = solve_graph(small_graph, small_graph.poses)
    assert outcome.converged
    assert np.all(outcome.poses[0] == small_graph.poses[0])  # gauge: pose 0 fixed
    assert np.all(np.diff(outcome.history) <= 0.0)  # LM never accepts an increase
    assert outcome.history.size == outcome.iterations + 1
    assert outcome.F == pytest.approx(objective.objective(small_graph, outcome.poses), rel=1e-12)
    assert_stationary(small_graph, outcome.poses)


def scipy_optimum(graph, start: np.ndarray) -> float:
    """F at SciPy's trust-region-reflective optimum of the same whitened residuals."""

    def whitened(free: np.ndarray) -> np.ndarray:
        poses = np.vstack([start[:1], free.reshape(-1, 3)])
        return objective.linearise(graph, poses).errors.ravel()

    fit = least_squares(whitened, start[1:].ravel(), xtol=1e-15, ftol=1e-15, gtol=1e-15)
    return float(2.0 * fit.cost)


def test_lm_matches_scipy_least_squares(rng) -> None:
    graph = synthetic_graph(rng, num_poses=40)
    start = chordal_initialisation(graph)
    outcome = solve_graph(graph, start)
    assert outcome.converged
    assert outcome.F == pytest.approx(scipy_optimum(graph, start), rel=1e-9)
    assert_stationary(graph.replace(poses=start), outcome.poses)


def test_solve_returns_a_consistent_result(small_graph) -> None:
    problem = DistributedProblem.single_robot(small_graph)
    result = get_method("lm")(with_start(problem, "chordal"), Budget(iterations=50))
    costs = objective.evaluate(small_graph, result.poses)
    assert (result.F, result.F_chordal, result.chi2) == pytest.approx(tuple(costs), rel=1e-12)
    assert result.history.size == result.iterations + 1
    assert result.history[0] == pytest.approx(
        objective.objective(small_graph, chordal_initialisation(small_graph))
    )
    assert result.parallel_s == result.wall_s > 0.0
    assert result.status.converged


def test_solve_respects_the_iteration_budget_and_the_inits(small_graph) -> None:
    problem = DistributedProblem.single_robot(small_graph.replace(poses=small_graph.poses + 0.3))
    short = solve(with_start(problem, "odometry"), Budget(iterations=2))
    assert short.iterations == 2
    assert short.history[0] == pytest.approx(objective.objective(small_graph))
    from_problem = solve(problem, Budget(iterations=0), seed=3)  # harness options are ignored
    assert from_problem.F == pytest.approx(objective.objective(problem.graph))
    with pytest.raises(ValueRangeError):
        with_start(problem, "ground-truth")


@pytest.mark.dataset
@pytest.mark.parametrize("name", sorted(REFERENCE_F))
def test_lm_from_chordal_reaches_the_reference_optimum(name: str) -> None:
    graph = require_dataset(name)
    outcome = reference_optimum(graph)
    assert outcome.converged
    assert outcome.F <= REFERENCE_F[name] * (1.0 + 1e-6)
    assert outcome.F >= REFERENCE_F[name] * (1.0 - 1e-5)  # the reference's printed precision
