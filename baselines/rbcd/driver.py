"""RBCD / RBCD++: the block-coordinate iteration and the method around it (dpgo, Tian et al.
2021: RBCD, RBCD++ and its fixed restart; ML-PGO, Li et al. 2024: the adaptive restart).

**One iteration = one round in which every robot of one colour class updates, in parallel**
(:mod:`baselines.rbcd.blocks`), all other robots fixed; the class is chosen greedily (largest
summed squared Riemannian-gradient norm, the block version of dpgo's greedy robot selection) or
round-robin. With one robot per class this is exactly dpgo's greedy RBCD; with more, it is the
parallel (Jacobi over an independent set) count, comparable to MM-PGO where every robot updates
each iteration. The acceleration, restarts and accounting: :func:`run_rbcd`; the method:
:func:`solve_rbcd` and :class:`MethodOptions`, which cc-pgo and ml-pgo share.

Example:
    >>> from popbench.methods import Budget
    >>> from popbench.problems.synthetic import make_problem
    >>> from baselines.rbcd import MethodOptions
    >>> problem = make_problem(robots=3, poses_per_robot=20, seed=0)
    >>> start = problem.graph.poses
    >>> from popbench.objective import evaluate
    >>> result = MethodOptions().solve(problem.graph, problem.robots, Budget(30), True, "adaptive")
    >>> bool(result.F < evaluate(problem.graph, start).F)
    True
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from typing import NamedTuple, Self

import numpy as np
import scipy.sparse as sp

from baselines.rbcd.blocks import ClassBlock, batch_groups, class_blocks, colour_robots
from baselines.rbcd.local_solver import LocalOptions, local_update
from baselines.rbcd.relaxation import (
    apply_q,
    connection_laplacian,
    cost_change,
    edge_relaxed_cost,
    flat,
    lift,
    random_stiefel,
    relaxed_cost,
)
from baselines.rbcd.rounding import ROUNDINGS, certificate_min_eigenvalue, round_solution
from baselines.rbcd.stiefel import pose_gradient_norms, project_manifold
from popbench import objective
from popbench.errors import ValueRangeError
from popbench.graph import PoseGraph
from popbench.methods import Budget, Result

RESTART_INTERVAL = 30  # fixed restart period of RBCD++ (dpgo restartInterval)
BATCH_BELOW_POSES = 300  # robots smaller than this are batched (see batch_groups)
ADAPTIVE_RESTART_TOLERANCE = 1e-9  # relative increase of f that triggers an adaptive restart


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

    **Acceleration** (RBCD++, dpgo), with ``B`` blocks (colour classes):
    ``γ ← (1 + √(1 + 4B²γ²)) / (2B)``, ``α ← 1/(γB)``, ``Y ← Proj((1−α)X + αV)``, the selected block
    ``X_b ← LocalOpt(Y)`` (others ``X ← Y``), ``V ← Proj(V + γ(X − Y))``. Restart ("fixed", cc-pgo):
    every ``restart_interval`` (30) iterations a plain update from ``X`` and ``V = X``, ``γ = 0``;
    ("adaptive", ml-pgo, Li et al. 2024): whenever the objective increases by more than a relative
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
        else:  # RBCD++: γ ← (1 + √(1 + 4B²γ²)) / (2B), α ← 1/(γB), B = num_blocks
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


def scaled_local_options(options: RBCDOptions, start_gradient: float) -> RBCDOptions:
    """``options`` with the local gradient tolerance ``min(gradient_tolerance,
    relative_gradient_tolerance × start_gradient)`` (``start_gradient`` = ``‖grad f(X₀)‖``)."""
    local = options.local
    tolerance = min(local.gradient_tolerance, local.relative_gradient_tolerance * start_gradient)
    return dataclasses.replace(
        options, local=dataclasses.replace(local, gradient_tolerance=tolerance)
    )


def robot_shares(block: ClassBlock, elapsed_s: float, products: np.ndarray) -> np.ndarray:
    """Split the measured time ``elapsed_s`` [s] of a batched class update among its robots in
    proportion to their work, ``nnz(Q_αα) × (Hessian–vector products + 1)`` (each product is
    one sparse multiply, one preconditioner solve of similar fill and a few vector operations on
    the robot's rows; the ``+ 1`` is the gradient and cost evaluation every update does).
    Returns ``(k,)`` seconds: what each robot would have spent computing alone."""
    work = block.robot_nnz * (products + 1.0)
    return elapsed_s * work / work.sum()


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
