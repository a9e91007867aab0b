"""Graduated non-convexity (GNC; Yang, Antonante, Tzoumas & Carlone, RA-L 2020) on the project's
sparse LM: the centralised robust reference (method ``"gnc"``), the floor of Table II.

Robust cost over the whitened residuals of the chosen cost (``objective``: eq. 1,
:func:`popbench.objective.linearise`, ``r_e² = ‖e_e‖² = κ_e r_θ² + τ_e ‖r_t‖²``; or g2o's
``chi2``, ``r_e² = e_eᵀ Λ_e e_e`` with the full information; both dimensionless)::

    min_x Σ_e ρ(r_e²),   TLS: ρ(r²) = min(r², c̄²)   GM: ρ(r²) = c̄² r² / (c̄² + r²)

with the inlier threshold ``c̄² = χ²₃(0.99) = 11.345`` (:data:`THRESHOLD`): an inlier whose
noise matches its information has ``r² ≈ χ²₃`` (three whitened coordinates; exactly for
isotropic translation information), so 1 % of the inliers lie beyond it.

GNC replaces ρ by a surrogate ``ρ_μ`` that is convex for one extreme of ``μ`` and equals ρ at
the other, and alternates (Black–Rangarajan duality) a weighted least-squares solve with a
closed-form weight update, moving μ by ``mu_step`` (1.4, GTSAM's default) after each round:

* **TLS** (default): ``μ₀ = c̄² / (2 r²_max − c̄²)``, ``μ ← 1.4 μ`` (towards TLS as μ → ∞);
  ``w = 1`` if ``r² ≤ μ/(μ+1) c̄²``, ``w = 0`` if ``r² ≥ (μ+1)/μ c̄²``, else
  ``w = c̄ √(μ(μ+1)) / r − μ``.
* **GM** (Geman–McClure): ``μ₀ = 2 r²_max / c̄²``, ``μ ← max(1, μ / 1.4)`` (GM itself at μ = 1);
  ``w = (μ c̄² / (r² + μ c̄²))²``.

``r²_max`` is the largest residual over the edges not known to be inliers at the non-robust
solution (all weights 1, the first LM solve), as in the paper's Remark 5 (GTSAM takes it at
the start instead, over every factor). If ``2 r²_max ≤ c̄²`` (TLS) nothing can be an outlier
and that solution is returned.

Known inliers (weight 1 throughout): the odometry edges, kinds ODOMETRY and INTER_RELATIVE
(the outlier model of :mod:`popbench.outliers` never corrupts them by default); they also keep
the weighted graph connected when loop closures get weight 0.

Inlier mask: TLS: final weight ≥ ½ (the final weights are binary); GM: final ``r² ≤ c̄²``
(the weight at the threshold, ``¼`` at μ = 1, as for MM-PGO's kernels in
:mod:`baselines.robust`).

One round (the weighted LM solve, its tolerances, the final polish) and the inner starts
(``inner_start``, :data:`BEST_RUNS`): docs/outliers.md, "`gnc`".
"""

from __future__ import annotations

import time

import numpy as np

from popbench import objective
from popbench.choices import OBJECTIVES
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph
from popbench.methods import Budget, Result
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.chordal import chordal_initialisation
from popbench.solvers.initial import anchored
from popbench.solvers.lm import NormalEquations, solve_graph
from popbench.status import Status, free_gradient_norm

SURROGATES = ("tls", "gm")
INNER_STARTS = ("best", "problem", "chordal")
THRESHOLD = objective.CHI2_3_99  # χ²₃(0.99), on ‖e‖² of eq. 1
MU_STEP = 1.4
COST_TOLERANCE = 1e-5
# Relative cost decrease that ends an inner LM solve (GTSAM's LevenbergMarquardtParams default).
INNER_TOLERANCE = 1e-5
WEIGHT_TOLERANCE = 1e-4
# inner_start="best": (start, warm_start) of the runs whose lowest robust cost is kept. The
# cold-started run from the problem's start (GTSAM's scheme) is the one that separates 100
# random false closures on m3500 where the warm one keeps 9 true closures out (docs/outliers.md).
BEST_RUNS = (("problem", True), ("problem", False), ("chordal", True))
ODOMETRY_KINDS = (EdgeKind.ODOMETRY, EdgeKind.INTER_RELATIVE)


