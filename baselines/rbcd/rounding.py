"""From the relaxation back to poses: the rounding of a rank-r iterate and the optimality
certificate (SE-Sync, Rosen et al. 2019, Alg. 2 and its certificate ``S = Q − SymBlockDiag(Λ)``;
dpgo's anchor rounding, ``getTrajectoryInGlobalFrame``). The two roundings compared: docs/rbcd.md.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import eigsh

from baselines.rbcd.relaxation import apply_q, flat
from baselines.rbcd.stiefel import multipliers
from popbench import se2
from popbench.errors import ValueRangeError

ROUNDINGS = ("svd", "anchor")


def rounding_basis(x: np.ndarray, anchor: int, rounding: str = "svd") -> np.ndarray:
    """The ``(r, 2)`` orthonormal basis ``U`` onto which :func:`round_solution` projects ``X``.

    ``"svd"`` (SE-Sync's rounding, Rosen et al. 2019, Alg. 2): the top-2 left singular vectors
    of ``Y = [Y_1 … Y_N]`` (``r × 2N``), i.e. the top eigenvectors of ``Y Yᵀ = Σ_i Y_i Y_iᵀ``,
    an ``r × r`` sum of per-robot terms (each robot sends one ``r × r`` matrix, so it stays
    distributed), with the second column negated when most ``det(Y_iᵀ U) < 0`` (the reflection
    fix). ``"anchor"`` (dpgo ``getTrajectoryInGlobalFrame``): ``U = Y_a``, the anchor's
    lifted rotation. At a rank-2 ``X`` the two agree; away from one (an unconverged iterate that
    still uses the extra dimensions, e.g. after 1000 rounds from the odometry start) the anchor
    basis discards everything orthogonal to one pose's plane, the SVD basis the least energy.
    """
    if rounding == "anchor":
        return x[anchor, :2].T.copy()
    if rounding != "svd":
        raise ValueRangeError("rounding", rounding, " or ".join(ROUNDINGS))
    rotation_rows = flat(x[:, :2])  # (2N, r): the rows Y_iᵀ
    _, vectors = np.linalg.eigh(rotation_rows.T @ rotation_rows)
    basis = vectors[:, [-1, -2]]  # the two largest eigenvalues
    m = x[:, :2] @ basis  # (N, 2, 2): Y_iᵀ U
    determinants = m[:, 0, 0] * m[:, 1, 1] - m[:, 0, 1] * m[:, 1, 0]
    if np.count_nonzero(determinants > 0) < 0.5 * determinants.size:
        basis[:, 1] *= -1.0
    return basis


def round_solution(
    x: np.ndarray, anchor: int, anchor_pose: np.ndarray, rounding: str = "svd"
) -> np.ndarray:
    """Round ``X`` ``(N, 3, r)`` to poses ``(N, 3)``.

    With the basis ``U`` of :func:`rounding_basis`: ``R_iᵀ ≈ Y_iᵀ U`` projected onto SO(2) (the
    nearest rotation, ``θ = atan2(M₀₁ − M₁₀, M₀₀ + M₁₁)`` for ``M = Y_iᵀ U``, which is the SVD
    projection with the determinant fix) and ``t_i = Uᵀ p_i``; the result is expressed so that
    the anchor sits at ``anchor_pose`` ``(3,)`` (the gauge).

    **Rounding** (:func:`round_solution`). By default SE-Sync's: project every ``X_i`` onto the
    top-2 eigenvectors ``U`` of ``Σ_i Y_i Y_iᵀ`` (``r × r``, summed over robots, so one small
    message per robot), with the reflection fixed by a determinant vote, then each ``Y_iᵀ U`` to its
    nearest rotation. dpgo's anchor rounding (``U = Y_a``, ``getTrajectoryInGlobalFrame``) is
    ``rounding="anchor"``. The two agree at a rank-2 iterate (every converged run here), but not at
    an unconverged one (measured: docs/rbcd.md).
    """
    basis = rounding_basis(x, anchor, rounding)
    m = x[:, :2] @ basis  # (N, 2, 2) = R_iᵀ up to the projection
    headings = np.arctan2(m[:, 0, 1] - m[:, 1, 0], m[:, 0, 0] + m[:, 1, 1])
    poses = np.column_stack([x[:, 2] @ basis, headings])
    return se2.compose(anchor_pose[None, :], se2.between(poses[anchor][None, :], poses))


#: certificates of at most this many rows (1,000 poses) get λ_min from a dense eigensolver: exact
#: and deterministic. ARPACK from its default random start once failed to converge on a 90-row
#: certificate (λ ≈ 0 is a multiple eigenvalue at a critical point, where SXᵀ = 0).
DENSE_CERTIFICATE_ROWS = 3_000


def certificate_min_eigenvalue(q: sp.spmatrix, x: np.ndarray) -> float:
    """``λ_min(S)`` with ``S = Q − SymBlockDiag(Λ)`` (SE-Sync's certificate; not in dpgo's code):
    ``Λ_i`` on the rotation rows of pose ``i``, zero on translations. ``λ_min ≥ −ε`` certifies
    that ``X`` is a global minimiser of the relaxation (``SXᵀ = 0`` at critical points, so
    ``λ_min ≤ 0``). Dense up to :data:`DENSE_CERTIFICATE_ROWS` rows, else Lanczos (ARPACK) from a
    fixed start vector."""
    lam = multipliers(x, apply_q(q, x))  # (N, 3)
    n = x.shape[0]
    lam_full = np.zeros((n, 3, 3))
    lam_full[:, 0, 0], lam_full[:, 1, 1] = lam[:, 0], lam[:, 2]
    lam_full[:, 0, 1] = lam_full[:, 1, 0] = lam[:, 1]
    rows = 3 * np.arange(n)[:, None, None] + np.arange(3)[:, None]
    cols = 3 * np.arange(n)[:, None, None] + np.arange(3)[None, :]
    rows, cols = np.broadcast_arrays(rows, cols)
    block_diag = sp.csr_matrix((lam_full.ravel(), (rows.ravel(), cols.ravel())), shape=q.shape)
    certificate = (q - block_diag).tocsc()
    if certificate.shape[0] <= DENSE_CERTIFICATE_ROWS:
        return float(np.linalg.eigvalsh(certificate.toarray())[0])
    start = np.random.default_rng(0).standard_normal(certificate.shape[0])  # reproducible
    value = eigsh(certificate, k=1, which="SA", tol=1e-8, maxiter=20 * q.shape[0], v0=start)[0]
    return float(value[0])
