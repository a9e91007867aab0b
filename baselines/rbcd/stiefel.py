"""The manifold ``(St(2, r) × R^r)^n`` in the transposed layout of :mod:`baselines.rbcd.relaxation`:
tangent projection, polar retraction, Riemannian gradient and Hessian (Absil, Mahony & Sepulchre
2008; the embedded metric, as SE-Sync and dpgo use it).

``X`` is ``(n, 3, r)``: rows ``X[i, :2] = Y_iᵀ`` orthonormal, ``X[i, 2] = p_iᵀ`` free. Symmetric
2×2 matrices per pose (the multipliers ``Λ_i``) are stored as ``(n, 3)`` ``[S₀₀, S₀₁, S₁₁]``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from baselines.rbcd.relaxation import apply_q


def _dot_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise inner products ``⟨a_i, b_i⟩`` of ``(n, r)`` arrays, ``(n,)``."""
    return np.einsum("nr,nr->n", a, b)


def _symmetric_times_rows(s: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``S_i @ rows_i`` for symmetric 2×2 ``S`` stored as ``(n, 3)`` ``[S₀₀, S₀₁, S₁₁]`` and
    ``rows`` ``(n, 2, r)``; returns ``(n, 2, r)``."""
    full = np.empty((s.shape[0], 2, 2))
    full[:, 0, 0], full[:, 1, 1] = s[:, 0], s[:, 2]
    full[:, 0, 1] = full[:, 1, 0] = s[:, 1]
    return full @ rows


def multipliers(x: np.ndarray, euclidean_gradient: np.ndarray) -> np.ndarray:
    """``Λ_i = sym(Y_iᵀ ∇_{Y_i} f)`` (the Lagrange multiplier estimates) as ``(n, 3)``
    ``[Λ₀₀, Λ₀₁, Λ₁₁]``."""
    y0, y1 = x[:, 0], x[:, 1]
    g0, g1 = euclidean_gradient[:, 0], euclidean_gradient[:, 1]
    off_diagonal = 0.5 * (_dot_rows(y0, g1) + _dot_rows(y1, g0))
    return np.column_stack([_dot_rows(y0, g0), off_diagonal, _dot_rows(y1, g1)])


def project_tangent(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Orthogonal projection of ``v`` ``(n, 3, r)`` onto the tangent space at ``x``:
    ``V_Y − Y sym(Yᵀ V_Y)`` on the Stiefel rows, the translation row unchanged."""
    out = v.copy()
    out[:, :2] -= _symmetric_times_rows(multipliers(x, v), x[:, :2])
    return out


def orthonormalise_rows(m: np.ndarray) -> np.ndarray:
    """Polar factor ``(M Mᵀ)^{-½} M`` of each ``(2, r)`` block of ``m`` ``(n, 2, r)`` (the nearest
    matrix with orthonormal rows), with the closed-form 2×2 inverse square root."""
    m0, m1 = m[:, 0], m[:, 1]
    a, b, d = _dot_rows(m0, m0), _dot_rows(m0, m1), _dot_rows(m1, m1)  # Gram matrix G = M Mᵀ
    s = np.sqrt(np.maximum(a * d - b * b, 0.0))
    t = np.sqrt(a + d + 2.0 * s)
    # √G = (G + sI)/t, so (√G)⁻¹ = t (G + sI)⁻¹ = t · adj(G + sI) / det(G + sI).
    scale = t / ((a + s) * (d + s) - b * b)
    inverse_root = np.column_stack([(d + s) * scale, -b * scale, (a + s) * scale])
    return _symmetric_times_rows(inverse_root, m)


def project_manifold(x: np.ndarray) -> np.ndarray:
    """The nearest point of ``(St(2, r) × R^r)^n`` to ``x`` ``(n, 3, r)``."""
    out = x.copy()
    out[:, :2] = orthonormalise_rows(x[:, :2])
    return out


def retract(x: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Polar retraction ``R_x(v) = Proj(x + v)``."""
    return project_manifold(x + v)


def riemannian_gradient(x: np.ndarray, euclidean_gradient: np.ndarray) -> np.ndarray:
    """``grad f(x)`` ``(n, 3, r)`` (embedded metric)."""
    return project_tangent(x, euclidean_gradient)


def riemannian_hessian(q: sp.spmatrix, x: np.ndarray, lam: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``Hess f(x)[v] = Proj_x(Q v − v_Y Λ)`` for ``f = ½⟨X, QX⟩ + ⟨X, G⟩`` (the linear term
    enters only through ``Λ = multipliers(x, ∇f)``, ``(n, 3)``); ``v`` tangent ``(n, 3, r)``."""
    out = apply_q(q, v)
    out[:, :2] -= _symmetric_times_rows(lam, v[:, :2])
    return project_tangent(x, out)


def pose_gradient_norms(x: np.ndarray, q_x: np.ndarray) -> np.ndarray:
    """``‖grad_i f‖²`` per pose, ``(N,)``, from ``X`` and ``QX``."""
    return np.einsum("nkr,nkr->n", *(2 * [riemannian_gradient(x, q_x)]))
