"""Method ``"local-lm"``: every robot solves its own local graph with LM, then the same
consensus as prop-v1 (:mod:`popbench.consensus.reconcile`).

It is the classical counterpart of prop-v1: the bound a learned local policy is chasing (a
policy can at best bring each local graph to its own optimum) with the same reconciliation.
With ``objective="chi2"`` the local solves minimise g2o's χ² (full information); the consensus
is F's (eq. 1) either way (docs/solve.md).
"""

from __future__ import annotations

import time

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

from popbench import se2
from popbench.choices import OBJECTIVES
from popbench.consensus.reconcile import (
    DEFAULT_CONSENSUS,
    DEFAULT_CONSENSUS_ITERATIONS,
    check_consensus,
    reconcile,
)
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph
from popbench.methods import Budget, Result
from popbench.problems.distributed import DistributedProblem, LocalGraph
from popbench.solvers.lm import solve_graph
from popbench.status import measure

LOCAL_ITERATIONS = 100


def local_optima(
    problem: DistributedProblem,
    iterations: int = LOCAL_ITERATIONS,
    excluded: np.ndarray | None = None,
    starts: list[np.ndarray] | None = None,
    cost: str = "F",
    copy_weight: float | None = None,
    copy_targets: np.ndarray | None = None,
    copy_relative: bool = False,
) -> tuple[list[np.ndarray], np.ndarray]:
    """Every robot's local graph solved by LM (its first owned pose fixed, unless
    ``copy_weight`` ties the separator copies to their owners' estimates).

    Args:
        problem: the distributed problem.
        iterations: LM steps at most per robot.
        excluded: ``(M,)`` bool over the global edges, True for edges left out of every local
            graph (e.g. injected outliers when the optimum serves as an expert's target), or None.
            A vertex that the remaining edges no longer join to the robot's first pose (a
            separator copy seen only over an excluded edge) keeps its start.
        starts: one ``(n_r, 3)`` start per robot (e.g. with placed separator copies); default
            the problem's start, ``problem.split()``.
        cost: the local cost, ``"F"`` (eq. 1) or ``"chi2"``.
        copy_weight: None: the copies are free (the local optimum); ``inf``: the copies are held
            at the problem's start ``problem.graph.poses`` (their owners' estimates before any
            exchange) and the robot's poses are solved around them; ``w > 0``: the copies are
            free but each is pulled to that estimate by a prior (:func:`copy_priors`, weight
            ``w``). The gauge is then the copies (or the priors' anchors), not the first pose.
            Not combined with ``excluded``.
        copy_targets: ``(N, 3)`` the owners' estimates of every global pose that
            ``copy_weight`` ties the copies to (default ``problem.graph.poses``).
        copy_relative: tie only the copies' relative poses per owner (:func:`relative_priors`,
            finite ``copy_weight``; the owners' frames stay free, the first pose the gauge).

    Returns:
        ``(local_poses, seconds)``: one ``(n_r, 3)`` optimum per robot (rows in
        ``local_vertices(r)`` order) and ``(n,)`` each robot's LM wall time [s].
    """
    if copy_weight is not None and (
        excluded is not None or not copy_weight > 0 or (copy_relative and np.isinf(copy_weight))
    ):
        raise ValueRangeError("copy_weight", copy_weight, "w > 0 or inf, without excluded")
    starts = problem.split() if starts is None else starts
    local_poses, seconds = [], np.zeros(problem.num_robots)
    for local, start in zip(problem.local_graphs, starts, strict=True):
        graph = local.graph
        started = time.perf_counter()
        if copy_weight is not None and local.num_vertices > local.owned_count:
            targets = (problem.graph.poses if copy_targets is None else copy_targets)[
                local.separator_ids
            ]
            if copy_relative:
                tied = relative_priors(local, targets, copy_weight)
                local_poses.append(solve_graph(tied, start, iterations, cost=cost).poses)
            else:
                local_poses.append(
                    _solve_tied(local, start, targets, copy_weight, iterations, cost)
                )
        elif excluded is None:
            local_poses.append(solve_graph(graph, start, iterations, cost=cost).poses)
        else:
            kept = graph.edge_subset(~excluded[local.edge_ids])
            start = np.asarray(start, dtype=float)
            local_poses.append(_solve_rooted(kept, start, iterations, cost))
        seconds[local.robot] = time.perf_counter() - started
    return local_poses, seconds


