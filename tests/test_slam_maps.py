"""Single-trajectory SLAM-shaped maps cut into robots (popbench.problems.slam_maps)."""

from __future__ import annotations

import numpy as np
import pytest

from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, odometry_composition, robot_kinds
from popbench.objective import g2o_errors
from popbench.problems import slam_maps, synthetic
from popbench.problems.partition import metis

SEEDS = range(12)


def test_same_seed_same_map_other_seed_other_map():
    a, b, c = (slam_maps.make_problem(3, (20, 40), seed=s) for s in (5, 5, 6))
    for field in ("poses", "tails", "heads", "measurements", "information", "kinds", "robots"):
        np.testing.assert_array_equal(getattr(a.graph, field), getattr(b.graph, field))
    assert a.graph.num_poses != c.graph.num_poses or not np.array_equal(
        a.graph.measurements, c.graph.measurements
    )


@pytest.mark.parametrize("robots", [1, 4, 7])
def test_one_trajectory_cut_by_the_tables_metis_split(robots):
    problem = slam_maps.make_problem(robots, 30, seed=2)
    graph = problem.graph
    n = robots * 30
    assert graph.poses.shape == graph.ground_truth.shape == (n, 3)
    assert problem.start == "odometry" and problem.num_robots == robots
    # one odometry chain 0 → 1 → … → N−1 first, then loop closures
    np.testing.assert_array_equal(graph.tails[: n - 1], np.arange(n - 1))
    np.testing.assert_array_equal(graph.heads[: n - 1], np.arange(1, n))
    assert np.all(graph.heads[n - 1 :] - graph.tails[n - 1 :] >= slam_maps.MIN_LOOP_GAP)
    # the owner of each pose is METIS's (seed 0) on the uncut map, the kinds relabelled by it
    uncut, _ = slam_maps.make_map(robots, 30, seed=2)
    np.testing.assert_array_equal(graph.robots, metis(uncut, robots, seed=0))
    np.testing.assert_array_equal(graph.kinds, robot_kinds(graph.tails, graph.heads, graph.robots))
    np.testing.assert_allclose(
        graph.poses, odometry_composition(n, graph.tails, graph.heads, graph.measurements)
    )
    np.testing.assert_allclose(graph.ground_truth[0], 0.0)
    if robots > 1:  # odometry edges cross robots: the trajectory is cut, not one walk each
        assert np.any(graph.kinds == EdgeKind.INTER_RELATIVE)


def test_loop_closures_join_revisited_places():
    graph, params = slam_maps.make_map(1, 400, seed=3)
    loops = slice(graph.num_poses - 1, None)
    truth = graph.ground_truth
    gap = truth[graph.heads[loops], :2] - truth[graph.tails[loops], :2]
    np.testing.assert_allclose(gap, 0.0, atol=1e-9)  # the same grid point
    assert params["loop_density"] == pytest.approx(
        (graph.num_edges - graph.num_poses + 1) / graph.num_poses
    )


def test_drawn_parameters_in_their_ranges():
    for seed in SEEDS:
        graph, params = slam_maps.make_map(7, slam_maps.POSES_PER_ROBOT, seed=seed)
        low, high = slam_maps.POSES_PER_ROBOT
        assert low <= params["poses_per_robot"] <= high
        assert graph.num_poses == 7 * params["poses_per_robot"]
        for name, bounds in (
            ("sigma_rotation", slam_maps.ROTATION_SIGMA),
            ("sigma_translation", slam_maps.TRANSLATION_SIGMA),
            ("anisotropy", slam_maps.ANISOTROPY),
            ("loop_factor", slam_maps.LOOP_FACTOR),
            ("straight", slam_maps.STRAIGHT),
            ("edge_jitter", slam_maps.EDGE_JITTER),
        ):
            assert bounds[0] <= params[name] <= bounds[1], name
        assert params["loop_density"] <= slam_maps.LOOP_DENSITY[1] + 1e-12
        # the information is diagonal, positive, anisotropic by the drawn factor on x / y
        info = graph.information
        assert np.all(info[:, [0, 0, 1, 1, 2, 2], [1, 2, 0, 2, 0, 1]] == 0.0)
        assert np.all(np.diagonal(info, axis1=1, axis2=2) > 0)
        ratio = np.sqrt(info[:, 1, 1] / info[:, 0, 0])  # σ_x / σ_y
        np.testing.assert_allclose(np.maximum(ratio, 1 / ratio), params["anisotropy"])
        odometry = 1.0 / np.sqrt(info[: graph.num_poses - 1, 2, 2])
        spread = 2.0 ** params["edge_jitter"] * (1 + 1e-9)
        assert np.all(odometry <= params["sigma_rotation"] * spread)
        assert np.all(odometry >= params["sigma_rotation"] / spread)


def test_scales_cover_the_registered_datasets_ranges():
    """Over a few maps the drawn σ spread over more than a decade, like the datasets'
    (grid1000_2 σ_θ 0.0096 rad … m3500c 0.335 rad)."""
    sigmas = [slam_maps.make_map(2, 10, seed=s)[1]["sigma_rotation"] for s in range(40)]
    assert min(sigmas) < 0.02 and max(sigmas) > 0.15


def test_measurement_noise_has_the_stated_information():
    """At the ground truth each whitened g2o error component (the information's frame: the
    measurement's) has unit variance."""
    graph, _ = slam_maps.make_map(4, 600, seed=8)
    r = g2o_errors(graph, graph.ground_truth)
    whitened = r * np.sqrt(np.diagonal(graph.information, axis1=1, axis2=2))
    tolerance = 4.0 / np.sqrt(2 * graph.num_edges)  # ~4 standard errors of a std estimate
    np.testing.assert_allclose(np.sqrt(np.mean(whitened**2, axis=0)), 1.0, atol=tolerance)


def test_slam_level_of_the_synthetic_generator():
    problem = synthetic.make_problem(3, slam_maps.LEVEL, poses_per_robot=20, seed=4)
    expected = slam_maps.make_problem(3, slam_maps.level_sizes(20), seed=4)
    np.testing.assert_array_equal(problem.graph.measurements, expected.graph.measurements)
    assert 3 * 20 <= problem.graph.num_poses <= 3 * 40


@pytest.mark.parametrize(
    "kwargs", [{"robots": 0}, {"robots": 2.5}, {"poses_per_robot": 1}, {"poses_per_robot": (9, 3)}]
)
def test_bad_arguments_raise_one_line_errors(kwargs):
    with pytest.raises(ValueRangeError):
        slam_maps.make_problem(**kwargs)
