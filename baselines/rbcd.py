"""Riemannian block-coordinate descent (RBCD / RBCD++) on the rank-r Burer–Monteiro relaxation.

The shared core of ``cc-pgo`` (Tian et al., dpgo) and ``ml-pgo`` (Li et al. 2024); see
REFERENCES.md §2 and §4. Measurements (speed, rounding) and the variants tried and not kept:
docs/rbcd.md.

**Relaxation** (d = 2). Pose ``i`` is lifted to ``X_i = [Y_i p_i] ∈ R^{r×3}`` with
``Y_i ∈ St(2, r)`` (``Y_iᵀY_i = I``) and ``p_i ∈ R^r``. Arrays here hold the transpose: ``X`` is
``(N, 3, r)`` with ``X[i, :2] = Y_iᵀ`` (orthonormal rows) and ``X[i, 2] = p_iᵀ``, so that
``X.reshape(3N, r)`` has rows ``3i, 3i+1`` (rotation) and ``3i+2`` (translation) per pose. An edge
``i → j`` with measurement ``T̃ = [[R̃, t̃], [0, 1]]`` and weights ``Ω = diag(κ, κ, τ)`` costs
``‖X_j − X_i T̃‖²_Ω = κ‖Y_j − Y_i R̃‖²_F + τ‖p_j − p_i − Y_i t̃‖²``, so that

    f(X) = ½ tr(Xᵀ Q X),   Q = Σ_e blocks  Q_ii += T̃ΩT̃ᵀ, Q_jj += Ω, Q_ij += −T̃Ω, Q_ji += −ΩT̃ᵀ,

the connection Laplacian of REFERENCES §2.1, and ``2 f(X) = F_chordal`` when ``r = 2`` and the
``Y_i`` are rotations (dpgo / MM-PGO print ``2f``).

**Blocks and one iteration.** Robot α owns the rows of its poses (the problem's ``graph.robots``).
Robots that share no edge have decoupled local problems, so the robot adjacency is coloured
greedily and each colour class (an independent set) is one block. **One iteration = one round in
which every robot of one colour class updates, in parallel**, with all other robots fixed; the
class is chosen greedily (largest summed squared Riemannian-gradient norm, the block version of
dpgo's greedy robot selection) or round-robin. With one robot per class this is exactly dpgo's
greedy RBCD; with more, it is the parallel (Jacobi over an independent set) count, comparable to
MM-PGO where every robot updates each iteration.

Where the rest is stated, beside the code that computes it: the local update (trust-region
Newton with tCG, batched per colour class) at :func:`local_update` and :func:`batch_groups`; the
RBCD++ acceleration (γ, α, ``Y``, ``V``) and the restarts, and the accounting
(``parallel_s``, ``messages``, ``history``), at :func:`run_rbcd`; the rounding at
:func:`round_solution` / :func:`rounding_basis`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping
from typing import NamedTuple, Self

import numpy as np
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType
from scipy.sparse.linalg import eigsh

from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.methods import Budget, Result

PRECONDITIONER_SHIFT = 0.1  # λ in Q_αα + λI (dpgo)
RESTART_INTERVAL = 30  # fixed restart period of RBCD++ (dpgo restartInterval)
BATCH_BELOW_POSES = 300  # robots smaller than this are batched (see batch_groups)
ADAPTIVE_RESTART_TOLERANCE = 1e-9  # relative increase of f that triggers an adaptive restart
MAX_REJECTIONS = 10  # trust-region rejections allowed in one robot update (dpgo)


# ----- the data matrix and the cost ------------------------------------------------------------


def measurement_matrices(graph: PoseGraph) -> np.ndarray:
    """Homogeneous measurements ``T̃ = [[R̃, t̃], [0, 1]]``, ``(M, 3, 3)``."""
    transforms = np.zeros((graph.num_edges, 3, 3))
    transforms[:, :2, :2] = se2.rotation(graph.measurements[:, 2])
    transforms[:, :2, 2] = graph.measurements[:, :2]
    transforms[:, 2, 2] = 1.0
    return transforms


def connection_laplacian(graph: PoseGraph) -> sp.csr_matrix:
    """The data matrix ``Q`` (REFERENCES §2.1), ``(3N, 3N)`` sparse symmetric PSD.

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


# ----- the manifold (St(2, r) × R^r)^n in the transposed layout --------------------------------


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


# ----- lifting and rounding ---------------------------------------------------------------------


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


ROUNDINGS = ("svd", "anchor")


def rounding_basis(x: np.ndarray, anchor: int, rounding: str = "svd") -> np.ndarray:
    """The ``(r, 2)`` orthonormal basis ``U`` onto which :func:`round_solution` projects ``X``.

    ``"svd"`` (SE-Sync's rounding, Rosen et al. 2019, Alg. 2): the top-2 left singular vectors
    of ``Y = [Y_1 … Y_N]`` (``r × 2N``), i.e. the top eigenvectors of ``Y Yᵀ = Σ_i Y_i Y_iᵀ``,
    an ``r × r`` sum of per-robot terms (each robot sends one ``r × r`` matrix, so it stays
    distributed), with the second column negated when most ``det(Y_iᵀ U) < 0`` (the reflection
    fix). ``"anchor"`` (dpgo ``getTrajectoryInGlobalFrame``, §2.8): ``U = Y_a``, the anchor's
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
    nearest rotation. dpgo's anchor rounding (``U = Y_a``, REFERENCES §2.8) is
    ``rounding="anchor"``. The two agree at a rank-2 iterate (every converged run here), but not at
    an unconverged one (measured: docs/rbcd.md).
    """
    basis = rounding_basis(x, anchor, rounding)
    m = x[:, :2] @ basis  # (N, 2, 2) = R_iᵀ up to the projection
    headings = np.arctan2(m[:, 0, 1] - m[:, 1, 0], m[:, 0, 0] + m[:, 1, 1])
    poses = np.column_stack([x[:, 2] @ basis, headings])
    return se2.compose(anchor_pose[None, :], se2.between(poses[anchor][None, :], poses))


