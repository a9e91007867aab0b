"""Synthetic multi-robot problems (paper §IV-A); outlier injection is in test_outliers.py."""

from __future__ import annotations

import numpy as np
import pytest

from popbench import se2
from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, odometry_composition
from popbench.objective import residuals
from popbench.problems.synthetic import MIN_LOOP_GAP, NOISE_LEVELS, make_problem


def test_same_seed_same_problem_other_seed_other_problem():
    a, b, c = make_problem(seed=3), make_problem(seed=3), make_problem(seed=4)
    for field in ("poses", "tails", "heads", "measurements", "information", "kinds"):
        np.testing.assert_array_equal(getattr(a.graph, field), getattr(b.graph, field))
    np.testing.assert_array_equal(a.graph.ground_truth, b.graph.ground_truth)
    assert not np.array_equal(a.graph.ground_truth, c.graph.ground_truth)


@pytest.mark.parametrize("robots", [1, 3, 7])
def test_structure(robots):
    problem = make_problem(robots=robots, poses_per_robot=60, loop_ratio=0.15, seed=1)
    graph = problem.graph
    n = robots * 60
    assert graph.poses.shape == graph.ground_truth.shape == (n, 3)
    assert problem.num_robots == robots and problem.start == "odometry"
    np.testing.assert_array_equal(graph.robots, np.arange(n) // 60)  # contiguous ids per robot
    # chain k → k+1 first, then round(0.15 N) loop closures
    assert graph.num_edges == n - 1 + round(0.15 * n)
    np.testing.assert_array_equal(graph.tails[: n - 1], np.arange(n - 1))
    np.testing.assert_array_equal(graph.heads[: n - 1], np.arange(1, n))
    kinds = graph.kinds
    boundary = (np.arange(n - 1) % 60) == 59
    assert np.all(kinds[: n - 1][boundary] == EdgeKind.INTER_RELATIVE)
    assert np.all(kinds[: n - 1][~boundary] == EdgeKind.ODOMETRY)
    loops = slice(n - 1, None)
    same = graph.robots[graph.tails[loops]] == graph.robots[graph.heads[loops]]
    np.testing.assert_array_equal(kinds[loops] == EdgeKind.LOOP, same)
    np.testing.assert_array_equal(kinds[loops] == EdgeKind.INTER_LOOP, ~same)
    gap = graph.heads[loops] - graph.tails[loops]
    assert np.all(gap[same] >= MIN_LOOP_GAP) and np.all(gap > 1)
    distance = np.linalg.norm(
        graph.ground_truth[graph.heads[loops], :2] - graph.ground_truth[graph.tails[loops], :2],
        axis=1,
    )
    assert np.all(distance <= 1.5 + 1e-9)
    pairs = set(zip(graph.tails.tolist(), graph.heads.tolist(), strict=True))
    assert len(pairs) == graph.num_edges  # no duplicate edges
    if robots == 7:
        assert set(np.unique(kinds)) == set(EdgeKind)


def test_initial_is_odometry_composition_and_gauge_at_origin():
    graph = make_problem(robots=4, seed=2).graph
    np.testing.assert_allclose(graph.ground_truth[0], 0.0, atol=1e-12)
    # independent recomputation: compose the chain measurements one by one
    chain = np.zeros((graph.num_poses, 3))
    for k in range(graph.num_poses - 1):
        chain[k + 1] = se2.compose(chain[k], graph.measurements[k])
    np.testing.assert_allclose(graph.poses, chain, atol=1e-9)
    expected = odometry_composition(graph.num_poses, graph.tails, graph.heads, graph.measurements)
    np.testing.assert_allclose(graph.poses, expected, atol=1e-12)
    # ground-truth steps are 1 m grid moves with quarter-turn headings
    steps = np.linalg.norm(np.diff(graph.ground_truth[:60, :2], axis=0), axis=1)
    np.testing.assert_allclose(steps, 1.0, atol=1e-9)


@pytest.mark.parametrize("level", ["V1", "V3"])
def test_noise_statistics_per_kind(level):
    """Residuals at the ground truth have std σ (per component) for each kind."""
    problem = make_problem(robots=30, noise=level, poses_per_robot=60, seed=7, loop_ratio=0.3)
    graph = problem.graph
    r = residuals(graph, graph.ground_truth)
    sigma_of = {
        EdgeKind.ODOMETRY: NOISE_LEVELS[level][0],
        EdgeKind.LOOP: NOISE_LEVELS[level][1],
        EdgeKind.INTER_RELATIVE: NOISE_LEVELS[level][2],
        EdgeKind.INTER_LOOP: NOISE_LEVELS[level][2],
    }
    for kind, sigma in sigma_of.items():
        sample = r[graph.kinds == kind]
        assert sample.shape[0] >= 25, kind
        tolerance = 4.0 / np.sqrt(2 * sample.size)  # ~4 standard errors of a std estimate
        assert abs(np.sqrt(np.mean(sample**2)) / sigma - 1.0) < tolerance, kind
        info = graph.information[graph.kinds == kind]
        np.testing.assert_allclose(info, np.broadcast_to(np.eye(3) / sigma**2, info.shape))


@pytest.mark.parametrize(
    "kwargs",
    [{"robots": 0}, {"robots": 2.5}, {"noise": "V4"}, {"poses_per_robot": 1}, {"loop_ratio": -1}],
)
def test_invalid_arguments(kwargs):
    with pytest.raises(ValueRangeError) as error:
        make_problem(**kwargs)
    assert "\n" not in str(error.value)


def test_perturbed_start_moves_each_odometry_step_by_its_scale_in_sigmas() -> None:
    from popbench.problems.synthetic import perturbed_start

    problem = make_problem(1, "V2", 400, loop_ratio=0.0, seed=3)
    assert np.allclose(perturbed_start(problem, 0.0, 1).graph.poses, problem.graph.poses)
    moved = perturbed_start(problem, 2.0, seed=1).graph
    steps = se2.between(moved.poses[moved.tails], moved.poses[moved.heads])
    whitened = se2.log(se2.between(moved.measurements, steps)) / np.sqrt(
        1.0 / np.diagonal(moved.information, axis1=1, axis2=2)
    )
    assert np.std(whitened, axis=0) == pytest.approx([2.0, 2.0, 2.0], rel=0.1)
    with pytest.raises(ValueRangeError, match="start noise"):
        perturbed_start(problem, -1.0, 0)
