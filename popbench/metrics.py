"""Accuracy measures beside the objective: the trajectory error against ground truth, bootstrap
confidence intervals of a statistic over problems and Student-t intervals of a mean over seeds."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def ate(estimate: np.ndarray, truth: np.ndarray) -> float:
    """Absolute trajectory error [m]: the RMS position error after the least-squares rigid
    SE(2) alignment of ``estimate`` to ``truth`` (Umeyama without scale).

    Args:
        estimate, truth: ``(N, 3)`` poses ``(x [m], y [m], θ [rad])``; only positions are used.
    """
    p, q = estimate[:, :2], truth[:, :2]
    p0, q0 = p - p.mean(0), q - q.mean(0)
    u, _, vt = np.linalg.svd(p0.T @ q0)
    reflection = np.sign(np.linalg.det(u @ vt))
    rotation = (u @ np.diag([1.0, reflection]) @ vt).T  # argmin_R Σ ‖R p0 − q0‖², det R = 1
    residual = p0 @ rotation.T - q0
    return float(np.sqrt((residual**2).sum(1).mean()))


def bootstrap_ci(
    values: np.ndarray,
    statistic: Callable[[np.ndarray], np.ndarray] = np.median,
    level: float = 0.95,
    resamples: int = 2000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of ``statistic`` over ``values``.

    Args:
        values: ``(K,)`` one value per problem (NaNs are dropped).
        statistic: reduces an array along ``axis=-1`` (``np.median``, ``np.mean``).
        level: the interval's coverage in (0, 1).
        resamples: bootstrap resamples; seed: their generator's seed (reproducible tables).

    Returns:
        ``(low, high)``; ``(nan, nan)`` for fewer than two values.
    """
    values = np.asarray(values, dtype=np.float64)
    values = values[~np.isnan(values)]
    if values.size < 2:
        return float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    samples = values[rng.integers(0, values.size, (resamples, values.size))]
    estimates = statistic(samples, axis=-1)
    tail = 100 * (1 - level) / 2
    low, high = np.percentile(estimates, [tail, 100 - tail])
    return float(low), float(high)


def mean_ci(values: np.ndarray, level: float = 0.95) -> tuple[float, float]:
    """The mean of ``values`` ``(K,)`` (NaNs dropped) and the half-width of its Student-t
    confidence interval at ``level``, ``t_{(1+level)/2, K−1} · s / √K`` (``s`` the sample
    standard deviation); the half-width is NaN for fewer than two values (mean NaN for none)."""
    from scipy import stats

    values = np.asarray(values, dtype=np.float64)
    values = values[~np.isnan(values)]
    if values.size == 0:
        return float("nan"), float("nan")
    mean = float(values.mean())
    if values.size < 2:
        return mean, float("nan")
    spread = float(values.std(ddof=1)) / np.sqrt(values.size)
    return mean, float(stats.t.ppf(0.5 + level / 2, values.size - 1) * spread)


def roc_auc(scores: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``scores`` ``(K,)`` for the ``positive`` ``(K,)`` bool labels:
    the probability that a random positive scores above a random negative, ties counting ½
    (Mann–Whitney U / (P·N), average ranks); NaN without both classes."""
    scores = np.asarray(scores, dtype=float)
    positive = np.asarray(positive, dtype=bool)
    p, n = int(positive.sum()), int((~positive).sum())
    if p == 0 or n == 0:
        return float("nan")
    order = np.argsort(scores, kind="mergesort")
    ranks = np.empty(scores.size)
    sorted_scores = scores[order]
    _, first, counts = np.unique(sorted_scores, return_index=True, return_counts=True)
    average = first + (counts + 1) / 2.0  # 1-based average rank of each tie group
    ranks[order] = np.repeat(average, counts)
    return float((ranks[positive].sum() - p * (p + 1) / 2.0) / (p * n))
