"""SE(2) maths (``popbench.se2``) and the per-edge errors of ``popbench.objective`` against GTSAM
4.3.0's ``Pose2`` / ``Rot2`` / ``BetweenFactorPose2``, an independent implementation.

Poses are seeded random ones plus hand-picked headings at ±π, next to ±π and near zero. Angles
are compared modulo 2π (GTSAM returns ``(-π, π]``, we return ``[-π, π)``). Tolerances are at
round-off, except GTSAM's ``Expmap``/``Logmap`` for ``0 < |θ| < 1e-4``: below 1e-10 it returns
``(ρ, θ)`` unchanged (error ``|θ||t|/2``), above it evaluates ``1 − cos θ`` in closed form and
loses ~``1e-16 |t| / θ`` (measured against 40-digit arithmetic with |t| = 11.4: 7.5e-7 at
θ = 1e-10, 9e-8 at 1e-8, 1.4e-9 at 1e-6, 1e-11 at 1e-4). There the reference is the exact
half-angle form ``V(θ) = (sin(θ/2) / (θ/2)) R(θ/2)``, which has no cancellation.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from conftest import require_dataset

from popbench import datasets, objective, se2

PI = np.pi
# Headings that stress wrapping and the small-angle branches.
SPECIAL_THETAS = np.array(
    [PI, -PI, PI - 1e-9, -PI + 1e-9, PI - 1e-3, -PI + 1e-3, 0.0, 1e-12, -1e-12, 1e-8, -1e-8, 1e-6]
)
TIGHT = 1e-12  # absolute, on coordinates of magnitude ≤ ~30
GTSAM_SMALL_ANGLE = 1e-4  # below this (θ ≠ 0) GTSAM's Expmap/Logmap lose precision
GTSAM_SMALL_ANGLE_ATOL = 5e-6  # measured ≤ 7.5e-7 with |t| ≤ 14 (see module docstring)
# Ours against the half-angle form: round-off only (se2 computes 1 − cos θ as 2 sin²(θ/2); the
# direct form cancelled to 4e-10 error at θ = 1e-6, |t| = 11.4).
HALF_ANGLE_ATOL = 1e-12


def random_poses(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """``n`` random poses, translations in [-10, 10]², headings uniform, with the special headings
    first."""
    poses = np.column_stack([rng.uniform(-10.0, 10.0, (n, 2)), rng.uniform(-PI, PI, n)])
    poses[: SPECIAL_THETAS.size, 2] = SPECIAL_THETAS
    return poses


def to_gtsam(pose: np.ndarray) -> gtsam.Pose2:
    return gtsam.Pose2(*map(float, pose))


def from_gtsam(pose: gtsam.Pose2) -> np.ndarray:
    return np.array([pose.x(), pose.y(), pose.theta()])


def gtsam_atol(theta: float) -> float:
    return GTSAM_SMALL_ANGLE_ATOL if 0.0 < abs(theta) < GTSAM_SMALL_ANGLE else 10 * TIGHT


def half_angle_v(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``V(θ) = s R(θ/2)`` with ``s = sin(θ/2) / (θ/2)``, returned as ``(s, θ/2)``."""
    half = np.asarray(theta) / 2.0
    return np.where(half == 0.0, 1.0, np.sin(half) / np.where(half == 0.0, 1.0, half)), half


def assert_poses_close(ours: np.ndarray, theirs: np.ndarray, atol: float = TIGHT) -> None:
    """Translations equal to ``atol``; headings equal to ``atol`` modulo 2π; ours in [-π, π)."""
    np.testing.assert_allclose(ours[..., :2], theirs[..., :2], rtol=0.0, atol=atol)
    np.testing.assert_allclose(se2.wrap(ours[..., 2] - theirs[..., 2]), 0.0, rtol=0.0, atol=atol)
    assert np.all((ours[..., 2] >= -PI) & (ours[..., 2] < PI))


def test_wrap_matches_gtsam_rot2_up_to_the_branch_at_pi(rng):
    angles = np.concatenate([rng.uniform(-20.0, 20.0, 500), SPECIAL_THETAS, [3 * PI, -3 * PI]])
    ours = se2.wrap(angles)
    theirs = np.array([gtsam.Rot2.fromAngle(float(a)).theta() for a in angles])
    assert np.all((ours >= -PI) & (ours < PI))
    # Same angle on the circle; equal as numbers except at the branch point ±π.
    np.testing.assert_allclose(se2.wrap(ours - theirs), 0.0, atol=1e-12)
    away = np.abs(np.abs(theirs) - PI) > 1e-9
    np.testing.assert_allclose(ours[away], theirs[away], rtol=0.0, atol=1e-12)


def test_rotation_rotate_unrotate_match_rot2(rng):
    thetas = random_poses(rng)[:, 2]
    vectors = rng.uniform(-10.0, 10.0, (thetas.size, 2))
    matrices = se2.rotation(thetas)
    rotated, unrotated = se2.rotate(thetas, vectors), se2.unrotate(thetas, vectors)
    for k, (theta, v) in enumerate(zip(thetas, vectors, strict=True)):
        rot = gtsam.Rot2.fromAngle(float(theta))
        np.testing.assert_allclose(matrices[k], rot.matrix(), rtol=0.0, atol=1e-15)
        np.testing.assert_allclose(rotated[k], rot.rotate(v), rtol=0.0, atol=TIGHT)
        np.testing.assert_allclose(unrotated[k], rot.unrotate(v), rtol=0.0, atol=TIGHT)


