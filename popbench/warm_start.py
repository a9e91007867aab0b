"""Distributed refinement from a one-pass estimate: ``mm-pgo`` started where another method ended.

The paper's second claim is that prop-v1 "provides a powerful initialization for classical
solvers"; ``prop-v2`` tests it with the centralised LM. These methods test it distributed:

* ``prop-v1+mm-pgo``: prop-v1 (one learned pass + the consensus), then ``mm-pgo`` from its
  estimate;
* ``local-lm+mm-pgo``: the classical counterpart, ``local-lm`` (every robot at its local optimum
  + the same consensus), then ``mm-pgo`` from its estimate.

The first method gets the call's options (seed, checkpoint, consensus, …), ``mm-pgo`` the same
(it ignores those it does not take) and the budget (``Budget.iterations`` rounds, Table I's
1000). ``refined=`` is the first method's Result on the same problem (the harness passes its
cached cell, :mod:`popbench.harness.refining`); None computes it.

Result: the estimate, costs and inlier mask are mm-pgo's (never above the first method's F:
the registry's :func:`~popbench.methods.never_worse` guards mm-pgo's own start); ``wall_s``,
``parallel_s``, ``iterations`` and ``messages`` are the sums of the two stages. ``history`` is in
mm-pgo's objective, ``F_chordal``: its first entry the start's, then mm-pgo's own entries (the
first of them the first method's estimate) at the first method's ``parallel_s`` plus mm-pgo's
parallel time, so a gap the first stage already reached is timed at its end (the first stage's
own path is not recorded in ``F_chordal``). ``extras``: ``F_first``, ``first_parallel_s`` and
``first_wall_s`` (the first stage), ``mm_pgo_iterations``, ``mm_pgo_parallel_s``.
"""

from __future__ import annotations

import numpy as np

from popbench import objective
from popbench.distributed import DistributedProblem
from popbench.methods import Budget, Result, get_method


def mm_pgo_from(
    first_method: str,
    problem: DistributedProblem,
    budget: Budget | None,
    refined: Result | None,
    options: dict[str, object],
) -> Result:
    """``mm-pgo`` started from ``first_method``'s estimate (module docstring)."""
    budget = budget or Budget()
    first = refined or get_method(first_method)(problem, budget, **options)
    warm = DistributedProblem(
        problem.graph.replace(poses=first.poses), "given", problem.outlier_mask
    )
    second = get_method("mm-pgo")(warm, budget, **options)
    history = np.concatenate(
        [[objective.chordal_objective(problem.graph, problem.graph.poses)], second.history]
    )
    history_s = None
    if second.history_s is not None:
        history_s = np.concatenate([[0.0], first.parallel_s + second.history_s])
    return Result(
        poses=second.poses,
        F=second.F,
        F_chordal=second.F_chordal,
        chi2=second.chi2,
        wall_s=first.wall_s + second.wall_s,
        parallel_s=first.parallel_s + second.parallel_s,
        iterations=first.iterations + second.iterations,
        history=history,
        history_s=history_s,
        history_objective=second.history_objective,
        inlier_mask=second.inlier_mask,
        messages=first.messages + second.messages,
        extras={
            **second.extras,
            "F_first": first.F,
            "first_parallel_s": first.parallel_s,
            "first_wall_s": first.wall_s,
            "mm_pgo_iterations": second.iterations,
            "mm_pgo_parallel_s": second.parallel_s,
        },
    )


def solve_prop_v1_mm_pgo(
    problem: DistributedProblem,
    budget: Budget | None = None,
    refined: Result | None = None,
    **options: object,
) -> Result:
    """Method ``"prop-v1+mm-pgo"``: prop-v1, then mm-pgo from its estimate."""
    return mm_pgo_from("prop-v1", problem, budget, refined, options)


def solve_local_lm_mm_pgo(
    problem: DistributedProblem,
    budget: Budget | None = None,
    refined: Result | None = None,
    **options: object,
) -> Result:
    """Method ``"local-lm+mm-pgo"``: local-lm, then mm-pgo from its estimate."""
    return mm_pgo_from("local-lm", problem, budget, refined, options)
