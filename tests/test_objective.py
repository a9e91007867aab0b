import numpy as np
import pytest

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


def explicit_rotation(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s], [s, c]])


def explicit_costs(graph, poses: np.ndarray) -> tuple[float, float, float]:
    """``(F_chordal, Σ κ r_θ², Σ κ r_θ⁴)`` edge by edge from 2×2 rotation matrices and the raw
    information, without ``objective`` or ``se2``:
    ``F_chordal = Σ κ‖R_q − R_p R̃‖²_F + τ‖t_q − t_p − R_p t̃‖²`` (κ = Λ_θθ,
    τ = 2 / tr(Λ_tt⁻¹)); ``r_θ`` is the angle of ``(R_p R̃)ᵀ R_q``."""
    chordal = kappa_r2 = kappa_r4 = 0.0
    for p, q, z, info in zip(
        graph.tails, graph.heads, graph.measurements, graph.information, strict=True
    ):
        kappa = info[2, 2]
        tau = 2.0 / np.trace(np.linalg.inv(info[:2, :2]))
        r_p, r_q, r_z = (explicit_rotation(a) for a in (poses[p, 2], poses[q, 2], z[2]))
        rotation_error = r_q - r_p @ r_z
        translation_error = poses[q, :2] - poses[p, :2] - r_p @ z[:2]
        chordal += kappa * np.sum(rotation_error**2) + tau * translation_error @ translation_error
        relative = (r_p @ r_z).T @ r_q
        r_theta = np.arctan2(relative[1, 0], relative[0, 0])
        kappa_r2 += kappa * r_theta**2
        kappa_r4 += kappa * r_theta**4
    return chordal, kappa_r2, kappa_r4


def test_chordal_objective_matches_the_frobenius_definition(small_graph, rng):
    for poses in (
        small_graph.poses,
        small_graph.ground_truth,
        small_graph.poses + rng.normal(0.0, 1.0, small_graph.poses.shape),  # r_θ up to ~π
    ):
        expected, _, _ = explicit_costs(small_graph, poses)
        assert objective.chordal_objective(small_graph, poses) == pytest.approx(expected, rel=1e-12)


def test_chordal_and_geodesic_agree_to_fourth_order_in_the_rotation_residual(small_graph):
    """Per edge ``‖R_q − R_p R̃‖²_F = 4(1 − cos r_θ)`` and ``‖t_q − t_p − R_p t̃‖² = ‖r_t‖²``,
    while ``F`` weighs ``κ r_θ²``. From the alternating series of ``cos`` (its partial sums bound
    it for every real ``r``): ``r²/2 − r⁴/24 ≤ 1 − cos r ≤ r²/2 − r⁴/24 + r⁶/720``, so

        ``0 ≤ 2r² − 4(1 − cos r) ≤ r⁴/6``   and   ``2r² − 4(1 − cos r) ≥ (r⁴/6)(1 − r²/30)``.

    Hence with ``G = F + Σ κ r_θ²`` (the geodesic cost with the chordal normalisation, rotation
    weight 2κ):  ``(1 − r_max²/30) Σ κ r_θ⁴/6 ≤ G − F_chordal ≤ Σ κ r_θ⁴/6``. ``F_chordal`` is *not*
    within ``O(r⁴)`` of ``F`` itself: the two differ by ``Σ κ r_θ²`` to leading order."""
    truth = small_graph.ground_truth  # rotation residuals = measurement noise, σ = 0.05
    f = objective.objective(small_graph, truth)
    f_chordal = objective.chordal_objective(small_graph, truth)
    _, kappa_r2, kappa_r4 = explicit_costs(small_graph, truth)
    r_max = np.abs(objective.residuals(small_graph, truth)[:, 2]).max()
    assert r_max < 0.2
    gap = f + kappa_r2 - f_chordal
    assert (1.0 - r_max**2 / 30.0) * kappa_r4 / 6.0 <= gap <= kappa_r4 / 6.0
    assert gap < 1e-3 * f_chordal  # so the agreement is close on this graph


def test_the_inlier_bound_is_the_chi2_quantile() -> None:
    from scipy.stats import chi2

    from popbench.objective import CHI2_3_99

    assert CHI2_3_99 == pytest.approx(chi2.ppf(0.99, 3), rel=1e-14)