def test_compose_inverse_between_match_pose2(rng):
    a, b = random_poses(rng), random_poses(rng)[::-1].copy()
    composed, inverted, relative = se2.compose(a, b), se2.inverse(a), se2.between(a, b)
    for k in range(a.shape[0]):
        pa, pb = to_gtsam(a[k]), to_gtsam(b[k])
        assert_poses_close(composed[k], from_gtsam(pa.compose(pb)))
        assert_poses_close(inverted[k], from_gtsam(pa.inverse()))
        assert_poses_close(relative[k], from_gtsam(pa.between(pb)))


def test_exp_matches_pose2_expmap(rng):
    xi = random_poses(rng)
    xi[-20:, 2] = rng.uniform(PI, 3 * PI, 20) * rng.choice([-1.0, 1.0], 20)  # |θ| > π wraps
    ours = se2.exp(xi)
    for k in range(xi.shape[0]):
        theirs = from_gtsam(gtsam.Pose2.Expmap(xi[k]))
        assert_poses_close(ours[k], theirs, atol=gtsam_atol(xi[k, 2]))


def test_exp_and_log_match_the_half_angle_form_at_small_angles(rng):
    """``exp``: ``t = V(θ) ρ``; ``log``: ``ρ = V(θ)⁻¹ t``, with ``V`` in the half-angle form."""
    thetas = np.concatenate([[0.0], np.geomspace(1e-12, 0.5, 47), -np.geomspace(1e-12, 0.5, 47)])
    vectors = rng.uniform(-10.0, 10.0, (thetas.size, 2))
    scale, half = half_angle_v(thetas)
    xi = np.column_stack([vectors, thetas])
    expected_t = scale[:, None] * se2.rotate(half, vectors)
    expected_rho = se2.unrotate(half, vectors) / scale[:, None]
    np.testing.assert_allclose(se2.exp(xi)[:, :2], expected_t, rtol=0.0, atol=HALF_ANGLE_ATOL)
    np.testing.assert_allclose(se2.log(xi)[:, :2], expected_rho, rtol=0.0, atol=HALF_ANGLE_ATOL)
    np.testing.assert_allclose(se2.exp(xi)[:, 2], thetas, rtol=0.0, atol=1e-15)


def test_log_matches_pose2_logmap_and_inverts_exp(rng):
    poses = random_poses(rng)
    poses = poses[np.abs(np.abs(poses[:, 2]) - PI) > 0.0]  # Logmap is two-valued at exactly ±π
    ours = se2.log(poses)
    for k in range(poses.shape[0]):
        theirs = gtsam.Pose2.Logmap(to_gtsam(poses[k]))
        atol = gtsam_atol(poses[k, 2])
        np.testing.assert_allclose(ours[k, :2], theirs[:2], rtol=0.0, atol=atol)
        np.testing.assert_allclose(se2.wrap(ours[k, 2] - theirs[2]), 0.0, atol=TIGHT)
    assert_poses_close(se2.exp(ours), poses, atol=1e-11)


@pytest.mark.dataset
def test_per_edge_errors_match_gtsam_between_factors_on_csail(rng):
    """CSAIL: anisotropic, correlated translation information (off-diagonal Λ_xy up to 4× Λ_xx),
    so a transposed or mis-read information block changes ``eᵀΛe``. Evaluated at the file's
    estimate and at poses with random headings (rotation residuals up to ±π, so the wrap and
    large-angle Logmap are exercised)."""
    graph = require_dataset("csail")
    factors, _ = gtsam.readG2o(str(datasets.dataset_path("csail", download=False)), is3D=False)
    assert factors.size() == graph.num_edges
    info = graph.information
    assert np.abs(info[:, 0, 1]).max() > np.abs(info[:, 0, 0]).max()  # not isotropic

    scrambled = graph.poses + rng.normal(0.0, 1.0, graph.poses.shape)
    scrambled[:, 2] = rng.uniform(-PI, PI, graph.num_poses)
    for poses in (graph.poses, scrambled):
        values = gtsam.Values()
        for key, pose in enumerate(poses):
            values.insert(key, to_gtsam(pose))
        residuals = objective.residuals(graph, poses)
        g2o_errors = objective.g2o_errors(graph, poses)
        logmap_errors = objective.logmap_errors(graph, poses)
        chi2 = objective.quadratic_form(logmap_errors, info)
        largest_rotation_residual = np.abs(residuals[:, 2]).max()
        for e in range(graph.num_edges):
            factor = factors.at(e)
            p, q = factor.keys()
            assert (p, q) == (graph.tails[e], graph.heads[e])
            relative = values.atPose2(p).between(values.atPose2(q))
            measured = factor.measured()
            # r_t = R_pᵀ(t_q − t_p) − t̃ and r_θ = wrap(θ_q − θ_p − θ̃) (paper eq. 1)
            np.testing.assert_allclose(
                residuals[e, :2], relative.translation() - measured.translation(), atol=1e-10
            )
            assert se2.wrap(residuals[e, 2] - (relative.theta() - measured.theta())) == (
                pytest.approx(0.0, abs=1e-12)
            )
            # g2o EDGE_SE2: t2v(z̃⁻¹ ∘ x_p⁻¹ ∘ x_q)
            assert_poses_close(g2o_errors[e], from_gtsam(measured.inverse() * relative), 1e-10)
            # GTSAM BetweenFactor<Pose2>: Logmap(z̃⁻¹ ∘ x_p⁻¹ ∘ x_q), and ½ eᵀΛe
            np.testing.assert_allclose(
                logmap_errors[e], factor.unwhitenedError(values), rtol=1e-9, atol=1e-10
            )
            assert chi2[e] == pytest.approx(2.0 * factor.error(values), rel=1e-9, abs=1e-12)
    assert largest_rotation_residual > 3.1  # the scrambled poses have residuals near ±π
