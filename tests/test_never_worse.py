"""No method returns a map worse than its start (docs/never_worse.md).

What runs by default (CI): the registry's rule on toy methods; the cheap methods (lm, local-lm,
mm-pgo at a reduced budget) through the registry on every registered dataset but city10k, n = 7,
odometry start; the Gauss–Newton base step's two fixes on synthetic problems. Marked slow:
city10k, and prop-v1 (its own rules, without the registry) on the registered datasets of at most
1,300 poses and on the Freiburg TORO files, which are looked up in $POPBENCH_DATA (or its toro/
folder) and skipped, named, where they are absent (they are not registered yet; CI has no
network).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import require_dataset

from popbench import methods, objective
from popbench.datasets import DATASETS
from popbench.problems.synthetic import make_problem
from popbench.status import NeverWorse

FREIBURG = ("frh", "fr079")  # registered; not in the team's data folder (CI skips them)
CHEAP = {  # method: (budget iterations, options): a reduced budget, enough to move every dataset
    "lm": (3, {}),
    "mm-pgo": (10, {}),
    "local-lm": (1, {"local_iterations": 3, "consensus_iterations": 10}),
}
SLOW_DATASETS = ("city10k",)  # 4 s at these budgets; the other graphs ≈ 8 s together
SMALL_DATASETS = tuple(
    name
    for name, record in DATASETS.items()
    if record.alias_of is None and not name.endswith("_gt") and record.poses <= 1300
)


def registered() -> list:
    """Every registered dataset once (no aliases, no ground-truth files), city10k slow."""
    names = [n for n, d in DATASETS.items() if d.alias_of is None and not n.endswith("_gt")]
    return [
        pytest.param(name, marks=pytest.mark.slow) if name in SLOW_DATASETS else name
        for name in names
    ]


# -- the registry's rule ---------------------------------------------------------------------------


def solve_away(problem, budget, scale: float = 0.3, **_) -> methods.Result:
    """A toy method that moves every pose by ``scale`` (raising F above a good start)."""
    poses = problem.graph.poses + scale * np.random.default_rng(0).normal(
        size=(problem.graph.num_poses, 3)
    )
    costs = objective.evaluate(problem.graph, poses)
    history = np.array([objective.objective(problem.graph), costs.F])
    return methods.Result(
        poses, **costs._asdict(), wall_s=1.0, parallel_s=0.5, iterations=1, history=history
    )


@pytest.fixture
def away(monkeypatch: pytest.MonkeyPatch) -> str:
    record = methods.MethodRecord("away", "test_never_worse:solve_away", "Away")
    monkeypatch.setitem(methods.METHODS, "away", record)
    return "away"


def test_the_registry_returns_the_start_for_an_estimate_above_it(away: str) -> None:
    problem = make_problem(robots=3, poses_per_robot=20, seed=1)
    start = problem.graph.poses.copy()
    f_init = objective.objective(problem.graph, start)
    solve = methods.get_method(away)
    assert methods.method_options(away) == ("scale",)  # the wrapper keeps the signature
    result = solve(problem, methods.Budget(1))
    assert result.extras["never_worse"] is NeverWorse.START
    assert json.loads(json.dumps(result.extras["never_worse"])) == "start"  # serialised as written
    assert result.extras["F_method"] > f_init
    np.testing.assert_array_equal(result.poses, start)
    assert result.F == pytest.approx(f_init) and result.history[-1] == pytest.approx(f_init)
    assert (result.wall_s, result.parallel_s, result.iterations) == (1.0, 0.5, 1)  # the method's
    kept = solve(problem, methods.Budget(1), scale=0.0)  # F equal to the start's: kept
    assert kept.extras["never_worse"] is NeverWorse.METHOD
    assert "F_method" not in kept.extras


def test_the_rule_is_not_applied_with_injected_outliers(away: str) -> None:
    from popbench.outliers import with_outliers

    problem = with_outliers(make_problem(robots=3, poses_per_robot=20, seed=1), 0.2, seed=1)
    result = methods.get_method(away)(problem, methods.Budget(1))
    assert result.extras["never_worse"] is NeverWorse.NOT_APPLIED
    assert result.F > objective.objective(problem.graph)


@pytest.mark.parametrize("dataset", registered())
def test_cheap_methods_never_return_F_above_the_start(dataset: str) -> None:
    from popbench.harness.problems import distributed_problem

    require_dataset(dataset)
    problem = distributed_problem(dataset, 7, "odometry")
    f_init = objective.objective(problem.graph, problem.graph.poses)
    for name, (iterations, options) in CHEAP.items():
        result = methods.get_method(name)(problem, methods.Budget(iterations), **options)
        assert result.F <= f_init, name
        assert result.F == pytest.approx(objective.objective(problem.graph, result.poses)), name
        assert result.extras["never_worse"] in ("method", "start"), name


# -- the Gauss–Newton base step (envs.sweep) -------------------------------------------------------


def trajectory_core(problems, **overrides):
    from envs.core import PGOCore
    from envs.modes import TRAJECTORY_MODES
    from envs.observation import Dimensions

    options = {**TRAJECTORY_MODES.core_options(), "reward": "F", **overrides}
    core = PGOCore(problems[0].num_robots, Dimensions.of(problems), len(problems), **options)
    core.load(problems, range(len(problems)))
    return core


def test_a_base_step_longer_than_the_bound_keeps_its_direction() -> None:
    """A tight Δmax shortens the Gauss–Newton step by one factor (same direction); the core's
    componentwise clip would have turned it."""
    from envs.expert import Expert

    problems = [make_problem(robots=3, poses_per_robot=16, seed=seed) for seed in (2, 3)]
    free, tight = trajectory_core(problems), trajectory_core(problems, delta_max=(0.01,) * 3)
    edge = Expert(free).edge()
    inverse_root = free.state.inverse_sqrt_information
    flat = edge.reshape(-1)

    def metric(core):  # (G, 3) the step in metres / radians
        whitened = core.base_step(edge).reshape(-1, 3, 1)
        return (inverse_root.flatten(0, 1)[torch.arange(flat.numel()), flat] @ whitened)[..., 0]

    long, short = metric(free), metric(tight)
    assert bool((long.abs().amax(-1) > 0.01).any())  # some steps do not fit the tight bound
    assert bool((short.abs() <= 0.01 + 1e-12).all())
    cosine = (long * short).sum(-1) / (long.norm(dim=-1) * short.norm(dim=-1)).clamp_min(1e-30)
    moving = long.norm(dim=-1) > 1e-6  # (the others are round-off)
    assert torch.allclose(cosine[moving], torch.ones_like(cosine[moving]), atol=1e-9)


# -- prop-v1's own rules (without the registry), slow ----------------------------------------------


def prop_v1_stages(problem) -> tuple[float, dict]:
    from agents.methods import solve_prop_v1

    result = solve_prop_v1(problem, methods.Budget())
    return result.F, result.extras


@pytest.mark.slow
@pytest.mark.parametrize("dataset", SMALL_DATASETS)
def test_prop_v1_never_returns_F_above_the_start(dataset: str) -> None:
    from popbench.harness.problems import distributed_problem

    require_dataset(dataset)
    problem = distributed_problem(dataset, 7, "odometry")
    f, extras = prop_v1_stages(problem)
    assert f <= extras["F_init"]  # by prop-v1's own rules, without the registry's


@pytest.mark.slow
@pytest.mark.parametrize("name", FREIBURG)
def test_prop_v1_on_the_freiburg_maps(name: str) -> None:
    """prop-v1's keep rules on the two Freiburg maps (docs/never_worse.md): its F is at most the
    start's and the consensus improves on it, whatever the actor's episode does there (the
    default actor's episode raises the hospital's robots' local F from 0.27 to 1,089)."""
    from popbench.harness.problems import distributed_problem

    require_dataset(name)  # skips, naming it, where the file is not on disk
    problem = distributed_problem(name, 7, "odometry")
    f, extras = prop_v1_stages(problem)
    assert f <= extras["F_init"]
    assert f < 0.1 * extras["F_init"]  # the consensus, at least, improves on the start
