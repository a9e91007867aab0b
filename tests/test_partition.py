"""Partitioning a pose graph among robots (METIS and contiguous blocks)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_dataset

from popbench.errors import PopbenchError, ValueRangeError
from popbench.graph import EdgeKind, make_graph
from popbench.problems.partition import (
    adjacency,
    assign,
    canonical_labels,
    contiguous,
    partition,
    partition_report,
)


def test_contiguous_blocks_like_mm_pgo():
    np.testing.assert_array_equal(contiguous(10, 3), [0, 0, 0, 0, 1, 1, 1, 2, 2, 2])
    np.testing.assert_array_equal(contiguous(5, 5), np.arange(5))
    sizes = np.bincount(contiguous(1228, 7))
    np.testing.assert_array_equal(sizes, [176, 176, 176, 175, 175, 175, 175])


def test_adjacency_is_undirected_and_deduplicated():
    graph = make_graph(
        np.zeros((4, 3)),
        tails=[0, 1, 1, 2, 3, 2],
        heads=[1, 0, 2, 2, 0, 1],  # 0–1 twice, 1–2 twice (reversed), a self loop 2–2
        measurements=np.zeros((6, 3)),
        information=np.tile(np.eye(3), (6, 1, 1)),
    )
    starts, neighbours = adjacency(graph)
    lists = [sorted(neighbours[starts[v] : starts[v + 1]].tolist()) for v in range(4)]
    assert lists == [[1, 3], [0, 2], [1], [0]]


def test_canonical_labels():
    np.testing.assert_array_equal(
        canonical_labels(np.array([2, 2, 0, 1, 0, 2])), [0, 0, 1, 2, 1, 0]
    )


def test_metis_small_graph_is_canonical_and_balanced(small_graph):
    robots = partition(small_graph, 3, seed=0)
    assert robots[0] == 0 and robots.dtype == np.int64
    first_vertex = [np.flatnonzero(robots == r)[0] for r in range(3)]
    assert first_vertex == sorted(first_vertex)
    assert np.bincount(robots).min() >= 8
    np.testing.assert_array_equal(robots, partition(small_graph, 3, seed=0))
    np.testing.assert_array_equal(partition(small_graph, 1), np.zeros(30))


@pytest.mark.parametrize("method", ["metis", "contiguous"])
@pytest.mark.parametrize("robots", [0, -2, 31, 1.5, True])
def test_robot_count_out_of_range(small_graph, method, robots):
    with pytest.raises(ValueRangeError) as error:
        partition(small_graph, robots, method)
    message = str(error.value)
    assert "\n" not in message and "robots" in message and repr(robots) in message


def test_unknown_method(small_graph):
    with pytest.raises(ValueRangeError, match="kahip"):
        partition(small_graph, 2, "kahip")


def test_every_vertex_its_own_robot(small_graph):
    """n = N is allowed: contiguous gives one pose per robot; METIS either does the same or fails
    with a one-line PopbenchError (never an empty robot)."""
    np.testing.assert_array_equal(partition(small_graph, 30, "contiguous"), np.arange(30))
    try:
        robots = partition(small_graph, 30, "metis")
    except PopbenchError as error:
        assert "\n" not in str(error) and "contiguous" in str(error)
    else:
        np.testing.assert_array_equal(np.sort(robots), np.arange(30))


def test_report_and_assign_hand_made(small_graph):
    robots = contiguous(30, 3)  # blocks 0..9, 10..19, 20..29
    report = partition_report(small_graph, robots)
    # cut: chain 9–10, 19–20; loops 0–29 (r0–r2), 5–15 (r0–r1), 20–9 (r2–r0)
    assert report.cut_edges == 5
    np.testing.assert_array_equal(report.sizes, [10, 10, 10])
    assert report.imbalance == 1.0
    graph = assign(small_graph, robots)
    np.testing.assert_array_equal(graph.robots, robots)
    expected = np.full(small_graph.num_edges, EdgeKind.ODOMETRY)
    expected[[9, 19]] = EdgeKind.INTER_RELATIVE
    expected[29:] = EdgeKind.INTER_LOOP
    np.testing.assert_array_equal(graph.kinds, expected)
    with pytest.raises(ValueRangeError):
        assign(small_graph, np.zeros(29, dtype=int))
    with pytest.raises(ValueRangeError):
        assign(small_graph, np.where(robots == 1, 2, robots))  # robot 1 unused


@pytest.mark.dataset
@pytest.mark.parametrize("robots", [5, 7])
def test_metis_beats_contiguous_on_intel(robots):
    graph = require_dataset("intel")
    metis = partition(graph, robots, "metis", seed=0)
    blocks = partition(graph, robots, "contiguous")
    metis_report = partition_report(graph, metis)
    block_report = partition_report(graph, blocks)
    assert metis[0] == 0 and np.unique(metis).size == robots
    assert metis_report.imbalance <= 1.03  # METIS default load imbalance (ufactor 30)
    # measured: 42 vs 222 cut edges (5 robots), 59 vs 246 (7 robots)
    assert metis_report.cut_edges < 0.5 * block_report.cut_edges