def certificate_min_eigenvalue(q: sp.spmatrix, x: np.ndarray) -> float:
    """``λ_min(S)`` with ``S = Q − SymBlockDiag(Λ)`` (REFERENCES §2.9): ``Λ_i`` on the rotation
    rows of pose ``i``, zero on translations. ``λ_min ≥ −ε`` certifies that ``X`` is a global
    minimiser of the relaxation (``SXᵀ = 0`` at critical points, so ``λ_min ≤ 0``)."""
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
    value = eigsh(certificate, k=1, which="SA", tol=1e-8, maxiter=20 * q.shape[0])[0]
    return float(value[0])


# ----- colour classes and the local solver -------------------------------------------------


class CholeskyPreconditioner:
    """``(Q_cc + λI)⁻¹`` of one colour class by a cached sparse Cholesky factor (CHOLMOD via
    cholespy, fill-reducing ordering chosen by CHOLMOD); the class's ``Q_cc`` is block diagonal
    (one block per robot), so this is every robot's dpgo preconditioner at once."""

    def __init__(self, hessian: sp.csr_matrix, shift: float) -> None:
        shifted = (hessian + shift * sp.identity(hessian.shape[0])).tocsr()
        self._factor = CholeskySolverD(
            shifted.shape[0],
            shifted.indptr.astype(np.int32),
            shifted.indices.astype(np.int32),
            shifted.data,
            MatrixType.CSR,
        )

    def solve(self, v: np.ndarray) -> np.ndarray:
        """``(Q_cc + λI)⁻¹ v`` for ``v`` ``(n, 3, r)``, returned ``(n, 3, r)``."""
        out = np.empty_like(v)
        self._factor.solve(np.ascontiguousarray(flat(v)), flat(out))
        return out


@dataclasses.dataclass(frozen=True, eq=False)
class ClassBlock:
    """The robots of one colour class (no two share an edge), updated together.

    Attributes:
        robots: ``(k,)`` robot ids of the class.
        poses: ``(n_c,)`` global ids of their poses, robot by robot (ascending within a robot).
        robot_of_pose: ``(n_c,)`` index ``0..k−1`` into ``robots`` of each pose's owner.
        hessian: ``Q_cc`` ``(3n_c, 3n_c)`` CSR, block diagonal with the robots' ``Q_αα``.
        preconditioner: the cached factor of ``Q_cc + λI``.
        reach_rows: ``(m,)`` rows of ``Q`` with a nonzero in the class's columns (its own rows and
            its neighbours' separator rows).
        reach: ``Q[reach_rows, class rows]`` ``(m, 3n_c)`` CSR: how a change of the class's
            poses changes ``QX``.
        own_in_reach: ``(3n_c,)`` positions of the class's own rows in ``reach_rows``
            (``reach[own_in_reach] = Q_cc``).
        separators: number of the class's poses with an edge to another robot.
        robot_nnz: ``(k,)`` nonzeros of each robot's ``Q_αα``: the work weight of one of its
            Hessian–vector products (see :func:`robot_shares`).
    """

    robots: np.ndarray
    poses: np.ndarray
    robot_of_pose: np.ndarray
    hessian: sp.csr_matrix
    preconditioner: CholeskyPreconditioner
    reach_rows: np.ndarray
    reach: sp.csr_matrix
    own_in_reach: np.ndarray
    separators: int
    robot_nnz: np.ndarray

    @property
    def num_robots(self) -> int:
        return self.robots.size

    @property
    def per_robot(self) -> _PerRobot:
        return _PerRobot(self.robot_of_pose, self.num_robots)


def pose_rows(poses: np.ndarray) -> np.ndarray:
    """Rows of ``X.reshape(3N, r)`` of the given poses, ``(3n,)``."""
    return (3 * poses[:, None] + np.arange(3)).ravel()


def class_blocks(
    q: sp.csr_matrix,
    graph: PoseGraph,
    robots: np.ndarray,
    classes: list[np.ndarray],
    shift: float = PRECONDITIONER_SHIFT,
) -> list[ClassBlock]:
    """One :class:`ClassBlock` per colour class of the assignment ``robots`` ``(N,)``, with the
    preconditioner ``Q_cc + shift·I``."""
    crossing = robots[graph.tails] != robots[graph.heads]
    is_separator = np.zeros(graph.num_poses, dtype=bool)
    is_separator[graph.tails[crossing]] = True
    is_separator[graph.heads[crossing]] = True
    blocks = []
    for members in classes:
        owned = [np.flatnonzero(robots == robot) for robot in members]
        poses = np.concatenate(owned)
        robot_of_pose = np.repeat(np.arange(members.size), [p.size for p in owned])
        rows = pose_rows(poses)
        columns = q[:, rows].tocsr()  # Q symmetric: the class's columns
        reach_rows = np.flatnonzero(np.diff(columns.indptr))
        hessian = q[rows][:, rows].tocsr()  # no edge joins two robots of a class
        robot_nnz = np.bincount(
            np.repeat(robot_of_pose, 3), np.diff(hessian.indptr), minlength=members.size
        )
        blocks.append(
            ClassBlock(
                robots=members,
                poses=poses,
                robot_of_pose=robot_of_pose,
                hessian=hessian,
                preconditioner=CholeskyPreconditioner(hessian, shift),
                reach_rows=reach_rows,
                reach=columns[reach_rows],
                own_in_reach=np.searchsorted(reach_rows, rows),
                separators=int(np.count_nonzero(is_separator[poses])),
                robot_nnz=robot_nnz,
            )
        )
    return blocks


