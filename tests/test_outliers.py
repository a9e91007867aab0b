"""Outlier injection (paper §IV-B, candidate sets of popbench.outliers) and its scores."""

from __future__ import annotations

import numpy as np
import pytest

from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind
from popbench.outliers import (
    candidate_edges,
    candidate_mask,
    inject_outliers,
    precision_recall,
    with_outliers,
)
from popbench.synthetic import make_problem

ODOMETRY_KINDS = (EdgeKind.ODOMETRY, EdgeKind.INTER_RELATIVE)


def test_default_injection_never_touches_odometry():
    problem = make_problem(robots=7, seed=0)
    graph = problem.graph
    assert np.any(graph.kinds == EdgeKind.INTER_RELATIVE)  # there are cut odometry edges
    odometry = np.isin(graph.kinds, ODOMETRY_KINDS)
    for seed in range(5):
        corrupted, mask = inject_outliers(problem, 1.0, seed=seed)
        assert not np.any(mask & odometry)
        np.testing.assert_array_equal(mask, ~odometry)  # rate 1: every loop closure
        np.testing.assert_array_equal(
            corrupted.measurements[odometry], graph.measurements[odometry]
        )
    # so the odometry start made from the corrupted graph is the clean one
    corrupted = with_outliers(problem, 1.0, seed=1)
    np.testing.assert_array_equal(corrupted.graph.poses, problem.graph.odometry_initial())


def test_candidate_sets():
    graph = make_problem(robots=5, seed=2).graph
    loops = candidate_mask(graph, "loops")
    paper = candidate_mask(graph, "paper")
    np.testing.assert_array_equal(loops, np.isin(graph.kinds, (EdgeKind.LOOP, EdgeKind.INTER_LOOP)))
    np.testing.assert_array_equal(paper, loops | (graph.kinds == EdgeKind.INTER_RELATIVE))
    np.testing.assert_array_equal(candidate_edges(graph), np.flatnonzero(loops))
    with pytest.raises(ValueRangeError):
        candidate_mask(graph, "odometry")


def test_inject_outliers_count_kinds_and_untouched_edges():
    problem = make_problem(robots=7, seed=0)
    graph = problem.graph
    for candidates in ("loops", "paper"):
        pool = candidate_edges(graph, candidates)
        corrupted, mask = inject_outliers(problem, 0.2, seed=5, candidates=candidates)
        assert mask.dtype == bool and mask.sum() == round(0.2 * pool.size)
        assert np.all(np.isin(np.flatnonzero(mask), pool))
        changed = np.any(corrupted.measurements != graph.measurements, axis=1)
        np.testing.assert_array_equal(changed, mask)
        np.testing.assert_array_equal(corrupted.information, graph.information)
        np.testing.assert_array_equal(corrupted.poses, graph.poses)
        again, mask_again = inject_outliers(graph, 0.2, seed=5, candidates=candidates)
        np.testing.assert_array_equal(again.measurements, corrupted.measurements)
        np.testing.assert_array_equal(mask_again, mask)
    assert inject_outliers(graph, 0.0, seed=5)[1].sum() == 0
    with pytest.raises(ValueRangeError):
        inject_outliers(problem, 1.5, seed=0)


def test_outlier_distribution():
    graph = make_problem(robots=40, seed=1, loop_ratio=0.3).graph
    mean_length = np.mean(np.linalg.norm(graph.measurements[:, :2], axis=1))
    corrupted, mask = inject_outliers(graph, 1.0, seed=2)
    z = corrupted.measurements[mask]
    assert mask.sum() > 500
    assert abs(np.std(z[:, :2]) / (0.5 * mean_length) - 1.0) < 0.1
    assert z[:, 2].min() >= -np.pi and z[:, 2].max() < np.pi
    assert abs(np.std(z[:, 2]) / (np.pi / np.sqrt(3)) - 1.0) < 0.1  # std of U(−π, π)


@pytest.mark.parametrize("candidates", ["loops", "paper"])
def test_single_robot_outliers_only_loops(small_graph, candidates):
    _, mask = inject_outliers(small_graph, 1.0, seed=0, candidates=candidates)
    np.testing.assert_array_equal(mask, small_graph.kinds == EdgeKind.LOOP)


def test_paper_candidates_break_the_odometry_start():
    problem = make_problem(robots=5, seed=3)
    corrupted = with_outliers(problem, 1.0, seed=1, candidates="paper")
    assert corrupted.outlier_mask.sum() == candidate_edges(problem.graph, "paper").size
    np.testing.assert_allclose(corrupted.graph.poses, corrupted.graph.odometry_initial())
    # the cut odometry edges are links of the chain, so the initial estimate changed
    assert not np.allclose(corrupted.graph.poses, problem.graph.poses)


def test_precision_recall_hand_made():
    flagged = np.array([True, True, False, False, True, False])
    truth = np.array([True, False, True, False, False, True])
    assert precision_recall(flagged, truth) == pytest.approx((1 / 3, 1 / 3))
    assert precision_recall(truth, truth) == (1.0, 1.0)
    nothing = np.zeros(6, dtype=bool)
    assert precision_recall(nothing, truth) == (1.0, 0.0)  # no flags: precision 1 by convention
    assert precision_recall(flagged, nothing) == (0.0, 1.0)  # no outliers: recall 1
    with pytest.raises(ValueRangeError):
        precision_recall(flagged[:3], truth)


def test_precision_recall_among_the_candidates():
    # edges 0-3 are candidates, 4-5 odometry; a flag on odometry is neither a hit nor a false
    # alarm when scoring among the candidates
    flagged = np.array([True, True, False, False, True, True])
    truth = np.array([True, False, True, False, False, False])
    among = np.array([True, True, True, True, False, False])
    assert precision_recall(flagged, truth) == pytest.approx((1 / 4, 1 / 2))
    assert precision_recall(flagged, truth, among) == pytest.approx((1 / 2, 1 / 2))
    assert precision_recall(flagged & ~among, truth, among) == (1.0, 0.0)
    with pytest.raises(ValueRangeError):
        precision_recall(flagged, truth, among[:3])
