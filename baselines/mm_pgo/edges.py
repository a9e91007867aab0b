"""MM-PGO's per-edge terms, vectorised over edges: residuals, costs, gradients and Gauss–Newton
blocks of ``F_e`` with planar quantities as complex numbers (Fan & Murphey 2024).

``F_e = κ_e‖R_q − R_pR̃_e‖²_F + τ_e‖t_q − t_p − R_pt̃_e‖²`` (SE-Sync's convention; MM-PGO's
internal ``f = ½F``). Translations are ``x + iy``, rotations ``e^{iθ}`` and residuals complex, so a
rotation of a vector is one complex multiply; each pose's ``cos θ, sin θ`` is computed once per
iterate (:class:`PoseTable`) and gathered by its edges (timings: docs/mm_pgo.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

TWO_PI = 2.0 * np.pi


def unit(angles: np.ndarray) -> np.ndarray:
    """``e^{iθ}`` ``(n,)`` complex of angles ``(n,)`` (rad): ``R(θ)`` as a unit complex number."""
    rotations = np.empty(angles.shape, dtype=complex)
    np.cos(angles, out=rotations.real)
    np.sin(angles, out=rotations.imag)
    return rotations


def abs2(values: np.ndarray) -> np.ndarray:
    """``|z|²`` ``(n,)`` of complex ``values`` ``(n,)``."""
    return values.real * values.real + values.imag * values.imag


class EdgeTerms(NamedTuple):
    """Rotations and residuals of edges ``p → q`` as complex numbers (``x + iy``; a rotation
    ``R(θ)`` as ``e^{iθ}``), every field ``(m,)`` complex.

    ``rot_p, rot_q``: ``R_p, R_q``; ``rot_pm``: ``R_pR̃``; ``t``: the world-frame translation
    residual ``t_q − t_p − R_pt̃``; ``r``: the first column of ``R_q − R_pR̃``
    (``‖R_q − R_pR̃‖²_F = 2|r|²``).
    """

    rot_p: np.ndarray
    rot_q: np.ndarray
    rot_pm: np.ndarray
    t: np.ndarray
    r: np.ndarray


class EdgeData(NamedTuple):
    """Constants of ``m`` edges: endpoint rows into a pose array, measurement (complex)."""

    tails: np.ndarray
    heads: np.ndarray
    t_m: np.ndarray  # t̃ [m]
    rot_m: np.ndarray  # R̃ = e^{iθ̃}


def edge_data(tails: np.ndarray, heads: np.ndarray, measurements: np.ndarray) -> EdgeData:
    """:class:`EdgeData` of edges whose endpoints are rows ``tails``/``heads`` of a pose array."""
    return EdgeData(
        tails, heads, measurements[:, 0] + 1j * measurements[:, 1], unit(measurements[:, 2])
    )


class PoseTable(NamedTuple):
    """Poses as contiguous ``(N,)`` columns: ``headings`` (rad), translations ``z = x + iy``
    and rotations ``u = e^{iθ}`` (each pose's trigonometry computed once, shared by its
    edges)."""

    headings: np.ndarray
    z: np.ndarray
    u: np.ndarray

    @property
    def poses(self) -> np.ndarray:
        """The poses ``(N, 3)``."""
        return np.column_stack([self.z.real, self.z.imag, self.headings])


def pose_table(poses: np.ndarray | PoseTable) -> PoseTable:
    """The :class:`PoseTable` of poses ``(N, 3)`` (a table is returned as it is)."""
    if isinstance(poses, PoseTable):
        return poses
    headings = poses[:, 2].copy()
    return PoseTable(headings, poses[:, 0] + 1j * poses[:, 1], unit(headings))


def edge_terms(
    poses: np.ndarray | PoseTable, edges: EdgeData, head_poses: np.ndarray | PoseTable | None = None
) -> EdgeTerms:
    """:class:`EdgeTerms` of ``edges`` with tails at rows of ``poses`` ``(·, 3)`` and heads at
    rows of ``head_poses`` (default ``poses``); either may be a :class:`PoseTable`."""
    tail_table = pose_table(poses)
    head_table = tail_table if head_poses is None else pose_table(head_poses)
    rot_p, rot_q = tail_table.u[edges.tails], head_table.u[edges.heads]
    rot_pm = rot_p * edges.rot_m
    t = head_table.z[edges.heads] - tail_table.z[edges.tails] - rot_p * edges.t_m
    return EdgeTerms(rot_p, rot_q, rot_pm, t, rot_q - rot_pm)


def edge_costs(terms: EdgeTerms, kappa: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``F_e = τ‖r_t‖² + κ‖R_q − R_pR̃‖²_F``, ``(m,)``."""
    return tau * abs2(terms.t) + 2.0 * kappa * abs2(terms.r)


