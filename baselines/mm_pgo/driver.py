"""MM-PGO / AMM-PGO (Fan & Murphey, T-RO 2024): distributed majorisation–minimisation on SE(2),
method ``"mm-pgo"`` — the iteration, its restarts, reweighting and accounting, and the gauge.

Every robot minimises its surrogate of :mod:`baselines.mm_pgo.team` in parallel (one iteration =
every robot updates once); AMM-PGO adds Nesterov extrapolation with the adaptive restart of
:mod:`baselines.mm_pgo.restart`; a robust kernel reweights the edges of
:mod:`baselines.mm_pgo.robust_weights`. The gauge is free in a team, as in MM-PGO's own code
(:func:`gauge_anchors`). Without a robust kernel the returned estimate is the iterate of lowest F
seen (never above the start; docs/mm_pgo.md).

Example:
    >>> from popbench.methods import Budget
    >>> from popbench.objective import evaluate
    >>> from popbench.problems.synthetic import make_problem
    >>> from baselines.mm_pgo import solve
    >>> problem = make_problem(robots=3, poses_per_robot=20, seed=0)
    >>> result = solve(problem, Budget(iterations=50))
    >>> bool(result.F < evaluate(problem.graph, problem.graph.poses).F)
    True
"""

from __future__ import annotations

import time

import numpy as np

from baselines import robust
from baselines.mm_pgo.edges import edge_costs, edge_terms, pose_table
from baselines.mm_pgo.restart import RestartState
from baselines.mm_pgo.robust_weights import ROBUST_MODES, edge_weights, robust_costs
from baselines.mm_pgo.team import TeamSystem
from popbench import objective, se2
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.methods import Budget, Result
from popbench.outliers import precision_recall
from popbench.problems.distributed import DistributedProblem


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
        _: options of other methods (``seed``, ...), ignored: MM-PGO is deterministic.

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
