"""The PGO objective and its companions, vectorised over edges.

* ``F`` (paper eq. 1 with ``w_R² = κ``, ``w_T² = τ``)::

      F(x) = Σ_e κ_e · wrap(θ_q − θ_p − θ̃)² + τ_e · ‖R(θ_p)ᵀ(t_q − t_p) − t̃‖²

* ``F_chordal`` (SE-Sync convention, no ½)::

      F_chordal(x) = Σ_e κ_e ‖R_q − R_p R̃‖²_F + τ_e ‖t_q − t_p − R_p t̃‖²
                   = Σ_e 4 κ_e (1 − cos r_θ) + τ_e ‖r_t‖²

* ``chi2``: g2o's EDGE_SE2 error ``e = t2v(z̃⁻¹ ∘ x_p⁻¹ ∘ x_q) = [R(θ̃)ᵀ r_t, r_θ]``, summed as
  ``Σ eᵀ Λ e`` (no ½; GTSAM's ``graph.error`` is ½ of the Logmap version of this).

with ``κ = Λ_θθ`` and ``τ = 2 / tr(Λ_tt⁻¹)`` (SE-Sync / DPGO / MM-PGO weights). ``F`` is
``chi2`` with each information replaced by ``diag(τ, τ, κ)``; :func:`anisotropy` measures how far
a file's information is from that (docs/solve.md). :func:`linearisation` and :func:`gradient`
serve each of the three costs (:data:`COSTS`).

Example:
    >>> from popbench.objective import evaluate
    >>> from popbench.problems.synthetic import make_problem
    >>> graph = make_problem(robots=2, poses_per_robot=10, seed=0).graph
    >>> costs = evaluate(graph)  # at graph.poses, the odometry start
    >>> bool(costs.F > evaluate(graph, graph.ground_truth).F > 0)
    True
"""

from __future__ import annotations

from typing import NamedTuple, TypeVar

import numpy as np

from popbench import se2
from popbench.graph import PoseGraph

# χ²₃(0.99) = scipy.stats.chi2.ppf(0.99, 3): the 0.99-quantile of an edge's eq. 1 term ‖e‖² (three
# whitened coordinates) when its noise matches its information; the inlier bound of GNC and the
# project's robust-kernel scale.
CHI2_3_99 = 11.344866730144373

# J = R(π/2); dR(θ)/dθ = R(θ) J.
_J = np.array([[0.0, -1.0], [1.0, 0.0]])

COSTS = ("F", "F_chordal", "chi2")

Array = TypeVar("Array")  # np.ndarray or torch.Tensor: edge_costs uses only elementwise ops


