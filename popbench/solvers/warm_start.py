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

from collections.abc import Callable

import numpy as np

from popbench import objective
from popbench.methods import Budget, Result, get_method
from popbench.problems.distributed import DistributedProblem


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


def refining_mm_pgo(first_method: str) -> Callable[..., Result]:
    """The entry point of method ``"<first_method>+mm-pgo"``: ``solve(problem, budget=None,
    refined=None, **options)``, :func:`mm_pgo_from` with ``first_method``."""

    def solve(
        problem: DistributedProblem,
        budget: Budget | None = None,
        refined: Result | None = None,
        **options: object,
    ) -> Result:
        return mm_pgo_from(first_method, problem, budget, refined, options)

    solve.__doc__ = (
        f"Method ``{first_method}+mm-pgo``: {first_method}, then mm-pgo from its estimate."
    )
    # The module attribute it is bound to, so that pickle (process pools) finds it by name.
    solve.__name__ = solve.__qualname__ = f"solve_{first_method.replace('-', '_')}_mm_pgo"
    return solve


solve_prop_v1_mm_pgo = refining_mm_pgo("prop-v1")
solve_local_lm_mm_pgo = refining_mm_pgo("local-lm")
