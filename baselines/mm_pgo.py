"""MM-PGO / AMM-PGO (Fan & Murphey, T-RO 2024): distributed majorisation–minimisation on SE(2).

Method ``"mm-pgo"``; REFERENCES.md §3 and §8.

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

**Node update** (in place of MM-PGO's ``proximal`` + TNT refinement, REFERENCES §3.4). Minimising
(1) exactly over ``SE(2)^{n_α}`` is a local PGO; an MM step only needs to *decrease* it. Each
robot takes one Gauss–Newton step on (1) and recovers its translations in closed form:

1. Rotations: ``δ = −H_α⁻¹ g_α``, ``g_α`` the gradient of (1) at the base point (= ``∇_α F``) in
   body-frame increments (``t_i ← t_i + R_i a_i``, ``θ_i ← θ_i + b_i``), ``H_α`` the Gauss–Newton
   Hessian of (1) — intra edges at the current geometry, inter terms (quadratic in linear
   coordinates) exact — refactorised every ``hessian_interval`` (10) iterations
   (``hessian_interval=0``: once, at zero residual, i.e. from the measurements only). Then
   ``θ_i ← θ_i + b_i`` (the exact retraction onto SO(2)).
2. Translations: the exact minimiser of (1) over the robot's translations for the new rotations,
   a weighted-Laplacian system ``L_α t = b`` (intra ``τ`` Laplacian + ``2τ`` of each inter edge on
   the diagonal), constant and factorised once (MM-PGO's ``recover_translations``).
3. Safeguard (plain MM steps): if (1) did not decrease, the rotation step is halved (up to 3
   times), then dropped (translation recovery alone cannot increase (1)). Hence **F is
   non-increasing** for ``accelerated=False`` (the MM descent property; tested).

Design notes (measured on MITb, n = 3): minimising the surrogate over unconstrained
``R ∈ R^{2×2}`` and projecting does not converge to a stationary point (with one robot it
reproduces the chordal relaxation every iteration); several inner Gauss–Newton steps per
iteration did not speed up the outer MM; a Hessian fixed at zero residual made the accelerated
scheme diverge on MITb, whose chordal initialisation is 44 % above the optimum. The gauge pose
(the first vertex of robot 0) is held fixed.

**Acceleration** (AMM-PGO, REFERENCES §3.5): ``s_{k+1} = ½ + ½√(4s_k² + 1)``,
``γ_k = (s_k − 1)/s_{k+1}``, ``Y = Xᵏ ⊕ γ_k(Xᵏ ⊖ Xᵏ⁻¹)`` (translations linearly, headings by the
wrapped difference; each robot extrapolates its own and its neighbours' poses, which it holds
from the last two exchanges), candidate = node update from ``Y`` without the safeguard. With
``F_k = F(Xᵏ)`` and ``G = Σ_α G^α(candidate | Xᵏ) ≥ F(candidate)``: ``F̄₀ ← (1−η₀)F̄₀ + η₀F_k``
(η₀ = 5e-4), ``F̄₁ ← max(F_k, (1−η₁)F̄₁ + η₁F_k)`` (η₁ = 2.5e-2); a **hard restart** when
``G > F̄₀``, a **soft restart** when ``G > F̄₁`` and counter₀ ≥ 10, or ``G > F_{k}`` and
counter₁ > 25 (counter₀ −2 when ``F_k ≤ F̄₁`` else +1; counter₁ reset when ``F`` decreased else
+1). A restart replaces every robot's candidate by its safeguarded plain step from ``Xᵏ``; a hard
one also sets ``s ← max(s/2, 1)``; both divide counter₀ by 3 and reset counter₁. The rules are
applied to team sums (two scalars all-reduced per iteration, as AMM-PGO* with its master node),
not per robot as in AMM-PGO#: the per-robot rule on robot shares of F oscillated (measured).

**Robust kernels** (:mod:`baselines.robust`) on loop-closure and inter-robot edges (kinds LOOP,
INTER_RELATIVE, INTER_LOOP; odometry keeps weight 1): IRLS weights ``w_e = ρ'(s_e)`` of the
unweighted chordal cost ``s_e = F_e`` multiply ``κ_e, τ_e``. They are recomputed from the
current iterate before the first iteration and every ``weight_interval`` (20) iterations
(static between updates: the weighted quadratic is minimised by MM; at an update each robot
refactorises ``H_α`` and ``L_α`` and the acceleration state is reset, since the surrogated
objective changed). ``inlier_mask``: an edge of a robust kind is an inlier when its weight at
the final estimate is at least the weight at ``s = c`` (:func:`robust.flag_threshold`), i.e.
when its final ``s ≤ c``; odometry is always an inlier; None for the kernel ``none``. When
``problem.outlier_mask`` is given, ``extras`` has ``precision``/``recall`` of the flagged edges.

**Accounting.** One *iteration* = every robot updates once (in parallel). ``wall_s`` = the whole
run in this process (set-up, initialisation, logging). ``parallel_s`` = set-up (the slowest
robot's factorisations) + Σ over iterations of (the slowest robot's update, timed by
``time.perf_counter`` around each robot's update, refactorisations and restart steps included)
+ the iteration's coordination (weights, the restart decision, the pose exchange).
Initialisation and the ``history`` log are not counted in ``parallel_s``. ``messages`` = Σ over
iterations of the separator poses sent, one per (pose, neighbouring robot) pair. ``history[k]`` =
``F_chordal(X_k)`` (``history[0]`` at the start).
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import SuperLU, splu

from baselines import robust
from popbench import objective, se2
from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph
from popbench.methods import Budget, Result
from popbench.outliers import precision_recall
from popbench.solvers.chordal import chordal_initialisation

ROBUST_KINDS = (EdgeKind.LOOP, EdgeKind.INTER_RELATIVE, EdgeKind.INTER_LOOP)
INITS = ("chordal", "odometry", "given")

# Adaptive restart of AMM-PGO (REFERENCES §3.5).
ETA_SLOW, ETA_FAST = 5e-4, 2.5e-2
MAX_SOFT_HITS_AVERAGE, MAX_SOFT_HITS_INCREASE = 10, 25
BACKTRACKING_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0)
REGULARISER = 1e-10  # ξ, relative to the largest diagonal entry (MM-PGO's regularizer)
_J = np.array([[0.0, -1.0], [1.0, 0.0]])  # R(π/2)


# ----- per-edge terms (vectorised over edges) ------------------------------------------------


class EdgeTerms(NamedTuple):
    """Trigonometry and residuals of edges ``p → q``, every field ``(m,)``.

    ``cos_p, sin_p, cos_q, sin_q``: of ``θ_p``, ``θ_q``; ``cos_pm, sin_pm``: of ``θ_p + θ̃``;
    ``tx, ty``: world-frame ``t_q − t_p − R_pt̃``; ``rx, ry``: first column of ``R_q − R_pR̃``
    (``‖R_q − R_pR̃‖²_F = 2(rx² + ry²)``).
    """

    cos_p: np.ndarray
    sin_p: np.ndarray
    cos_q: np.ndarray
    sin_q: np.ndarray
    cos_pm: np.ndarray
    sin_pm: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    rx: np.ndarray
    ry: np.ndarray


class EdgeData(NamedTuple):
    """Constants of ``m`` edges: endpoint rows into a pose array, measurement and weights."""

    tails: np.ndarray
    heads: np.ndarray
    mx: np.ndarray  # t̃ [m]
    my: np.ndarray
    cos_m: np.ndarray  # cos θ̃, sin θ̃
    sin_m: np.ndarray


def edge_data(tails: np.ndarray, heads: np.ndarray, measurements: np.ndarray) -> EdgeData:
    """:class:`EdgeData` of edges whose endpoints are rows ``tails``/``heads`` of a pose array."""
    return EdgeData(
        tails,
        heads,
        measurements[:, 0].copy(),
        measurements[:, 1].copy(),
        np.cos(measurements[:, 2]),
        np.sin(measurements[:, 2]),
    )


def edge_terms(poses: np.ndarray, edges: EdgeData) -> EdgeTerms:
    """:class:`EdgeTerms` of ``edges`` at ``poses`` ``(·, 3)``."""
    cos, sin = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    cos_p, sin_p, cos_q, sin_q = (
        cos[edges.tails],
        sin[edges.tails],
        cos[edges.heads],
        sin[edges.heads],
    )
    delta = poses[edges.heads, :2] - poses[edges.tails, :2]
    tx = delta[:, 0] - (cos_p * edges.mx - sin_p * edges.my)
    ty = delta[:, 1] - (sin_p * edges.mx + cos_p * edges.my)
    cos_pm = cos_p * edges.cos_m - sin_p * edges.sin_m
    sin_pm = sin_p * edges.cos_m + cos_p * edges.sin_m
    return EdgeTerms(
        cos_p, sin_p, cos_q, sin_q, cos_pm, sin_pm, tx, ty, cos_q - cos_pm, sin_q - sin_pm
    )


def edge_costs(terms: EdgeTerms, kappa: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``F_e = τ‖r_t‖² + κ‖R_q − R_pR̃‖²_F``, ``(m,)``."""
    return tau * (terms.tx**2 + terms.ty**2) + 2.0 * kappa * (terms.rx**2 + terms.ry**2)


