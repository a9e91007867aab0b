"""The initial estimate ("start") of a problem, made in one place.

A :class:`~popbench.problems.distributed.DistributedProblem` carries its start: its ``graph.poses``
are the initial estimate and ``problem.start`` names how they were made. Every method starts from
``problem.graph.poses``; the CLI, the harness and the environments build problems with
:func:`with_start`, so a table, ``popbench solve`` and a direct call agree on the start.

Starts (:data:`STARTS`):

* ``"odometry"``: composition of the odometry chain (:meth:`PoseGraph.odometry_initial`),
  the standard, hard start (docs/conventions.md, "Initial estimate").
* ``"chordal"``: chordal relaxation + translation recovery
  (:func:`popbench.solvers.chordal.chordal_initialisation`).
* ``"given"``: the poses the graph already holds (a file's estimate, or a caller's).

A graph with ``FIX`` poses (``PoseGraph.fixed``) keeps them: an odometry or chordal estimate is
moved rigidly so that the first fixed pose is at the file's value, and every fixed pose is set
to the file's value bit for bit (:func:`anchored`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, TypeVar

import numpy as np

from popbench.errors import ValueRangeError

if TYPE_CHECKING:
    from popbench.graph import PoseGraph
    from popbench.problems.distributed import DistributedProblem

STARTS = ("odometry", "chordal", "given")

GraphOrProblem = TypeVar("GraphOrProblem", "PoseGraph", "DistributedProblem")


def check_start(start: str, option: str = "start") -> str:
    """``start`` unchanged, or a one-line :class:`ValueRangeError` naming ``option`` and the
    allowed values (:data:`STARTS`)."""
    if start not in STARTS:
        raise ValueRangeError(option, start, " | ".join(STARTS))
    return start


def initial_estimate(graph: PoseGraph, start: str) -> np.ndarray:
    """The ``(N, 3)`` poses ``(x, y, θ)`` of the start named ``start`` (see :data:`STARTS`) for
    ``graph``; a new array (never ``graph.poses`` itself)."""
    check_start(start)
    if start == "odometry":
        return anchored(graph, graph.odometry_initial(), graph.poses)
    if start == "chordal":
        from popbench.solvers.chordal import chordal_initialisation

        return anchored(graph, chordal_initialisation(graph), graph.poses)
    return np.array(graph.poses, dtype=np.float64)


def anchored(graph: PoseGraph, estimate: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``estimate`` ``(N, 3)`` with ``graph``'s ``FIX`` poses at ``values`` ``(N, 3)`` (the
    file's poses): the whole estimate moved rigidly to put the first fixed pose there, then every
    fixed pose copied bit for bit. ``estimate`` itself where the graph has no ``FIX`` pose."""
    if graph.fixed is None or len(graph.fixed) == 0:
        return estimate
    from popbench import se2

    first = int(graph.fixed[0])
    motion = se2.compose(values[first], se2.inverse(estimate[first]))
    moved = se2.compose(motion[None, :], estimate)
    moved[graph.fixed] = values[graph.fixed]
    return moved


def with_start(problem_or_graph: GraphOrProblem, start: str) -> GraphOrProblem:
    """A copy of a pose graph or of a problem whose poses are the ``start`` estimate.

    A problem keeps its robot assignment and outlier mask and records ``start``; the estimate
    is made from its (global) graph's measurements, so after outliers are injected it is made
    from the corrupted ones, as a real system would.
    """
    from popbench.problems.distributed import DistributedProblem

    if isinstance(problem_or_graph, DistributedProblem):
        graph = problem_or_graph.graph
        poses = initial_estimate(graph, start)
        return DistributedProblem(graph.replace(poses=poses), start, problem_or_graph.outlier_mask)
    return problem_or_graph.replace(poses=initial_estimate(problem_or_graph, start))
