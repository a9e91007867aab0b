"""The start of a problem: one list of names, one function that makes the poses."""

from __future__ import annotations

import numpy as np
import pytest

from popbench.errors import ValueRangeError
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.chordal import chordal_initialisation
from popbench.solvers.initial import STARTS, check_start, initial_estimate, with_start


def test_each_start_makes_its_poses(small_graph) -> None:
    moved = small_graph.replace(poses=small_graph.poses + 0.3)
    np.testing.assert_array_equal(initial_estimate(moved, "odometry"), moved.odometry_initial())
    np.testing.assert_array_equal(initial_estimate(moved, "chordal"), chordal_initialisation(moved))
    given = initial_estimate(moved, "given")
    np.testing.assert_array_equal(given, moved.poses)
    assert given is not moved.poses  # a copy: a method may not edit the graph through it
    assert STARTS == ("odometry", "chordal", "given")


def test_an_unknown_start_is_one_line_naming_the_allowed_ones(small_graph) -> None:
    with pytest.raises(ValueRangeError, match=r"invalid --init 'random': allowed odometry \|"):
        check_start("random", "--init")
    with pytest.raises(ValueRangeError, match="chordal | given"):
        initial_estimate(small_graph, "ground-truth")
    assert check_start("chordal") == "chordal"


def test_a_problem_carries_its_start_and_keeps_its_split(small_graph) -> None:
    mask = np.zeros(small_graph.num_edges, dtype=bool)
    mask[3] = True
    problem = DistributedProblem.from_graph(small_graph, 3, start="given", outlier_mask=mask)
    chordal = with_start(problem, "chordal")
    assert chordal.start == "chordal" and problem.start == "given"
    np.testing.assert_array_equal(chordal.graph.poses, chordal_initialisation(problem.graph))
    np.testing.assert_array_equal(chordal.robots, problem.robots)
    np.testing.assert_array_equal(chordal.graph.kinds, problem.graph.kinds)
    assert chordal.outlier_mask is mask
    graph = with_start(small_graph, "odometry")  # a graph in, a graph out
    np.testing.assert_array_equal(graph.poses, small_graph.odometry_initial())
