"""prop-v1's actor episode never raises any robot's local F on the registered maps, before the
keep rule (agents.methods.Episode.kept) has anything to undo: Table I's eight maps, fr079 and frh,
n = 7, odometry start, the default actor under the default step rule (docs/environment.md, "The
step rule"). Under the clipped rule the same actor raised some robot's local F on 6 of these 10
maps (docs/training.md, "The gap to local-lm on Table I's maps, decomposed")."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from conftest import require_dataset

from agents.methods import DEFAULT_CHECKPOINT, cached_actor, run_episode
from popbench import objective
from popbench.choices import DEFAULT_STEP_RULE
from popbench.harness.defaults import TABLE1_DATASETS
from popbench.harness.problems import distributed_problem

MAPS = (*TABLE1_DATASETS, "fr079", "frh")
# a robot whose local graph has no loop closure sits at F ≈ 1e-25 at the start; its episode may
# move that by round-off, so the comparison allows 1e-9 (absolute) beside 1e-9 (relative)
ROUND_OFF = 1e-9


@pytest.mark.dataset
@pytest.mark.slow
@pytest.mark.parametrize("name", MAPS)
def test_the_default_actor_never_raises_a_robots_local_f(name: str) -> None:
    require_dataset(name)
    problem = distributed_problem(name, 7, "odometry")
    actor, task = cached_actor(str(DEFAULT_CHECKPOINT), "cpu")
    with torch.no_grad():
        episode = run_episode(
            actor, problem, task=dataclasses.replace(task, step_rule=DEFAULT_STEP_RULE)
        )
    start = np.array(
        [
            objective.objective(local.graph, poses)
            for local, poses in zip(problem.local_graphs, episode.start_poses, strict=True)
        ]
    )
    end = np.array(
        [
            objective.objective(local.graph, poses)
            for local, poses in zip(problem.local_graphs, episode.local_poses, strict=True)
        ]
    )
    np.testing.assert_allclose(episode.local_F, end, rtol=1e-8, atol=ROUND_OFF)
    assert (end <= start * (1 + ROUND_OFF) + ROUND_OFF).all(), (start, end)
    assert end.sum() < start.sum()  # the episode still lowers the robots' local F
