"""The rank-r Burer–Monteiro relaxation of planar PGO: the connection Laplacian ``Q``, the
relaxed cost ``f`` and the lifting of poses (SE-Sync, Rosen et al. 2019; dpgo, Tian et al. 2021:
the connection Laplacian ``Q = AΩAᵀ``).

Pose ``i`` is lifted to ``X_i = [Y_i p_i] ∈ R^{r×3}`` with ``Y_i ∈ St(2, r)`` and ``p_i ∈ R^r``.
Arrays hold the transpose: ``X`` is ``(N, 3, r)`` with ``X[i, :2] = Y_iᵀ`` (orthonormal rows) and
``X[i, 2] = p_iᵀ``, so ``X.reshape(3N, r)`` has rows ``3i, 3i+1`` (rotation) and ``3i+2``
(translation) per pose. An edge ``i → j`` with measurement ``T̃ = [[R̃, t̃], [0, 1]]`` and weights
``Ω = diag(κ, κ, τ)`` costs ``‖X_j − X_i T̃‖²_Ω = κ‖Y_j − Y_i R̃‖²_F + τ‖p_j − p_i − Y_i t̃‖²``, so

    f(X) = ½ tr(Xᵀ Q X),   Q = Σ_e blocks  Q_ii += T̃ΩT̃ᵀ, Q_jj += Ω, Q_ij += −T̃Ω, Q_ji += −ΩT̃ᵀ,

and ``2 f(X) = F_chordal`` when ``r = 2`` and the ``Y_i`` are rotations (dpgo and MM-PGO print
``2f``).

Example:
    >>> import numpy as np
    >>> from popbench.problems.synthetic import make_problem
    >>> from popbench.objective import chordal_objective
    >>> from baselines.rbcd.relaxation import apply_q, connection_laplacian, lift, relaxed_cost
    >>> graph = make_problem(robots=2, poses_per_robot=10, seed=0).graph
    >>> x = lift(graph.poses, np.eye(2))  # rank 2: the poses themselves
    >>> f = relaxed_cost(x, apply_q(connection_laplacian(graph), x))
    >>> bool(np.isclose(2 * f, chordal_objective(graph, graph.poses)))
    True
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from popbench import objective, se2
from popbench.graph import PoseGraph


def measurement_matrices(graph: PoseGraph) -> np.ndarray:
    """Homogeneous measurements ``T̃ = [[R̃, t̃], [0, 1]]``, ``(M, 3, 3)``."""
    transforms = np.zeros((graph.num_edges, 3, 3))
    transforms[:, :2, :2] = se2.rotation(graph.measurements[:, 2])
    transforms[:, :2, 2] = graph.measurements[:, :2]
    transforms[:, 2, 2] = 1.0
    return transforms


def connection_laplacian(graph: PoseGraph) -> sp.csr_matrix:
    """The data matrix ``Q`` (dpgo's connection Laplacian ``AΩAᵀ``), ``(3N, 3N)`` sparse
    symmetric PSD.

    ``½ tr(Xᵀ Q X)`` with ``X`` ``(3N, r)`` is the relaxed cost ``f`` (module docstring).
    """
    kappa, tau = objective.weights(graph.information)
    omega = np.zeros((graph.num_edges, 3, 3))
    omega[:, 0, 0] = omega[:, 1, 1] = kappa
    omega[:, 2, 2] = tau
    transforms = measurement_matrices(graph)
    t_omega = transforms @ omega  # T̃Ω, (M, 3, 3)
    blocks = np.stack(
        [t_omega @ np.swapaxes(transforms, 1, 2), omega, -t_omega, -np.swapaxes(t_omega, 1, 2)]
    )  # (4, M, 3, 3): (i,i), (j,j), (i,j), (j,i)
    block_rows = np.stack([graph.tails, graph.heads, graph.tails, graph.heads])  # (4, M)
    block_cols = np.stack([graph.tails, graph.heads, graph.heads, graph.tails])
    offsets = np.arange(3)
    rows = 3 * block_rows[:, :, None, None] + offsets[:, None]
    cols = 3 * block_cols[:, :, None, None] + offsets[None, :]
    rows, cols = np.broadcast_arrays(rows, cols)
    size = 3 * graph.num_poses
    return sp.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(size, size))


def flat(x: np.ndarray) -> np.ndarray:
    """``(n, 3, r)`` → ``(3n, r)`` view."""
    return x.reshape(-1, x.shape[-1])


def relaxed_cost(x: np.ndarray, q_x: np.ndarray) -> float:
    """``f = ½⟨X, QX⟩`` from ``X`` and ``QX``, both ``(N, 3, r)``."""
    return 0.5 * float(np.vdot(x, q_x))


def edge_relaxed_cost(graph: PoseGraph, x: np.ndarray) -> float:
    """``f`` of ``X`` ``(N, 3, r)`` summed from its edge residuals,
    ``½ Σ_e κ‖Y_j − Y_iR̃‖²_F + τ‖p_j − p_i − Y_it̃‖²`` (equal to :func:`relaxed_cost`, but
    accurate to the residuals' precision: ``½⟨X, QX⟩`` cancels terms of size ``⟨|X|, |Q||X|⟩``,
    which on a graph with tiny residuals is ~10⁵ × ``f``, so its rounding error is too)."""
    kappa, tau = objective.weights(graph.information)
    cos, sin = np.cos(graph.measurements[:, 2:]), np.sin(graph.measurements[:, 2:])
    shift = graph.measurements[:, :2]
    tail, head = x[graph.tails], x[graph.heads]  # rows: Y_iᵀ (2), p_iᵀ
    y0, y1 = tail[:, 0], tail[:, 1]
    rotation_0 = head[:, 0] - (cos * y0 + sin * y1)  # rows of (Y_j − Y_iR̃)ᵀ = Y_jᵀ − R̃ᵀY_iᵀ
    rotation_1 = head[:, 1] - (cos * y1 - sin * y0)
    translation = head[:, 2] - tail[:, 2] - (shift[:, :1] * y0 + shift[:, 1:] * y1)
    squares = np.einsum("mr,mr->m", rotation_0, rotation_0) + np.einsum(
        "mr,mr->m", rotation_1, rotation_1
    )
    return 0.5 * float(kappa @ squares + tau @ np.einsum("mr,mr->m", translation, translation))


def cost_change(x: np.ndarray, q_x: np.ndarray, x_new: np.ndarray, q_x_new: np.ndarray) -> float:
    """``f(X_new) − f(X) = ½⟨X_new − X, QX_new + QX⟩`` (``Q`` symmetric), all ``(N, 3, r)``:
    accurate to the size of the change, not of ``⟨|X|, |Q||X|⟩`` as the difference of two
    :func:`relaxed_cost` values is."""
    return 0.5 * float(np.vdot(x_new - x, q_x_new + q_x))


def apply_q(q: sp.spmatrix, x: np.ndarray) -> np.ndarray:
    """``Q X`` for ``X`` ``(n, 3, r)``, returned ``(n, 3, r)``."""
    return (q @ flat(x)).reshape(x.shape)


def random_stiefel(rank: int, seed: int) -> np.ndarray:
    """A seeded random ``(2, r)`` matrix with orthonormal rows (``Y_liftᵀ``, dpgo's
    ``fixedStiefelVariable``)."""
    gaussian = np.random.default_rng(seed).standard_normal((rank, 2))
    q, _ = np.linalg.qr(gaussian)
    return q.T


def lift(poses: np.ndarray, lift_rows: np.ndarray) -> np.ndarray:
    """Lift poses ``(N, 3)`` to ``X`` ``(N, 3, r)``: ``Y_i = L R_i``, ``p_i = L t_i`` with
    ``L = lift_rowsᵀ`` ``(r, 2)``."""
    rotations = se2.rotation(poses[:, 2])  # (N, 2, 2)
    x = np.empty((poses.shape[0], 3, lift_rows.shape[1]))
    x[:, :2] = np.swapaxes(rotations, 1, 2) @ lift_rows  # Y_iᵀ = R_iᵀ Lᵀ
    x[:, 2] = poses[:, :2] @ lift_rows  # p_iᵀ = t_iᵀ Lᵀ
    return x