def squared_residuals(graph: PoseGraph, poses: np.ndarray, cost: str = "F") -> np.ndarray:
    """``r_e² = ‖e_e‖²`` of ``cost`` (``"F"``, eq. 1, or ``"chi2"``) per edge, ``(M,)``
    (dimensionless)."""
    return objective.edge_squares(graph, poses, cost)


def initial_mu(surrogate: str, max_squared: float, threshold: float = THRESHOLD) -> float:
    """μ₀ from the largest squared residual of the non-robust solution (module docstring);
    ``-1.0`` for TLS when ``2 r²_max ≤ c̄²`` (no edge can be an outlier)."""
    if surrogate == "gm":
        return 2.0 * max_squared / threshold
    denominator = 2.0 * max_squared - threshold
    return threshold / denominator if denominator > 0.0 else -1.0


def next_mu(surrogate: str, mu: float, step: float = MU_STEP) -> float:
    """μ of the next round: TLS ``μ·step``, GM ``max(1, μ/step)``."""
    return mu * step if surrogate == "tls" else max(1.0, mu / step)


def gnc_weights(
    surrogate: str, squared: np.ndarray, mu: float, threshold: float = THRESHOLD
) -> np.ndarray:
    """Closed-form GNC weights in ``[0, 1]`` for squared residuals ``squared`` (``(M,)``) at μ
    (module docstring), same shape."""
    if surrogate == "gm":
        return (mu * threshold / (squared + mu * threshold)) ** 2
    upper = (mu + 1.0) / mu * threshold
    lower = mu / (mu + 1.0) * threshold
    middle = np.sqrt(threshold * mu * (mu + 1.0) / np.maximum(squared, 1e-300)) - mu
    return np.where(squared >= upper, 0.0, np.where(squared <= lower, 1.0, middle))


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    surrogate: str = "tls",
    threshold: float = THRESHOLD,
    inner_start: str = "best",
    warm_start: bool = True,
    inner_iterations: int = 100,
    mu_step: float = MU_STEP,
    inner_tolerance: float = INNER_TOLERANCE,
    objective: str = "F",
    **_: object,
) -> Result:
    """Method ``"gnc"``: centralised GNC (module docstring), robots ignored, the graph's ``FIX``
    poses (or vertex 0) held fixed.

    Args:
        problem: the problem; its graph may hold outliers; ``problem.graph.poses`` is the
            ``"problem"`` inner start.
        budget: ``iterations`` GNC rounds at most (one round = one weight update and one inner
            LM solve; default budget 1000, GNC stops far earlier by its own rule) and an
            optional wall-clock cap [s], checked between rounds.
        surrogate: ``"tls"`` (truncated least squares) or ``"gm"`` (Geman–McClure).
        threshold: ``c̄²``, in units of ``‖e‖²`` (default χ²₃(0.99) = 11.345).
        inner_start: ``"best"``, ``"problem"`` or ``"chordal"`` (below).
        warm_start: start each round's LM from the last round's estimate (default) instead of
            the inner start (GTSAM's choice).
        inner_iterations: LM steps per inner solve at most.
        mu_step: the factor μ moves by per round (> 1).
        inner_tolerance: relative cost decrease that ends an inner solve (the non-robust one and
            each round's; the final polish uses LM's default, 1e-10).
        objective: the cost whose edge terms the kernel takes: ``"F"`` (eq. 1; the tables) or
            ``"chi2"`` (full information; ``popbench solve``'s default).
        _: options of other methods (``seed``, ...), ignored: GNC is deterministic.

    Returns:
        :class:`~popbench.methods.Result`: ``inlier_mask`` from the final weights,
        ``history`` = ``objective`` (over every edge, unweighted) after the non-robust solve and
        each round (the last entry after the final polish),
        ``extras``: ``weights`` (``(M,)``), ``mu`` per round, ``rounds``, ``lm_steps``,
        ``surrogate``, ``threshold``, ``inner_start`` (the start kept), ``robust_cost``;
        ``wall_s`` covers both runs for ``"best"``. ``status``: GNC's stopping rule, the robust
        cost ``Σ_e ρ(r_e²)`` (odometry edges: ``r_e²``) at the result and at the problem's start,
        and its gradient norm (``ρ'(r²)``-weighted) at the result.

    Rounds and the inner start: docs/outliers.md ("`gnc`").
    """
    if objective not in OBJECTIVES:
        raise ValueRangeError("gnc objective", objective, " | ".join(OBJECTIVES))
    if surrogate not in SURROGATES:
        raise ValueRangeError("gnc surrogate", surrogate, " | ".join(SURROGATES))
    if inner_start not in INNER_STARTS:
        raise ValueRangeError("gnc inner start", inner_start, " | ".join(INNER_STARTS))
    if not threshold > 0.0 or not mu_step > 1.0 or not inner_tolerance > 0.0:
        raise ValueRangeError(
            "gnc threshold / mu_step / inner_tolerance",
            (threshold, mu_step, inner_tolerance),
            "> 0 / > 1 / > 0",
        )
    budget = Budget() if budget is None else budget
    started = time.perf_counter()
    if inner_start != "best":
        runs = ((inner_start, warm_start),)
    elif warm_start:
        runs = BEST_RUNS
    else:
        runs = (("problem", False), ("chordal", False))
    structure = NormalEquations(problem.graph)  # one sparse pattern and order for every solve
    options = (surrogate, threshold, inner_iterations, mu_step, inner_tolerance, objective)
    results = [
        _solve_from(problem, budget, start, structure, warm, *options) for start, warm in runs
    ]
    result = min(results, key=lambda r: r.extras["robust_cost"])
    result.wall_s = result.parallel_s = time.perf_counter() - started
    return result


