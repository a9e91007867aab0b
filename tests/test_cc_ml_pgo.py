"""CC-PGO / ML-PGO (RBCD on the rank-r relaxation): the relaxation against the objective, the
manifold calculus against finite differences, rounding, the certificate, and convergence to a
published optimum."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_dataset

from baselines import cc_pgo, ml_pgo
from baselines.rbcd import (
    blocks,
    driver,
    local_solver,
    relaxation,
    stiefel,
)
from baselines.rbcd import (
    rounding as rbcd_rounding,
)
from popbench import objective, se2
from popbench.datasets import DATASETS
from popbench.errors import ValueRangeError
from popbench.methods import Budget, get_method
from popbench.problems.distributed import DistributedProblem
from popbench.problems.partition import partition, partition_report
from popbench.solvers.initial import with_start

MIT_OPTIMUM = DATASETS["mit"].chordal_optimum  # F_chordal*, SE-Sync convention


def _random_point(rng: np.random.Generator, num_poses: int, rank: int) -> np.ndarray:
    return stiefel.project_manifold(rng.normal(size=(num_poses, 3, rank)))


def _cost(q, x: np.ndarray) -> float:
    return relaxation.relaxed_cost(x, relaxation.apply_q(q, x))


def test_twice_relaxed_cost_is_the_chordal_objective_at_rank_two(small_graph, rng):
    q = relaxation.connection_laplacian(small_graph)
    for poses in (small_graph.poses, small_graph.ground_truth, rng.normal(size=(30, 3))):
        expected = objective.chordal_objective(small_graph, poses)
        assert 2 * _cost(q, relaxation.lift(poses, np.eye(2))) == pytest.approx(expected, rel=1e-12)
        lifted = relaxation.lift(
            poses, relaxation.random_stiefel(5, seed=3)
        )  # rank 5: the same cost
        assert 2 * _cost(q, lifted) == pytest.approx(expected, rel=1e-12)


def test_riemannian_gradient_and_hessian_match_finite_differences(small_graph, rng):
    q = relaxation.connection_laplacian(small_graph)
    x = _random_point(rng, small_graph.num_poses, 4)
    euclidean = relaxation.apply_q(q, x)
    gradient = stiefel.riemannian_gradient(x, euclidean)
    direction = stiefel.project_tangent(x, rng.normal(size=x.shape))
    step = 1e-5

    def along(t: float) -> float:
        return _cost(q, stiefel.retract(x, t * direction))

    slope = (along(step) - along(-step)) / (2 * step)
    assert slope == pytest.approx(np.vdot(gradient, direction), rel=1e-6)
    # the polar retraction is second order, so the curve's curvature is ⟨v, Hess f[v]⟩
    hessian = stiefel.riemannian_hessian(q, x, stiefel.multipliers(x, euclidean), direction)
    step = 1e-4
    curvature = (along(step) - 2 * along(0.0) + along(-step)) / step**2
    assert curvature == pytest.approx(np.vdot(direction, hessian), rel=1e-4)
    # the gradient is tangent: orthogonal to the normal directions Y S (S symmetric)
    normal = stiefel._symmetric_times_rows(rng.normal(size=(x.shape[0], 3)), x[:, :2])
    assert np.vdot(gradient[:, :2], normal) == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("rounding", rbcd_rounding.ROUNDINGS)
def test_rounding_a_lifted_embedding_returns_the_poses(small_graph, rounding):
    truth = small_graph.ground_truth
    lifted = relaxation.lift(
        se2.compose(np.array([3.0, -1.0, 0.7]), truth), relaxation.random_stiefel(5, 1)
    )
    rounded = rbcd_rounding.round_solution(
        lifted, anchor=0, anchor_pose=truth[0], rounding=rounding
    )
    np.testing.assert_allclose(rounded[:, :2], truth[:, :2], atol=1e-10)
    np.testing.assert_allclose(se2.wrap(rounded[:, 2] - truth[:, 2]), 0.0, atol=1e-10)


def test_svd_rounding_fixes_the_reflection_and_ignores_orthogonal_changes_of_the_lift(
    small_graph, rng
):
    truth = small_graph.ground_truth
    lifted = relaxation.lift(truth, relaxation.random_stiefel(5, 2))
    reference = rbcd_rounding.round_solution(lifted, anchor=4, anchor_pose=truth[4])
    flips = 0
    for _ in range(12):  # X -> X O, O in O(r) with det ±1: the same cost, the same rounding
        orthogonal, _ = np.linalg.qr(rng.normal(size=(5, 5)))
        turned = lifted @ orthogonal
        basis = rbcd_rounding.rounding_basis(turned, anchor=4)
        np.testing.assert_allclose(basis.T @ basis, np.eye(2), atol=1e-12)
        m = turned[:, :2] @ basis
        assert np.all(np.linalg.det(m) > 0)  # R_iᵀ, not reflections
        _, vectors = np.linalg.eigh(
            relaxation.flat(turned[:, :2]).T @ relaxation.flat(turned[:, :2])
        )
        flips += np.linalg.det(turned[0, :2] @ vectors[:, [-1, -2]]) < 0  # needed the fix
        rounded = rbcd_rounding.round_solution(turned, anchor=4, anchor_pose=truth[4])
        np.testing.assert_allclose(rounded[:, :2], reference[:, :2], atol=1e-9)
        np.testing.assert_allclose(se2.wrap(rounded[:, 2] - reference[:, 2]), 0.0, atol=1e-9)
    assert 0 < flips < 12  # both orientations of the eigenvector basis occurred


def test_svd_rounding_keeps_the_dominant_plane_of_an_unconverged_iterate(small_graph, rng):
    """X = lift(poses) + a weaker component in a third direction (what an unconverged iterate
    looks like): the SVD basis is the poses' plane whatever the anchor; the anchor's own rows
    are tilted by the extra component, and its rounding is worse."""
    truth = small_graph.ground_truth
    lift_rows = relaxation.random_stiefel(5, 3)
    extra = np.linalg.qr(np.column_stack([lift_rows.T, rng.normal(size=5)]))[0][:, 2]
    lifted = relaxation.lift(truth, lift_rows)
    lifted[:, :2] += 0.3 * rng.normal(size=(truth.shape[0], 2, 1)) * extra
    lifted = stiefel.project_manifold(lifted)
    costs = {}
    for rounding in rbcd_rounding.ROUNDINGS:
        rounded = rbcd_rounding.round_solution(
            lifted, anchor=0, anchor_pose=truth[0], rounding=rounding
        )
        costs[rounding] = objective.chordal_objective(small_graph, rounded)
    assert costs["svd"] < costs["anchor"]
    with pytest.raises(ValueRangeError, match="rounding"):
        rbcd_rounding.rounding_basis(lifted, 0, "nearest")


@pytest.mark.parametrize("method", [cc_pgo, ml_pgo])
def test_an_unknown_rounding_is_rejected_before_any_round(small_graph, method, monkeypatch):
    def no_rounds(*_args, **_kwargs):
        raise AssertionError("the rounds ran before the option was checked")

    monkeypatch.setattr(driver, "run_rbcd", no_rounds)
    problem = DistributedProblem(small_graph.replace(robots=np.repeat(np.arange(3), 10)))
    with pytest.raises(ValueRangeError, match="rounding"):
        method.solve(problem, Budget(iterations=5), rounding="nearest")


def test_colour_classes_are_independent_sets_covering_every_robot(small_graph):
    robots = np.repeat(np.arange(6), 5)
    classes = blocks.colour_robots(small_graph, robots)
    assert sorted(np.concatenate(classes).tolist()) == list(range(6))
    a, b = robots[small_graph.tails], robots[small_graph.heads]
    for members in classes:
        inside = np.isin(a, members) & np.isin(b, members)
        assert np.all(a[inside] == b[inside])
    # robots of at least `batch_below` poses update alone, the smaller ones as one batch
    groups = blocks.batch_groups(np.array([0, 1, 2]), np.array([5, 500, 7]), batch_below=300)
    assert [g.tolist() for g in groups] == [[1], [0, 2]]


def test_the_certificate_is_the_same_from_the_dense_and_the_lanczos_solver(
    small_graph, monkeypatch
):
    from baselines.rbcd import rounding

    problem = with_start(DistributedProblem.from_graph(small_graph, 3), "chordal")
    dense = cc_pgo.solve(problem, Budget(iterations=150), certify=True)
    monkeypatch.setattr(rounding, "DENSE_CERTIFICATE_ROWS", 0)  # ARPACK, from its fixed start
    lanczos = cc_pgo.solve(problem, Budget(iterations=150), certify=True)
    assert lanczos.extras["certificate_min_eig"] == pytest.approx(
        dense.extras["certificate_min_eig"], abs=1e-7
    )


@pytest.mark.parametrize("solve", [cc_pgo.solve, ml_pgo.solve])
def test_small_graph_converges_certifiably_with_consistent_accounting(small_graph, solve):
    problem = with_start(DistributedProblem.from_graph(small_graph, 3), "chordal")
    result = solve(problem, Budget(iterations=150), certify=True)
    # λ_min(S) ≈ 0 (to the accuracy of an iterate whose robots stop at a local gradient norm of
    # 1e-2, as dpgo's do, against ‖Q‖ ≈ 10²): the rank-5 iterate is a global minimiser of the
    # relaxation ...
    assert result.extras["gradient_norm"] < 0.05  # dpgo's global stopping threshold is 0.1
    assert result.extras["certificate_min_eig"] > -1e-4
    # ... and the relaxation is tight: rounding loses nothing
    assert result.F_chordal == pytest.approx(result.extras["relaxed_F_chordal"], rel=1e-8)
    # the incrementally maintained QX matches a fresh evaluation of the final iterate
    assert result.history[-1] == pytest.approx(result.extras["relaxed_F_chordal"])
    assert result.history.shape == (result.iterations + 1,) == (151,)
    assert 0 < result.parallel_s <= result.wall_s
    assert result.messages > 0
    assert result.F == pytest.approx(objective.objective(small_graph, result.poses))
    np.testing.assert_allclose(result.poses[0], small_graph.poses[0], atol=1e-9)  # the gauge


def test_same_seed_same_result_and_unknown_options_fail(small_graph):
    problem = DistributedProblem.from_graph(small_graph, 3)
    first = cc_pgo.solve(problem, Budget(iterations=20), seed=4)
    second = cc_pgo.solve(problem, Budget(iterations=20), seed=4)
    np.testing.assert_array_equal(first.poses, second.poses)
    np.testing.assert_array_equal(first.history, second.history)
    from popbench.errors import ValueRangeError

    with pytest.raises(ValueRangeError):
        cc_pgo.solve(problem, Budget(iterations=1), rank=1)


def test_ml_pgo_repartitions_with_metis_and_cc_pgo_keeps_the_assignment(small_graph):
    problem = DistributedProblem.from_graph(small_graph, 3, partition="contiguous")
    metis = partition_report(small_graph, partition(small_graph, 3, "metis")).cut_edges
    contiguous = partition_report(small_graph, problem.robots).cut_edges
    budget = Budget(iterations=2)
    assert ml_pgo.solve(problem, budget).extras["cut_edges"] == metis
    assert ml_pgo.solve(problem, budget, repartition=False).extras["cut_edges"] == contiguous
    assert cc_pgo.solve(problem, budget).extras["cut_edges"] == contiguous


def test_registry_resolves_both_methods():
    # wrapped by the registry's never-worse rule (popbench.methods.never_worse)
    assert get_method("cc-pgo").__wrapped__ is cc_pgo.solve
    assert get_method("ml-pgo").__wrapped__ is ml_pgo.solve


@pytest.mark.dataset
@pytest.mark.slow
@pytest.mark.parametrize("name", ["cc-pgo", "ml-pgo"])
def test_mit_three_robots_reaches_the_published_optimum(name):
    graph = require_dataset("mit")
    problem = with_start(DistributedProblem.from_graph(graph, 3), "chordal")
    result = get_method(name)(problem, Budget(iterations=150))
    assert result.F_chordal / MIT_OPTIMUM - 1 < 1e-3
    assert result.F_chordal / MIT_OPTIMUM - 1 > -1e-4  # not below the certified optimum
    assert result.history[0] > 80.0  # from the chordal start (88.13), not from the optimum


def test_batched_class_update_equals_each_robot_updating_alone(small_graph, rng):
    robots = np.repeat(np.arange(6), 5)
    classes = blocks.colour_robots(small_graph, robots)
    members = next(c for c in classes if c.size >= 2)
    q = relaxation.connection_laplacian(small_graph)
    x = _random_point(rng, small_graph.num_poses, 5)
    q_x = relaxation.apply_q(q, x)
    options = local_solver.LocalOptions(
        rtr_iterations=2, tcg_iterations=10, gradient_tolerance=1e-6
    )

    def update(group: np.ndarray) -> tuple[np.ndarray, local_solver.LocalStep]:
        (block,) = blocks.class_blocks(q, small_graph, robots, [group])
        step = local_solver.local_update(block, x[block.poses], q_x[block.poses], options)
        # the returned change of QX is that of the new poses
        moved = x.copy()
        moved[block.poses] = step.z
        np.testing.assert_allclose(
            relaxation.flat(relaxation.apply_q(q, moved) - q_x)[block.reach_rows],
            step.q_change,
            atol=1e-10,
        )
        return block.poses, step

    poses, (together, _, products) = update(members)
    assert np.all(products > 0)
    for index, robot in enumerate(members):
        own, (alone, _, own_products) = update(np.array([robot]))
        mine = np.isin(poses, own)
        np.testing.assert_allclose(together[mine], alone, atol=1e-12)
        assert products[index] == own_products[0]
    # the update decreased every robot's local cost
    moved = x.copy()
    moved[poses] = together
    assert _cost(q, moved) < _cost(q, x)


def test_robot_by_robot_rounds_match_batched_rounds(small_graph):
    robots = np.repeat(np.arange(6), 5)
    runs = [
        driver.solve_rbcd(
            with_start(small_graph, "chordal"),
            robots,
            Budget(iterations=40),
            driver.RBCDOptions(batch_below=below),
            rank=5,
            certify=False,
            seed=0,
        )
        for below in (0, 10**9)  # every robot alone / every class one batch
    ]
    np.testing.assert_allclose(runs[0].history, runs[1].history, rtol=1e-9)
    assert runs[0].messages == runs[1].messages
