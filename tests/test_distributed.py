"""DistributedProblem: local graphs, separators, splitting and assembling estimates."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import require_dataset

from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind
from popbench.objective import objective
from popbench.problems.distributed import DistributedProblem
from popbench.problems.partition import contiguous
from popbench.problems.synthetic import make_problem


@pytest.fixture
def problem():
    return make_problem(robots=4, poses_per_robot=25, seed=3)


def test_local_graphs_cover_every_edge_once_or_twice(problem):
    graph = problem.graph
    crossing = graph.robots[graph.tails] != graph.robots[graph.heads]
    np.testing.assert_array_equal(problem.inter_robot_edges, np.flatnonzero(crossing))
    counts = np.zeros(graph.num_edges, dtype=int)
    for r in range(problem.num_robots):
        edges = problem.local_edges(r)
        assert np.all(np.diff(edges) > 0)
        touches = (graph.robots[graph.tails[edges]] == r) | (graph.robots[graph.heads[edges]] == r)
        assert np.all(touches)
        counts[edges] += 1
    np.testing.assert_array_equal(counts, np.where(crossing, 2, 1))
    kinds = graph.kinds[problem.inter_robot_edges]
    assert np.all((kinds == EdgeKind.INTER_RELATIVE) | (kinds == EdgeKind.INTER_LOOP))


def test_local_vertices_owned_then_separator_copies(problem):
    graph = problem.graph
    appearances = np.zeros(graph.num_poses, dtype=int)
    for r in range(problem.num_robots):
        local = problem.local_graph(r)
        np.testing.assert_array_equal(problem.owned(r), np.flatnonzero(graph.robots == r))
        np.testing.assert_array_equal(local.owned_ids, problem.owned(r))
        edges = problem.local_edges(r)
        endpoints = np.union1d(graph.tails[edges], graph.heads[edges])
        expected_copies = endpoints[graph.robots[endpoints] != r]
        np.testing.assert_array_equal(local.separator_ids, expected_copies)
        np.testing.assert_array_equal(
            problem.local_vertices(r), np.concatenate([problem.owned(r), expected_copies])
        )
        appearances[local.global_ids] += 1
    # separators are exactly the vertices duplicated into more than one local graph
    np.testing.assert_array_equal(problem.separators, np.flatnonzero(appearances > 1))
    assert np.all(appearances >= 1)
    assert problem.separators.size > 0


def test_local_graph_reindexing_maps_back(problem):
    graph = problem.graph
    for r in range(problem.num_robots):
        local = problem.local_graph(r)
        lg = local.graph
        ids, edges = local.global_ids, local.edge_ids
        np.testing.assert_array_equal(ids[lg.tails], graph.tails[edges])
        np.testing.assert_array_equal(ids[lg.heads], graph.heads[edges])
        np.testing.assert_array_equal(lg.measurements, graph.measurements[edges])
        np.testing.assert_array_equal(lg.information, graph.information[edges])
        np.testing.assert_array_equal(lg.kinds, graph.kinds[edges])
        np.testing.assert_array_equal(lg.poses, graph.poses[ids])
        np.testing.assert_array_equal(lg.ground_truth, graph.ground_truth[ids])
        np.testing.assert_array_equal(lg.robots, graph.robots[ids])
        assert local.robot == r and local.owned_count == problem.owned(r).size


def test_local_objectives_count_inter_robot_edges_twice(problem):
    graph = problem.graph
    x = graph.ground_truth
    total = sum(
        objective(problem.local_graph(r).graph, x[problem.local_vertices(r)])
        for r in range(problem.num_robots)
    )
    inter = graph.replace(
        tails=graph.tails[problem.inter_robot_edges],
        heads=graph.heads[problem.inter_robot_edges],
        measurements=graph.measurements[problem.inter_robot_edges],
        information=graph.information[problem.inter_robot_edges],
        kinds=graph.kinds[problem.inter_robot_edges],
    )
    assert total == pytest.approx(objective(graph, x) + objective(inter, x), rel=1e-12)


def test_assemble_inverts_split_and_takes_owner_copies(problem, rng):
    x = rng.normal(size=(problem.graph.num_poses, 3))
    locals_ = problem.split(x)
    np.testing.assert_array_equal(problem.assemble(locals_), x)
    # changing a non-owner copy changes nothing; changing the owner's copy does
    r = next(r for r in range(problem.num_robots) if problem.local_graph(r).separator_ids.size)
    local = problem.local_graph(r)
    locals_[r][local.owned_count] += 1.0
    np.testing.assert_array_equal(problem.assemble(locals_), x)
    locals_[r][0] += 1.0
    assert not np.array_equal(problem.assemble(locals_), x)
    np.testing.assert_array_equal(problem.split()[r], problem.graph.poses[local.global_ids])


def test_from_graph_metis_contiguous_and_explicit(small_graph):
    metis = DistributedProblem.from_graph(small_graph, 3)
    assert metis.num_robots == 3 and metis.robots[0] == 0
    blocks = DistributedProblem.from_graph(small_graph, 3, partition="contiguous")
    np.testing.assert_array_equal(blocks.robots, contiguous(30, 3))
    assert blocks.inter_robot_edges.size == 5
    explicit = DistributedProblem.from_graph(small_graph, contiguous(30, 3), start="chordal")
    np.testing.assert_array_equal(explicit.graph.kinds, blocks.graph.kinds)
    assert explicit.start == "chordal"
    with pytest.raises(ValueRangeError):
        DistributedProblem.from_graph(small_graph, 31)
    with pytest.raises(ValueRangeError):
        DistributedProblem.from_graph(small_graph, 0)


def test_single_robot_and_unassigned_graph(small_graph):
    for problem in (DistributedProblem.single_robot(small_graph), DistributedProblem(small_graph)):
        assert problem.num_robots == 1
        assert problem.separators.size == 0 and problem.inter_robot_edges.size == 0
        local = problem.local_graph(0)
        np.testing.assert_array_equal(local.global_ids, np.arange(30))
        np.testing.assert_array_equal(local.edge_ids, np.arange(small_graph.num_edges))
        np.testing.assert_array_equal(problem.assemble(problem.split()), small_graph.poses)


@pytest.mark.dataset
def test_intel_split_among_seven_robots():
    problem = DistributedProblem.from_graph(require_dataset("intel"), 7)
    graph = problem.graph
    counts = np.zeros(graph.num_edges, dtype=int)
    for local in problem.local_graphs:
        counts[local.edge_ids] += 1
    assert counts.sum() == graph.num_edges + problem.inter_robot_edges.size
    assert set(np.unique(counts)) == {1, 2}
    np.testing.assert_array_equal(problem.assemble(problem.split()), graph.poses)
