"""Outlier injection (paper §IV-B, candidate sets of popbench.outliers) and its scores."""

from __future__ import annotations

import numpy as np
import pytest

from popbench.errors import DataFormatError, ValueRangeError
from popbench.graph import EdgeKind, robot_kinds, single_robot_kinds
from popbench.outliers import (
    ADDED_MODELS,
    ADDED_SIGMA_T,
    ADDED_SIGMA_THETA,
    LOCAL_WINDOW,
    add_false_loop_closures,
    candidate_edges,
    candidate_mask,
    inject_outliers,
    precision_recall,
    read_outlier_mask,
    with_outliers,
)
from popbench.problems.synthetic import make_problem

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


# ----- Vertigo-style added false loop closures ----------------------------------------------


def _groups(graph, mask):
    """The added edges as groups: a dict measurement-row → (tails, heads, informations)."""
    groups: dict = {}
    for edge in np.flatnonzero(mask):
        key = tuple(graph.measurements[edge])
        tails, heads, infos = groups.setdefault(key, ([], [], []))
        tails.append(graph.tails[edge])
        heads.append(graph.heads[edge])
        infos.append(graph.information[edge])
    return groups


@pytest.mark.parametrize("model", ADDED_MODELS)
def test_added_closures_count_order_kinds_and_reproducibility(model):
    problem = make_problem(robots=5, seed=2, loop_ratio=0.3)
    graph = problem.graph
    loops = candidate_edges(graph, "loops")
    size = 3 if model == "vertigo-grouped" else 1
    added, mask = add_false_loop_closures(graph, 0.4, model, seed=7, group_size=3)
    expected = round(0.4 * loops.size / size) * size
    assert mask.sum() == expected > 0 and added.num_edges == graph.num_edges + expected
    # the true edges are kept, in order; the poses are untouched
    for field in ("tails", "heads", "measurements", "information", "kinds"):
        np.testing.assert_array_equal(getattr(added, field)[~mask], getattr(graph, field))
    np.testing.assert_array_equal(added.poses, graph.poses)
    # every added edge is a closure, labelled as any edge between its poses would be
    gap = np.abs(added.tails[mask] - added.heads[mask])
    assert gap.min() >= 2 and (model != "vertigo-local" or gap.max() <= LOCAL_WINDOW)
    np.testing.assert_array_equal(added.kinds, robot_kinds(added.tails, added.heads, graph.robots))
    assert set(added.kinds[mask]) <= {EdgeKind.LOOP, EdgeKind.INTER_LOOP}
    assert np.all(candidate_mask(added, "loops")[mask])
    # not appended: each one follows the last edge that reaches its later pose
    reach = np.maximum.accumulate(np.maximum(added.tails, added.heads)[~mask])
    for edge in np.flatnonzero(mask):
        before = np.count_nonzero(~mask[:edge])  # true edges before it
        later = max(added.tails[edge], added.heads[edge])
        assert before == np.searchsorted(reach, later, side="right")
    assert not np.all(mask[graph.num_edges :])
    # information lent by a true loop closure; measurement near the identity
    true_info = graph.information[loops].reshape(loops.size, 1, 9)
    lent = added.information[mask].reshape(1, -1, 9)
    assert np.all(np.any(np.all(true_info == lent, axis=2), axis=0))
    assert np.all(np.abs(added.measurements[mask][:, :2]) < 6 * ADDED_SIGMA_T)
    again, mask_again = add_false_loop_closures(graph, 0.4, model, seed=7, group_size=3)
    np.testing.assert_array_equal(mask_again, mask)
    np.testing.assert_array_equal(again.measurements, added.measurements)
    np.testing.assert_array_equal(again.tails, added.tails)
    other, _ = add_false_loop_closures(graph, 0.4, model, seed=8, group_size=3)
    assert not np.array_equal(other.measurements, added.measurements)


