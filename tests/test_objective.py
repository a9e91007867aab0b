import numpy as np

from popbench import objective, se2


def test_gradient_matches_finite_differences(small_graph, rng):
    poses = small_graph.poses + rng.normal(0, 0.1, small_graph.poses.shape)
    analytic = objective.gradient(small_graph, poses)
    eps = 1e-6
    numeric = np.zeros_like(poses)
    for i in range(poses.shape[0]):
        for k in range(3):
            step = np.zeros_like(poses)
            step[i, k] = eps
            numeric[i, k] = (
                objective.objective(small_graph, poses + step)
                - objective.objective(small_graph, poses - step)
            ) / (2 * eps)
    np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-5)


def test_objective_zero_at_consistent_poses(small_graph):
    truth = small_graph.ground_truth
    exact = small_graph.replace(
        measurements=se2.between(truth[small_graph.tails], truth[small_graph.heads])
    )
    costs = objective.evaluate(exact, truth)
    assert max(costs) < 1e-20


def test_weights_match_definition(small_graph):
    kappa, tau = objective.weights(small_graph.information)
    info = small_graph.information[0]
    assert kappa[0] == info[2, 2]
    np.testing.assert_allclose(tau[0], 2.0 / np.trace(np.linalg.inv(info[:2, :2])))


def test_chordal_and_geodesic_agree_for_small_rotations(small_graph):
    r = objective.residuals(small_graph)
    kappa, tau = objective.weights(small_graph.information)
    expected = np.sum(4 * kappa * (1 - np.cos(r[:, 2])) + tau * np.sum(r[:, :2] ** 2, 1))
    np.testing.assert_allclose(objective.chordal_objective(small_graph), expected)