def _solve_from(
    problem: DistributedProblem,
    budget: Budget,
    inner_start: str,
    structure: NormalEquations,
    warm_start: bool,
    surrogate: str,
    threshold: float,
    inner_iterations: int,
    mu_step: float,
    inner_tolerance: float,
    cost: str,
) -> Result:
    """GNC from one inner start (``"problem"`` or ``"chordal"``); see :func:`solve`."""
    graph = problem.graph
    started = time.perf_counter()
    start = graph.poses
    if inner_start == "chordal":
        start = anchored(graph, chordal_initialisation(graph), graph.poses)
    known = np.isin(graph.kinds, np.array(ODOMETRY_KINDS, dtype=np.int8))
    weights = np.ones(graph.num_edges)
    inner = {
        "structure": structure,
        "relative_tolerance": inner_tolerance,
        "decrement_tolerance": inner_tolerance,
        "cost": cost,
    }
    outcome = solve_graph(graph, start, inner_iterations, **inner)
    poses, lm_steps = outcome.poses, outcome.iterations
    history, mus = [outcome.F], []
    squared = squared_residuals(graph, poses, cost)
    unknown = ~known
    mu = initial_mu(surrogate, float(squared[unknown].max(initial=0.0)), threshold)
    converged = mu <= 0.0
    previous_cost = float(np.sum(squared))
    for _ in range(budget.iterations if not converged else 0):
        if budget.seconds is not None and time.perf_counter() - started > budget.seconds:
            break
        weights = np.where(known, 1.0, gnc_weights(surrogate, squared, mu, threshold))
        origin = poses if warm_start else start
        outcome = solve_graph(graph, origin, inner_iterations, edge_weights=weights, **inner)
        poses, lm_steps = outcome.poses, lm_steps + outcome.iterations
        squared = squared_residuals(graph, poses, cost)
        history.append(outcome.F)
        mus.append(mu)
        budget.round_done(len(mus))
        weighted = float(np.sum(weights * squared))
        if _done(surrogate, mu, weights[unknown], weighted, previous_cost):
            converged = True
            break
        mu, previous_cost = next_mu(surrogate, mu, mu_step), weighted
    # polish: the last estimate to LM's own tolerance at the final weights
    outcome = solve_graph(
        graph, poses, inner_iterations, edge_weights=weights, structure=structure, cost=cost
    )
    poses, lm_steps = outcome.poses, lm_steps + outcome.iterations
    squared = squared_residuals(graph, poses, cost)
    history[-1] = outcome.F
    if surrogate == "tls":
        inlier = weights >= 0.5
    else:
        inlier = squared <= threshold
    inlier |= known
    wall_s = time.perf_counter() - started
    costs = objective.evaluate(graph, poses)
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=wall_s,
        parallel_s=wall_s,
        iterations=len(mus),
        history=np.array(history),
        inlier_mask=inlier,
        history_objective=cost,
        status=robust_status(
            graph, poses, known, (surrogate, threshold, max(mu, 1.0)), cost, converged, len(mus)
        ),
        extras={
            "weights": weights,
            "mu": np.array(mus),
            "rounds": len(mus),
            "lm_steps": lm_steps,
            "surrogate": surrogate,
            "threshold": threshold,
            "inner_start": inner_start,
            "warm_start": warm_start,
            "robust_cost": robust_cost(surrogate, squared, threshold, max(mu, 1.0)),
        },
    )


