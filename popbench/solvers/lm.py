"""Sparse Levenberg–Marquardt on the PGO objective ``F`` (paper eq. 1, κ/τ weights): the
centralised reference solver (method ``"lm"``) and the optimum floor ``F*``.

``F(x) = Σ_e ‖e_e(x)‖²`` with the whitened residuals of :func:`popbench.objective.linearise`.
One LM step solves the damped Gauss–Newton system

    (H + λ D) δ = −g,   H = JᵀJ,  g = Jᵀe,  D = diag(H) clipped to ``[1e-6, ∞)``

(Marquardt's scale-invariant damping) for the additive increment δ of poses ``1..N−1``; pose 0
is held fixed (gauge): its three columns are removed from ``J``. A step is accepted when it
lowers the cost; λ then follows Nielsen's rule ``λ ← λ · max(1/10, 1 − (2ρ − 1)³)`` with the
gain ratio ``ρ = (F − F_new) / L(δ)`` and the model decrease ``L(δ) = −gᵀδ + λ δᵀDδ``; a
rejected step multiplies λ by ``ν`` and doubles ``ν`` (reset to 2 on acceptance). λ starts at
1e-8 (nearly Gauss–Newton); Nielsen's shrink floor is 1/10 instead of his 1/3. Both choices
were measured on every dataset (fewer steps from chordal starts, e.g. M3500 4 instead of 12,
same minima); pose graphs have very soft low-frequency modes that a larger damping slows down.
Headings are wrapped to ``[-π, π)`` after each step.

One *iteration* is one LM step, accepted or rejected (each costs one factorisation).

Stopping: an accepted step with ``F − F_new ≤ 1e-10 · F``, ``‖∇F‖_∞ ≤ 1e-9``, or a rejected
step smaller than ``1e-14 · (1 + ‖x‖_∞)`` (no representable progress left). Optionally
(``decrement_tolerance``, off by default; GNC's warm-started rounds use it) also an accepted
step after which the decrease predicted for the next step with the last factorisation,
``gᵀ(H + λD)⁻¹g`` at the new ``g`` (one triangular solve), is ``≤ tol · F``: the step that would
only confirm convergence is then not factorised.

Sparse linear algebra: ``H``'s block pattern depends only on the edge list, so the CSC structure,
the map from every per-edge 3×3 block entry to its CSC slot, and a fill-reducing order are built
once per graph. The order is METIS nested dissection (pymetis) of the pose graph, expanded to the
three coordinates of each pose: on City10000 its LU is ≈ 5 % sparser and ≈ 35 % faster than
SuperLU's own MMD(AᵀA + A) order (measured). Each iteration scatters the block values with
``np.bincount`` and runs SuperLU in the natural order with diagonal pivots (``H + λD`` is SPD).

``rotation_cost="chordal"`` minimises ``F_chordal`` instead (SE-Sync's cost, rotation residual
``4κ(1 − cos r_θ)``): its landscape differs, and on high-noise graphs LM on ``F_chordal`` followed
by LM on ``F`` reaches a much lower minimum of ``F`` than LM on ``F`` directly (M3500c, measured).
:func:`reference_optimum` therefore keeps the better of both paths from the chordal start.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import pymetis
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from popbench import objective, se2
from popbench.distributed import DistributedProblem
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.methods import Budget, Result
from popbench.solvers.chordal import chordal_initialisation

ROTATION_COSTS = ("geodesic", "chordal")

_INITIAL_DAMPING = 1e-8
_SHRINK_FLOOR = 0.1
_MIN_DAMPING_SCALE = 1e-6
_STEP_TOLERANCE = 1e-14
# SuperLU settings for symmetric positive-definite matrices: diagonal pivots, symmetric mode.
_SPD_OPTIONS = {"diag_pivot_thresh": 0.0, "options": {"SymmetricMode": True}}


class LMOutcome(NamedTuple):
    """What :func:`solve_graph` returns.

    Attributes:
        poses: ``(N, 3)`` final estimate.
        history: ``(iterations + 1,)`` ``F`` (eq. 1) of the current estimate after each step, the
            first entry the start (a rejected step repeats the previous value).
        iterations: LM steps taken (accepted or rejected).
        converged: True when a stopping test fired before the iteration or time budget ran out.
        accepted: accepted steps.
        gradient_norm: ``‖∇C‖_∞`` of the minimised cost ``C`` over the free poses at ``poses``.
        history_s: ``(iterations + 1,)`` wall time [s] since the start of the solve at each
            ``history`` entry, or None (an outcome assembled from several solves).
    """

    poses: np.ndarray
    history: np.ndarray
    iterations: int
    converged: bool
    accepted: int
    gradient_norm: float
    history_s: np.ndarray | None = None

    @property
    def F(self) -> float:  # noqa: N802 - the paper's symbol
        return float(self.history[-1])


class NormalEquations:
    """Sparse structure of the gauge-fixed ``H = JᵀJ`` (``3(N−1)`` square), built once per graph.

    Free pose ``i`` owns the renumbered coordinates ``3·position[i] + (0, 1, 2)``, ``position``
    a fill-reducing order. Per edge the four 3×3 blocks ``(p,p), (p,q), (q,p), (q,q)`` of ``H``
    go to fixed CSC slots; entries touching pose 0 go to one extra, discarded slot.
    """

    def __init__(self, graph: PoseGraph) -> None:
        position = np.full(graph.num_poses, -1, dtype=np.int64)  # pose 0: -1 (fixed)
        position[1:] = _vertex_order(graph)
        size = 3 * (graph.num_poses - 1)
        block_rows = position[np.stack([graph.tails, graph.tails, graph.heads, graph.heads], 1)]
        block_cols = position[np.stack([graph.tails, graph.heads, graph.tails, graph.heads], 1)]
        offsets = np.arange(3)
        rows = 3 * block_rows[:, :, None, None] + offsets[:, None]  # (M, 4, 3, 1)
        cols = 3 * block_cols[:, :, None, None] + offsets[None, :]  # (M, 4, 1, 3)
        rows, cols = (a.ravel() for a in np.broadcast_arrays(rows, cols))
        keys = np.where((rows >= 0) & (cols >= 0), cols * size + rows, -1)  # CSC (column) order
        unique_keys, slots = np.unique(keys, return_inverse=True)
        if unique_keys.size and unique_keys[0] == -1:  # gauge entries -> the last, extra slot
            unique_keys = unique_keys[1:]
            slots = np.where(slots == 0, unique_keys.size, slots - 1)
        self.size = size
        self.nnz = unique_keys.size
        self.slots = slots
        self.indices = (unique_keys % size).astype(np.int32)
        self.indptr = np.searchsorted(unique_keys // size, np.arange(size + 1)).astype(np.int32)
        diagonal = np.arange(size)
        self.diagonal_slots = np.searchsorted(unique_keys, diagonal * size + diagonal)
        # Renumbered coordinate k is entry free_dof[k] of the flattened (N, 3) pose array.
        self.free_dof = np.empty(size, dtype=np.int64)
        self.free_dof[(3 * position[1:, None] + offsets).ravel()] = np.arange(
            3, 3 * graph.num_poses
        )
        self.edge_dof = np.concatenate([3 * position[graph.tails], 3 * position[graph.heads]])

    def hessian_values(self, lin: objective.Linearisation) -> np.ndarray:
        """CSC values of ``H = JᵀJ`` over the free poses (renumbered), ``(nnz,)``."""
        jacobians = np.stack([lin.jac_tail, lin.jac_head], 1)  # (M, 2, 3, 3): tail, head
        # (M, 2, 2, 3, 3) blocks J_aᵀ J_b in the slot order (p,p), (p,q), (q,p), (q,q); einsum's
        # optimised path: the products and sums of a batched matmul, ≈ 5× faster (measured)
        blocks = np.einsum("maki,mbkj->mabij", jacobians, jacobians, optimize=True)
        return np.bincount(self.slots, blocks.ravel(), self.nnz + 1)[: self.nnz]

    def gradient(self, lin: objective.Linearisation) -> np.ndarray:
        """``g = Jᵀe`` over the free poses (renumbered), ``(3(N−1),)`` (= ½ ∇F)."""
        per_edge = np.concatenate(
            [
                np.einsum("mij,mi->mj", lin.jac_tail, lin.errors),
                np.einsum("mij,mi->mj", lin.jac_head, lin.errors),
            ]
        )
        keep = self.edge_dof >= 0
        dof = self.edge_dof[keep, None] + np.arange(3)
        return np.bincount(dof.ravel(), per_edge[keep].ravel(), self.size)

    def system(self, hessian: np.ndarray, damping: np.ndarray) -> sp.csc_matrix:
        """``H + diag(damping)`` as a CSC matrix."""
        values = hessian.copy()
        values[self.diagonal_slots] += damping
        return sp.csc_matrix((values, self.indices, self.indptr), shape=(self.size, self.size))

    def update(self, poses: np.ndarray, step: np.ndarray) -> np.ndarray:
        """``x + δ`` for ``δ`` in renumbered free coordinates, headings wrapped, ``(N, 3)``."""
        flat = poses.ravel().copy()
        flat[self.free_dof] += step
        moved = flat.reshape(poses.shape)
        moved[:, 2] = se2.wrap(moved[:, 2])
        return moved


def _vertex_order(graph: PoseGraph) -> np.ndarray:
    """Position of each free pose ``1..N−1`` in a METIS nested-dissection order, ``(N−1,)``."""
    num_free = graph.num_poses - 1
    ends = np.concatenate([graph.tails, graph.heads]) - 1
    others = np.concatenate([graph.heads, graph.tails]) - 1
    keep = (ends >= 0) & (others >= 0) & (ends != others)
    adjacency = sp.csr_matrix(
        (np.ones(int(keep.sum())), (ends[keep], others[keep])), shape=(num_free, num_free)
    )
    adjacency.sum_duplicates()
    _, new_position = pymetis.nested_dissection(
        adjacency=pymetis.CSRAdjacency(adj_starts=adjacency.indptr, adjacent=adjacency.indices)
    )
    return np.asarray(new_position, dtype=np.int64)


def _linearise(
    graph: PoseGraph,
    poses: np.ndarray,
    rotation_cost: str,
    sqrt_weights: np.ndarray | None = None,
) -> tuple[objective.Linearisation, float]:
    """Whitened residuals and Jacobians of the minimised cost, and ``F`` (eq. 1, unweighted) at
    ``poses``.

    ``"geodesic"``: ``F`` itself. ``"chordal"``: ``F_chordal``, whose rotation residual is
    ``4κ(1 − cos r_θ) = (2√(2κ) sin(r_θ/2))²``, derivative ``√2 cos(r_θ/2) · d(√κ r_θ)``.
    ``sqrt_weights`` (``(M,)``, optional) scales each edge's residual and Jacobian rows by
    ``√w_e``, so the minimised cost is ``Σ_e w_e ‖e_e‖²``.
    """
    lin = objective.linearise(graph, poses)
    value = float(np.sum(lin.errors**2))
    if rotation_cost == "chordal":
        kappa, _ = objective.weights(graph.information)
        half_angle = 0.5 * lin.errors[:, 2] / np.sqrt(kappa)  # r_θ / 2
        errors = lin.errors.copy()
        errors[:, 2] = 2.0 * np.sqrt(2.0 * kappa) * np.sin(half_angle)
        factor = np.sqrt(2.0) * np.cos(half_angle)[:, None]
        jac_tail, jac_head = lin.jac_tail.copy(), lin.jac_head.copy()
        jac_tail[:, 2] *= factor
        jac_head[:, 2] *= factor
        lin = objective.Linearisation(errors, jac_tail, jac_head)
    if sqrt_weights is not None:
        lin = objective.Linearisation(
            lin.errors * sqrt_weights[:, None],
            lin.jac_tail * sqrt_weights[:, None, None],
            lin.jac_head * sqrt_weights[:, None, None],
        )
    return lin, value


def solve_graph(
    graph: PoseGraph,
    poses0: np.ndarray,
    iterations: int = 100,
    *,
    rotation_cost: str = "geodesic",
    relative_tolerance: float = 1e-10,
    gradient_tolerance: float = 1e-9,
    seconds: float | None = None,
    edge_weights: np.ndarray | None = None,
    structure: NormalEquations | None = None,
    decrement_tolerance: float = 0.0,
) -> LMOutcome:
    """Minimise ``F`` (or ``F_chordal``) from ``poses0`` by sparse Levenberg–Marquardt, pose 0
    fixed; with ``edge_weights`` the weighted cost ``Σ_e w_e ‖e_e‖²`` instead.

    Args:
        graph: the pose graph (connected; its own ``poses`` are not used).
        poses0: ``(N, 3)`` start.
        iterations: at most this many LM steps (accepted or rejected).
        rotation_cost: ``"geodesic"`` minimises ``F`` (eq. 1), ``"chordal"`` ``F_chordal``.
        relative_tolerance: stop after an accepted step with ``C − C_new ≤ tol · C``.
        gradient_tolerance: stop when ``‖∇C‖_∞`` over the free poses is at most this (units
            of the cost per metre / radian).
        seconds: optional wall-clock cap [s], checked before each step.
        edge_weights: optional ``(M,)`` per-edge weights ``w_e ≥ 0`` (dimensionless) of the
            minimised cost, e.g. robust IRLS / GNC weights; the stopping tests apply to the
            weighted cost. Edges of weight 0 drop out: the weighted graph must still pin every
            pose (connected through positive weights).
        structure: ``NormalEquations(graph)`` built by the caller, for repeated solves on one
            edge list (GNC's rounds); built here when None. Same numbers either way.
        decrement_tolerance: when > 0, also stop after an accepted step whose predicted next
            decrease with the last factorisation is at most this times the cost (module
            docstring); 0 (default) keeps the plain LM above.

    Returns:
        :class:`LMOutcome` (its ``history`` is always ``F``, eq. 1, unweighted).
    """
    if rotation_cost not in ROTATION_COSTS:
        raise ValueRangeError("rotation cost", rotation_cost, " | ".join(ROTATION_COSTS))
    sqrt_weights = None
    if edge_weights is not None:
        edge_weights = np.asarray(edge_weights, dtype=np.float64)
        if edge_weights.shape != (graph.num_edges,) or np.any(~(edge_weights >= 0.0)):
            raise ValueRangeError(
                "edge weights", edge_weights.shape, f"({graph.num_edges},) values >= 0"
            )
        sqrt_weights = np.sqrt(edge_weights)
    started = time.perf_counter()
    poses = np.array(poses0, dtype=np.float64)
    poses[:, 2] = se2.wrap(poses[:, 2])
    lin, value = _linearise(graph, poses, rotation_cost, sqrt_weights)
    history, history_s = [value], [time.perf_counter() - started]
    if graph.num_poses < 2:
        return LMOutcome(poses, np.array(history), 0, True, 0, 0.0, np.array(history_s))
    normal = NormalEquations(graph) if structure is None else structure
    cost = float(np.sum(lin.errors**2))
    hessian, gradient = normal.hessian_values(lin), normal.gradient(lin)
    damping, growth = _INITIAL_DAMPING, 2.0
    converged, accepted = False, 0
    for _ in range(iterations):
        if 2.0 * np.max(np.abs(gradient)) <= gradient_tolerance:
            converged = True
            break
        if seconds is not None and time.perf_counter() - started > seconds:
            break
        scale = np.maximum(hessian[normal.diagonal_slots], _MIN_DAMPING_SCALE)
        lu = splu(normal.system(hessian, damping * scale), permc_spec="NATURAL", **_SPD_OPTIONS)
        step = -lu.solve(gradient)
        model_decrease = float(-gradient @ step + damping * (step * scale) @ step)
        trial = normal.update(poses, step)
        trial_lin, trial_value = _linearise(graph, trial, rotation_cost, sqrt_weights)
        trial_cost = float(np.sum(trial_lin.errors**2))
        if trial_cost < cost:
            gain = (cost - trial_cost) / model_decrease
            damping *= max(_SHRINK_FLOOR, 1.0 - (2.0 * gain - 1.0) ** 3)
            growth = 2.0
            decrease = cost - trial_cost
            poses, lin, cost, value = trial, trial_lin, trial_cost, trial_value
            hessian, gradient = normal.hessian_values(lin), normal.gradient(lin)
            accepted += 1
            history.append(value)
            history_s.append(time.perf_counter() - started)
            if decrease <= relative_tolerance * (cost + decrease):
                converged = True
                break
            if decrement_tolerance > 0.0 and gradient @ lu.solve(gradient) <= (
                decrement_tolerance * cost
            ):  # the next step's predicted decrease, with the last factorisation
                converged = True
                break
        else:
            damping *= growth
            growth *= 2.0
            history.append(value)
            history_s.append(time.perf_counter() - started)
            if np.max(np.abs(step)) <= _STEP_TOLERANCE * (1.0 + np.max(np.abs(poses))):
                converged = True
                break
    gradient_norm = 2.0 * float(np.max(np.abs(gradient)))
    return LMOutcome(
        poses,
        np.array(history),
        len(history) - 1,
        converged,
        accepted,
        gradient_norm,
        np.array(history_s),
    )


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    chordal_stage: bool = True,
    relative_tolerance: float = 1e-10,
    gradient_tolerance: float = 1e-9,
    **_: object,
) -> Result:
    """Method ``"lm"``: centralised sparse LM on the whole graph (robots are ignored).

    Args:
        problem: the problem; LM starts from its start, ``problem.graph.poses``.
        budget: ``iterations`` LM steps (accepted or rejected; default 1000) and an optional
            wall-clock cap.
        chordal_stage: first minimise ``F_chordal``, then ``F`` (both share the budget). On by
            default: measured from the chordal start on the eight Table I datasets, it reaches
            the same F* on seven and a lower minimum on m3500c (2580.45 vs 4071.18), in fewer
            steps there; ``-o chordal_stage=false`` gives plain LM on ``F``.
        relative_tolerance, gradient_tolerance: stopping tests of :func:`solve_graph`.
        _: options of other methods (``seed``, ...), ignored: LM is deterministic.

    Returns:
        :class:`~popbench.methods.Result`; ``parallel_s == wall_s`` (one process),
        ``history`` = ``F`` per LM step, ``messages == 0``.
    """
    budget = Budget() if budget is None else budget
    tolerances = {
        "relative_tolerance": relative_tolerance,
        "gradient_tolerance": gradient_tolerance,
    }
    graph = problem.graph
    started = time.perf_counter()
    start = graph.poses
    stages = ("chordal", "geodesic") if chordal_stage else ("geodesic",)
    poses, histories, steps_left = start, [], budget.iterations
    converged, accepted, gradient_norm = True, 0, 0.0
    for rotation_cost in stages:
        elapsed = time.perf_counter() - started
        seconds_left = None if budget.seconds is None else budget.seconds - elapsed
        outcome = solve_graph(
            graph,
            poses,
            steps_left,
            rotation_cost=rotation_cost,
            seconds=seconds_left,
            **tolerances,
        )
        poses, steps_left = outcome.poses, steps_left - outcome.iterations
        histories.append(outcome.history if not histories else outcome.history[1:])
        converged, accepted = outcome.converged, accepted + outcome.accepted
        gradient_norm = outcome.gradient_norm
    wall_s = time.perf_counter() - started
    history = np.concatenate(histories)
    costs = objective.evaluate(graph, poses)
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=wall_s,
        parallel_s=wall_s,
        iterations=history.size - 1,
        history=history,
        extras={
            "converged": converged,
            "accepted": accepted,
            "gradient_norm": gradient_norm,
            "init": problem.start,
            "chordal_stage": chordal_stage,
        },
    )


def reference_optimum(graph: PoseGraph, iterations: int = 500) -> LMOutcome:
    """``F*``: the better of two LM runs from the chordal initialisation — LM on ``F``, and LM
    on ``F_chordal`` followed by LM on ``F`` (see the module docstring). Uncertified.

    Returns:
        The :class:`LMOutcome` with the lower final ``F`` (``.F``, ``.poses``); for the
        two-stage run, ``history`` and the counts cover both stages.
    """
    start = chordal_initialisation(graph)
    direct = solve_graph(graph, start, iterations)
    first = solve_graph(graph, start, iterations, rotation_cost="chordal")
    second = solve_graph(graph, first.poses, iterations)
    staged = LMOutcome(
        poses=second.poses,
        history=np.concatenate([first.history, second.history[1:]]),
        iterations=first.iterations + second.iterations,
        converged=second.converged,
        accepted=first.accepted + second.accepted,
        gradient_norm=second.gradient_norm,
    )
    return staged if staged.F < direct.F else direct


def chordal_optimum(graph: PoseGraph, iterations: int = 500) -> float:
    """``F_chordal*``: the ``F_chordal`` that LM on ``F_chordal`` reaches from the chordal
    initialisation (the first stage of :func:`reference_optimum`); uncertified. The reference
    of the histories that record ``F_chordal`` (the RBCD and MM baselines)."""
    outcome = solve_graph(graph, chordal_initialisation(graph), iterations, rotation_cost="chordal")
    return objective.chordal_objective(graph, outcome.poses)
