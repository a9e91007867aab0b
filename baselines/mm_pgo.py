"""MM-PGO / AMM-PGO (Fan & Murphey, T-RO 2024): distributed majorisation–minimisation on SE(2).

Method ``"mm-pgo"``; REFERENCES.md §3 and §8. Design notes, measurements and the variants tried
and not kept: docs/mm_pgo.md.

**Objective.** ``F_chordal(X) = Σ_e F_e`` with ``F_e = κ_e‖R_q − R_pR̃_e‖²_F + τ_e‖t_q − t_p −
R_pt̃_e‖²`` (SE-Sync convention; MM-PGO's internal ``f = ½F``). Each ``F_e`` is a convex quadratic
in the *linear coordinates* of the poses, ``(t_i, R_i)`` with ``R_i ∈ R^{2×2}``; the non-convexity
is only the constraint ``R_i ∈ SO(2)``. With the edge residual ``r_e = A_e y_p + B_e y_q`` (the
world-frame translation residual ``t_q − t_p − R_pt̃`` and the rotation residual ``R_q − R_pR̃``,
weighted by ``τ`` and ``κ``), for any two points

    F_e(y) ≤ F_e(yᵏ) + ⟨∇F_e, y − yᵏ⟩ + 2‖A_eδ_p‖² + 2‖B_eδ_q‖²,   δ = y − yᵏ,

because ``‖a + b‖² ≤ 2‖a‖² + 2‖b‖²``. This is MM-PGO's majoriser ``Γ_α`` (REFERENCES §3.3): exact on
intra-robot edges, **2× the edge's weights on the own pose's diagonal block** for inter-robot
edges. Splitting ``F_e(yᵏ)`` in halves, robot α's surrogate is

    G^α(X^α | Xᵏ) = Σ_{e intra} F_e(X^α) + Σ_{e inter} 2 ‖r_e(x_i, x_jᵏ) − ½ r_e(xᵏ)‖²_W    (1)

(``i`` its own end, ``j`` the neighbour's, ``‖·‖²_W`` the κ/τ-weighted norm), so that
``Σ_α G^α(X^α | Xᵏ) ≥ F(X)`` with equality at ``Xᵏ``, and the robots' subproblems are independent
given the neighbours' poses of the previous iterate (Jacobi: all robots update in parallel).

Where the rest is stated, beside the code that computes it: the node update (one Gauss–Newton
rotation step on (1), exact translation recovery, safeguard) at :meth:`TeamSystem.plain_step`;
the Hessian refresh at :meth:`TeamSystem.hessian_drift`; the AMM-PGO extrapolation and restarts
at :class:`RestartState`; the robust reweighting at :func:`edge_weights`; the batched team system
at :class:`TeamSystem`; the accounting (``parallel_s``, ``messages``, ``history``) at
:func:`solve`. The gauge is free in a team, as in MM-PGO's own code
(:func:`gauge_anchors`). Without a robust kernel the
returned estimate is the iterate of lowest F seen (never above the start; docs/mm_pgo.md).
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType

from baselines import robust
from popbench import objective, se2
from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph
from popbench.methods import Budget, Result
from popbench.outliers import precision_recall


@dataclasses.dataclass(frozen=True)
class RobustMode:
    """Where a robust kernel acts and its default scale (:mod:`baselines.robust`).

    Attributes:
        kinds: the edge kinds under the kernel (the others keep weight 1, are never flagged).
        scale: the kernel scale ``c`` used when ``kernel_scale`` is not given.
    """

    kinds: tuple[EdgeKind, ...]
    scale: float


ROBUST_MODES: dict[str, RobustMode] = {
    # MM-PGO's own code: the kernel on the inter-node edges only (DPGOProblem::evaluate_E over
    # the inter-node incidence mB_[1]: cut odometry and inter-robot loop closures), c = 0.25.
    "authors": RobustMode((EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP), robust.AUTHORS_SCALE),
    # The project's earlier reading: intra-robot loop closures too, c = χ²₃(0.99).
    "project": RobustMode(
        (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP), robust.DEFAULT_SCALE
    ),
}

# Adaptive restart of AMM-PGO (REFERENCES §3.5).
ETA_SLOW, ETA_FAST = 5e-4, 2.5e-2
MAX_SOFT_HITS_AVERAGE, MAX_SOFT_HITS_INCREASE = 10, 25
BACKTRACKING_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0)
TWO_PI = 2.0 * np.pi
REGULARISER = 1e-10  # ξ, relative to the largest diagonal entry (MM-PGO's regularizer)


# ----- per-edge terms (vectorised over edges) ------------------------------------------------


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


class Update(NamedTuple):
    """A team update: the new poses, their edge terms and edge costs ``(M,)`` (at the
    current, robust-weighted, weights)."""

    poses: PoseTable
    terms: EdgeTerms
    costs: np.ndarray


# ----- acceleration state --------------------------------------------------------------------


@dataclasses.dataclass
class RestartState:
    """The team's acceleration / adaptive-restart state (REFERENCES §3.5).

    **Acceleration** (AMM-PGO, REFERENCES §3.5): ``s_{k+1} = ½ + ½√(4s_k² + 1)``,
    ``γ_k = (s_k − 1)/s_{k+1}``, ``Y = Xᵏ ⊕ γ_k(Xᵏ ⊖ Xᵏ⁻¹)`` (translations linearly, headings by the
    wrapped difference; each robot extrapolates its own and its neighbours' poses, which it holds
    from the last two exchanges), candidate = node update from ``Y`` without the safeguard. With
    ``F_k = F(Xᵏ)`` and ``G = Σ_α G^α(candidate | Xᵏ) ≥ F(candidate)``: ``F̄₀ ← (1−η₀)F̄₀ + η₀F_k``
    (η₀ = 5e-4), ``F̄₁ ← max(F_k, (1−η₁)F̄₁ + η₁F_k)`` (η₁ = 2.5e-2); a **hard restart** when
    ``G > F̄₀``, a **soft restart** when ``G > F̄₁`` and counter₀ ≥ 10, or ``G > F_{k}`` and
    counter₁ > 25 (counter₀ −2 when ``F_k ≤ F̄₁`` else +1; counter₁ reset when ``F`` decreased else
    +1). A restart replaces every robot's candidate by its safeguarded plain step from ``Xᵏ``; a
    hard one also sets ``s ← max(s/2, 1)``; both divide counter₀ by 3 and reset counter₁. The rules
    are applied to team sums (two scalars all-reduced per iteration, as AMM-PGO* with its master
    node), not per robot as in AMM-PGO# (the per-robot rule oscillated: docs/mm_pgo.md).

    *Deviation (odometry starts):* after each update ``F̄₀ ← min(F̄₀, F̄₁)``. §3.5 initialises
    ``F̄₀`` at the first ``F``; with η₀ = 5e-4 it then stays near that ``F`` for thousands of
    iterations, so from a start orders of magnitude above the optimum (odometry) the hard restart
    never fired. Capped by the fast average, ``F̄₀`` follows the actual ``F`` down. Measurements and
    the alternatives not kept: docs/mm_pgo.md.
    """

    s: float = 1.0
    average_slow: float = np.inf  # F̄₀
    average_fast: float = np.inf  # F̄₁
    hits_average: int = 0  # counter₀
    hits_increase: int = 0  # counter₁
    previous_objective: float = np.inf  # F(Xᵏ⁻¹)

    def observe(self, value: float) -> None:
        """Update counters and running averages with ``F_k = F(Xᵏ)``."""
        if not np.isfinite(self.average_slow):
            self.average_slow = self.average_fast = value
        if value <= self.average_fast:
            self.hits_average = max(self.hits_average - 2, 0)
        else:
            self.hits_average += 1
        self.hits_increase = 0 if value <= self.previous_objective else self.hits_increase + 1
        self.previous_objective = value
        self.average_slow = (1.0 - ETA_SLOW) * self.average_slow + ETA_SLOW * value
        self.average_fast = max(value, (1.0 - ETA_FAST) * self.average_fast + ETA_FAST * value)
        # F̄₀ capped by F̄₁: from a start far above the optimum (odometry) the slow average
        # would stay near F₀ for thousands of iterations and never trigger a hard restart.
        self.average_slow = min(self.average_slow, self.average_fast)

    def restart(self, surrogate: float) -> str | None:
        """``"hard"``, ``"soft"`` or None for candidates whose summed surrogate value is
        ``surrogate`` (call after :meth:`observe`)."""
        if surrogate > self.average_slow:
            return "hard"
        if (surrogate > self.average_fast and self.hits_average >= MAX_SOFT_HITS_AVERAGE) or (
            surrogate > self.previous_objective and self.hits_increase > MAX_SOFT_HITS_INCREASE
        ):
            return "soft"
        return None


# ----- fixed-pattern sparse assembly ---------------------------------------------------------


class SparsePattern(NamedTuple):
    """CSC structure of a square matrix summed from COO entries given in a fixed order.

    ``slots[k]``: the position in the CSC data of entry ``k`` (``nnz`` for a dropped entry, in
    a row or column of a pinned unknown); ``diagonal``: the positions of the diagonal entries.
    """

    size: int
    indptr: np.ndarray
    indices: np.ndarray
    slots: np.ndarray
    diagonal: np.ndarray
    pinned: np.ndarray


def sparse_pattern(
    rows: np.ndarray, cols: np.ndarray, size: int, pinned: np.ndarray
) -> SparsePattern:
    """The :class:`SparsePattern` of entries at ``(rows, cols)`` ``(K,)`` of a ``size × size``
    matrix, plus its whole diagonal; entries in a row or column of a ``pinned`` unknown
    (indices) are dropped (:func:`assemble` puts 1 on their diagonal)."""
    is_pinned = np.zeros(size, dtype=bool)
    is_pinned[pinned] = True
    keep = ~(is_pinned[rows] | is_pinned[cols])
    kept = int(keep.sum())
    diagonal = np.arange(size, dtype=np.int64)
    keys = np.concatenate([cols[keep] * size + rows[keep], diagonal * size + diagonal])
    unique, inverse = np.unique(keys, return_inverse=True)  # column-major order = CSC order
    slots = np.full(rows.size, unique.size, dtype=np.int64)
    slots[keep] = inverse[:kept]
    indptr = np.zeros(size + 1, dtype=np.int64)
    np.cumsum(np.bincount(unique // size, minlength=size), out=indptr[1:])
    return SparsePattern(size, indptr, unique % size, slots, inverse[kept:], np.asarray(pinned))


def assemble(pattern: SparsePattern, values: np.ndarray) -> sp.csc_matrix:
    """The matrix of ``pattern`` with entry values ``values`` ``(K,)`` (duplicates summed), plus
    ``ξ·max diag`` on the diagonal (MM-PGO's regulariser) and 1 on pinned diagonals."""
    nnz = pattern.indices.size
    data = np.bincount(pattern.slots, weights=values, minlength=nnz + 1)[:nnz]
    data[pattern.diagonal] += REGULARISER * data[pattern.diagonal].max()
    data[pattern.diagonal[pattern.pinned]] = 1.0
    return sp.csc_matrix((data, pattern.indices, pattern.indptr), shape=(pattern.size,) * 2)


class CholeskyFactor:
    """Sparse Cholesky factor of a symmetric positive-definite CSC matrix (cholespy: an
    AMD-ordered supernodal factorisation; its solves measured 3–4× faster than SuperLU's on
    these systems, its factorisations as fast)."""

    def __init__(self, matrix: sp.csc_matrix) -> None:
        self._solver = CholeskySolverD(
            matrix.shape[0],
            matrix.indptr.astype(np.int32),
            matrix.indices.astype(np.int32),
            np.ascontiguousarray(matrix.data),
            MatrixType.CSC,
        )

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` for ``rhs`` ``(n,)`` or ``(n, k)``."""
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        solution = np.empty_like(rhs)
        self._solver.solve(rhs, solution)
        return solution


# ----- the team's stacked subproblems --------------------------------------------------------


class TeamSystem:
    """Every robot's Jacobi subproblem (1), stacked into one block-diagonal system.

    Robot α's unknowns are its owned poses; (1) couples them only to each other (intra edges)
    and to *fixed* copies of neighbours' poses (inter edges), so the robots' Gauss–Newton
    Hessians ``H_α`` and translation Laplacians ``L_α`` are the diagonal blocks of one
    ``3N × 3N`` (``N × N``) matrix over all poses, and one factorisation / one solve gives every
    robot exactly its own answer. Edge arrays are global (``M``); an inter edge enters (1)
    twice, once for each endpoint's robot.

    **Batched execution** (:class:`TeamSystem`). The robots' subproblems are independent given
    ``Xᵏ``, so their Hessians / Laplacians are the diagonal blocks of one block-diagonal matrix over
    all poses (no entry couples two robots; tested): per iteration the whole team takes one
    vectorised pass over the global edge arrays, one factorisation (when ``H`` is refreshed) and
    one solve, which give every robot exactly its own update. Matrices are assembled into a fixed
    CSC pattern (precomputed slots, ``np.bincount``); factorisations use cholespy's sparse Cholesky
    (chosen by measurement: docs/mm_pgo.md). Planar quantities are complex numbers (translations
    ``x + iy``, rotations ``e^{iθ}``, residuals), so a rotation of a vector is one complex
    multiply; each pose's ``cos θ, sin θ`` is computed once per iterate (:class:`PoseTable`) and
    gathered by its edges (timings: docs/mm_pgo.md). The backtracking of the safeguard is per robot
    (a failing robot halves only its own step).

    Args:
        graph: the global graph (``graph.robots`` assigned).
        anchors: the vertices held fixed ``(k,)`` (see :func:`gauge_anchors`; empty: a free
            gauge).
    """

    def __init__(self, graph: PoseGraph, anchors: np.ndarray) -> None:
        robots = graph.robots
        self.robots = robots
        self.num_robots = graph.num_robots
        self.num_poses = n = graph.num_poses
        self.edges = e = edge_data(graph.tails, graph.heads, graph.measurements)
        self.inter = robots[e.tails] != robots[e.heads]
        self.intra = ~self.inter
        self.inter_edges = edge_data(
            e.tails[self.inter], e.heads[self.inter], graph.measurements[self.inter]
        )
        self.factor = np.where(self.inter, 2.0, 1.0)  # (1): own-end blocks ×2 on inter edges
        self.inter_index = np.flatnonzero(self.inter)
        self.geometry_at_zero = HessianGeometry(1j * e.t_m, e.rot_m)  # J t̃, R̃
        self.anchors = anchors = np.asarray(anchors, dtype=np.int64).reshape(-1)
        m = e.tails.size
        # Sum of per-edge [tail contributions; head contributions] onto the poses.
        self.scatter = sp.csr_matrix(
            (np.ones(2 * m), (np.concatenate([e.tails, e.heads]), np.arange(2 * m))),
            shape=(n, 2 * m),
        )
        # Robot of each term of (1): intra edges, inter edges' tail terms, their head terms.
        self.term_robots = np.concatenate(
            [
                robots[e.tails[self.intra]],
                robots[self.inter_edges.tails],
                robots[self.inter_edges.heads],
            ]
        )
        # Makespan model: a robot's work = owned poses + local edges (an inter edge counts twice).
        work = np.bincount(self.term_robots, minlength=self.num_robots) + np.bincount(
            robots, minlength=self.num_robots
        )
        self.slowest_share = float(work.max() / work.sum())
        i = self.inter_edges
        pairs = np.unique(
            np.concatenate(
                [
                    i.tails * self.num_robots + robots[i.heads],
                    i.heads * self.num_robots + robots[i.tails],
                ]
            )
        )
        self.messages_per_iteration = int(pairs.size)  # (separator pose, neighbour robot) pairs
        intra_tails, intra_heads = e.tails[self.intra], e.heads[self.intra]
        block_rows = np.concatenate([e.tails, e.heads, intra_tails, intra_heads])
        block_cols = np.concatenate([e.tails, e.heads, intra_heads, intra_tails])
        self.translation_pattern = sparse_pattern(block_rows, block_cols, n, anchors)
        k = np.arange(3)
        rows = np.broadcast_to(
            3 * block_rows[:, None, None] + k[None, :, None], (block_rows.size, 3, 3)
        )
        cols = np.broadcast_to(
            3 * block_cols[:, None, None] + k[None, None, :], (block_rows.size, 3, 3)
        )
        pinned = (3 * anchors[:, None] + k[None, :]).ravel()
        self.hessian_pattern = sparse_pattern(rows.ravel(), cols.ravel(), 3 * n, pinned)
        # Intra edges with an anchor at one end: the other end's row sees its fixed translation.
        is_anchor = np.zeros(n, dtype=bool)
        is_anchor[anchors] = True
        self.anchor_tail = self.intra & is_anchor[e.tails]
        self.anchor_head = self.intra & is_anchor[e.heads]

    # -- weights and factorisations --

    def set_weights(
        self, kappa: np.ndarray, tau: np.ndarray, terms: EdgeTerms | None = None
    ) -> None:
        """Set the (robust-weighted) edge weights ``(M,)``; factorise ``H`` (at the geometry of
        ``terms``, default zero residual) and the translation Laplacian ``L`` (normal equations
        of (1) in the translations)."""
        self.kappa, self.tau = kappa, tau
        self.factorise_hessian(terms)
        self.translation_weight = weight = self.factor * tau
        intra = weight[self.intra]
        values = np.concatenate([weight, weight, -intra, -intra])
        self.translation = CholeskyFactor(assemble(self.translation_pattern, values))
        e = self.edges
        tail, head = self.anchor_tail, self.anchor_head
        self.anchor_coupling = sp.csr_matrix(  # −L[:, anchors] before pinning, (N, N)
            (
                np.concatenate([weight[tail], weight[head]]),
                (
                    np.concatenate([e.heads[tail], e.tails[head]]),
                    np.concatenate([e.tails[tail], e.heads[head]]),
                ),
            ),
            shape=(self.num_poses, self.num_poses),
        )

    def geometry(self, terms: EdgeTerms | None) -> HessianGeometry:
        """The Gauss–Newton geometry of every edge: intra edges at ``terms`` (at zero residual
        for None), inter edges always at zero residual (their terms of (1) are quadratic in
        linear coordinates)."""
        if terms is None:
            return self.geometry_at_zero
        e, intra, zero = self.edges, self.intra, self.geometry_at_zero
        # J R_pᵀ(t_q − t_p) = J(R_pᵀw + t̃) and R(θ_q − θ_p) = R_pᵀR_q on intra edges.
        lever = 1j * (terms.rot_p.conj() * terms.t + e.t_m)
        relative = terms.rot_p.conj() * terms.rot_q
        return HessianGeometry(
            np.where(intra, lever, zero.lever), np.where(intra, relative, zero.relative)
        )

    def hessian_drift(self, terms: EdgeTerms) -> float:
        """The largest :func:`jacobian_drift` over the edges between the geometry ``H`` was
        factorised at and that of ``terms``.

        *Hessian refresh.* ``H`` depends on the iterate only through each intra edge's lever
        ``J R_pᵀ(t_q − t_p)`` and relative rotation ``R(θ_q − θ_p)``, i.e. through the translation
        residual's Jacobian ``J_e = [−I, −lever | R(φ), 0]``. Every ``hessian_interval`` (10)
        iterations the largest relative change ``‖J_e − J_e⁰‖_F / ‖J_e⁰‖_F`` since the last
        factorisation is measured (O(M)) and ``H`` is refactorised when it exceeds
        ``hessian_tolerance`` (0.02); ``hessian_tolerance=0`` refactorises every
        ``hessian_interval`` iterations (the former rule). Measurements behind the 0.02:
        docs/mm_pgo.md.
        """
        return float(jacobian_drift(self.geometry(terms), self.hessian_geometry).max())

    def factorise_hessian(self, terms: EdgeTerms | None) -> None:
        """Factorise ``H = ⊕_α H_α`` at :meth:`geometry` of ``terms`` (own-end blocks of inter
        edges ×2)."""
        self.hessian_geometry = self.geometry(terms)
        tt, th, hh = gauss_newton_blocks(self.hessian_geometry, self.kappa, self.tau)
        factor, intra = self.factor[:, None, None], self.intra
        values = np.concatenate(
            [
                (factor * tt).ravel(),
                (factor * hh).ravel(),
                th[intra].ravel(),
                np.swapaxes(th[intra], 1, 2).ravel(),
            ]
        )
        self.hessian = CholeskyFactor(assemble(self.hessian_pattern, values))

    # -- evaluations --

    def shares(self, costs: np.ndarray) -> np.ndarray:
        """Each robot's share ``(R,)`` of ``F = Σ costs`` (edge costs ``(M,)``): its intra
        costs + ½ of its inter ones; ``G^α(Xᵏ | Xᵏ)``."""
        halves = 0.5 * costs[self.inter]
        return np.bincount(
            self.term_robots,
            weights=np.concatenate([costs[self.intra], halves, halves]),
            minlength=self.num_robots,
        )

    def inter_terms(
        self, poses: np.ndarray | PoseTable, base_poses: np.ndarray | PoseTable, base: EdgeTerms
    ) -> tuple[np.ndarray, np.ndarray]:
        """The inter edges' terms of (1) ``(M_inter,)`` for their tails' robots and for their
        heads' robots: the robot's own end at ``poses``, the neighbour's copy at ``base_poses``
        (edge terms ``base``)."""
        i, inter = self.inter_edges, self.inter_index
        poses, base_poses = pose_table(poses), pose_table(base_poses)
        kappa, tau = self.kappa[inter], self.tau[inter]
        base_inter = select(base, inter)
        own_tail = shifted_costs(edge_terms(poses, i, base_poses), base_inter, kappa, tau)
        own_head = shifted_costs(edge_terms(base_poses, i, poses), base_inter, kappa, tau)
        return own_tail, own_head

    def surrogates(
        self,
        poses: np.ndarray | PoseTable,
        costs: np.ndarray,
        base_poses: np.ndarray | PoseTable,
        base: EdgeTerms,
    ) -> np.ndarray:
        """``G^α(poses | base_poses)`` of every robot ``(R,)``, eq. (1): intra edges at
        ``poses`` (edge costs ``costs`` ``(M,)``), inter edges by :meth:`inter_terms`."""
        own_tail, own_head = self.inter_terms(poses, base_poses, base)
        return np.bincount(
            self.term_robots,
            weights=np.concatenate([costs[self.intra], own_tail, own_head]),
            minlength=self.num_robots,
        )

    def surrogate_total(
        self, poses: PoseTable, costs: np.ndarray, base_poses: PoseTable, base: EdgeTerms
    ) -> float:
        """``Σ_α G^α(poses | base_poses)`` (arguments as :meth:`surrogates`)."""
        own_tail, own_head = self.inter_terms(poses, base_poses, base)
        intra = costs.sum() - costs[self.inter_index].sum()
        return float(intra + own_tail.sum() + own_head.sum())

    # -- the node update, every robot at once --

    def rotation_step(self, terms: EdgeTerms) -> np.ndarray:
        """Heading increments ``(N,)`` of the Gauss–Newton steps ``−H_α⁻¹ ∇G^α`` at the base
        point whose edge terms are ``terms`` (``∇G^α`` there = robot α's block of ``∇F``)."""
        gradient = self.scatter @ body_gradients(terms, self.edges, self.kappa, self.tau)
        gradient[self.anchors] = 0.0
        return -self.hessian.solve(gradient.ravel())[2::3]

    def recover_translations(
        self, headings: np.ndarray, base_poses: np.ndarray | PoseTable, base: EdgeTerms
    ) -> PoseTable:
        """Poses with ``headings`` ``(N,)`` and every robot's translations minimising its
        ``G^α(· | base_poses)`` (edge terms ``base``) for them; the anchors keep their poses.

        Normal equations ``L t = b`` of ``Σ a τ‖t_q − t_p − c − βw‖²`` (``a, β`` = 1, 0 intra,
        2, ½ inter; ``c = R_pt̃``, ``w`` the base's world residual); on an inter edge the tail's
        row holds the head's copy ``t_q`` fixed, the head's row the tail's copy (its heading in
        ``c`` included): row ``p`` gets ``aτ([inter] t_q − c − βw)``, row ``q`` gets
        ``aτ(c + βw)`` intra and ``aτ(t_p + R_pt̃ + ½w) = aτ(t_q − ½w)`` (base values) inter.
        """
        e, i, base_poses = self.edges, self.inter_index, pose_table(base_poses)
        weight = self.translation_weight
        rotations = unit(headings)
        offsets = rotations[e.tails] * e.t_m  # aτ(c + βw)
        offsets[i] += 0.5 * base.t[i]
        offsets *= weight
        m = offsets.size
        contributions = np.empty(2 * m, dtype=complex)
        np.negative(offsets, out=contributions[:m])
        contributions[m:] = offsets
        copies = weight[i] * base_poses.z[e.heads[i]]  # aτ t_q, the head's copy (inter edges)
        contributions[i] += copies
        contributions[m + i] = copies - 0.5 * weight[i] * base.t[i]
        rhs = self.scatter @ contributions.view(float).reshape(2 * m, 2)
        if self.anchors.size:
            anchored = np.zeros(self.num_poses, dtype=complex)
            anchored[self.anchors] = base_poses.z[self.anchors]
            rhs += (self.anchor_coupling @ anchored).view(float).reshape(-1, 2)
            rhs[self.anchors] = anchored[self.anchors].view(float).reshape(-1, 2)
        translations = self.translation.solve(rhs)
        return PoseTable(headings, translations.view(complex).ravel(), rotations)

    def plain_step(self, poses: PoseTable, base: EdgeTerms, shares: np.ndarray) -> Update:
        """Every robot's safeguarded MM step from ``poses`` (edge terms ``base``, robot shares
        of ``F`` ``shares``), with ``G^α(new | poses) ≤ shares[α]``; a robot whose step fails
        halves its own step.

        **Node update** (in place of MM-PGO's ``proximal`` + TNT refinement, REFERENCES §3.4).
        Minimising (1) exactly over ``SE(2)^{n_α}`` is a local PGO; an MM step only needs to
        *decrease* it. Each robot takes one Gauss–Newton step on (1) and recovers its translations
        in closed form:

        1. Rotations: ``δ = −H_α⁻¹ g_α``, ``g_α`` the gradient of (1) at the base point
           (= ``∇_α F``) in body-frame increments (``t_i ← t_i + R_i a_i``, ``θ_i ← θ_i + b_i``),
           ``H_α`` the Gauss–Newton Hessian of (1) — intra edges at a recent geometry, inter terms
           (quadratic in linear coordinates) exact — factorised at the start and refactorised when
           its geometry has drifted (:meth:`hessian_drift`; ``hessian_interval=0``: once, at zero
           residual, i.e. from the measurements only). Then ``θ_i ← θ_i + b_i`` (the exact
           retraction onto SO(2)).
        2. Translations: the exact minimiser of (1) over the robot's translations for the new
           rotations, a weighted-Laplacian system ``L_α t = b`` (intra ``τ`` Laplacian + ``2τ`` of
           each inter edge on the diagonal), constant and factorised once (MM-PGO's
           ``recover_translations``).
        3. Safeguard (plain MM steps): if (1) did not decrease, the rotation step is halved (up to 3
           times), then dropped (translation recovery alone cannot increase (1)). Hence **F is
           non-increasing** for ``accelerated=False`` (the MM descent property; tested).
        """
        step = self.rotation_step(base)
        scale = np.ones(self.num_robots)
        accepted = np.zeros(self.num_robots, dtype=bool)
        for factor in BACKTRACKING_STEPS:
            scale[~accepted] = factor
            candidate = self.recover_translations(
                poses.headings + scale[self.robots] * step, poses, base
            )
            terms = edge_terms(candidate, self.edges)
            costs = edge_costs(terms, self.kappa, self.tau)
            accepted |= self.surrogates(candidate, costs, poses, base) <= shares
            if accepted.all():
                break
        return Update(candidate, terms, costs)

    def accelerated_step(
        self, poses: PoseTable, previous: PoseTable, gamma: float, base: EdgeTerms
    ) -> tuple[Update, float]:
        """The node update from the extrapolation ``Y = Xᵏ ⊕ γ(Xᵏ ⊖ Xᵏ⁻¹)`` (``poses``,
        ``previous``; ``base`` the edge terms of ``Xᵏ``) and ``Σ_α G^α(candidate | Xᵏ)``."""
        extrapolated = extrapolate(poses, previous, gamma)
        at_y = edge_terms(extrapolated, self.edges)
        candidate = self.recover_translations(
            extrapolated.headings + self.rotation_step(at_y), extrapolated, at_y
        )
        terms = edge_terms(candidate, self.edges)
        costs = edge_costs(terms, self.kappa, self.tau)
        surrogate = self.surrogate_total(candidate, costs, poses, base)
        return Update(candidate, terms, costs), surrogate


# ----- the method ----------------------------------------------------------------------------


def gauge_anchors(graph: PoseGraph) -> np.ndarray:
    """The vertices held fixed ``(k,)``: the first vertex of every robot with no inter-robot
    edge (its subproblem (1) is invariant to a rigid motion of its poses). Every other robot's
    subproblem is anchored by its neighbours' fixed copies, so in a connected team of two or
    more robots the gauge is free, as in MM-PGO's own code; one robot alone anchors its first
    vertex."""
    robots = graph.robots
    linked = np.zeros(graph.num_robots, dtype=bool)
    cut = robots[graph.tails] != robots[graph.heads]
    linked[robots[graph.tails[cut]]] = linked[robots[graph.heads[cut]]] = True
    first = np.full(graph.num_robots, graph.num_poses, dtype=np.int64)
    np.minimum.at(first, robots, np.arange(graph.num_poses))
    return first[~linked & (first < graph.num_poses)]


def to_frame_of(poses: np.ndarray, vertex: int, target: np.ndarray) -> np.ndarray:
    """``poses`` ``(N, 3)`` moved rigidly so that pose ``vertex`` equals ``target`` ``(3,)``
    (``T ∘ X`` with ``T = target ∘ X_vertex⁻¹``; every relative pose, hence F, unchanged)."""
    turn = target[2] - poses[vertex, 2]
    rotation = se2.rotation(np.array([turn]))[0]
    moved = np.empty_like(poses)
    moved[:, :2] = (poses[:, :2] - poses[vertex, :2]) @ rotation.T + target[:2]
    moved[:, 2] = se2.wrap(poses[:, 2] + turn)
    return moved


def robust_costs(graph: PoseGraph, poses: np.ndarray, kinds: tuple[EdgeKind, ...]) -> np.ndarray:
    """``s_e = F_e`` ``(M,)`` at ``poses`` on the edges of ``kinds``, 0 elsewhere."""
    kappa, tau = objective.weights(graph.information)
    terms = edge_terms(poses, edge_data(graph.tails, graph.heads, graph.measurements))
    under = np.isin(graph.kinds, np.array(kinds, dtype=np.int8))
    return np.where(under, edge_costs(terms, kappa, tau), 0.0)


def edge_weights(
    graph: PoseGraph, poses: np.ndarray, kernel: str, scale: float, kinds: tuple[EdgeKind, ...]
) -> np.ndarray:
    """IRLS weights ``(M,)`` at ``poses``: ``ρ'(F_e)`` on the edges of ``kinds``, 1 elsewhere.

    **Robust kernels** (:mod:`baselines.robust`) on the edge kinds of the robust mode
    (:data:`ROBUST_MODES`: ``"authors"``, as MM-PGO's own code, the inter-robot edges
    INTER_RELATIVE and INTER_LOOP; ``"project"`` also the intra-robot loop closures LOOP; the
    others keep weight 1): IRLS weights ``w_e = ρ'(s_e)`` of the unweighted chordal cost
    ``s_e = F_e`` multiply ``κ_e, τ_e``. They are recomputed from the current iterate before the
    first iteration and every ``weight_interval`` (20) iterations (static between updates: the
    weighted quadratic is minimised by MM; at an update each robot refactorises ``H_α`` (at the
    current iterate) and ``L_α`` and the acceleration state is reset, since the surrogated
    objective changed; MM-PGO's code instead re-evaluates the weights in every gradient, under a
    majoriser built with weight 1). ``inlier_mask``: an edge under the kernel is an outlier when
    its final weight is below the weight at ``s = flag_bound``, i.e. its final
    ``s > flag_bound`` (:func:`robust.flagged`; MM-PGO's code flags nothing, the rule is the
    project's); every other edge is an inlier (in the ``"authors"`` mode an intra-robot loop
    closure is never flagged); None for the kernel ``none``. When ``problem.outlier_mask`` is
    given, ``extras`` has ``precision``/``recall`` of the flagged edges.
    """
    # s = 0 off the kernel's kinds, where every kernel's weight is exactly 1
    return robust.weights(kernel, robust_costs(graph, poses, kinds), scale)


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    kernel: str = "none",
    kernel_scale: float | None = None,
    robust_mode: str = "authors",
    flag_bound: float = robust.INLIER_BOUND,
    accelerated: bool = True,
    weight_interval: int = 20,
    hessian_interval: int = 10,
    hessian_tolerance: float = 0.02,
    seed: int = 0,
    **_: object,
) -> Result:
    """Run (A)MM-PGO on ``problem`` (see the module docstring).

    Args:
        problem: the multi-robot problem (``graph.robots`` = the robots' vertex sets); the
            iterations start from its start, ``graph.poses``.
        budget: iterations (default 1000) and optional wall-clock seconds.
        kernel: ``"none"``, ``"huber"``, ``"gm"`` or ``"welsch"``.
        kernel_scale: ``c`` in units of the weighted squared residual ``s``; None: the robust
            mode's (0.25 for ``"authors"``, χ²₃(0.99) for ``"project"``).
        robust_mode: the edges under the kernel (:data:`ROBUST_MODES`, :func:`edge_weights`).
        flag_bound: the ``s`` above which an edge under the kernel is flagged
            (:data:`robust.INLIER_BOUND`).
        accelerated: Nesterov acceleration with adaptive restart (AMM-PGO) or plain MM-PGO.
        weight_interval: iterations between robust-weight updates.
        hessian_interval: iterations between checks of ``H_α``'s drift (refactorised at the
            current iterate when it exceeds ``hessian_tolerance``); 0 keeps the zero-residual
            ``H_α`` throughout.
        hessian_tolerance: the largest relative change of an edge's Jacobian (see
            :meth:`TeamSystem.hessian_drift`) tolerated before ``H_α`` is refactorised; 0: at every
            check.
        seed: unused (the method is deterministic); accepted for the common interface.

    **Accounting.** One *iteration* = every robot updates once (in parallel). ``wall_s`` = the whole
    run in this process (set-up, initialisation, logging). ``parallel_s`` is a **model** of the
    makespan, since the robots are computed together: the measured time of each batched iteration
    (refactorisations, restart steps, the restart decision and reweighting included) and of the
    set-up factorisations, times the slowest robot's share of the work, work_α = owned poses + local
    edges (an inter edge counts for both robots) — the sizes its vectorised pass and its sparse
    solves scale with. It ignores per-robot fixed (interpreter) overhead and communication latency.
    Initialisation and the final evaluation are not counted in ``parallel_s``. ``messages`` = Σ over
    iterations of the separator poses sent, one per (pose, neighbouring robot) pair.
    ``extras["refactorisations"]`` counts the refreshes of ``H`` after the set-up. ``history[k]`` =
    ``F_chordal(X_k)`` (``history[0]`` at the start), read off the edge residuals the iteration
    computes anyway (no extra evaluation); ``history_s[k]`` = ``parallel_s`` after the set-up and
    ``k`` iterations (its last entry ``parallel_s``).
    """
    del seed
    start = time.perf_counter()
    budget = budget or Budget()
    robust.check_kernel(kernel)
    if robust_mode not in ROBUST_MODES:
        raise ValueRangeError("mm-pgo robust mode", robust_mode, " | ".join(ROBUST_MODES))
    mode = ROBUST_MODES[robust_mode]
    kernel_scale = mode.scale if kernel_scale is None else kernel_scale
    if (
        kernel_scale <= 0
        or flag_bound <= 0
        or weight_interval < 1
        or hessian_interval < 0
        or hessian_tolerance < 0
    ):
        raise ValueRangeError(
            "kernel_scale, flag_bound, weight_interval, hessian_interval, hessian_tolerance",
            (kernel_scale, flag_bound, weight_interval, hessian_interval, hessian_tolerance),
            "c > 0, bound > 0, interval ≥ 1, interval ≥ 0, tolerance ≥ 0",
        )
    graph = problem.graph
    start_poses = graph.poses.copy()
    poses = pose_table(start_poses)
    kappa, tau = objective.weights(graph.information)
    tic = time.perf_counter()
    team = TeamSystem(graph, gauge_anchors(graph))
    terms = edge_terms(poses, team.edges)
    at_start = terms if hessian_interval > 0 else None  # H's geometry; None: zero residual
    team.set_weights(kappa, tau, at_start)
    parallel_s = (time.perf_counter() - tic) * team.slowest_share
    costs = edge_costs(terms, kappa, tau)
    previous = poses
    history, history_s = [], []
    state = RestartState()
    best, best_objective = poses, np.inf  # the lowest-F iterate (kernel "none")
    iterations = weight_updates = hard_restarts = soft_restarts = refactorisations = 0
    while iterations < budget.iterations:
        if budget.seconds is not None and time.perf_counter() - start > budget.seconds:
            break
        tic = time.perf_counter()
        if kernel != "none" and iterations % weight_interval == 0:
            team.set_weights(
                kappa
                * (weights := edge_weights(graph, poses.poses, kernel, kernel_scale, mode.kinds)),
                tau * weights,
                terms if hessian_interval > 0 else None,
            )
            weight_updates += 1
            state = RestartState()  # the surrogated objective changed
            costs = edge_costs(terms, team.kappa, team.tau)
        objective_now = float(costs.sum())  # F(Xᵏ) (robust-weighted): one scalar all-reduced
        history.append(
            objective_now if kernel == "none" else float(edge_costs(terms, kappa, tau).sum())
        )
        history_s.append(parallel_s)
        if kernel == "none" and objective_now < best_objective:
            best, best_objective = poses, objective_now
        if hessian_interval > 0 and iterations % hessian_interval == 0:
            if team.hessian_drift(terms) > hessian_tolerance:
                team.factorise_hessian(terms)
                refactorisations += 1
        s_next = 0.5 + 0.5 * np.sqrt(4.0 * state.s**2 + 1.0)
        gamma = (state.s - 1.0) / s_next if accelerated else 0.0
        state.observe(objective_now)
        restart = None
        if gamma > 0.0:
            following, surrogate = team.accelerated_step(poses, previous, gamma, terms)
            restart = state.restart(surrogate)
        if gamma <= 0.0 or restart is not None:
            following = team.plain_step(poses, terms, team.shares(costs))
        if restart == "hard":
            s_next = max(0.5 * s_next, 1.0)
            hard_restarts += 1
        elif restart == "soft":
            soft_restarts += 1
        if restart is not None:
            state.hits_average //= 3
            state.hits_increase = 0
        state.s = s_next
        previous, (poses, terms, costs) = poses, following
        parallel_s += (time.perf_counter() - tic) * team.slowest_share
        iterations += 1
        budget.round_done(iterations)

    if kernel == "none" and best_objective < float(costs.sum()):
        poses = best  # never return a worse iterate than one already seen (restarts)
    reference = int(np.flatnonzero(graph.robots == 0)[0])  # the output's gauge
    poses = to_frame_of(poses.poses, reference, start_poses[reference])
    costs = objective.evaluate(graph, poses)
    history.append(costs.F_chordal)
    history_s.append(parallel_s)
    extras: dict[str, object] = {
        "init": problem.start,
        "kernel": kernel,
        "kernel_scale": kernel_scale,
        "robust_mode": robust_mode,
        "accelerated": accelerated,
        "hard_restarts": hard_restarts,
        "soft_restarts": soft_restarts,
        "weight_updates": weight_updates,
        "refactorisations": refactorisations,
        "parallel_model": "batched time × slowest robot's share of poses + local edges",
    }
    inlier_mask = None
    if kernel != "none":
        final_costs = robust_costs(graph, poses, mode.kinds)
        # s = 0 off the kernel's kinds: weight 1, never flagged (flag_bound > 0)
        inlier_mask = ~robust.flagged(kernel, final_costs, flag_bound)
        extras["weights"] = robust.weights(kernel, final_costs, kernel_scale)
        if problem.outlier_mask is not None:
            extras["precision"], extras["recall"] = precision_recall(
                ~inlier_mask, problem.outlier_mask
            )
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=time.perf_counter() - start,
        parallel_s=parallel_s,
        iterations=iterations,
        history=np.asarray(history),
        inlier_mask=inlier_mask,
        messages=team.messages_per_iteration * iterations,
        extras=extras,
        history_s=np.asarray(history_s),
        history_objective="F_chordal",
    )
