"""popbench.metrics: ATE and bootstrap intervals."""

from __future__ import annotations

import numpy as np
import pytest

from popbench import se2
from popbench.metrics import ate, bootstrap_ci


def test_ate_ignores_a_rigid_motion_and_measures_an_offset(rng):
    truth = np.column_stack([rng.normal(0, 5, (40, 2)), rng.uniform(-np.pi, np.pi, 40)])
    moved = se2.compose(np.array([[3.0, -2.0, 0.7]]), truth)
    assert ate(moved, truth) == pytest.approx(0.0, abs=1e-12)
    bent = truth.copy()
    bent[:20, 0] += 1.0  # half the points 1 m off: after the best fit the RMS error is < 0.5
    assert 0.0 < ate(bent, truth) <= 0.5


def test_bootstrap_interval_contains_the_statistic_and_shrinks():
    rng = np.random.default_rng(1)
    small, large = rng.normal(10, 1, 20), rng.normal(10, 1, 2000)
    low, high = bootstrap_ci(small)
    assert low <= np.median(small) <= high
    low_large, high_large = bootstrap_ci(large)
    assert high_large - low_large < high - low
    assert bootstrap_ci(small, np.mean) == bootstrap_ci(small, np.mean)  # seeded
    assert np.isnan(bootstrap_ci(np.array([1.0]))[0])


def test_roc_auc_counts_ties_as_half_and_needs_both_classes():
    from popbench.metrics import roc_auc

    assert roc_auc(np.array([0.9, 0.8, 0.1, 0.2]), np.array([True, True, False, False])) == 1.0
    assert roc_auc(np.array([0.1, 0.9]), np.array([True, False])) == 0.0
    assert roc_auc(np.array([0.5, 0.5, 0.5]), np.array([True, False, False])) == 0.5
    # one positive above one of two negatives and tied with the other: (1 + ½) / 2
    assert roc_auc(np.array([0.5, 0.2, 0.5]), np.array([True, False, False])) == 0.75
    assert np.isnan(roc_auc(np.array([0.3]), np.array([True])))
