"""The per-problem normalised score of a held-out row: 0 at ``gn-sweep``, 1 at the optimum F*.

For a row's F after the consensus on held-out problem p,

    score_p = (F_gn-sweep,p − F_p) / (F_gn-sweep,p − F*_p)

the fraction of the no-learning reference's gap to the problem's optimum that the row closes.
``gn-sweep`` (the Gauss–Newton base step in a fixed edge order, then the consensus) is the zero:
every shipped actor acts on that base step, so a score above 0 is what its learnt edge order
and correction add. F* (:func:`popbench.solvers.lm.reference_optimum`, centralised LM from the
chordal start, 0.1 s per n = 7 problem) is the one: no estimate of the problem can go below it,
so the denominator is positive on every problem and a score is at most 1 (a row above F* on a
problem is refused: the references were made on other problems). ``local-lm`` is not a usable
one: its F is above gn-sweep's on 29 of the 100 committed problems (the scale would change
sign). A blow-up gives a large negative score; the interquartile mean and the probabilities of
improvement of :mod:`popbench.harness.stratified` are robust to it (docs/algorithms.md).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from popbench.errors import ValueRangeError

ZERO_ROW = "gn-sweep"
PROBLEM_KEY = ("noise", "robots", "poses_per_robot", "problem_seed")
# A row's F may lie this far (relative) below F*: F* is LM's converged value, not certified.
OPTIMUM_SLACK = 1e-6


def optimum(problems: pd.DataFrame) -> pd.Series:
    """F* of each held-out problem of ``problems`` (columns :data:`PROBLEM_KEY`), indexed by
    them."""
    from popbench.problems.synthetic import make_problem
    from popbench.solvers.lm import reference_optimum

    keys = problems[list(PROBLEM_KEY)].drop_duplicates()
    values = [
        reference_optimum(make_problem(int(robots), noise, int(poses), seed=int(seed)).graph).F
        for noise, robots, poses, seed in keys.itertuples(index=False)
    ]
    return pd.Series(values, index=pd.MultiIndex.from_frame(keys), name="F_optimum")


def normalised(records: pd.DataFrame, zero: pd.DataFrame, best: pd.Series) -> pd.DataFrame:
    """``records`` (columns :data:`PROBLEM_KEY` and F) with ``F_zero`` (the ``zero`` records'
    F on the same problem: gn-sweep's), ``F_optimum`` (``best``, :func:`optimum`) and ``score``
    (module docstring). A one-line ValueRangeError names a problem without a zero record, or
    one where a row lies below F*."""
    key = list(PROBLEM_KEY)
    zero_f = zero.drop_duplicates(key).set_index(key)["F"].rename("F_zero")
    out = records.join(zero_f, on=key).join(best, on=key)
    missing = out[out["F_zero"].isna() | out["F_optimum"].isna()]
    if not missing.empty:
        first = missing.iloc[0]
        raise ValueRangeError(
            "problem without a gn-sweep reference (the score's zero)",
            f"{first['noise']}-n{first['robots']} seed {first['problem_seed']}",
            "a --reference held-out folder with a gn-sweep row on every scored problem",
        )
    for frame in (out, out.assign(F=out["F_zero"])):
        below = frame[frame["F"] < frame["F_optimum"] * (1 - OPTIMUM_SLACK)]
        if not below.empty:
            first = below.iloc[0]
            raise ValueRangeError(
                f"F on problem seed {first['problem_seed']} (below its optimum F* "
                f"{first['F_optimum']:.6g})",
                float(first["F"]),
                "F ≥ F*: records and references of the same problems (poses per robot)",
            )
    gap = out["F_zero"] - out["F_optimum"]
    return out.assign(score=(out["F_zero"] - out["F"]) / np.where(gap > 0, gap, np.nan))
