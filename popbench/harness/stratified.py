"""rliable's aggregate metrics over (runs × tasks) score matrices, with its stratified bootstrap,
in NumPy (Agarwal et al., "Deep RL at the edge of the statistical precipice", NeurIPS 2021).

A score matrix is ``(runs, tasks)``: here the runs are training seeds and the tasks the held-out
problems. :func:`iqm` is the interquartile mean over all its entries, :func:`improvement` the
probability of improvement P(X > Y) (per task, the Mann–Whitney U of X's runs against Y's over
``runs_x · runs_y``, ties counting one half; then the mean over tasks), :func:`profile` the
fraction of entries above each threshold τ. The same definitions as ``rliable.metrics`` (the
tests compare them), vectorised over bootstrap replicates.

:func:`interval` gives percentile intervals from ``reps`` replicates, by one of two schemes:

* ``"runs"`` — rliable's stratified bootstrap (its default, ``task_bootstrap=False``): in every
  task, the runs are drawn with replacement independently of the other tasks, and each matrix
  of a pair independently. It measures how the aggregate would move with other runs on the
  same tasks, treating a task's runs as independent of the other tasks' runs.
* ``"seeds"`` — the seeds drawn once for all tasks (a seed's actor is one actor on every
  problem), and the tasks drawn with replacement too. With few seeds this is the wider and the
  more honest measure of what another set of seeds would give.

rliable's own bootstrap (``rliable.library``) imports ``arch``: arch 7.2 (the last release
rliable 1.2 accepts) fails to import next to pandas 3, and arch 8 rejects rliable's
``random_state=None``; hence this module (docs/algorithms.md).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

SCHEMES = ("runs", "seeds")


def iqm(scores: np.ndarray) -> np.ndarray:
    """Interquartile mean of ``scores`` ``(..., runs, tasks)`` over its last two axes: the mean
    of the entries left after cutting ⌊N/4⌋ from each end of the sorted N (scipy's trim_mean)."""
    flat = np.sort(scores.reshape(*scores.shape[:-2], -1), axis=-1)
    cut = flat.shape[-1] // 4
    return flat[..., cut : flat.shape[-1] - cut].mean(axis=-1)


def improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) of ``x`` ``(..., runs_x, tasks)`` over ``y`` ``(..., runs_y, tasks)``: per task
    the fraction of run pairs where X is above Y (ties ½), averaged over tasks."""
    above = x[..., :, None, :] > y[..., None, :, :]
    tied = x[..., :, None, :] == y[..., None, :, :]
    return (above + 0.5 * tied).mean(axis=(-3, -2, -1))


def profile(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Fraction of the entries of ``scores`` ``(..., runs, tasks)`` above each of ``taus``
    ``(T,)``: shape ``(..., T)`` (rliable's run-score distribution)."""
    flat = scores.reshape(*scores.shape[:-2], 1, -1)
    return (flat > taus[:, None]).mean(axis=-1)


def resample(
    scores: np.ndarray, reps: int, rng: np.random.Generator, columns: np.ndarray | None = None
) -> np.ndarray:
    """``reps`` bootstrap copies of ``scores`` ``(runs, tasks)``, shape ``(reps, runs, tasks)``:
    without ``columns``, the runs drawn in every task independently (``"runs"``); with
    ``columns`` ``(reps, 1, tasks)``, the tasks drawn, the runs once for all tasks
    (``"seeds"``)."""
    runs, tasks = scores.shape
    if columns is None:
        rows = rng.integers(0, runs, (reps, runs, tasks))
        return np.take_along_axis(np.broadcast_to(scores, (reps, runs, tasks)), rows, axis=1)
    return scores[rng.integers(0, runs, (reps, runs, 1)), columns]


def interval(
    statistic: Callable[..., np.ndarray],
    *matrices: np.ndarray,
    reps: int = 2000,
    seed: int = 0,
    scheme: str = "runs",
    level: float = 0.95,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``statistic(*matrices)`` and its percentile interval over ``reps`` bootstrap replicates,
    each matrix ``(runs, tasks)`` resampled independently by ``scheme`` (module docstring; for
    ``"seeds"`` the matrices share the draw of the tasks: the problems are the same for every
    algorithm). Returns ``(estimate, low, high)``, each of the statistic's shape."""
    if scheme not in SCHEMES:
        raise ValueError(f"bootstrap scheme {scheme!r}: allowed {', '.join(SCHEMES)}")
    rng = np.random.default_rng(seed)
    columns = None
    if scheme == "seeds":
        tasks = matrices[0].shape[1]
        columns = rng.integers(0, tasks, (reps, 1, tasks))
    replicates = statistic(*(resample(m, reps, rng, columns) for m in matrices))
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(replicates, [tail, 100 - tail], axis=0)
    return statistic(*matrices), low, high