def copy_priors(local: LocalGraph, targets: np.ndarray, weight: float) -> PoseGraph:
    """``local.graph`` with one prior per separator copy: an anchor vertex held at the copy's
    ``targets`` row (appended after the local vertices, in copy order; the graph's only fixed
    poses) and an edge anchor → copy measuring the identity, with ``weight`` times the summed
    information of the local edges at the copy. Its F at ``[poses; targets]`` is the local F
    plus ``weight`` · Σ_copies (the copies' eq. 1 disagreement with their targets).

    Args:
        local: one robot's local graph (``n_r`` vertices, ``c`` copies).
        targets: ``(c, 3)`` the owners' estimates of the copies.
        weight: the priors' weight w > 0 (dimensionless).
    """
    graph, owned, n = local.graph, local.owned_count, local.num_vertices
    copies = np.arange(owned, n)
    information = np.zeros((n, 3, 3))
    np.add.at(information, graph.tails, graph.information)
    np.add.at(information, graph.heads, graph.information)
    anchors = np.arange(n, n + copies.size)
    return graph.replace(
        poses=np.vstack([graph.poses, targets]),
        tails=np.concatenate([graph.tails, anchors]),
        heads=np.concatenate([graph.heads, copies]),
        measurements=np.vstack([graph.measurements, np.zeros((copies.size, 3))]),
        information=np.concatenate([graph.information, weight * information[copies]]),
        kinds=np.concatenate([graph.kinds, np.full(copies.size, EdgeKind.INTER_LOOP, np.int8)]),
        ground_truth=None,
        robots=None,
        fixed=anchors,
    )


def relative_priors(local: LocalGraph, targets: np.ndarray, weight: float) -> PoseGraph:
    """``local.graph`` with the copies of each owner chained (in global id order) by edges
    measuring their relative pose in ``targets``, each with ``weight`` times the mean of its two
    copies' summed local information: a penalty on the copies' shape, free of the owners'
    frames (a copy alone of its owner is free).

    Args:
        local: one robot's local graph (``c`` copies).
        targets: ``(c, 3)`` the owners' estimates of the copies.
        weight: the priors' weight w > 0 (dimensionless).
    """
    graph, owned = local.graph, local.owned_count
    information = np.zeros((local.num_vertices, 3, 3))
    np.add.at(information, graph.tails, graph.information)
    np.add.at(information, graph.heads, graph.information)
    owners = graph.robots[owned:]
    order = np.lexsort((local.separator_ids, owners))
    same = owners[order][1:] == owners[order][:-1]
    a, b = order[:-1][same], order[1:][same]  # copy indices (0-based among the copies)
    return graph.replace(
        tails=np.concatenate([graph.tails, owned + a]),
        heads=np.concatenate([graph.heads, owned + b]),
        measurements=np.vstack([graph.measurements, se2.between(targets[a], targets[b])]),
        information=np.concatenate(
            [graph.information, weight * (information[owned + a] + information[owned + b]) / 2]
        ),
        kinds=np.concatenate([graph.kinds, np.full(a.size, EdgeKind.INTER_LOOP, np.int8)]),
    )


def _solve_tied(
    local: LocalGraph,
    start: np.ndarray,
    targets: np.ndarray,
    weight: float,
    iterations: int,
    cost: str,
) -> np.ndarray:
    """``(n_r, 3)``: LM on one local graph with its copies held at ``targets`` (``weight`` =
    inf) or pulled to them by :func:`copy_priors`, from ``start`` (held copies start there)."""
    start = np.array(start, dtype=float)
    if np.isinf(weight):
        start[local.owned_count :] = targets
        held = local.graph.replace(fixed=np.arange(local.owned_count, local.num_vertices))
        return solve_graph(held, start, iterations, cost=cost).poses
    tied = copy_priors(local, targets, weight)
    poses = solve_graph(tied, np.vstack([start, targets]), iterations, cost=cost).poses
    return poses[: local.num_vertices]