def shifted_costs(
    terms: EdgeTerms, base: EdgeTerms, kappa: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """``2‖r_e(terms) − ½ r_e(base)‖²_W``, ``(m,)``: an inter edge's term of (1)."""
    return 2.0 * tau * abs2(terms.t - 0.5 * base.t) + 4.0 * kappa * abs2(terms.r - 0.5 * base.r)


def select(terms: EdgeTerms, edges: np.ndarray) -> EdgeTerms:
    """The :class:`EdgeTerms` of a subset ``edges`` (mask or indices)."""
    return EdgeTerms(*(field[edges] for field in terms))


def body_gradients(
    terms: EdgeTerms, edges: EdgeData, kappa: np.ndarray, tau: np.ndarray
) -> np.ndarray:
    """Gradients of ``F_e`` with respect to body-frame increments ``(a, b)`` of the tail (rows
    ``:m``) and of the head (rows ``m:``) (``t ← t + R a``, ``θ ← θ + b``), ``(2m, 3)``.

    With ``r = R_pᵀ(t_q − t_p) − t̃ = R_pᵀ w`` (``w`` the world residual): ``∂r/∂a_p = −I``,
    ``∂r/∂b_p = −J(r + t̃)``, ``∂r/∂a_q = R_pᵀR_q`` (so ``∂F/∂a_q = 2τR_qᵀw``); the rotation term
    ``4κ(1 − cos r_θ)`` has derivative ``∓4κ sin r_θ`` (``⟨J(r + t̃), r⟩ = ⟨Jt̃, r⟩ =
    Im(conj(t̃) r)`` in complex form).
    """
    body = terms.rot_p.conj() * terms.t  # r = R_pᵀw
    head = terms.rot_q.conj() * terms.t  # R_qᵀw
    rotation_term = 4.0 * kappa * (terms.rot_q * terms.rot_pm.conj()).imag
    two_tau = 2.0 * tau
    m = body.size
    gradients = np.empty((2 * m, 3))  # filled column by column (contiguous sources)
    np.multiply(body.real, -two_tau, out=gradients[:m, 0])
    np.multiply(body.imag, -two_tau, out=gradients[:m, 1])
    gradients[:m, 2] = -two_tau * (edges.t_m.conj() * body).imag - rotation_term
    np.multiply(head.real, two_tau, out=gradients[m:, 0])
    np.multiply(head.imag, two_tau, out=gradients[m:, 1])
    gradients[m:, 2] = rotation_term
    return gradients


class HessianGeometry(NamedTuple):
    """The iterate-dependent inputs of the Gauss–Newton blocks of ``m`` edges (complex
    ``(m,)``): ``lever`` = ``J R_pᵀ(t_q − t_p)``; ``relative`` = ``R(θ_q − θ_p)``."""

    lever: np.ndarray
    relative: np.ndarray


def gauss_newton_blocks(
    geometry: HessianGeometry, kappa: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Newton Hessian blocks of ``F_e`` in body-frame increments,
    ``(tail-tail, tail-head, head-head)``, each ``(m, 3, 3)``.

    ``∂r_t = [−I, −lever | R(φ), 0]`` with ``r_t = R_pᵀ(t_q − t_p) − t̃``, ``φ = θ_q − θ_p``
    (:class:`HessianGeometry`); ``∂r_θ = [0, −1 | 0, 1]``; ``H = 2τ J_tᵀJ_t + 4κ J_θᵀJ_θ``
    (``4κ(1 − cos r) ≈ 2κ r²``). At zero residual ``lever = Jt̃`` and ``φ = θ̃``: the blocks
    depend on the measurements only.
    """
    lever, relative = geometry.lever, geometry.relative
    m = lever.shape[0]
    jac_tail = np.zeros((m, 2, 3))
    jac_tail[:, :, :2] = -np.eye(2)
    jac_tail[:, 0, 2], jac_tail[:, 1, 2] = -lever.real, -lever.imag
    jac_head = np.zeros((m, 2, 3))
    jac_head[:, 0, 0] = jac_head[:, 1, 1] = relative.real
    jac_head[:, 1, 0] = relative.imag
    jac_head[:, 0, 1] = -relative.imag
    two_tau = 2.0 * tau[:, None, None]
    e_theta = np.zeros((3, 3))
    e_theta[2, 2] = 1.0
    rotation = 4.0 * kappa[:, None, None] * e_theta
    tail_tail = two_tau * np.einsum("mki,mkj->mij", jac_tail, jac_tail) + rotation
    tail_head = two_tau * np.einsum("mki,mkj->mij", jac_tail, jac_head) - rotation
    head_head = two_tau * np.einsum("mki,mkj->mij", jac_head, jac_head) + rotation
    return tail_tail, tail_head, head_head


def jacobian_drift(geometry: HessianGeometry, reference: HessianGeometry) -> np.ndarray:
    """Relative change ``‖J_e − J_e⁰‖_F / ‖J_e⁰‖_F`` ``(m,)`` of the translation residual's
    Jacobian ``J_e = [−I, −lever | R(φ), 0]`` between ``reference`` and ``geometry``
    (``‖J_e⁰‖²_F = 4 + |lever⁰|²``, ``‖R(φ) − R(φ⁰)‖²_F = 2|e^{iφ} − e^{iφ⁰}|²``)."""
    change = abs2(geometry.lever - reference.lever) + 2.0 * abs2(
        geometry.relative - reference.relative
    )
    return np.sqrt(change / (4.0 + abs2(reference.lever)))


def extrapolate(current: PoseTable, previous: PoseTable, gamma: float) -> PoseTable:
    """Nesterov extrapolation ``X + γ(X ⊖ X_prev)``: translations linearly, headings by the
    difference wrapped to ``[−π, π]``."""
    difference = current.headings - previous.headings
    difference -= TWO_PI * np.rint(difference / TWO_PI)
    headings = current.headings + gamma * difference
    return PoseTable(headings, current.z + gamma * (current.z - previous.z), unit(headings))