def batch_groups(members: np.ndarray, sizes: np.ndarray, batch_below: int) -> list[np.ndarray]:
    """Split a colour class ``members`` ``(k,)`` into update batches: every robot with at least
    ``batch_below`` poses (``sizes`` ``(n,)`` poses per robot) alone, the smaller ones together.

    Batching removes per-robot overhead but makes every batched robot pay for the slowest one's
    tCG iterations on the whole batch's arrays; measured on m3500 (300 rounds, same machine):
    7 robots of ~500 poses ran 10 % faster one by one, 35 robots of ~100 poses 25 % faster
    batched; on city10k 35 robots of ~285 poses ran as fast either way. The results agree up to
    floating-point summation order.

    **Batched:** the robots of a class share no edge, so their
    problems are independent and are solved together as one block-diagonal problem (one ``Q_cc``
    product and one Cholesky solve of the class per tCG iteration), with every scalar of the
    trust-region / tCG iteration (radius, step, curvature, acceptance, stopping) kept per robot, so
    each robot follows exactly the iteration it would run alone (up to floating-point summation
    order). Only robots with fewer than ``BATCH_BELOW_POSES`` (300) poses are batched; larger ones,
    whose arrays are big enough to hide the per-call overhead, update one by one
    (:func:`batch_groups`).
    """
    small = sizes[members] < batch_below
    alone = [members[[i]] for i in np.flatnonzero(~small)]
    return alone + ([members[small]] if small.any() else [])


def colour_robots(graph: PoseGraph, robots: np.ndarray) -> list[np.ndarray]:
    """Greedy (largest degree first) colouring of the robot adjacency graph.

    Returns:
        The colour classes, each an array of robot ids no two of which share an edge.
    """
    count = int(robots.max()) + 1
    a, b = robots[graph.tails], robots[graph.heads]
    crossing = a != b
    adjacent = np.zeros((count, count), dtype=bool)
    adjacent[a[crossing], b[crossing]] = True
    adjacent |= adjacent.T
    colours = np.full(count, -1)
    for robot in np.argsort(-adjacent.sum(axis=1), kind="stable"):
        taken = set(colours[adjacent[robot]].tolist())
        colours[robot] = next(c for c in range(count) if c not in taken)
    return [np.flatnonzero(colours == c) for c in range(colours.max() + 1)]


@dataclasses.dataclass(frozen=True)
class LocalOptions:
    """Riemannian trust-region settings of one robot update (dpgo ``ROptParameters``).

    The defaults (1 accepted step, ≤ 10 tCG iterations) are cheaper than dpgo's (3, 50) and, on
    m3500 with 7 robots, reached 1e-3 of the optimum in as many rounds (58 vs 55 with adaptive
    restart, 115 vs 112 with the fixed one) in ~60 % of the time (benchmarks/bench_rbcd.py).

    Attributes:
        rtr_iterations: accepted trust-region steps per update (dpgo 3).
        tcg_iterations: truncated-CG iterations per trust-region step (dpgo 50).
        gradient_tolerance: stop the update when ``‖grad f_α‖ <`` this (dpgo 1e-2), or below
            ``relative_gradient_tolerance`` × the team's ``‖grad f‖`` at the start when that is
            smaller (:func:`scaled_local_options`).
        relative_gradient_tolerance: the scale-aware bound above: residuals ``s×`` smaller give
            gradients ``s×`` smaller, and with the absolute 1e-2 alone every robot stopped
            updating on a graph of tiny residuals (``docs/rbcd.md``). 2e-3 keeps 1e-2 on every
            Table I start (the smallest start gradient, csail chordal, is 5.45).
        preconditioner_shift: ``λ`` of the preconditioner ``Q_αα + λI`` (dpgo 0.1; on m3500
            with 7 robots 1e-3 and 1e-5 converged no faster per round).
    """

    rtr_iterations: int = 1
    tcg_iterations: int = 10
    gradient_tolerance: float = 1e-2
    relative_gradient_tolerance: float = 2e-3
    preconditioner_shift: float = PRECONDITIONER_SHIFT


def scaled_local_options(options: RBCDOptions, start_gradient: float) -> RBCDOptions:
    """``options`` with the local gradient tolerance ``min(gradient_tolerance,
    relative_gradient_tolerance × start_gradient)`` (``start_gradient`` = ``‖grad f(X₀)‖``)."""
    local = options.local
    tolerance = min(local.gradient_tolerance, local.relative_gradient_tolerance * start_gradient)
    return dataclasses.replace(
        options, local=dataclasses.replace(local, gradient_tolerance=tolerance)
    )


