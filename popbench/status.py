"""Where a method stopped: the typed record every :class:`~popbench.methods.Result` carries.

``converged`` says whether the method's own stopping test fired (LM: a relative decrease, a
gradient or a step test; GNC: GTSAM's rules; a fixed-length method such as MM-PGO or RBCD:
:func:`settled`, the relative decrease of its last round). ``gradient_norm`` is a first-order
measure comparable across methods: ``‖∇C‖_∞`` of the cost ``C`` the method minimises, at the
returned poses, over the free poses (every pose but the fixed ones: vertex 0, or the file's
``FIX`` poses), in ``C``'s units per metre (x, y) and per radian (θ). ``cost`` and
``start_cost`` are ``C`` at the returned poses and at the problem's start: the never-worse rule
(:func:`popbench.methods.keep_better`) compares them for a robust method or a method minimising
``chi2``. docs/solve.md.
"""

from __future__ import annotations

import dataclasses
import enum

import numpy as np

from popbench import objective
from popbench.graph import PoseGraph

# A round that lowers the minimised cost by at most this relative amount ends a fixed-length run
# "settled" (GTSAM's default relativeErrorTol is 1e-5; one round of a first-order method moves
# less than an LM step, hence the tighter bound).
SETTLED_TOLERANCE = 1e-6


class NeverWorse(enum.StrEnum):
    """What the never-worse rule (:func:`popbench.methods.keep_better`) returned, in
    ``Result.extras["never_worse"]``: a ``str`` (it compares and serialises as its value)."""

    METHOD = "method"  # the method's estimate: not worse than the start
    START = "start"  # the problem's start: the estimate was worse on the cost compared
    NOT_APPLIED = "not applied"  # a problem with injected outliers: the estimate, unjudged


@dataclasses.dataclass(frozen=True)
class Status:
    """Whether a method met its stopping test, and where it stopped.

    Attributes:
        objective: the cost ``C`` minimised (:data:`popbench.objective.COSTS`; for a robust
            method the cost whose edge terms its kernel takes).
        converged: its stopping test fired (not the budget).
        rounds: rounds run (the method's ``Result.iterations``).
        gradient_norm: ``‖∇C‖_∞`` at the returned poses over the free poses.
        cost: ``C`` at the returned poses (robust: ``Σ_e ρ(r_e²)``).
        start_cost: ``C`` at the problem's start.
        robust: the kernel ``ρ`` (``"tls"``, ``"gm"``) or None (``C`` itself).
    """

    objective: str
    converged: bool
    rounds: int
    gradient_norm: float
    cost: float
    start_cost: float
    robust: str | None = None

    def as_record(self) -> dict[str, object]:
        """A JSON-ready dict of the fields."""
        return dataclasses.asdict(self)


def free_gradient_norm(
    graph: PoseGraph,
    poses: np.ndarray,
    cost: str,
    edge_weights: np.ndarray | None = None,
) -> float:
    """``‖∇C‖_∞`` over the free poses (not vertex 0 / the ``FIX`` poses) for
    ``C = Σ_e w_e`` × (edge term of ``cost``)."""
    gradient = objective.gradient(graph, poses, cost, edge_weights)
    free = np.ones(graph.num_poses, dtype=bool)
    free[[0] if graph.fixed is None else graph.fixed] = False
    return float(np.max(np.abs(gradient[free]), initial=0.0))


def measure(graph: PoseGraph, poses: np.ndarray, cost: str, converged: bool, rounds: int) -> Status:
    """The :class:`Status` of a non-robust method that minimised ``cost`` and returned
    ``poses``; the start is ``graph.poses``."""
    return Status(
        objective=cost,
        converged=bool(converged),
        rounds=int(rounds),
        gradient_norm=free_gradient_norm(graph, poses, cost),
        cost=objective.cost_value(graph, poses, cost),
        start_cost=objective.cost_value(graph, graph.poses, cost),
    )


def settled(history: np.ndarray, tolerance: float = SETTLED_TOLERANCE) -> bool:
    """The stopping test of a fixed-length run: its last round lowered the recorded cost
    (``history``, ``(K,)``) by at most ``tolerance`` relative (or raised it not at all)."""
    if len(history) < 2:
        return False
    before, after = float(history[-2]), float(history[-1])
    return abs(before - after) <= tolerance * max(abs(after), np.finfo(float).tiny)
