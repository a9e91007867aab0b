"""GNC (popbench.solvers.gnc) and LM's per-edge weights; cross-checked against GTSAM 4.3.0's
GncOptimizer (test-only dependency) on intel with 10 % outliers."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_dataset

from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, make_graph
from popbench.methods import Budget, get_method
from popbench.outliers import candidate_mask, precision_recall
from popbench.problems.distributed import DistributedProblem
from popbench.solvers import gnc
from popbench.solvers.lm import solve_graph


def test_edge_weights_scale_the_cost(small_graph):
    ones = solve_graph(small_graph, small_graph.poses, 50)
    plain = solve_graph(small_graph, small_graph.poses, 50, edge_weights=np.ones(32))
    np.testing.assert_allclose(ones.poses, plain.poses, atol=1e-12)
    # a uniform scale does not move the optimum
    scaled = solve_graph(small_graph, small_graph.poses, 50, edge_weights=np.full(32, 7.0))
    np.testing.assert_allclose(scaled.poses, ones.poses, atol=1e-6)
    # weight 0 on the loop closures: the odometry chain alone, solved exactly
    weights = np.where(small_graph.kinds == EdgeKind.LOOP, 0.0, 1.0)
    chain = solve_graph(small_graph, small_graph.poses, 50, edge_weights=weights)
    np.testing.assert_allclose(chain.poses, small_graph.odometry_initial(), atol=1e-8)
    with pytest.raises(ValueRangeError):
        solve_graph(small_graph, small_graph.poses, 5, edge_weights=-np.ones(32))
    with pytest.raises(ValueRangeError):
        solve_graph(small_graph, small_graph.poses, 5, edge_weights=np.ones(3))


def test_decrement_stop_skips_the_confirming_step(small_graph, rng):
    """From near the optimum LM needs a second step only to see that the first converged;
    ``decrement_tolerance`` predicts that with the first step's factorisation instead."""
    exact = solve_graph(small_graph, small_graph.poses, 50)
    start = exact.poses + rng.normal(0.0, 1e-3, exact.poses.shape)
    plain = solve_graph(small_graph, start, 50, relative_tolerance=1e-5)
    early = solve_graph(small_graph, start, 50, relative_tolerance=1e-5, decrement_tolerance=1e-5)
    assert early.converged and early.iterations < plain.iterations
    assert early.F == pytest.approx(exact.F, rel=1e-5)


def test_weights_and_mu_schedule():
    c = gnc.THRESHOLD
    squared = np.array([0.0, 0.5 * c, c, 2.0 * c, 100.0 * c])
    mu = 0.7
    w = gnc.gnc_weights("tls", squared, mu)
    assert w[0] == 1.0 and w[-1] == 0.0 and np.all(np.diff(w) <= 0) and np.all(w >= 0)
    # the middle branch is continuous with both ends
    lower, upper = mu / (mu + 1) * c, (mu + 1) / mu * c
    for edge, value in ((lower, 1.0), (upper, 0.0)):
        assert gnc.gnc_weights("tls", np.array([edge]), mu)[0] == pytest.approx(value, abs=1e-12)
    np.testing.assert_allclose(gnc.gnc_weights("gm", squared, 1.0), (c / (squared + c)) ** 2)
    assert gnc.initial_mu("tls", 2.0 * c) == pytest.approx(1.0 / 3.0)
    assert gnc.initial_mu("tls", 0.4 * c) == -1.0
    assert gnc.initial_mu("gm", 3.0 * c) == pytest.approx(6.0)
    assert gnc.next_mu("tls", 2.0) == pytest.approx(2.8)
    assert gnc.next_mu("gm", 1.2) == 1.0


