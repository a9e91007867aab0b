"""MM-PGO's team system: every robot's majorised subproblem, stacked into one block-diagonal
system, and the node update of every robot at once (Fan & Murphey 2024).

Each ``F_e`` is a convex quadratic in the *linear coordinates* ``(t_i, R_i)``, ``R_i ∈ R^{2×2}``;
the non-convexity is only ``R_i ∈ SO(2)``. With the edge residual ``r_e = A_e y_p + B_e y_q``,

    F_e(y) ≤ F_e(yᵏ) + ⟨∇F_e, y − yᵏ⟩ + 2‖A_eδ_p‖² + 2‖B_eδ_q‖²,   δ = y − yᵏ,

because ``‖a + b‖² ≤ 2‖a‖² + 2‖b‖²``: MM-PGO's majoriser ``Γ_α``, exact on intra-robot edges and
**2× the edge's weights on the own pose's diagonal block** for inter-robot edges. Splitting
``F_e(yᵏ)`` in halves, robot α's surrogate is

    G^α(X^α | Xᵏ) = Σ_{e intra} F_e(X^α) + Σ_{e inter} 2 ‖r_e(x_i, x_jᵏ) − ½ r_e(xᵏ)‖²_W    (1)

(``i`` its own end, ``j`` the neighbour's, ``‖·‖²_W`` the κ/τ-weighted norm), so that
``Σ_α G^α(X^α | Xᵏ) ≥ F(X)`` with equality at ``Xᵏ``, and the robots' subproblems are independent
given the neighbours' poses of the previous iterate (Jacobi: all robots update in parallel).
The node update: :meth:`TeamSystem.plain_step`; the Hessian refresh:
:meth:`TeamSystem.hessian_drift`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from baselines.mm_pgo.edges import (
    EdgeTerms,
    HessianGeometry,
    PoseTable,
    body_gradients,
    edge_costs,
    edge_data,
    edge_terms,
    extrapolate,
    gauss_newton_blocks,
    jacobian_drift,
    pose_table,
    select,
    shifted_costs,
    unit,
)
from popbench.graph import PoseGraph
from popbench.sparse import CholeskyFactor

BACKTRACKING_STEPS = (1.0, 0.5, 0.25, 0.125, 0.0)
REGULARISER = 1e-10  # ξ, relative to the largest diagonal entry (MM-PGO's regularizer)


class Update(NamedTuple):
    """A team update: the new poses, their edge terms and edge costs ``(M,)`` (at the
    current, robust-weighted, weights)."""

    poses: PoseTable
    terms: EdgeTerms
    costs: np.ndarray


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

        **Node update** (in place of MM-PGO's ``proximal`` + TNT refinement).
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
