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
1e-8 (nearly Gauss–Newton); Nielsen's shrink floor is 1/10 instead of his 1/3 (both measured:
docs/lm.md). Headings are wrapped to ``[-π, π)`` after each step.

One *iteration* is one LM step, accepted or rejected (each costs one factorisation).

Stopping: an accepted step with ``F − F_new ≤ 1e-10 · F``, ``‖∇F‖_∞ ≤ 1e-9``, or a rejected
step smaller than ``1e-14 · (1 + ‖x‖_∞)`` (no representable progress left). Optionally
(``decrement_tolerance``, off by default; GNC's warm-started rounds use it) also an accepted
step after which the decrease predicted for the next step with the last factorisation,
``gᵀ(H + λD)⁻¹g`` at the new ``g`` (one triangular solve), is ``≤ tol · F``: the step that would
only confirm convergence is then not factorised.

Sparse linear algebra: ``H``'s block pattern depends only on the edge list, so the CSC structure,
the map from every per-edge 3×3 block entry to its CSC slot, and a fill-reducing order are built
once per graph. The order is METIS nested dissection of the pose graph, expanded to the three
coordinates of each pose; each iteration scatters the block values with ``np.bincount`` and
factorises ``H + λD`` (SPD) by :func:`popbench.sparse.spd_lu` (measured: docs/sparse.md).

``rotation_cost="chordal"`` minimises ``F_chordal`` instead (SE-Sync's cost, rotation residual
``4κ(1 − cos r_θ)``): its landscape differs, and on high-noise graphs LM on ``F_chordal`` followed
by LM on ``F`` can reach a much lower minimum of ``F`` than LM on ``F`` directly (docs/lm.md).
:func:`reference_optimum` therefore keeps the better of both paths from the chordal start.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np
import scipy.sparse as sp

from popbench import objective, se2
from popbench.choices import OBJECTIVES
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.methods import Budget, Result
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.chordal import chordal_initialisation
from popbench.sparse import nested_dissection, spd_lu
from popbench.status import Status

ROTATION_COSTS = ("geodesic", "chordal")

_INITIAL_DAMPING = 1e-8
_SHRINK_FLOOR = 0.1
_MIN_DAMPING_SCALE = 1e-6
_STEP_TOLERANCE = 1e-14


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


def fixed_poses(graph: PoseGraph) -> np.ndarray:
    """The internal indices of the poses held fixed, ``(K,)`` int64: the graph's ``FIX`` poses,
    or vertex 0 (the gauge) when it has none."""
    return np.array([0] if graph.fixed is None else graph.fixed, dtype=np.int64)


class NormalEquations:
    """Sparse structure of the gauge-fixed ``H = JᵀJ`` (``3(N−K)`` square), built once per graph.

    The ``K`` fixed poses (:func:`fixed_poses`: vertex 0, or the graph's ``FIX`` poses) have no
    columns. Free pose ``i`` owns the renumbered coordinates ``3·position[i] + (0, 1, 2)``,
    ``position`` a fill-reducing order. Per edge the four 3×3 blocks ``(p,p), (p,q), (q,p),
    (q,q)`` of ``H`` go to fixed CSC slots; entries touching a fixed pose go to one extra,
    discarded slot.
    """

    def __init__(self, graph: PoseGraph) -> None:
        free = np.ones(graph.num_poses, dtype=bool)
        free[fixed_poses(graph)] = False
        self.free = free
        position = np.full(graph.num_poses, -1, dtype=np.int64)  # fixed poses: -1
        position[free] = _vertex_order(graph, free)
        size = 3 * int(free.sum())
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
        self.free_dof[(3 * position[free, None] + offsets).ravel()] = (
            3 * np.flatnonzero(free)[:, None] + offsets
        ).ravel()
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
        """``x + δ`` for ``δ`` in renumbered free coordinates, free headings wrapped, ``(N, 3)``;
        the fixed poses are copied bit for bit."""
        flat = poses.ravel().copy()
        flat[self.free_dof] += step
        moved = flat.reshape(poses.shape)
        moved[self.free, 2] = se2.wrap(moved[self.free, 2])
        return moved


def _vertex_order(graph: PoseGraph, free: np.ndarray) -> np.ndarray:
    """Position of each free pose (``free``: ``(N,)`` bool) in a METIS nested-dissection order,
    ``(N_free,)``, in vertex order."""
    num_free = int(free.sum())
    if num_free == 0:
        return np.zeros(0, dtype=np.int64)
    index = np.cumsum(free) - 1  # vertex -> index among the free poses
    ends = np.concatenate([graph.tails, graph.heads])
    others = np.concatenate([graph.heads, graph.tails])
    keep = free[ends] & free[others] & (ends != others)
    adjacency = sp.csr_matrix(
        (np.ones(int(keep.sum())), (index[ends[keep]], index[others[keep]])),
        shape=(num_free, num_free),
    )
    adjacency.sum_duplicates()
    _, position = nested_dissection(adjacency.indptr, adjacency.indices)
    return position


def _linearise(
    graph: PoseGraph,
    poses: np.ndarray,
    cost: str,
    sqrt_weights: np.ndarray | None = None,
    reported: str = "F",
) -> tuple[objective.Linearisation, float]:
    """Whitened residuals and Jacobians of the minimised ``cost`` (one of
    :data:`popbench.objective.COSTS`), and the ``reported`` cost (``"F"`` or ``"chi2"``,
    unweighted) at ``poses``.

    ``sqrt_weights`` (``(M,)``, optional) scales each edge's residual and Jacobian rows by
    ``√w_e``, so the minimised cost is ``Σ_e w_e ‖e_e‖²``.
    """
    if reported == "F":
        lin = objective.linearise(graph, poses)
        value = float(np.sum(lin.errors**2))
        if cost == "F_chordal":
            lin = objective.chordal_rotation(lin, graph.information)
    else:
        lin = objective.linearisation(graph, poses, cost)
        value = float(np.sum(lin.errors**2)) if cost == reported else objective.chi2(graph, poses)
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
    cost: str = "F",
) -> LMOutcome:
    """Minimise ``F`` (or ``F_chordal``, or ``chi2``) from ``poses0`` by sparse
    Levenberg–Marquardt, the fixed poses (:func:`fixed_poses`) held at their ``poses0`` values
    bit for bit; with ``edge_weights`` the weighted cost ``Σ_e w_e ‖e_e‖²`` instead.

    Args:
        graph: the pose graph (connected; its own ``poses`` are not used).
        poses0: ``(N, 3)`` start.
        iterations: at most this many LM steps (accepted or rejected).
        rotation_cost: ``"geodesic"`` minimises ``cost``, ``"chordal"`` ``F_chordal`` (a stage
            towards ``cost``).
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
        cost: ``"F"`` (eq. 1) or ``"chi2"`` (g2o's, full information).

    Returns:
        :class:`LMOutcome` (its ``history`` is always ``cost``, unweighted).
    """
    if rotation_cost not in ROTATION_COSTS:
        raise ValueRangeError("rotation cost", rotation_cost, " | ".join(ROTATION_COSTS))
    if cost not in OBJECTIVES:
        raise ValueRangeError("objective", cost, " | ".join(OBJECTIVES))
    reported = cost
    minimised = "F_chordal" if rotation_cost == "chordal" else cost
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
    normal = NormalEquations(graph) if structure is None else structure
    poses[normal.free, 2] = se2.wrap(poses[normal.free, 2])
    lin, value = _linearise(graph, poses, minimised, sqrt_weights, reported)
    history, history_s = [value], [time.perf_counter() - started]
    if normal.size == 0:
        return LMOutcome(poses, np.array(history), 0, True, 0, 0.0, np.array(history_s))
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
        lu = spd_lu(normal.system(hessian, damping * scale))
        step = -lu.solve(gradient)
        model_decrease = float(-gradient @ step + damping * (step * scale) @ step)
        trial = normal.update(poses, step)
        trial_lin, trial_value = _linearise(graph, trial, minimised, sqrt_weights, reported)
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
    objective: str = "F",
    **_: object,
) -> Result:
    """Method ``"lm"``: centralised sparse LM on the whole graph (robots are ignored), the
    graph's ``FIX`` poses (or vertex 0) held fixed.

    Args:
        problem: the problem; LM starts from its start, ``problem.graph.poses``.
        budget: ``iterations`` LM steps (accepted or rejected; default 1000) and an optional
            wall-clock cap.
        chordal_stage: first minimise ``F_chordal``, then ``F`` (both share the budget); on by
            default (measured: docs/lm.md); ``-o chordal_stage=false`` gives plain LM on ``F``.
        relative_tolerance, gradient_tolerance: stopping tests of :func:`solve_graph`.
        objective: the cost minimised, ``"F"`` (eq. 1; the tables) or ``"chi2"`` (g2o's, with
            each edge's full information; ``popbench solve``'s default). docs/solve.md.
        _: options of other methods (``seed``, ...), ignored: LM is deterministic.

    Returns:
        :class:`~popbench.methods.Result`; ``parallel_s == wall_s`` (one process),
        ``history`` = ``objective`` per LM step (``history_objective``), ``messages == 0``,
        ``status`` the final stage's stopping test and gradient norm.
    """
    from popbench.objective import evaluate

    budget = Budget() if budget is None else budget
    tolerances = {
        "relative_tolerance": relative_tolerance,
        "gradient_tolerance": gradient_tolerance,
        "cost": objective,
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
    costs = evaluate(graph, poses)
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=wall_s,
        parallel_s=wall_s,
        iterations=history.size - 1,
        history=history,
        extras={"accepted": accepted, "init": problem.start, "chordal_stage": chordal_stage},
        history_objective=objective,
        status=Status(
            objective=objective,
            converged=converged,
            rounds=history.size - 1,
            gradient_norm=gradient_norm,
            cost=float(history[-1]),
            start_cost=float(history[0]),
        ),
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