def _grid_with_outliers(rng: np.random.Generator):
    """A 6×6 lattice walk with every lattice loop closure, three replaced by gross outliers."""
    cells = [(x, y if x % 2 == 0 else 5 - y) for x in range(6) for y in range(6)]
    truth = np.array([[x, y, 0.0] for x, y in cells], dtype=float)
    index = {cell: k for k, cell in enumerate(cells)}
    tails = list(range(35))
    heads = list(range(1, 36))
    for (x, y), k in index.items():
        for other in ((x + 1, y), (x, y + 1)):
            j = index.get(other)
            if j is not None and abs(j - k) > 1:
                tails.append(k)
                heads.append(j)
    tails, heads = np.array(tails), np.array(heads)
    z = se2.between(truth[tails], truth[heads]) + rng.normal(0, 0.01, (tails.size, 3))
    info = np.tile(np.diag([1e4, 1e4, 1e4]), (tails.size, 1, 1))
    graph = make_graph(truth, tails, heads, z, info, ground_truth=truth)
    outlier = np.zeros(tails.size, dtype=bool)
    outlier[[40, 45, 50]] = True
    z[outlier] = [[3.0, -2.0, 2.5], [-1.5, 4.0, -1.0], [2.0, 2.0, 3.0]]
    graph = graph.replace(measurements=z)
    return graph.replace(poses=graph.odometry_initial()), outlier


@pytest.mark.parametrize("surrogate", ["tls", "gm"])
def test_gnc_flags_the_hand_made_outliers(surrogate, rng):
    graph, outlier = _grid_with_outliers(rng)
    problem = DistributedProblem.from_graph(graph, 1, outlier_mask=outlier)
    result = get_method("gnc")(problem, Budget(iterations=100), surrogate=surrogate)
    np.testing.assert_array_equal(~result.inlier_mask, outlier)
    assert result.status.converged and result.iterations == result.extras["mu"].size
    # the inliers at their least-squares optimum without the outliers (GM keeps a small weight
    # (c̄² / r²)² on each outlier, so its estimate is pulled by a few mm)
    clean = solve_graph(graph, graph.poses, 50, edge_weights=(~outlier).astype(float))
    np.testing.assert_allclose(result.poses, clean.poses, atol=1e-8 if surrogate == "tls" else 1e-2)
    lm = get_method("lm")(problem, Budget(iterations=100))
    assert result.F > lm.F  # GNC does not fit the outliers


def _reference_gnc_tls(graph, known):
    """Straightforward GNC-TLS: every round cold-started from ``graph.poses`` and solved by LM
    to its default tolerance, the sparse structure rebuilt for every solve; returns the inlier
    mask and the final poses."""
    start = graph.poses
    squared = gnc.squared_residuals(graph, solve_graph(graph, start).poses)
    mu = gnc.initial_mu("tls", squared[~known].max())
    previous = squared.sum()
    for _ in range(100):
        weights = np.where(known, 1.0, gnc.gnc_weights("tls", squared, mu))
        poses = solve_graph(graph, start, edge_weights=weights).poses
        squared = gnc.squared_residuals(graph, poses)
        cost = np.sum(weights * squared)
        binary = np.all((weights < 1e-4) | (weights > 1 - 1e-4))
        if abs(cost - previous) / previous < gnc.COST_TOLERANCE or binary:
            break
        mu, previous = 1.4 * mu, cost
    return (weights >= 0.5) | known, poses


def test_fast_path_matches_a_straightforward_gnc(rng):
    """The default path (warm starts, inner LM to 1e-5, one shared sparse structure, final
    polish) flags the same edges and reaches the same F and poses as a plain cold-start GNC,
    here with three gross outliers and two adjacent loop closures shifted by 6 and 1.5 σ, so
    that several rounds see fractional weights and GNC must choose which of the two to reject
    (it rejects one: the other absorbs the shift)."""
    graph, outlier = _grid_with_outliers(rng)
    loops = np.flatnonzero((graph.kinds == EdgeKind.LOOP) & ~outlier)
    z = graph.measurements.copy()
    z[loops[0], 0] += 0.06  # σ = 0.01 m
    z[loops[1], 1] += 0.015
    graph = graph.replace(measurements=z)
    known = np.isin(graph.kinds, gnc.ODOMETRY_KINDS)
    inlier, poses = _reference_gnc_tls(graph, known)
    problem = DistributedProblem.from_graph(graph, 1)
    result = gnc.solve(problem, inner_start="problem")
    np.testing.assert_array_equal(result.inlier_mask, inlier)
    assert not inlier[outlier].any() and inlier[loops[:2]].sum() == 1 and (~inlier).sum() == 4
    np.testing.assert_allclose(result.poses, poses, atol=1e-7)
    assert result.F == pytest.approx(objective.objective(graph, poses), rel=1e-9)
    # the straightforward options of the same code (GTSAM's cold starts, tight inner LM)
    plain = gnc.solve(problem, inner_start="problem", warm_start=False, inner_tolerance=1e-10)
    np.testing.assert_array_equal(plain.inlier_mask, inlier)
    assert plain.F == pytest.approx(result.F, rel=1e-9)
    with pytest.raises(ValueRangeError):
        gnc.solve(problem, inner_tolerance=0.0)