def test_single_robot_graph_gets_loop_kinds(small_graph):
    added, mask = add_false_loop_closures(small_graph, 1.0, "vertigo-random", seed=1)
    assert mask.sum() == 3  # small_graph has 3 loop closures
    np.testing.assert_array_equal(added.kinds, single_robot_kinds(added.tails, added.heads))
    assert np.all(added.kinds[mask] == EdgeKind.LOOP)


def test_grouped_closures_are_mutually_consistent():
    graph = make_problem(robots=3, seed=4, loop_ratio=0.3).graph
    added, mask = add_false_loop_closures(graph, 0.5, "vertigo-grouped", seed=3, group_size=4)
    groups = _groups(added, mask)
    assert len(groups) * 4 == mask.sum() and len(groups) >= 3
    for tails, heads, infos in groups.values():
        assert len(tails) == 4
        order = np.argsort(tails)
        np.testing.assert_array_equal(np.diff(np.array(tails)[order]), 1)
        np.testing.assert_array_equal(np.diff(np.array(heads)[order]), 1)  # (a + k, b + k)
        assert all(np.array_equal(info, infos[0]) for info in infos)
    # with the default group size of one, the random model makes one edge per measurement
    single, single_mask = add_false_loop_closures(graph, 0.5, "vertigo-random", seed=3)
    assert len(_groups(single, single_mask)) == single_mask.sum()


def test_added_measurement_distribution():
    graph = make_problem(robots=40, seed=1, loop_ratio=0.3).graph
    added, mask = add_false_loop_closures(graph, 1.0, "vertigo-random", seed=2)
    z = added.measurements[mask]
    assert mask.sum() > 500
    assert abs(np.std(z[:, :2]) / ADDED_SIGMA_T - 1.0) < 0.1
    assert abs(np.std(z[:, 2]) / ADDED_SIGMA_THETA - 1.0) < 0.1
    assert abs(np.mean(z[:, :2])) < 0.05


def test_added_closures_reject_bad_arguments(small_graph):
    for kwargs in (
        {"rate": 0.1, "model": "corrupt"},
        {"rate": 1.5, "model": "vertigo-random"},
        {"rate": 0.1, "model": "vertigo-grouped", "group_size": 0},
    ):
        with pytest.raises(ValueRangeError):
            add_false_loop_closures(small_graph, **kwargs)
    added, mask = add_false_loop_closures(small_graph, 0.0, "vertigo-local")
    assert added is small_graph and not mask.any()


def test_outlier_mask_file(tmp_path):
    path = tmp_path / "m.mask"
    path.write_text("# one line per edge\n0\n1\n\n0  # a true closure\n1\n")
    np.testing.assert_array_equal(read_outlier_mask(path, 4), [False, True, False, True])
    with pytest.raises(DataFormatError, match=r"m\.mask:6: 4 mask value\(s\), the graph has 5"):
        read_outlier_mask(path, 5)
    path.write_text("0\n1\n2\n")
    with pytest.raises(DataFormatError, match=r"m\.mask:3: outlier mask value '2': allowed 0 or 1"):
        read_outlier_mask(path, 3)


def test_table_ii_runs_prop_v1_with_the_outlier_trained_actor_and_keys_cells_by_it():
    from popbench.datasets import file_sha256
    from popbench.harness.outliers import OutliersConfig, cell_specs
    from popbench.methods import OUTLIER_ACTOR_CHECKPOINT, method_record, named_path

    specs = cell_specs(OutliersConfig(datasets=("intel",), seeds=(0,)))
    learned = [spec for spec in specs if spec["method"] == "prop-v1"]
    assert learned, "Table II has a prop-v1 row"
    path = named_path(OUTLIER_ACTOR_CHECKPOINT)
    assert path is not None and path.is_file()
    assert path != method_record("prop-v1").checkpoint_path()  # not Table I's actor
    for spec in learned:
        assert spec["options"]["checkpoint"] == OUTLIER_ACTOR_CHECKPOINT
        assert spec["checkpoint_sha256"] == file_sha256(path)
    others = [spec for spec in specs if spec["method"] != "prop-v1"]
    assert all("checkpoint" not in spec["options"] for spec in others)