def body_gradients(
    terms: EdgeTerms, edges: EdgeData, kappa: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Gradients of ``F_e`` with respect to body-frame increments ``(a, b)`` of the tail and the
    head (``t ← t + R a``, ``θ ← θ + b``), each ``(m, 3)``.

    With ``r = R_pᵀ(t_q − t_p) − t̃``: ``∂r/∂a_p = −I``, ``∂r/∂b_p = −J(r + t̃)``,
    ``∂r/∂a_q = R(θ_q − θ_p)``; the rotation term ``4κ(1 − cos r_θ)`` has derivative
    ``∓4κ sin r_θ`` (``⟨J(r + t̃), r⟩ = ⟨Jt̃, r⟩``).
    """
    bx = terms.cos_p * terms.tx + terms.sin_p * terms.ty  # r = R_pᵀ (world residual)
    by = terms.cos_p * terms.ty - terms.sin_p * terms.tx
    rotation_term = 4.0 * kappa * (terms.sin_q * terms.cos_pm - terms.cos_q * terms.sin_pm)
    two_tau = 2.0 * tau
    cos_d = terms.cos_p * terms.cos_q + terms.sin_p * terms.sin_q  # R(θ_q − θ_p)
    sin_d = terms.cos_p * terms.sin_q - terms.sin_p * terms.cos_q
    g_tail = np.empty((bx.size, 3))
    g_tail[:, 0] = -two_tau * bx
    g_tail[:, 1] = -two_tau * by
    g_tail[:, 2] = -two_tau * (edges.mx * by - edges.my * bx) - rotation_term
    g_head = np.empty((bx.size, 3))
    g_head[:, 0] = two_tau * (cos_d * bx + sin_d * by)
    g_head[:, 1] = two_tau * (cos_d * by - sin_d * bx)
    g_head[:, 2] = rotation_term
    return g_tail, g_head


def gauss_newton_blocks(
    lever: np.ndarray, relative_heading: np.ndarray, kappa: np.ndarray, tau: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gauss–Newton Hessian blocks of ``F_e`` in body-frame increments,
    ``(tail-tail, tail-head, head-head)``, each ``(m, 3, 3)``.

    ``∂r_t = [−I, −lever | R(relative_heading), 0]`` with ``r_t = R_pᵀ(t_q − t_p) − t̃``,
    ``lever = J R_pᵀ(t_q − t_p)`` ``(m, 2)``; ``∂r_θ = [0, −1 | 0, 1]``;
    ``H = 2τ J_tᵀJ_t + 4κ J_θᵀJ_θ`` (``4κ(1 − cos r) ≈ 2κ r²``). At zero residual
    ``lever = Jt̃`` and ``relative_heading = θ̃``: the blocks depend on the measurements only.
    """
    m = lever.shape[0]
    jac_tail = np.zeros((m, 2, 3))
    jac_tail[:, :, :2] = -np.eye(2)
    jac_tail[:, :, 2] = -lever
    jac_head = np.zeros((m, 2, 3))
    jac_head[:, :, :2] = se2.rotation(relative_heading)
    two_tau = 2.0 * tau[:, None, None]
    e_theta = np.zeros((3, 3))
    e_theta[2, 2] = 1.0
    rotation = 4.0 * kappa[:, None, None] * e_theta
    tail_tail = two_tau * np.einsum("mki,mkj->mij", jac_tail, jac_tail) + rotation
    tail_head = two_tau * np.einsum("mki,mkj->mij", jac_tail, jac_head) - rotation
    head_head = two_tau * np.einsum("mki,mkj->mij", jac_head, jac_head) + rotation
    return tail_tail, tail_head, head_head


def _block_coo(
    blocks: np.ndarray, rows: np.ndarray, cols: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """COO triplets of 3×3 ``blocks`` ``(m, 3, 3)`` placed at pose rows/cols ``(m,)``."""
    k = np.arange(3)
    r = np.broadcast_to(3 * rows[:, None, None] + k[None, :, None], blocks.shape)
    c = np.broadcast_to(3 * cols[:, None, None] + k[None, None, :], blocks.shape)
    return r.ravel(), c.ravel(), blocks.ravel()


def _factorise(matrix: sp.spmatrix) -> SuperLU:
    """Sparse LU of a symmetric positive-definite matrix (symmetric ordering, no pivoting)."""
    matrix = sp.csc_matrix(matrix)
    matrix = matrix + REGULARISER * matrix.diagonal().max() * sp.identity(matrix.shape[0])
    return splu(
        sp.csc_matrix(matrix),
        permc_spec="MMD_AT_PLUS_A",
        diag_pivot_thresh=0.0,
        options={"SymmetricMode": True},
    )


def extrapolate(current: np.ndarray, previous: np.ndarray, gamma: float) -> np.ndarray:
    """Nesterov extrapolation ``X + γ(X ⊖ X_prev)`` of poses ``(m, 3)``: translations linearly,
    headings by the wrapped difference."""
    difference = current - previous
    difference[:, 2] = se2.wrap(difference[:, 2])
    return current + gamma * difference


# ----- acceleration state --------------------------------------------------------------------


@dataclasses.dataclass
class RestartState:
    """The team's acceleration / adaptive-restart state (REFERENCES §3.5)."""

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


# ----- one robot -----------------------------------------------------------------------------


class RobotSolver:
    """Robot α's local edges, cached factorisations and node update.

    Robot α works on a local pose array ``[owned poses (n); separator copies (k)]`` (rows
    ``0..n−1`` are its variables) and on every edge with an owned endpoint: intra edges
    (both owned) and inter edges (one owned).

    Args:
        graph: the global graph (``graph.robots`` assigned).
        robot: α.
        anchor: the gauge vertex (held fixed when α owns it).
    """

    def __init__(self, graph: PoseGraph, robot: int, anchor: int) -> None:
        robots = graph.robots
        self.owned = np.flatnonzero(robots == robot)
        n = self.owned.size
        own_tail = robots[graph.tails] == robot
        own_head = robots[graph.heads] == robot
        self.edges_global = np.flatnonzero(own_tail | own_head)
        tails, heads = graph.tails[self.edges_global], graph.heads[self.edges_global]
        copies = np.unique(
            np.concatenate([tails, heads])[robots[np.concatenate([tails, heads])] != robot]
        )
        self.local_ids = np.concatenate([self.owned, copies])
        local_of = np.full(graph.num_poses, -1, dtype=np.int64)
        local_of[self.local_ids] = np.arange(self.local_ids.size)
        self.edges = edge_data(
            local_of[tails], local_of[heads], graph.measurements[self.edges_global]
        )
        self.tail_owned = self.edges.tails < n
        self.head_owned = self.edges.heads < n
        self.inter = ~(self.tail_owned & self.head_owned)
        # (1): factor 2 and shift ½ on inter terms.
        self.factor = np.where(self.inter, 2.0, 1.0)
        self.shift = np.where(self.inter, 0.5, 0.0)
        self.share_weight = np.where(self.inter, 0.5, 1.0)
        m = self.edges_global.size
        # Sum of per-edge [tail contributions; head contributions] onto the owned poses.
        rows = np.concatenate([self.edges.tails, self.edges.heads])
        keep = rows < n
        self.scatter = sp.csr_matrix(
            (np.ones(keep.sum()), (rows[keep], np.flatnonzero(keep))), shape=(n, 2 * m)
        )
        self.free = self.owned != anchor
        self.free_dofs = np.flatnonzero(np.repeat(self.free, 3))
        self.num_owned = n
        pairs = set(
            zip(
                self.local_ids[self.edges.tails[self.tail_owned & self.inter]].tolist(),
                robots[self.local_ids[self.edges.heads[self.tail_owned & self.inter]]].tolist(),
                strict=True,
            )
        ) | set(
            zip(
                self.local_ids[self.edges.heads[self.head_owned & self.inter]].tolist(),
                robots[self.local_ids[self.edges.tails[self.head_owned & self.inter]]].tolist(),
                strict=True,
            )
        )
        self.messages_per_iteration = len(pairs)  # (separator pose, neighbour robot) pairs
        self.measurements = graph.measurements[self.edges_global]

    # -- weights and factorisations --

    def set_weights(self, kappa: np.ndarray, tau: np.ndarray) -> None:
        """Set the (robust-weighted) edge weights ``(M,)`` and refactorise ``H_α`` (at zero
        residual) and ``L_α``."""
        self.kappa, self.tau = kappa[self.edges_global], tau[self.edges_global]
        self.factorise_hessian(None)
        n, e = self.num_owned, self.edges
        # Translation normal equations of (1): Σ factor·τ ‖t_q − t_p − …‖² over owned rows.
        weight = self.factor * self.tau
        both = ~self.inter
        rows = np.concatenate(
            [e.tails[self.tail_owned], e.heads[self.head_owned], e.tails[both], e.heads[both]]
        )
        cols = np.concatenate(
            [e.tails[self.tail_owned], e.heads[self.head_owned], e.heads[both], e.tails[both]]
        )
        values = np.concatenate(
            [weight[self.tail_owned], weight[self.head_owned], -weight[both], -weight[both]]
        )
        laplacian = sp.csc_matrix((values, (rows, cols)), shape=(n, n))
        self.translation = _factorise(laplacian[self.free][:, self.free])
        self.translation_fixed = laplacian[self.free][:, ~self.free]

    def factorise_hessian(self, terms: EdgeTerms | None) -> None:
        """Factorise ``H_α``, the Gauss–Newton Hessian of (1): intra edges at zero residual
        (``terms=None``) or at the geometry of ``terms``; inter terms (quadratic in linear
        coordinates, own-end block ×2) never depend on the iterate."""
        n, e = self.num_owned, self.edges
        lever = self.measurements[:, :2] @ _J.T
        heading = self.measurements[:, 2]
        if terms is not None:
            # J R_pᵀ(t_q − t_p) = J(r + t̃) and θ_q − θ_p on intra edges.
            bx = terms.cos_p * terms.tx + terms.sin_p * terms.ty + e.mx
            by = terms.cos_p * terms.ty - terms.sin_p * terms.tx + e.my
            intra = ~self.inter
            lever = np.where(intra[:, None], np.column_stack([-by, bx]), lever)
            relative = np.arctan2(
                terms.cos_p * terms.sin_q - terms.sin_p * terms.cos_q,
                terms.cos_p * terms.cos_q + terms.sin_p * terms.sin_q,
            )
            heading = np.where(intra, relative, heading)
        tt, th, hh = gauss_newton_blocks(lever, heading, self.kappa, self.tau)
        factor = self.factor[:, None, None]  # Γ_α: own-end block ×2 on inter edges
        both = ~self.inter
        tail_rows, head_rows = e.tails, e.heads
        pieces = [
            _block_coo(
                factor[self.tail_owned] * tt[self.tail_owned],
                tail_rows[self.tail_owned],
                tail_rows[self.tail_owned],
            ),
            _block_coo(
                factor[self.head_owned] * hh[self.head_owned],
                head_rows[self.head_owned],
                head_rows[self.head_owned],
            ),
            _block_coo(th[both], tail_rows[both], head_rows[both]),
            _block_coo(np.swapaxes(th[both], 1, 2), head_rows[both], tail_rows[both]),
        ]
        rows, cols, values = (np.concatenate(parts) for parts in zip(*pieces, strict=True))
        hessian = sp.csc_matrix((values, (rows, cols)), shape=(3 * n, 3 * n))
        self.hessian = _factorise(hessian[self.free_dofs][:, self.free_dofs])

    # -- evaluations --

    def share(self, terms: EdgeTerms) -> float:
        """The robot's share of ``F``: intra costs + ½ inter costs."""
        return float(np.dot(self.share_weight, edge_costs(terms, self.kappa, self.tau)))

    def surrogate(self, terms: EdgeTerms, base: EdgeTerms) -> float:
        """``G^α(· | base)``, eq. (1), of the poses whose edge terms are ``terms``."""
        sx = terms.tx - self.shift * base.tx
        sy = terms.ty - self.shift * base.ty
        ux = terms.rx - self.shift * base.rx
        uy = terms.ry - self.shift * base.ry
        costs = self.tau * (sx * sx + sy * sy) + 2.0 * self.kappa * (ux * ux + uy * uy)
        return float(np.dot(self.factor, costs))

    # -- the node update --

    def rotation_step(self, terms: EdgeTerms) -> np.ndarray:
        """Heading increments ``(n,)`` of the Gauss–Newton step ``−H_α⁻¹ ∇G^α`` at the base
        point of (1) whose edge terms are ``terms``."""
        g_tail, g_head = body_gradients(terms, self.edges, self.kappa, self.tau)
        gradient = self.scatter @ np.concatenate([g_tail, g_head])
        step = np.zeros(3 * self.num_owned)
        step[self.free_dofs] = -self.hessian.solve(gradient.ravel()[self.free_dofs])
        return step[2::3]

    def recover_translations(
        self, headings: np.ndarray, poses: np.ndarray, base: EdgeTerms
    ) -> np.ndarray:
        """Local poses with the owned ``headings`` ``(n,)`` and the owned translations minimising
        ``G^α(· | base)`` for them; separator copies (and the gauge) keep ``poses``.

        Normal equations ``L_α t = b`` of ``Σ a τ‖t_q − t_p − c − βw‖²`` (``a, β`` = 1, 0 intra,
        2, ½ inter; ``c = R_pt̃``, ``w`` the base's world residual): row ``p`` gets
        ``aτ([q copy] t_q − c − βw)``, row ``q`` gets ``aτ(c + βw + [p copy] t_p)``.
        """
        n, e = self.num_owned, self.edges
        result = poses.copy()
        result[:n, 2] = headings
        cos, sin = np.cos(result[:, 2]), np.sin(result[:, 2])
        cos_p, sin_p = cos[e.tails], sin[e.tails]
        cx = cos_p * e.mx - sin_p * e.my + self.shift * base.tx
        cy = sin_p * e.mx + cos_p * e.my + self.shift * base.ty
        weight = self.factor * self.tau
        copy_head = ~self.head_owned
        copy_tail = ~self.tail_owned
        contributions = np.empty((2 * e.tails.size, 2))
        m = e.tails.size
        contributions[:m, 0] = weight * (copy_head * result[e.heads, 0] - cx)
        contributions[:m, 1] = weight * (copy_head * result[e.heads, 1] - cy)
        contributions[m:, 0] = weight * (cx + copy_tail * result[e.tails, 0])
        contributions[m:, 1] = weight * (cy + copy_tail * result[e.tails, 1])
        rhs = self.scatter @ contributions
        translations = result[:n, :2]
        free_rhs = rhs[self.free] - self.translation_fixed @ translations[~self.free]
        translations[self.free] = self.translation.solve(free_rhs)
        return result

    def plain_step(
        self, poses: np.ndarray, base: EdgeTerms, share: float
    ) -> tuple[np.ndarray, EdgeTerms]:
        """Safeguarded MM step from the local poses ``poses`` (whose edge terms are ``base``):
        the new local poses and their edge terms, with ``G^α(new | base) ≤ share``."""
        step = self.rotation_step(base)
        for scale in BACKTRACKING_STEPS:
            candidate = self.recover_translations(
                poses[: self.num_owned, 2] + scale * step, poses, base
            )
            terms = edge_terms(candidate, self.edges)
            if self.surrogate(terms, base) <= share:
                break
        return candidate, terms

    def propose(
        self, current: np.ndarray, previous: np.ndarray, gamma: float, refresh_hessian: bool
    ) -> tuple[np.ndarray, float, float]:
        """Robot α's candidate from the global iterates ``Xᵏ``, ``Xᵏ⁻¹`` ``(N, 3)``: the
        node update from the extrapolation ``Y`` when ``γ > 0``, else the plain step.

        Returns:
            ``(owned poses (n, 3), G^α(them | Xᵏ), f_k)``, ``f_k`` the robot's share of ``F(Xᵏ)``.
        """
        local = current[self.local_ids]
        base = edge_terms(local, self.edges)
        share = self.share(base)
        self._local, self._base, self._share = local, base, share
        if refresh_hessian:
            self.factorise_hessian(base)
        if gamma <= 0.0:
            candidate, terms = self.plain_step(local, base, share)
        else:
            extrapolated = extrapolate(local, previous[self.local_ids], gamma)
            extrapolated[: self.num_owned][~self.free] = local[: self.num_owned][~self.free]
            at_y = edge_terms(extrapolated, self.edges)
            candidate = self.recover_translations(
                extrapolated[: self.num_owned, 2] + self.rotation_step(at_y), extrapolated, at_y
            )
            candidate[self.num_owned :] = local[self.num_owned :]
            terms = edge_terms(candidate, self.edges)
        return candidate[: self.num_owned], self.surrogate(terms, base), share

    def restart_step(self) -> np.ndarray:
        """The plain step from the ``Xᵏ`` of the last :meth:`propose`, owned poses ``(n, 3)``."""
        return self.plain_step(self._local, self._base, self._share)[0][: self.num_owned]


# ----- the method ----------------------------------------------------------------------------


def initial_estimate(graph: PoseGraph, init: str) -> np.ndarray:
    """``(N, 3)`` starting poses: ``"chordal"`` (chordal relaxation + translation recovery),
    ``"odometry"`` (odometry composition) or ``"given"`` (``graph.poses``)."""
    if init == "chordal":
        return chordal_initialisation(graph)
    if init == "odometry":
        return graph.odometry_initial()
    if init == "given":
        return graph.poses.copy()
    raise ValueRangeError("init", init, ", ".join(INITS))


def edge_weights(graph: PoseGraph, poses: np.ndarray, kernel: str, scale: float) -> np.ndarray:
    """IRLS weights ``(M,)`` at ``poses``: ``ρ'(F_e)`` on robust kinds, 1 on odometry."""
    kappa, tau = objective.weights(graph.information)
    terms = edge_terms(poses, edge_data(graph.tails, graph.heads, graph.measurements))
    robust_edge = np.isin(graph.kinds, np.array(ROBUST_KINDS, dtype=np.int8))
    return np.where(robust_edge, robust.weights(kernel, edge_costs(terms, kappa, tau), scale), 1.0)


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    init: str = "chordal",
    kernel: str = "none",
    kernel_scale: float = robust.DEFAULT_SCALE,
    accelerated: bool = True,
    weight_interval: int = 20,
    hessian_interval: int = 10,
    seed: int = 0,
    **_: object,
) -> Result:
    """Run (A)MM-PGO on ``problem`` (see the module docstring).

    Args:
        problem: the multi-robot problem (``graph.robots`` = the robots' vertex sets).
        budget: iterations (default 1000) and optional wall-clock seconds.
        init: ``"chordal"``, ``"odometry"`` or ``"given"`` (``problem.graph.poses``).
        kernel: ``"none"``, ``"huber"``, ``"gm"`` or ``"welsch"``.
        kernel_scale: ``c`` in units of the whitened squared residual (default χ²₃ 0.99).
        accelerated: Nesterov acceleration with adaptive restart (AMM-PGO) or plain MM-PGO.
        weight_interval: iterations between robust-weight updates.
        hessian_interval: iterations between refactorisations of ``H_α`` at the current
            iterate; 0 keeps the zero-residual ``H_α`` throughout.
        seed: unused (the method is deterministic); accepted for the common interface.
    """
    del seed
    start = time.perf_counter()
    budget = budget or Budget()
    robust.check_kernel(kernel)
    if kernel_scale <= 0 or weight_interval < 1 or hessian_interval < 0:
        raise ValueRangeError(
            "kernel_scale, weight_interval, hessian_interval",
            (kernel_scale, weight_interval, hessian_interval),
            "c > 0, interval ≥ 1, interval ≥ 0",
        )
    graph = problem.graph
    poses = initial_estimate(graph, init)
    history = [objective.chordal_objective(graph, poses)]
    kappa, tau = objective.weights(graph.information)
    anchor = int(np.flatnonzero(graph.robots == 0)[0])
    solvers = [RobotSolver(graph, robot, anchor) for robot in range(graph.num_robots)]
    setup_times = []
    for robot in solvers:
        tic = time.perf_counter()
        robot.set_weights(kappa, tau)
        setup_times.append(time.perf_counter() - tic)
    parallel_s = max(setup_times)
    previous = poses.copy()
    messages_per_iteration = sum(robot.messages_per_iteration for robot in solvers)
    state = RestartState()
    iterations = weight_updates = hard_restarts = soft_restarts = 0
    while iterations < budget.iterations:
        if budget.seconds is not None and time.perf_counter() - start > budget.seconds:
            break
        tic = time.perf_counter()
        reweight = kernel != "none" and iterations % weight_interval == 0
        if reweight:
            weights = edge_weights(graph, poses, kernel, kernel_scale)
            weight_updates += 1
            state = RestartState()  # the surrogated objective changed
        s_next = 0.5 + 0.5 * np.sqrt(4.0 * state.s**2 + 1.0)
        gamma = (state.s - 1.0) / s_next if accelerated else 0.0
        refresh = hessian_interval > 0 and iterations % hessian_interval == 0
        coordination = time.perf_counter() - tic
        following = poses.copy()
        robot_times = np.zeros(len(solvers))
        surrogate_total = objective_total = 0.0
        for index, robot in enumerate(solvers):
            tic = time.perf_counter()
            if reweight:
                robot.set_weights(kappa * weights, tau * weights)
            candidate, value, share = robot.propose(poses, previous, gamma, refresh)
            following[robot.owned] = candidate
            surrogate_total += value
            objective_total += share
            robot_times[index] = time.perf_counter() - tic
        tic = time.perf_counter()
        state.observe(objective_total)  # F(Xᵏ) and Σ_α G^α: two scalars all-reduced
        restart = state.restart(surrogate_total) if gamma > 0.0 else None
        coordination += time.perf_counter() - tic
        if restart is not None:
            for index, robot in enumerate(solvers):
                tic = time.perf_counter()
                following[robot.owned] = robot.restart_step()
                robot_times[index] += time.perf_counter() - tic
            if restart == "hard":
                s_next = max(0.5 * s_next, 1.0)
                hard_restarts += 1
            else:
                soft_restarts += 1
            state.hits_average //= 3
            state.hits_increase = 0
        state.s = s_next
        tic = time.perf_counter()
        previous, poses = poses, following
        parallel_s += robot_times.max() + coordination + time.perf_counter() - tic
        history.append(objective.chordal_objective(graph, poses))
        iterations += 1

    poses = np.column_stack([poses[:, :2], se2.wrap(poses[:, 2])])
    costs = objective.evaluate(graph, poses)
    extras: dict[str, object] = {
        "init": init,
        "kernel": kernel,
        "kernel_scale": kernel_scale,
        "accelerated": accelerated,
        "hard_restarts": hard_restarts,
        "soft_restarts": soft_restarts,
        "weight_updates": weight_updates,
        "history_objective": "F_chordal",
    }
    inlier_mask = None
    if kernel != "none":
        final_weights = edge_weights(graph, poses, kernel, kernel_scale)
        inlier_mask = final_weights >= robust.flag_threshold(kernel, kernel_scale)
        extras["weights"] = final_weights
        if problem.outlier_mask is not None:
            extras["precision"], extras["recall"] = precision_recall(
                ~inlier_mask, problem.outlier_mask
            )
    return Result(
        poses=poses,
        F=costs.F,
        F_chordal=costs.F_chordal,
        chi2=costs.chi2,
        wall_s=time.perf_counter() - start,
        parallel_s=parallel_s,
        iterations=iterations,
        history=np.asarray(history),
        inlier_mask=inlier_mask,
        messages=messages_per_iteration * iterations,
        extras=extras,
    )
