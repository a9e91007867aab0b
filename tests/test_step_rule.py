"""The environment's step rule (envs.core.PGOCore ``step_rule``): the line search never lets a
step raise an agent's local F, where the clipped rule can; the scale it picks is the best of its
candidates; the non-monotone rule lets F rise within its window but never above the window's
largest value; the rule travels with the task (docs/environment.md, "The step rule")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from envs.core import PGOCore
from envs.correction import LINE_SEARCH_SCALES, nonmonotone_choice
from envs.expert import Expert
from envs.modes import NONMONOTONE_WINDOW, TRAJECTORY_MODES, EnvModes
from popbench import objective
from popbench.errors import ValueRangeError
from popbench.problems.synthetic import make_problem

SMALL = {"robots": 3, "poses_per_robot": 20}
TASKS = {
    "subtree, base step": TRAJECTORY_MODES,
    "subtree, no base": EnvModes("subtree", "invariant", "whitened", "none"),
    "pose, metric": EnvModes("pose", "paper", "metric", "none"),
}


def random_episode(task: EnvModes, rule: str, seed: int) -> np.ndarray:
    """``(T + 1, n)`` every agent's local F along one episode of uniformly random edges and
    corrections drawn over twice the action bound (the rule, not the policy, keeps them safe)."""
    problem = make_problem(seed=seed, **SMALL)
    core = PGOCore.for_problems([problem], dataclasses.replace(task, step_rule=rule))
    rng = np.random.default_rng(seed)
    bound = 2 * core.action_bound.numpy()
    losses = [core.state.loss[0].numpy().copy()]
    for _ in range(core.horizon):
        mask = core.action_mask()[0].numpy()
        edge = np.where(mask, rng.random(mask.shape), -1.0).argmax(-1)
        delta = rng.uniform(-bound, bound, (mask.shape[0], 3))
        core.step(torch.as_tensor(edge).view(1, -1), torch.as_tensor(delta).view(1, -1, 3))
        losses.append(core.state.loss[0].numpy().copy())
    return np.array(losses)


@pytest.mark.parametrize("rule", ["line-search", "search-with-clip"])
@pytest.mark.parametrize("name", list(TASKS))
def test_line_search_never_raises_a_local_f_where_clipping_does(name: str, rule: str) -> None:
    raised_by_clip = 0
    for seed in range(3):
        searched = random_episode(TASKS[name], rule, seed)
        rises = np.diff(searched, axis=0)
        assert (rises <= 1e-9 * (1.0 + searched[:-1])).all(), rises.max()
        assert searched[-1].sum() < searched[0].sum()  # and it still moves
        clipped = random_episode(TASKS[name], "clip", seed)
        raised_by_clip += int((np.diff(clipped, axis=0) > 0).any())
    assert raised_by_clip > 0  # the random policy does raise F without the search


@pytest.mark.parametrize("name", list(TASKS))
def test_the_nonmonotone_rule_never_raises_its_reference(name: str) -> None:
    rose_within_the_window = 0
    for seed in range(3):
        losses = random_episode(TASKS[name], "nonmonotone", seed)
        padded = np.concatenate([np.repeat(losses[:1], NONMONOTONE_WINDOW - 1, 0), losses])
        windows = np.lib.stride_tricks.sliding_window_view(padded, NONMONOTONE_WINDOW, axis=0)
        reference = windows.max(-1)  # (T + 1, n): the largest of the last M values
        assert (losses[1:] <= reference[:-1] * (1 + 1e-9) + 1e-9).all()
        assert (losses[-1] <= losses[0] * (1 + 1e-9) + 1e-9).all()
        assert losses[-1].sum() < losses[0].sum()
        rose_within_the_window += int((np.diff(losses, axis=0) > 1e-9).any())
    assert rose_within_the_window > 0  # unlike the line search, a step may raise F


def test_the_nonmonotone_choice_takes_the_largest_acceptable_scale() -> None:
    recent = torch.tensor([[5.0, 3.0, 2.0], [2.0, 2.0, 2.0]])  # the current value last
    change = torch.tensor([[4.0, 2.5, -0.5, 0.0], [1.0, -0.1, -0.3, 0.0]])
    # agent 0: 2 + 4 > 5, 2 + 2.5 <= 5 → index 1; agent 1: 2 + 1 > 2, 2 - 0.1 <= 2 → index 1
    assert nonmonotone_choice(change, recent).tolist() == [1, 1]
    assert nonmonotone_choice(
        torch.full((1, 4), 9.0).index_fill(1, torch.tensor([3]), 0.0), recent[:1]
    ).tolist() == [3]  # only α = 0 is left


def test_the_core_keeps_its_loss_equal_to_the_local_objective() -> None:
    problem = make_problem(seed=7, **SMALL)
    task = dataclasses.replace(TRAJECTORY_MODES, step_rule="nonmonotone")
    core = PGOCore.for_problems([problem], task)
    expert = Expert(core)
    for _ in range(core.horizon):
        core.step(*expert.act())
        recent = core.state.recent_f[0, :, -1].numpy()  # the rule's own running local F
        np.testing.assert_allclose(recent, core.state.loss[0].numpy(), rtol=1e-9, atol=1e-9)
    copies = core.local_poses(0)
    for agent, (local, poses) in enumerate(zip(problem.local_graphs, copies, strict=True)):
        exact = objective.objective(local.graph, poses)
        assert float(core.state.loss[0, agent]) == pytest.approx(exact, rel=1e-9, abs=1e-9)


def test_the_chosen_scale_is_the_best_candidate() -> None:
    problem = make_problem(seed=2, **SMALL)
    task = dataclasses.replace(TRAJECTORY_MODES, base="none")
    rng = np.random.default_rng(0)
    for _ in range(5):
        edge = torch.as_tensor(rng.integers(0, 10, 3)).view(1, 3)
        delta = torch.as_tensor(rng.uniform(-8, 8, (1, 3, 3)))
        outcomes = []
        for scale in LINE_SEARCH_SCALES:  # each candidate executed under the clip-free rule
            core = PGOCore.for_problems([problem], task, delta_max=(1e9,) * 3)
            core.action_bound.fill_(1e9)
            core.step(edge, scale * delta)
            outcomes.append(core.state.loss[0].numpy().copy())
        searched = PGOCore.for_problems(
            [problem], dataclasses.replace(task, step_rule="line-search")
        )
        searched.step(edge, delta)
        best = np.min(outcomes, axis=0)
        np.testing.assert_allclose(searched.state.loss[0].numpy(), best, rtol=1e-9)


@pytest.mark.parametrize("name", list(TASKS))
def test_the_search_with_the_clip_beats_both_of_its_parents_at_each_step(name: str) -> None:
    problem = make_problem(seed=3, **SMALL)
    rng = np.random.default_rng(1)
    for _ in range(5):
        edge = torch.as_tensor(rng.integers(0, 10, 3)).view(1, 3)
        outcomes, draw = {}, rng.uniform(-2, 2, (1, 3, 3))  # twice the action bound
        for rule in ("clip", "line-search", "search-with-clip"):
            core = PGOCore.for_problems([problem], dataclasses.replace(TASKS[name], step_rule=rule))
            core.step(edge, torch.as_tensor(draw * core.action_bound.numpy()))
            outcomes[rule] = core.state.loss[0].numpy().copy()
        best = np.minimum(outcomes["clip"], outcomes["line-search"])
        assert (outcomes["search-with-clip"] <= best * (1 + 1e-9) + 1e-9).all()


@pytest.mark.parametrize("name", list(TASKS))
def test_the_search_with_the_clip_has_the_clip_rules_step_as_a_candidate(
    name: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    problem = make_problem(seed=4, **SMALL)
    rng = np.random.default_rng(2)
    edge = torch.as_tensor(rng.integers(0, 10, 3)).view(1, 3)
    draw = rng.uniform(-2, 2, (1, 3, 3))
    poses = {}
    for rule in ("clip", "search-with-clip"):
        core = PGOCore.for_problems([problem], dataclasses.replace(TASKS[name], step_rule=rule))
        core.step(edge, torch.as_tensor(draw * core.action_bound.numpy()))
        poses[rule] = core.state.poses.clone()
        # forced: the candidate before α = 0, which must be the clip rule's own step
        monkeypatch.setattr(
            "envs.core.monotone_choice",
            lambda change: torch.full_like(change[:, 0], change.shape[1] - 2).long(),
        )
    torch.testing.assert_close(poses["search-with-clip"], poses["clip"], rtol=1e-12, atol=1e-12)


def test_an_unknown_step_rule_is_refused() -> None:
    with pytest.raises(ValueRangeError, match="step_rule"):
        PGOCore.for_problems([make_problem(seed=0, **SMALL)], step_rule="trust-region")