def _solve_rooted(
    graph: PoseGraph, start: np.ndarray, iterations: int, cost: str = "F"
) -> np.ndarray:
    """``(N, 3)``: LM on the vertices joined to vertex 0 by ``graph``'s edges (vertex 0 fixed);
    the other vertices keep their ``start``."""
    adjacency = sparse.coo_matrix(
        (np.ones(graph.num_edges), (graph.tails, graph.heads)), shape=(graph.num_poses,) * 2
    )
    labels = csgraph.connected_components(adjacency, directed=False)[1]
    rooted = labels == labels[0]
    if rooted.all():
        return solve_graph(graph, start, iterations, cost=cost).poses
    index = np.cumsum(rooted) - 1  # new ids of the rooted vertices (vertex 0 stays 0)
    keep = rooted[graph.tails]  # an edge with one rooted end has both
    sub = graph.edge_subset(keep)
    sub = sub.replace(
        poses=start[rooted],
        tails=index[sub.tails],
        heads=index[sub.heads],
        ground_truth=None if graph.ground_truth is None else graph.ground_truth[rooted],
        robots=None if graph.robots is None else graph.robots[rooted],
    )
    poses = start.copy()
    poses[rooted] = solve_graph(sub, start[rooted], iterations, cost=cost).poses
    return poses


def solve(
    problem: DistributedProblem,
    budget: Budget | None = None,
    local_iterations: int = LOCAL_ITERATIONS,
    consensus: str = DEFAULT_CONSENSUS,
    consensus_iterations: int = DEFAULT_CONSENSUS_ITERATIONS,
    objective: str = "F",
    **_: object,
) -> Result:
    """Method ``"local-lm"`` (module docstring).

    Args:
        problem: the distributed problem; ``graph.poses`` is the start.
        budget: unused (the local solves run to convergence, at most ``local_iterations``).
        local_iterations: LM steps at most per robot.
        consensus: one of :data:`popbench.consensus.reconcile.CONSENSUS_MODES`.
        consensus_iterations: ADMM iterations at most.
        objective: the local solves' cost, ``"F"`` (eq. 1) or ``"chi2"``.

    Result: ``iterations`` = 1 (one local solve per robot); ``history`` = F at the start, of the
    assembled local optima, and after the consensus; ``parallel_s`` = the slowest robot's LM
    plus the consensus's simulated makespan; ``history_s`` = 0, the slowest robot's LM, and
    ``parallel_s``; ``extras``: F_local, F_aligned and the consensus's
    iterations. ``status``: ``objective`` at the result, converged when the consensus met its
    tolerance.
    """
    from popbench.objective import evaluate
    from popbench.objective import objective as eq1

    del budget
    check_consensus(consensus)
    if objective not in OBJECTIVES:
        raise ValueRangeError("local-lm objective", objective, " | ".join(OBJECTIVES))
    started = time.perf_counter()
    graph = problem.graph
    f_init = eq1(graph, graph.poses)
    local_poses, seconds = local_optima(problem, local_iterations, cost=objective)
    local_s = float(seconds.max(initial=0.0))
    reconciled = reconcile(problem, local_poses, consensus, consensus_iterations)
    costs = evaluate(graph, reconciled.poses)
    return Result(
        poses=reconciled.poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=time.perf_counter() - started,
        parallel_s=local_s + reconciled.parallel_s,
        iterations=1,
        history=np.array([f_init, reconciled.F_before, costs.F]),
        history_s=np.array([0.0, local_s, local_s + reconciled.parallel_s]),
        messages=reconciled.messages,
        extras={
            "F_init": f_init,
            "F_local": reconciled.F_before,
            "F_aligned": reconciled.F_aligned,
            "consensus_iterations": reconciled.iterations,
            "consensus_converged": reconciled.converged,
        },
        status=measure(graph, reconciled.poses, objective, reconciled.converged, 1),
    )