def robust_status(
    graph: PoseGraph,
    poses: np.ndarray,
    known: np.ndarray,
    kernel: tuple[str, float, float],
    cost: str,
    converged: bool,
    rounds: int,
) -> Status:
    """The :class:`~popbench.status.Status` of GNC's answer: ``C = Σ_known r_e² + Σ_other
    ρ(r_e²)`` (``kernel`` = ``(surrogate, c̄², μ)``, :func:`robust_cost`) at ``poses`` and at
    the problem's start, and ``‖∇C‖_∞`` with ``∇C = Σ_e ρ'(r_e²) ∇r_e²`` (TLS: ``ρ' = 1``
    below ``c̄²``, else 0; GM: the GNC weight at μ)."""

    surrogate, threshold, mu = kernel

    def value(squared: np.ndarray) -> float:
        robust = robust_cost(surrogate, squared[~known], threshold, mu)
        return float(np.sum(squared[known])) + robust

    squared = squared_residuals(graph, poses, cost)
    slopes = (
        (squared < threshold).astype(float)
        if surrogate == "tls"
        else (gnc_weights(surrogate, squared, mu, threshold))
    )
    slopes[known] = 1.0
    return Status(
        objective=cost,
        converged=converged,
        rounds=rounds,
        gradient_norm=free_gradient_norm(graph, poses, cost, slopes),
        cost=value(squared),
        start_cost=value(squared_residuals(graph, graph.poses, cost)),
        robust=surrogate,
    )


def robust_cost(surrogate: str, squared: np.ndarray, threshold: float, mu: float = 1.0) -> float:
    """``Σ_e ρ(r_e²)``: TLS ``min(r², c̄²)``; GM ``μ c̄² r² / (μ c̄² + r²)`` (GM at μ = 1)."""
    if surrogate == "tls":
        return float(np.sum(np.minimum(squared, threshold)))
    return float(np.sum(mu * threshold * squared / (mu * threshold + squared)))


def _done(
    surrogate: str, mu: float, weights: np.ndarray, cost: float, previous_cost: float
) -> bool:
    """GTSAM's stopping rules (module docstring) after a round at ``mu``."""
    if abs(cost - previous_cost) / max(previous_cost, 1e-7) < COST_TOLERANCE:
        return True
    if surrogate == "gm":
        return mu <= 1.0
    binary = (weights <= WEIGHT_TOLERANCE) | (weights >= 1.0 - WEIGHT_TOLERANCE)
    return bool(np.all(binary))
