"""The imitation phase (agents.imitation): its losses and a short DAgger run."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from agents.config import TRAJECTORY_TASK, ExperimentConfig, ImitationConfig
from agents.imitation import imitate, imitation_losses, make_core


def test_edge_loss_is_the_log_of_the_right_choices_probability():
    log_probs = torch.log(torch.tensor([[0.5, 0.3, 0.2, 0.0]]))
    right = torch.tensor([[False, True, True, False]])
    zero = torch.zeros(1, 3)
    edge_loss, delta_loss = imitation_losses(
        log_probs, right, zero, zero, torch.tensor([True]), torch.ones(3)
    )
    assert float(edge_loss) == pytest.approx(-math.log(0.5))
    assert float(delta_loss) == 0.0


def test_delta_loss_clips_the_label_and_ignores_the_no_op():
    log_probs = torch.zeros(2, 2)
    right = torch.ones(2, 2, dtype=torch.bool)
    delta = torch.tensor([[1.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    label = torch.tensor([[3.0, 0.0, 0.0], [0.0, 0.0, 0.0]])  # clipped to 2 on x
    bound = torch.full((3,), 2.0)
    _, delta_loss = imitation_losses(
        log_probs, right, delta, label, torch.tensor([True, False]), bound
    )
    assert float(delta_loss) == pytest.approx(((1.0 - 2.0) / 2.0) ** 2)


def test_a_short_dagger_run_trains_the_actor(tmp_path):
    from agents.actor import HybridActor
    from tests.conftest import tiny_model

    experiment = ExperimentConfig(robots=3, poses_per_robot=12, seed=1)
    core, sampler = make_core(TRAJECTORY_TASK, experiment, 1, 0)
    core.load([sampler.draw(0)], [0])
    observation = core.observation()
    model = dataclasses.replace(tiny_model(), delta_max=tuple(float(v) for v in core.action_bound))
    actor = HybridActor(
        observation["node_features"].shape[-1], observation["edge_attr"].shape[-1], model
    )
    before = [p.detach().clone() for p in actor.parameters()]
    config = ImitationConfig(episodes=3, num_envs=2, beta_decay=0.5)
    logs = imitate(actor, TRAJECTORY_TASK, experiment, config)
    assert [log.episode for log in logs] == [0, 1, 2]
    assert [log.beta for log in logs] == [1.0, 0.5, 0.25]
    assert all(math.isfinite(log.edge_loss) and math.isfinite(log.delta_loss) for log in logs)
    # with β = 1 the expert acts: its episode removes most of the local error
    assert logs[0].local_gain > 0.5
    assert any(not torch.equal(a, b) for a, b in zip(before, actor.parameters(), strict=True))
    assert not actor.training