class _PerRobot:
    """Per-robot reductions and broadcasts over a class's poses (robot ``robot_of_pose[i]``
    owns pose ``i``): the vectorised tCG / RTR keep one scalar per robot."""

    def __init__(self, robot_of_pose: np.ndarray, num_robots: int) -> None:
        self.owner, self.count = robot_of_pose, num_robots

    def inner(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``⟨a_α, b_α⟩`` per robot, ``(k,)``, for ``a``, ``b`` ``(n_c, 3, r)``."""
        if self.count == 1:
            return np.array([np.vdot(a, b)])
        return np.bincount(self.owner, np.einsum("nkr,nkr->n", a, b), minlength=self.count)

    def spread(self, values: np.ndarray) -> np.ndarray:
        """Per-robot ``(k,)`` values broadcastable against ``(n_c, 3, r)`` (one robot: the
        ``(1,)`` array itself)."""
        return values if self.count == 1 else values[self.owner][:, None, None]


def truncated_cg(
    gradient: np.ndarray,
    preconditioned_gradient: np.ndarray,
    hessian: Callable[[np.ndarray], np.ndarray],
    precondition: Callable[[np.ndarray], np.ndarray],
    radius: np.ndarray,
    max_iterations: int,
    active: np.ndarray,
    robots: _PerRobot,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Preconditioned Steihaug–Toint truncated CG for ``min ⟨g,η⟩ + ½⟨η,Hη⟩``, ``‖η‖_P ≤ Δ``
    (Absil, Mahony & Sepulchre 2008, Alg. 11; the trust region in the preconditioner's norm),
    run for every robot of a class at once: all scalars (step, radius, stopping) are per robot
    ``(k,)``; ``H`` and ``P`` are block diagonal over the robots, so the robots' iterations are
    independent and each stops on its own test (a stopped robot's iterate is frozen).

    Args:
        gradient: ``g`` ``(n_c, 3, r)``; preconditioned_gradient: ``P⁻¹g`` (projected).
        radius: ``Δ`` per robot ``(k,)``.
        active: ``(k,)`` robots that run; the others return ``η = 0``.

    Returns:
        ``(η, Hη, hit_boundary (k,), hessian_products (k,))``.
    """
    eta = np.zeros_like(gradient)
    h_eta = np.zeros_like(gradient)
    residual = gradient.copy()
    r_z = robots.inner(residual, preconditioned_gradient)
    delta = -preconditioned_gradient
    e_pe, e_pd, d_pd = np.zeros_like(r_z), np.zeros_like(r_z), r_z  # ‖η‖²_P, ⟨η,δ⟩_P, ‖δ‖²_P
    initial_norm = np.sqrt(robots.inner(residual, residual))
    stop_norm = initial_norm * np.minimum(initial_norm, 0.1)  # ‖r₀‖ min(‖r₀‖^θ, κ), θ=1, κ=0.1
    running = active.copy()
    hit_boundary = np.zeros_like(active)
    products = np.zeros(active.shape, dtype=np.int64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for iteration in range(max_iterations):
            h_delta = hessian(delta)
            products += running
            curvature = robots.inner(delta, h_delta)
            alpha = np.where(curvature > 0, r_z / curvature, np.inf)
            e_pe_next = e_pe + 2.0 * alpha * e_pd + alpha**2 * d_pd
            boundary = running & ((curvature <= 0) | ~(e_pe_next < radius**2))
            tau = (-e_pd + np.sqrt(e_pd**2 + d_pd * (radius**2 - e_pe))) / d_pd
            running &= ~boundary
            hit_boundary |= boundary
            step = np.where(boundary, tau, np.where(running, alpha, 0.0))
            eta += robots.spread(step) * delta
            h_eta += robots.spread(step) * h_delta
            if iteration == max_iterations - 1:  # η is final: no next residual or direction
                break
            residual += robots.spread(np.where(running, alpha, 0.0)) * h_delta
            e_pe = np.where(running, e_pe_next, e_pe)
            running &= np.sqrt(robots.inner(residual, residual)) > stop_norm
            if not running.any():
                break
            z = precondition(residual)
            r_z_next = robots.inner(residual, z)
            beta = np.where(running, r_z_next / r_z, 0.0)
            r_z = np.where(running, r_z_next, r_z)
            delta = -z + robots.spread(beta) * delta
            e_pd = np.where(running, beta * (e_pd + alpha * d_pd), e_pd)
            d_pd = np.where(running, r_z + beta**2 * d_pd, d_pd)
    return eta, h_eta, hit_boundary, products


class LocalStep(NamedTuple):
    """The outcome of :func:`local_update`: the new ``Z`` ``(n_c, 3, r)``, the change of ``QX``
    on the class's ``reach_rows`` ``(m, r)``, and each robot's Hessian–vector products ``(k,)``
    (its work)."""

    z: np.ndarray
    q_change: np.ndarray
    products: np.ndarray


def local_update(
    block: ClassBlock, z: np.ndarray, euclidean: np.ndarray, options: LocalOptions
) -> LocalStep:
    """Every robot α of the class runs RTR on ``f_α(Z) = ½⟨Z, Q_αα Z⟩ + ⟨Z, G_α⟩`` from ``z``
    ``(n_c, 3, r)``, given its Euclidean gradient there, ``euclidean = Q_αα Z + G_α`` (the
    class's rows of ``QY``), ``(n_c, 3, r)``; vectorised over the class with per-robot trust
    regions, acceptance and stopping (the robots are independent).

    **Local update** (dpgo ``PGOAgent::updateX``): with neighbours fixed, robot α minimises
    ``f_α(Z) = ½⟨Z, Q_αα Z⟩ + ⟨Z, G_α⟩`` over ``(St(2, r) × R^r)^{n_α}`` by Riemannian
    trust-region Newton steps with truncated (Steihaug–Toint) CG, preconditioned by a cached sparse
    Cholesky factor of ``Q_αα + λI`` (dpgo's preconditioner); by default one accepted step with ≤ 10
    tCG iterations (dpgo: 3 steps, ≤ 50; see :class:`LocalOptions`). The linear term ``G_α`` only
    needs the neighbours' separator poses, and is never formed: the update starts from the gradient
    ``∇f_α(Z) = (QY)_α`` the round already has, and a candidate step ``Δ`` is judged by
    ``f_α(Z + Δ) − f_α(Z) = ⟨Δ, ∇f_α(Z)⟩ + ½⟨Δ, Q_αα Δ⟩`` from one sparse product with the class's
    columns of ``Q`` (which also gives the change of the neighbours' ``QX``), so a robot update
    costs its tCG iterations (one Hessian product and one preconditioner solve each, none after the
    last) plus one product per trust-region step.

    Costs are tracked relative to ``f_α(z)``: a step ``Δ`` costs
    ``f_α(Z + Δ) − f_α(Z) = ⟨Δ, ∇f_α(Z)⟩ + ½⟨Δ, Q_αα Δ⟩`` and moves the gradient by ``Q_αα Δ``,
    so each candidate needs one sparse product, ``reach · Δ``, whose own rows are ``Q_αα Δ`` and
    whose other rows are the change of the neighbours' ``QX`` (neither ``G_α`` nor ``f_α``
    itself is ever formed).

    Each robot runs until ``options.rtr_iterations`` steps were accepted, its gradient norm
    falls below ``options.gradient_tolerance``, or ``MAX_REJECTIONS`` steps were rejected (each
    rejection shrinks its radius ×¼, as dpgo does). Its first radius is 10 × the P-norm of its
    preconditioned gradient.
    """
    robots = block.per_robot
    rank = z.shape[-1]

    def precondition(point: np.ndarray, v: np.ndarray) -> np.ndarray:
        return project_tangent(point, block.preconditioner.solve(v))

    q_change = np.zeros((block.reach_rows.size, rank))
    radius = np.full(block.num_robots, np.inf)
    accepted = np.zeros(block.num_robots, dtype=np.int64)
    rejected = np.zeros_like(accepted)
    products = np.zeros_like(accepted)
    pending = np.ones(block.num_robots, dtype=bool)
    moved = pending
    while True:
        if moved.any():  # the gradient, its preconditioned version and Λ at the new point
            gradient = riemannian_gradient(z, euclidean)
            pending &= np.sqrt(robots.inner(gradient, gradient)) >= options.gradient_tolerance
            if not pending.any():
                break
            preconditioned = precondition(z, gradient)
            first = ~np.isfinite(radius)
            p_norm = np.sqrt(np.maximum(robots.inner(preconditioned, gradient), 0.0))
            radius[first] = 10.0 * p_norm[first]
            lam = multipliers(z, euclidean)
            point = z
        eta, h_eta, hit_boundary, used = truncated_cg(
            gradient,
            preconditioned,
            lambda v, point=point, lam=lam: riemannian_hessian(block.hessian, point, lam, v),
            lambda v, point=point: precondition(point, v),
            radius,
            options.tcg_iterations,
            pending,
            robots,
        )
        products += used
        model_decrease = -(robots.inner(gradient, eta) + 0.5 * robots.inner(eta, h_eta))
        step = np.where(robots.spread(pending), retract(z, eta) - z, 0.0)
        reach_step = block.reach @ flat(step)
        q_step = reach_step[block.own_in_reach].reshape(step.shape)  # Q_cc Δ
        decrease = -robots.inner(step, euclidean + 0.5 * q_step)
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = np.where(model_decrease > 0, decrease / model_decrease, -np.inf)
        radius = np.where(pending & (rho < 0.25), radius / 4.0, radius)
        radius = np.where(pending & (rho > 0.75) & hit_boundary, radius * 2.0, radius)
        moved = pending & (rho > 1e-4) & (decrease > 0)
        if np.array_equal(moved, pending):  # every robot that stepped moved
            q_change += reach_step
        else:
            step = np.where(robots.spread(moved), step, 0.0)
            reach_step = block.reach @ flat(step)
            q_step = reach_step[block.own_in_reach].reshape(step.shape)
            q_change += reach_step
        z = z + step
        euclidean = euclidean + q_step
        accepted += moved
        rejected += pending & ~moved
        pending &= (accepted < options.rtr_iterations) & (rejected < MAX_REJECTIONS)
        if not pending.any():
            break
    return LocalStep(z, q_change, products)


def robot_shares(block: ClassBlock, elapsed_s: float, products: np.ndarray) -> np.ndarray:
    """Split the measured time ``elapsed_s`` [s] of a batched class update among its robots in
    proportion to their work, ``nnz(Q_αα) × (Hessian–vector products + 1)`` (each product is
    one sparse multiply, one preconditioner solve of similar fill and a few vector operations on
    the robot's rows; the ``+ 1`` is the gradient and cost evaluation every update does).
    Returns ``(k,)`` seconds: what each robot would have spent computing alone."""
    work = block.robot_nnz * (products + 1.0)
    return elapsed_s * work / work.sum()


# ----- the block-coordinate iteration ----------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class RBCDOptions:
    """How RBCD runs.

    Attributes:
        accelerated: Nesterov acceleration (RBCD++).
        restart: ``"fixed"`` (every ``restart_interval`` iterations, dpgo / cc-pgo) or
            ``"adaptive"`` (when the objective increases, ml-pgo).
        restart_interval: period of the fixed restart.
        selection: ``"greedy"`` (colour class with the largest gradient norm) or
            ``"round-robin"``.
        local: the robots' trust-region settings.
        batch_below: robots of a class with fewer poses than this update together as one
            block-diagonal batch, the others one by one (see :func:`batch_groups`).
        rounding: ``"svd"`` (SE-Sync's, the default) or ``"anchor"`` (dpgo's); see
            :func:`rounding_basis`.
    """

    accelerated: bool = True
    restart: str = "fixed"
    restart_interval: int = RESTART_INTERVAL
    selection: str = "greedy"
    local: LocalOptions = LocalOptions()
    batch_below: int = BATCH_BELOW_POSES
    rounding: str = "svd"


@dataclasses.dataclass(frozen=True)
class RBCDRun:
    """The outcome of :func:`run_rbcd`: the best ``x`` seen ``(N, 3, r)``, ``history`` (``2f`` per
    round, first entry the start), rounds run, simulated makespan [s], separator poses sent,
    momentum restarts, and ``history_s``: the makespan [s] at each ``history`` entry (0 first,
    ``parallel_s`` last)."""

    x: np.ndarray
    history: np.ndarray
    iterations: int
    parallel_s: float
    messages: int
    restarts: int
    history_s: np.ndarray


class _Update(NamedTuple):
    """One block round: the new ``X`` and ``QX``, the poses that moved, the slowest and summed
    robot update times [s], and the separator poses the updated robots send."""

    x: np.ndarray
    q_x: np.ndarray
    poses: np.ndarray
    slowest_s: float
    robots_s: float
    separators: int


class _Rounds:
    """One block round: select a colour class at ``Y`` and update its robots in parallel.

    ``batches[c]`` holds colour class ``c``'s robots as :class:`ClassBlock` s: one block of all
    of them (robots below ``RBCDOptions.batch_below`` poses, :func:`batch_groups`) or one per
    robot."""

    def __init__(self, batches: list[list[ClassBlock]], options: RBCDOptions) -> None:
        self.batches, self.options = batches, options
        self.class_poses = [np.concatenate([b.poses for b in blocks]) for blocks in batches]
        self.class_separators = [sum(b.separators for b in blocks) for blocks in batches]
        self.class_of_pose = np.empty(sum(p.size for p in self.class_poses), dtype=np.int64)
        for colour, poses in enumerate(self.class_poses):
            self.class_of_pose[poses] = colour

    def select(self, y: np.ndarray, q_y: np.ndarray, iteration: int) -> int:
        if self.options.selection == "round-robin":
            return iteration % len(self.batches)
        scores = np.bincount(
            self.class_of_pose, pose_gradient_norms(y, q_y), minlength=len(self.batches)
        )
        return int(np.argmax(scores))

    def update(self, y: np.ndarray, q_y: np.ndarray, iteration: int) -> _Update:
        """The robots of the selected class minimise their local problems at ``Y`` (``QY``
        given); the other robots keep ``Y``. Each block's measured time is split among its
        robots by :func:`robot_shares` (a one-robot block keeps its own time)."""
        colour = self.select(y, q_y, iteration)
        x_new, q_x_new = y.copy(), q_y.copy()
        slowest_s = robots_s = 0.0
        for block in self.batches[colour]:
            start = time.perf_counter()
            step = local_update(block, y[block.poses], q_y[block.poses], self.options.local)
            x_new[block.poses] = step.z
            flat(q_x_new)[block.reach_rows] += step.q_change
            elapsed_s = time.perf_counter() - start
            slowest_s = max(slowest_s, float(robot_shares(block, elapsed_s, step.products).max()))
            robots_s += elapsed_s
        return _Update(
            x_new,
            q_x_new,
            self.class_poses[colour],
            slowest_s,
            robots_s,
            self.class_separators[colour],
        )


def run_rbcd(
    q: sp.csr_matrix,
    batches: list[list[ClassBlock]],
    num_robots: int,
    x0: np.ndarray,
    budget: Budget,
    options: RBCDOptions,
    initial_cost: float | None = None,
) -> RBCDRun:
    """RBCD / RBCD++ from ``x0`` ``(N, 3, r)`` for ``budget.iterations`` rounds (or until
    ``budget.seconds``); one round as in the module docstring (one colour class updates).

    **Acceleration** (RBCD++, REFERENCES §2.4), with ``B`` blocks (colour classes):
    ``γ ← (1 + √(1 + 4B²γ²)) / (2B)``, ``α ← 1/(γB)``, ``Y ← Proj((1−α)X + αV)``, the selected block
    ``X_b ← LocalOpt(Y)`` (others ``X ← Y``), ``V ← Proj(V + γ(X − Y))``. Restart ("fixed", cc-pgo):
    every ``restart_interval`` (30) iterations a plain update from ``X`` and ``V = X``, ``γ = 0``;
    ("adaptive", ml-pgo, §4.1): whenever the objective increases by more than a relative
    ``ADAPTIVE_RESTART_TOLERANCE`` (1e-9 of ``f``), the iteration is redone as a plain update from
    ``X`` and the momentum reset. The tolerance ignores increases at the level of the floating-point
    error of ``f`` near convergence (measured: docs/rbcd.md). ``f(x0)`` is ``initial_cost`` (e.g.
    :func:`edge_relaxed_cost`; default ``½⟨X, QX⟩``) and each round adds :func:`cost_change`, so
    the rule compares changes accurate to their own size, not to ``⟨|X|, |Q||X|⟩``. Returns the
    iterate with the lowest ``f`` seen.

    **Accounting.** ``parallel_s`` = Σ over rounds of (the slowest updating robot's local update
    time + the round's vectorised bookkeeping — extrapolation, gradient norms, objective — divided
    by the number of robots, as each robot would do its share). A robot's local update time is
    modelled from the batched update: a robot updating alone keeps its measured time; a batch's
    measured time is split among its robots in proportion to their work
    ``nnz(Q_αα) × (Hessian–vector products + 1)`` (:func:`robot_shares`).
    ``messages`` = Σ over rounds of the separator poses (poses with an edge to another robot) of
    every robot whose estimate changed that round (all robots in an accelerated round, the updated
    class in a plain one). ``history[k]`` = ``2 f(X_k)``, the relaxation's F_chordal after round
    ``k`` (``history[0]`` at the start); the rounded estimate's F / F_chordal are evaluated once,
    at the end. ``history_s[k]`` = ``parallel_s`` after round ``k``.
    """
    start = time.perf_counter()
    rounds = _Rounds(batches, options)
    num_blocks = len(batches)
    all_separators = sum(rounds.class_separators)
    x, q_x = x0, apply_q(q, x0)
    cost = relaxed_cost(x, q_x) if initial_cost is None else initial_cost
    v, gamma = x, 0.0
    history, history_s = [2.0 * cost], [0.0]
    best_x, best_cost = x, cost
    parallel_s, messages, restarts, iteration = 0.0, 0, 0, 0
    while iteration < budget.iterations:
        if budget.seconds is not None and time.perf_counter() - start > budget.seconds:
            break
        iteration += 1
        round_start = time.perf_counter()
        fixed_restart = options.restart == "fixed" and iteration % options.restart_interval == 0
        plain = not options.accelerated or fixed_restart
        if plain:
            update = rounds.update(x, q_x, iteration)
            messages += update.separators
        else:  # RBCD++ (§2.4): γ ← (1 + √(1 + 4B²γ²)) / (2B), α ← 1/(γB), B = num_blocks
            gamma = (1.0 + np.sqrt(1.0 + 4.0 * num_blocks**2 * gamma**2)) / (2.0 * num_blocks)
            alpha = 1.0 / (gamma * num_blocks)
            y = project_manifold((1.0 - alpha) * x + alpha * v)  # Y ← Proj((1−α)X + αV)
            update = rounds.update(y, apply_q(q, y), iteration)
            moved = update.poses  # elsewhere X_new = Y, so V (on the manifold) keeps its value
            v = v.copy()
            v[moved] = project_manifold(v[moved] + gamma * (update.x[moved] - y[moved]))
            messages += all_separators
        slowest_s, robots_s = update.slowest_s, update.robots_s
        cost_new = cost + cost_change(x, q_x, update.x, update.q_x)
        restart = options.accelerated and plain
        increased = cost_new > cost + ADAPTIVE_RESTART_TOLERANCE * abs(cost)
        if options.accelerated and not plain and options.restart == "adaptive" and increased:
            update = rounds.update(x, q_x, iteration)  # redo the round without momentum
            slowest_s, robots_s = slowest_s + update.slowest_s, robots_s + update.robots_s
            messages += update.separators
            cost_new = cost + cost_change(x, q_x, update.x, update.q_x)
            restart = True
        if restart:
            v, gamma = update.x, 0.0
            restarts += 1
        x, q_x, cost = update.x, update.q_x, cost_new
        if cost < best_cost:
            best_x, best_cost = x, cost
        history.append(2.0 * cost)
        budget.round_done(iteration)
        shared_s = time.perf_counter() - round_start - robots_s
        parallel_s += slowest_s + shared_s / num_robots
        history_s.append(parallel_s)
    return RBCDRun(
        best_x,
        np.asarray(history),
        iteration,
        parallel_s,
        messages,
        restarts,
        np.asarray(history_s),
    )


# ----- the method: initialise, iterate, round, report --------------------------------------------


def solve_rbcd(
    graph: PoseGraph,
    robots: np.ndarray,
    budget: Budget,
    options: RBCDOptions,
    rank: int,
    certify: bool,
    seed: int,
) -> Result:
    """Run RBCD on ``graph`` split by ``robots`` ``(N,)`` and round the result.

    Args:
        graph: the global pose graph; ``graph.poses`` is the start (lifted to rank ``r``) and
            ``graph.poses[0]`` fixes the gauge of the output.
        robots: ``(N,)`` vertex → robot assignment (the blocks).
        budget: rounds (one colour class each) and an optional wall-clock cap.
        options: acceleration, restart and local-solver settings.
        rank: ``r ≥ 2`` of the relaxation (dpgo 5).
        certify: also compute ``λ_min`` of the certificate (``extras["certificate_min_eig"]``).
        seed: seeds the random lifting matrix ``St(2, r)``.

    Returns:
        The :class:`~popbench.methods.Result`; ``history`` holds the relaxation's ``2f``
        (F_chordal of the rank-r iterate) per round, ``F``/``F_chordal``/``chi2`` are those of
        the rounded poses. ``parallel_s`` includes the lifting of the start and
        ``1/n`` of the setup (Q, blocks, factorisations, which each robot does for itself);
        ``history_s`` is that set-up time plus the rounds' makespan so far (last: ``parallel_s``).
    """
    if rank < 2:
        raise ValueRangeError("rank", rank, "an integer ≥ 2")
    if options.rounding not in ROUNDINGS:  # before the rounds, not after them
        raise ValueRangeError("rounding", options.rounding, " or ".join(ROUNDINGS))
    start = time.perf_counter()
    x0 = lift(graph.poses, random_stiefel(rank, seed))
    initialised = time.perf_counter()
    q = connection_laplacian(graph)
    classes = colour_robots(graph, robots)
    sizes = np.bincount(robots)
    groups = [batch_groups(members, sizes, options.batch_below) for members in classes]
    shift = options.local.preconditioner_shift
    batches = [class_blocks(q, graph, robots, group, shift) for group in groups]
    num_robots = int(robots.max()) + 1
    setup_s = time.perf_counter() - initialised
    setup_parallel_s = (initialised - start) + setup_s / num_robots
    start_gradient = float(np.sqrt(pose_gradient_norms(x0, apply_q(q, x0)).sum()))
    run_options = scaled_local_options(options, start_gradient)
    run = run_rbcd(q, batches, num_robots, x0, budget, run_options, edge_relaxed_cost(graph, x0))
    anchor = 0  # vertex 0 (owned by robot 0) keeps its estimate: the gauge
    poses = round_solution(run.x, anchor, graph.poses[anchor], options.rounding)
    costs = objective.evaluate(graph, poses)
    wall_s = time.perf_counter() - start
    extras = {
        "rank": rank,
        "colours": len(classes),
        "cut_edges": int(np.count_nonzero(robots[graph.tails] != robots[graph.heads])),
        "restarts": run.restarts,
        "relaxed_F_chordal": float(run.history.min()),  # of the returned (best) iterate
        "gradient_norm": float(np.sqrt(pose_gradient_norms(run.x, apply_q(q, run.x)).sum())),
        "history": "relaxed F_chordal (2f of the rank-r iterate) per round",
        "iteration": "one colour class of non-adjacent robots updates in parallel",
    }
    if certify:
        extras["certificate_min_eig"] = certificate_min_eigenvalue(q, run.x)
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=wall_s,
        parallel_s=setup_parallel_s + run.parallel_s,
        iterations=run.iterations,
        history=run.history,
        messages=run.messages,
        extras=extras,
        history_s=setup_parallel_s + run.history_s,
        history_objective="F_chordal",
    )


@dataclasses.dataclass(frozen=True)
class MethodOptions:
    """The options cc-pgo and ml-pgo share, with their defaults; each method's own options
    (``baselines.cc_pgo.Options``, ``baselines.ml_pgo.Options``, named by their records:
    :attr:`popbench.methods.MethodRecord.options`) add to these fields, which are what
    ``popbench solve -o KEY=VALUE`` accepts.

    Attributes:
        rank: relaxation rank ``r ≥ 2`` (dpgo 5).
        certify: report ``λ_min`` of the optimality certificate in ``extras``.
        seed: seeds the lifting matrix (ml-pgo: its METIS partition too).
        selection: ``"greedy"`` or ``"round-robin"`` colour-class selection.
        rtr_iterations: accepted trust-region steps per robot update (dpgo 3).
        tcg_iterations: truncated-CG iterations per trust-region step (dpgo 50).
        rounding: ``"svd"`` (SE-Sync's rounding, default) or ``"anchor"`` (dpgo's); see
            :func:`rounding_basis`.
    """

    rank: int = 5
    certify: bool = False
    seed: int = 0
    selection: str = "greedy"
    rtr_iterations: int = 1
    tcg_iterations: int = 10
    rounding: str = "svd"

    @classmethod
    def of(cls, options: Mapping[str, object]) -> Self:
        """The fields named in ``options`` (a method's ``**options``), the others at their
        defaults; keys that are not fields are ignored (the harness's common options)."""
        names = {field.name for field in dataclasses.fields(cls)}
        return cls(**{key: value for key, value in options.items() if key in names})  # type: ignore[arg-type]

    def solve(
        self, graph: PoseGraph, robots: np.ndarray, budget: Budget, accelerated: bool, restart: str
    ) -> Result:
        """:func:`solve_rbcd` with these options, RBCD++ or plain RBCD (``accelerated``) and the
        ``restart`` rule (:class:`RBCDOptions`)."""
        local = LocalOptions(rtr_iterations=self.rtr_iterations, tcg_iterations=self.tcg_iterations)
        options = RBCDOptions(
            accelerated, restart, selection=self.selection, local=local, rounding=self.rounding
        )
        return solve_rbcd(graph, robots, budget, options, self.rank, self.certify, self.seed)
