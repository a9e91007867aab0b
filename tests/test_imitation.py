"""The imitation phase (agents.imitation): its losses and a short DAgger run."""

from __future__ import annotations

import dataclasses
import math

import pytest
import torch

from agents.config import ExperimentConfig, ImitationConfig
from agents.imitation import imitate, make_core
from agents.loss_terms import imitation_losses, pre_tanh_label
from envs.modes import TRAJECTORY_MODES


def test_edge_loss_is_the_log_of_the_right_choices_probability():
    log_probs = torch.log(torch.tensor([[0.5, 0.3, 0.2, 0.0]]))
    right = torch.tensor([[False, True, True, False]])
    zero = torch.zeros(1, 3)
    edge_loss, delta_loss = imitation_losses(
        log_probs, right, zero, zero, zero, torch.tensor([True]), torch.ones(3)
    )
    assert float(edge_loss) == pytest.approx(-math.log(0.5))
    assert float(delta_loss) == 0.0  # the label's u* = 0 at the mean, log σ = 0


def test_delta_loss_scales_the_clipped_pre_tanh_label_and_ignores_the_no_op():
    log_probs = torch.zeros(3, 2)
    right = torch.ones(3, 2, dtype=torch.bool)
    mean = torch.tensor([[0.2, 0.0, 0.0], [0.0, 0.0, 0.0], [5.0, 5.0, 5.0]])
    log_std = torch.zeros(3, 3)
    label = torch.tensor([[1.0, 0.0, 3.0], [0.0, 0.4, 0.0], [0.0, 0.0, 0.0]])  # θ clipped
    bound = torch.full((3,), 2.0)
    acting = torch.tensor([True, True, False])
    _, delta_loss = imitation_losses(log_probs, right, mean, log_std, label, acting, bound)
    u = pre_tanh_label(label[:2], bound)
    scale = (1.4826 * (u - u.median(0).values).abs().median(0).values).clamp(min=1e-3)
    error = (u - mean[:2]) / scale
    huber = torch.where(error.abs() <= 1, 0.5 * error**2, error.abs() - 0.5)
    width = 0.5 * ((u - mean[:2]) ** 2).clamp(max=9.0)
    assert float(delta_loss) == pytest.approx(float((huber + width).sum(-1).mean()), rel=1e-5)
    # the mean at the label leaves only the width term's log σ = 0
    _, at_label = imitation_losses(
        log_probs,
        right,
        u.new_zeros(3, 3).index_copy(0, torch.arange(2), u),
        log_std,
        label,
        acting,
        bound,
    )
    assert float(at_label) == pytest.approx(0.0, abs=1e-6)


def test_the_nll_trains_the_log_std_towards_the_error_scale():
    """σ follows the spread of the labels around the mean (the exploration width GA-SAC starts
    from), where the squared error left it untouched."""
    torch.manual_seed(0)
    label = 0.3 * torch.randn(256, 3)  # bound 5: u* ≈ label / 5, spread 0.06
    mean = torch.zeros(256, 3)
    log_std = torch.full((3,), -1.0, requires_grad=True)
    optimiser = torch.optim.Adam([log_std], lr=0.01)
    for _ in range(800):
        optimiser.zero_grad()
        _, loss = imitation_losses(
            torch.zeros(256, 2),
            torch.ones(256, 2, dtype=torch.bool),
            mean,
            log_std.expand(256, 3),
            label,
            torch.ones(256, dtype=torch.bool),
            torch.full((3,), 5.0),
        )
        loss.backward()
        optimiser.step()
    spread = pre_tanh_label(label, torch.full((3,), 5.0)).pow(2).mean(0).sqrt()  # RMS about μ
    # within 10 %: the cap at 3σ trims the sample's tails, so σ ends slightly below the RMS
    torch.testing.assert_close(log_std.detach().exp(), spread, rtol=0.1, atol=0.0)
    assert float(log_std.detach().exp().max()) < 0.1  # from 0.37: σ followed the labels


def test_a_short_dagger_run_trains_the_actor(tmp_path):
    from agents.actor import HybridActor
    from tests.conftest import tiny_model

    experiment = ExperimentConfig(robots=3, poses_per_robot=12, seed=1)
    core, sampler = make_core(TRAJECTORY_MODES, experiment, 1, 0)
    core.load([sampler.draw(0)], [0])
    observation = core.observation()
    model = dataclasses.replace(tiny_model(), delta_max=tuple(float(v) for v in core.action_bound))
    actor = HybridActor(
        observation["node_features"].shape[-1], observation["edge_attr"].shape[-1], model
    )
    before = [p.detach().clone() for p in actor.parameters()]
    config = ImitationConfig(episodes=3, num_envs=2, beta_decay=0.5)
    logs = imitate(actor, TRAJECTORY_MODES, experiment, config)
    assert [log.episode for log in logs] == [0, 1, 2]
    assert [log.beta for log in logs] == [1.0, 0.5, 0.25]
    assert all(math.isfinite(log.edge_loss) and math.isfinite(log.delta_loss) for log in logs)
    # with β = 1 the expert acts: its episode removes most of the local error
    assert logs[0].local_gain > 0.5
    assert any(not torch.equal(a, b) for a, b in zip(before, actor.parameters(), strict=True))
    assert not actor.training
