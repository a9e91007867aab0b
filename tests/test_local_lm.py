"""local-lm (every robot's local optimum, then the consensus) and popbench.consensus.reconcile."""

from __future__ import annotations

import numpy as np
import pytest

from popbench import objective, se2
from popbench.consensus.reconcile import CONSENSUS_MODES, reconcile
from popbench.errors import ValueRangeError
from popbench.problems.distributed import DistributedProblem
from popbench.problems.synthetic import make_problem
from popbench.solvers import lm, local_lm


@pytest.fixture(scope="module")
def problem() -> DistributedProblem:
    return make_problem(robots=3, poses_per_robot=30, noise="V2", seed=5)


def test_local_optima_are_stationary_and_below_the_start(problem):
    optima, seconds = local_lm.local_optima(problem)
    assert seconds.shape == (3,) and np.all(seconds > 0)
    for local, poses in zip(problem.local_graphs, optima, strict=True):
        graph = local.graph
        assert np.array_equal(poses[0], graph.poses[0])  # the local gauge stays put
        assert objective.objective(graph, poses) < objective.objective(graph, graph.poses)
        # a much tighter solve from there lowers F by no more than round-off of the stopping rule
        tighter = lm.solve_graph(
            graph, poses, 200, relative_tolerance=1e-15, gradient_tolerance=1e-12
        ).poses
        f_ours, f_tight = objective.objective(graph, poses), objective.objective(graph, tighter)
        assert f_tight <= f_ours <= f_tight * (1 + 1e-8)


def test_excluded_edges_are_left_out(problem):
    excluded = np.zeros(problem.graph.num_edges, dtype=bool)
    loops = np.flatnonzero(problem.graph.kinds != 0)
    excluded[loops] = True
    optima, _ = local_lm.local_optima(problem, excluded=excluded)
    # with only odometry left (a tree on every robot's owned chain), the optimum is the
    # odometry composition: every remaining residual vanishes
    for local, poses in zip(problem.local_graphs, optima, strict=True):
        kept = local.graph.edge_subset(~excluded[local.edge_ids])
        assert objective.objective(kept, poses) < 1e-12


def test_one_robot_is_the_centralised_optimum(problem):
    single = DistributedProblem.single_robot(problem.graph)
    ours = local_lm.solve(single)
    reference = lm.solve_graph(single.graph, single.graph.poses, local_lm.LOCAL_ITERATIONS)
    assert ours.F == pytest.approx(objective.objective(single.graph, reference.poses), rel=1e-9)
    assert ours.history[0] > ours.F


@pytest.mark.parametrize("mode", CONSENSUS_MODES)
def test_local_lm_lowers_F_through_either_consensus(problem, mode):
    result = local_lm.solve(problem, consensus=mode)
    f_init = objective.objective(problem.graph, problem.graph.poses)
    assert result.F < f_init
    if mode == "admm":
        assert result.extras["F_aligned"] == result.extras["F_local"]
    else:
        assert result.extras["F_aligned"] <= result.extras["F_local"] + 1e-9
    assert result.messages > 0 and result.parallel_s > 0


def test_unknown_consensus_is_one_line_error(problem):
    with pytest.raises(ValueRangeError, match="admm"):
        reconcile(problem, problem.split(), "gauss")


def test_held_copies_stay_at_the_start_and_the_rest_is_optimal(problem):
    held, _ = local_lm.local_optima(problem, copy_weight=np.inf)
    free, _ = local_lm.local_optima(problem)
    for local, poses, optimum in zip(problem.local_graphs, held, free, strict=True):
        graph, owned = local.graph, local.owned_count
        assert np.array_equal(poses[owned:], problem.graph.poses[local.separator_ids])
        fixed = graph.replace(fixed=np.arange(owned, local.num_vertices))
        tighter = lm.solve_graph(
            fixed, poses, 200, relative_tolerance=1e-15, gradient_tolerance=1e-12
        ).poses
        f_held = objective.objective(graph, poses)
        assert objective.objective(graph, tighter) <= f_held <= objective.objective(graph) + 1e-9
        assert f_held >= objective.objective(graph, optimum) - 1e-9  # the free optimum is lower


def test_copy_priors_add_a_weighted_disagreement_and_span_free_to_held(problem):
    local = problem.local_graphs[1]
    targets = problem.graph.poses[local.separator_ids]
    poses = local.graph.poses + 0.01 * np.arange(local.num_vertices * 3).reshape(-1, 3) % 0.07
    stacked = np.vstack([poses, targets])
    f_local = objective.objective(local.graph, poses)
    one, two = (
        objective.objective(local_lm.copy_priors(local, targets, w), stacked) - f_local
        for w in (1.0, 2.0)
    )
    assert one > 0 and two == pytest.approx(2 * one, rel=1e-12)
    assert objective.objective(
        local_lm.copy_priors(local, targets, 1.0), np.vstack([poses, poses[local.owned_count :]])
    ) == pytest.approx(f_local, abs=1e-12)
    free = local_lm.local_optima(problem)[0][1]
    held = local_lm.local_optima(problem, copy_weight=np.inf)[0][1]
    weak = local_lm.local_optima(problem, copy_weight=1e-8)[0][1]
    strong = local_lm.local_optima(problem, copy_weight=1e8)[0][1]
    f = lambda x: objective.objective(local.graph, x)  # noqa: E731
    assert f(weak) == pytest.approx(f(free), rel=1e-4)
    assert f(strong) == pytest.approx(f(held), rel=1e-4)
    with pytest.raises(ValueRangeError, match="copy_weight"):
        local_lm.local_optima(problem, copy_weight=0.0)


def test_copy_targets_replace_the_start_as_the_owners_estimates(problem):
    targets = problem.graph.ground_truth
    held, _ = local_lm.local_optima(problem, copy_weight=np.inf, copy_targets=targets)
    for local, poses in zip(problem.local_graphs, held, strict=True):
        assert np.array_equal(poses[local.owned_count :], targets[local.separator_ids])


def test_relative_priors_ignore_the_owners_frames(problem):
    local = problem.local_graphs[1]
    targets = problem.graph.ground_truth[local.separator_ids]
    shifted = se2.compose(np.array([3.0, -2.0, 0.7]), targets)  # one rigid frame move
    poses = local.graph.poses.copy()
    poses[local.owned_count :] = targets
    tied = local_lm.relative_priors(local, targets, 5.0)
    assert tied.num_edges > local.graph.num_edges
    f_local = objective.objective(local.graph, poses)
    assert objective.objective(tied, poses) == pytest.approx(f_local, abs=1e-9)
    poses[local.owned_count :] = shifted
    moved = local_lm.relative_priors(local, targets, 5.0)
    assert objective.objective(moved, poses) == pytest.approx(
        objective.objective(local.graph, poses), abs=1e-9
    )
    optima, _ = local_lm.local_optima(problem, copy_weight=1.0, copy_relative=True)
    assert np.array_equal(optima[1][0], local.graph.poses[0])  # the first pose is the gauge
    with pytest.raises(ValueRangeError, match="copy_weight"):
        local_lm.local_optima(problem, copy_weight=np.inf, copy_relative=True)