def weights(information: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-edge rotation and translation weights ``(κ, τ)``, each ``(M,)``.

    ``κ = Λ_θθ``; ``τ = 2 / tr(Λ_tt⁻¹)`` with ``Λ_tt`` the 2×2 translation block.
    """
    kappa = information[:, 2, 2]
    a, b, d = information[:, 0, 0], information[:, 0, 1], information[:, 1, 1]
    tau = 2.0 * (a * d - b * b) / (a + d)  # 2 / tr(Λ_tt⁻¹) for a 2×2 block
    return kappa, tau


def residuals(graph: PoseGraph, poses: np.ndarray | None = None) -> np.ndarray:
    """Unweighted residuals ``[r_t, r_θ]``, ``(M, 3)``: ``r_t = R_pᵀ(t_q − t_p) − t̃`` [m],
    ``r_θ = wrap(θ_q − θ_p − θ̃)`` [rad] (paper eq. 1)."""
    poses = graph.poses if poses is None else poses
    relative = se2.between(poses[graph.tails], poses[graph.heads])
    r_t = relative[:, :2] - graph.measurements[:, :2]
    r_theta = se2.wrap(relative[:, 2] - graph.measurements[:, 2])
    return np.column_stack([r_t, r_theta])


def edge_costs(r: Array, kappa: Array, tau: Array) -> Array:
    """Per-edge terms of paper eq. 1, ``κ_e r_θ² + τ_e ‖r_t‖²``, shape ``r.shape[:-1]``.

    ``r (..., 3)``: residuals ``[r_t, r_θ]`` (:func:`residuals`); ``kappa``, ``tau``
    ``r.shape[:-1]`` (:func:`weights`). Only elementwise arithmetic, so the same function serves
    NumPy arrays and torch tensors (envs.core's batched residuals) alike.
    """
    return kappa * r[..., 2] ** 2 + tau * (r[..., 0] ** 2 + r[..., 1] ** 2)


def g2o_errors(graph: PoseGraph, poses: np.ndarray | None = None) -> np.ndarray:
    """g2o EDGE_SE2 errors ``t2v(z̃⁻¹ x_p⁻¹ x_q) = [R(θ̃)ᵀ r_t, r_θ]``, ``(M, 3)``."""
    r = residuals(graph, poses)
    return np.column_stack([se2.unrotate(graph.measurements[:, 2], r[:, :2]), r[:, 2]])


def logmap_errors(graph: PoseGraph, poses: np.ndarray | None = None) -> np.ndarray:
    """GTSAM ``BetweenFactor<Pose2>`` errors ``Logmap(z̃⁻¹ x_p⁻¹ x_q)``, ``(M, 3)``."""
    poses = graph.poses if poses is None else poses
    relative = se2.between(poses[graph.tails], poses[graph.heads])
    return se2.log(se2.between(graph.measurements, relative))


def quadratic_form(errors: np.ndarray, information: np.ndarray) -> np.ndarray:
    """Per-edge ``eᵀ Λ e``, ``(M,)``."""
    return np.einsum("mi,mij,mj->m", errors, information, errors)


def objective(graph: PoseGraph, poses: np.ndarray | None = None) -> float:
    """``F`` (paper eq. 1, κ/τ weights): the sum of :func:`edge_costs`."""
    return float(np.sum(edge_costs(residuals(graph, poses), *weights(graph.information))))


def chordal_objective(graph: PoseGraph, poses: np.ndarray | None = None) -> float:
    """``F_chordal`` (SE-Sync convention): ``Σ 4κ(1 − cos r_θ) + τ‖r_t‖²``."""
    r = residuals(graph, poses)
    kappa, tau = weights(graph.information)
    return float(np.sum(4.0 * kappa * (1.0 - np.cos(r[:, 2])) + tau * np.sum(r[:, :2] ** 2, 1)))


def chi2(graph: PoseGraph, poses: np.ndarray | None = None) -> float:
    """g2o χ² ``Σ eᵀΛe`` with the EDGE_SE2 error (no ½)."""
    return float(np.sum(quadratic_form(g2o_errors(graph, poses), graph.information)))


class Costs(NamedTuple):
    """The three reported costs of one estimate."""

    F: float
    F_chordal: float
    chi2: float


def evaluate(graph: PoseGraph, poses: np.ndarray | None = None) -> Costs:
    """``(F, F_chordal, chi2)`` of ``poses`` (default: the graph's own estimate)."""
    return Costs(objective(graph, poses), chordal_objective(graph, poses), chi2(graph, poses))


class Linearisation(NamedTuple):
    """Whitened residuals and their Jacobians: ``F = Σ_e ‖e_e‖²``.

    ``errors``: ``(M, 3)`` = ``[√τ r_t, √κ r_θ]``; ``jac_tail``/``jac_head``: ``(M, 3, 3)``
    derivatives of ``errors`` with respect to ``(t_p, θ_p)`` and ``(t_q, θ_q)``.
    """

    errors: np.ndarray
    jac_tail: np.ndarray
    jac_head: np.ndarray


def _unwhitened_linearisation(
    graph: PoseGraph, poses: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The residuals ``r`` of eq. 1 ``(M, 3)`` and their Jacobians with respect to the tail and
    head poses ``(M, 3, 3)`` (additive increments): what both linearisations whiten.

    ``∂r_t/∂t_p = −R_pᵀ``, ``∂r_t/∂θ_p = −J R_pᵀ (t_q − t_p)``, ``∂r_t/∂t_q = R_pᵀ``,
    ``∂r_θ/∂θ_p = −1``, ``∂r_θ/∂θ_q = 1``, with ``J = R(π/2)``.
    """
    rot_t = np.swapaxes(se2.rotation(poses[graph.tails, 2]), -1, -2)  # R_pᵀ
    delta = poses[graph.heads, :2] - poses[graph.tails, :2]
    m = graph.num_edges
    jac_tail = np.zeros((m, 3, 3))
    jac_head = np.zeros((m, 3, 3))
    jac_tail[:, :2, :2] = -rot_t
    jac_tail[:, :2, 2] = -(_J @ np.einsum("mij,mj->mi", rot_t, delta)[..., None])[..., 0]
    jac_tail[:, 2, 2] = -1.0
    jac_head[:, :2, :2] = rot_t
    jac_head[:, 2, 2] = 1.0
    return residuals(graph, poses), jac_tail, jac_head


def linearise(graph: PoseGraph, poses: np.ndarray | None = None) -> Linearisation:
    """Whitened residuals of eq. 1 and their analytic Jacobians (additive pose increments):
    each row of :func:`_unwhitened_linearisation` scaled by ``(√τ, √τ, √κ)``."""
    poses = graph.poses if poses is None else poses
    r, jac_tail, jac_head = _unwhitened_linearisation(graph, poses)
    kappa, tau = weights(graph.information)
    row_weights = np.sqrt(np.column_stack([tau, tau, kappa]))  # (M, 3)
    return Linearisation(
        r * row_weights, jac_tail * row_weights[:, :, None], jac_head * row_weights[:, :, None]
    )


def linearise_chi2(graph: PoseGraph, poses: np.ndarray | None = None) -> Linearisation:
    """Whitened g2o errors ``Lᵀ e`` (``Λ = L Lᵀ``, Cholesky) and their Jacobians, so that
    ``chi2 = Σ_e ‖Lᵀ e_e‖²`` with the full 3×3 information, cross terms included.

    ``e = A r`` with ``A = diag(R(θ̃)ᵀ, 1)`` and ``r`` the residuals of eq. 1, whose Jacobians
    are those of :func:`linearise` before whitening.
    """
    poses = graph.poses if poses is None else poses
    r, jac_tail, jac_head = _unwhitened_linearisation(graph, poses)
    m = graph.num_edges
    whiten = np.zeros((m, 3, 3))  # Lᵀ A
    whiten[:, :2, :2] = np.swapaxes(se2.rotation(graph.measurements[:, 2]), -1, -2)
    whiten[:, 2, 2] = 1.0
    whiten = np.swapaxes(np.linalg.cholesky(graph.information), -1, -2) @ whiten
    return Linearisation(np.einsum("mij,mj->mi", whiten, r), whiten @ jac_tail, whiten @ jac_head)


def linearisation(graph: PoseGraph, poses: np.ndarray, cost: str = "F") -> Linearisation:
    """Whitened residuals and Jacobians of one of :data:`COSTS`: ``cost = Σ_e ‖errors_e‖²``.

    ``"F"``: :func:`linearise`. ``"chi2"``: :func:`linearise_chi2`. ``"F_chordal"``: the rotation
    residual of ``F`` replaced by ``2√(2κ) sin(r_θ/2)`` (``4κ(1 − cos r_θ)`` squared), whose
    derivative is ``√2 cos(r_θ/2) · d(√κ r_θ)``.
    """
    if cost == "chi2":
        return linearise_chi2(graph, poses)
    lin = linearise(graph, poses)
    return chordal_rotation(lin, graph.information) if cost == "F_chordal" else lin


def chordal_rotation(lin: Linearisation, information: np.ndarray) -> Linearisation:
    """``F``'s linearisation (:func:`linearise`) turned into ``F_chordal``'s (see
    :func:`linearisation`)."""
    kappa, _ = weights(information)
    half_angle = 0.5 * lin.errors[:, 2] / np.sqrt(kappa)  # r_θ / 2
    errors = lin.errors.copy()
    errors[:, 2] = 2.0 * np.sqrt(2.0 * kappa) * np.sin(half_angle)
    factor = np.sqrt(2.0) * np.cos(half_angle)[:, None]
    jac_tail, jac_head = lin.jac_tail.copy(), lin.jac_head.copy()
    jac_tail[:, 2] *= factor
    jac_head[:, 2] *= factor
    return Linearisation(errors, jac_tail, jac_head)


def edge_squares(graph: PoseGraph, poses: np.ndarray, cost: str = "F") -> np.ndarray:
    """Each edge's term of ``cost`` (one of :data:`COSTS`), ``(M,)`` (dimensionless)."""
    return np.sum(linearisation(graph, poses, cost).errors ** 2, axis=1)


def gradient(
    graph: PoseGraph,
    poses: np.ndarray | None = None,
    cost: str = "F",
    edge_weights: np.ndarray | None = None,
) -> np.ndarray:
    """``∇C`` with respect to the poses, ``(N, 3)`` (``2 Jᵀ e``, scattered to vertices), for
    ``C = Σ_e w_e ‖errors_e‖²`` of ``cost`` (:func:`linearisation`; ``w = 1`` by default).
    Units: the cost's per metre (x, y) and per radian (θ)."""
    lin = linearisation(graph, graph.poses if poses is None else poses, cost)
    errors = lin.errors if edge_weights is None else lin.errors * edge_weights[:, None]
    g_tail = 2.0 * np.einsum("mij,mi->mj", lin.jac_tail, errors)
    g_head = 2.0 * np.einsum("mij,mi->mj", lin.jac_head, errors)
    n = graph.num_poses
    return np.column_stack(
        [
            np.bincount(graph.tails, g_tail[:, k], n) + np.bincount(graph.heads, g_head[:, k], n)
            for k in range(3)
        ]
    )


def cost_value(graph: PoseGraph, poses: np.ndarray, cost: str = "F") -> float:
    """The value of one of :data:`COSTS` at ``poses``."""
    return {"F": objective, "F_chordal": chordal_objective, "chi2": chi2}[cost](graph, poses)


def anisotropy(information: np.ndarray) -> np.ndarray:
    """Per edge, how unevenly ``F`` weighs residuals against the full information, ``(M,)``:
    ``λ_max / λ_min`` of ``D^{-1/2} Λ D^{-1/2}`` with ``D = diag(τ, τ, κ)``, ``F``'s stand-in
    for ``Λ``. 1 where ``Λ = D`` (then ``chi2 ≡ F`` for that edge); an edge's ``chi2`` term lies
    between ``λ_min`` and ``λ_max`` times its ``F`` term for any residual."""
    kappa, tau = weights(information)
    scale = 1.0 / np.sqrt(np.stack([tau, tau, kappa], axis=1))
    eigenvalues = np.linalg.eigvalsh(information * scale[:, :, None] * scale[:, None, :])
    return eigenvalues[:, -1] / eigenvalues[:, 0]