def test_gnc_without_outliers_is_least_squares(small_graph):
    problem = DistributedProblem.from_graph(small_graph, 1)
    result = gnc.solve(problem, inner_start="problem")
    assert result.inlier_mask.all() and result.iterations == 0 and result.status.converged
    np.testing.assert_allclose(result.poses, solve_graph(small_graph, small_graph.poses).poses)
    with pytest.raises(ValueRangeError):
        gnc.solve(problem, surrogate="huber")
    with pytest.raises(ValueRangeError):
        gnc.solve(problem, inner_start="odometry")


@pytest.mark.dataset
def test_gnc_matches_gtsam_gnc_on_intel_with_outliers():
    """Same flagged set as GTSAM's GncLMOptimizer (TLS, known inliers = odometry + the prior
    that fixes the gauge, threshold at probability 0.99 = ½χ²₃(0.99) on GTSAM's ½‖e‖²), from the
    same odometry start. GTSAM's factors are BetweenFactor<Pose2> with diagonal sigmas
    (1/√τ, 1/√τ, 1/√κ), so their whitened residual is eq. 1's up to Logmap vs eq. 1 (equal for
    small rotation errors, the inliers); GTSAM takes μ₀ at the start instead of the non-robust
    solution. Neither difference changes the flagged set here."""
    import gtsam  # test-only dependency

    from popbench.harness.outliers import corrupted_problem

    require_dataset("intel")
    problem = corrupted_problem("intel", 7, 0.1, 0, "odometry")  # Table II's cell, seed 0
    graph, truth = problem.graph, problem.outlier_mask
    kappa, tau = objective.weights(graph.information)
    factors = gtsam.NonlinearFactorGraph()
    for k in range(graph.num_edges):
        sigmas = np.array([1.0 / np.sqrt(tau[k])] * 2 + [1.0 / np.sqrt(kappa[k])])
        factors.add(
            gtsam.BetweenFactorPose2(
                int(graph.tails[k]),
                int(graph.heads[k]),
                gtsam.Pose2(*graph.measurements[k]),
                gtsam.noiseModel.Diagonal.Sigmas(sigmas),
            )
        )
    factors.add(
        gtsam.PriorFactorPose2(
            0, gtsam.Pose2(*graph.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, 1e-6)
        )
    )
    values = gtsam.Values()
    for key, pose in enumerate(graph.poses):
        values.insert(key, gtsam.Pose2(*pose))
    known = np.isin(graph.kinds, gnc.ODOMETRY_KINDS)
    params = gtsam.GncLMParams()
    params.setLossType(gtsam.GncLossType.TLS)
    params.setKnownInliers([*np.flatnonzero(known).tolist(), graph.num_edges])
    optimizer = gtsam.GncLMOptimizer(factors, values, params)
    optimizer.setInlierCostThresholdsAtProbability(0.99)
    assert optimizer.getInlierCostThresholds()[0] == pytest.approx(0.5 * gnc.THRESHOLD)
    optimizer.optimize()
    gtsam_flags = np.asarray(optimizer.getWeights())[: graph.num_edges] < 0.5

    result = gnc.solve(problem, inner_start="problem")
    ours = ~result.inlier_mask
    np.testing.assert_array_equal(ours, gtsam_flags)
    among = candidate_mask(graph)
    assert precision_recall(ours, truth, among) == (1.0, 1.0)
