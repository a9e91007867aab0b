"""PGOCore.observation_update names every observation entry a step changed (with its new value),
in every environment mode, so the incremental policy reads the same changes as a full diff."""

from __future__ import annotations

import itertools

import pytest
import torch

from envs.core import PGOCore
from envs.observation import Dimensions
from popbench.problems.synthetic import make_problem

MODES = list(itertools.product(("pose", "subtree"), ("paper", "invariant"), ("metric", "whitened")))


@pytest.mark.parametrize(("correction", "observation", "action_scale"), MODES)
def test_observation_update_covers_the_full_diff(correction, observation, action_scale):
    problems = [make_problem(robots=3, poses_per_robot=16, seed=seed) for seed in range(2)]
    core = PGOCore(
        3,
        Dimensions.of(problems),
        2,
        reward="F",
        correction=correction,
        observation=observation,
        action_scale=action_scale,
        base="gauss-newton" if correction == "subtree" else "none",
    )
    core.load(problems, [0, 1])
    generator = torch.Generator().manual_seed(0)
    for _ in range(25):
        before = core.observation()
        mask = core.action_mask()
        edge = torch.multinomial(mask.flatten(0, 1).float(), 1, generator=generator).view(2, 3)
        delta = 0.2 * torch.randn(2, 3, 3, generator=generator, dtype=torch.float64)
        core.step(edge, delta)
        after = core.observation()
        vertices, features, edges, residuals = core.observation_update()
        assert torch.all(vertices[1:] > vertices[:-1]) and torch.all(edges[1:] > edges[:-1])
        all_features = after["node_features"].flatten(0, 2)
        all_residuals = after["residuals"].flatten(0, 2)
        assert torch.equal(features, all_features[vertices])
        assert torch.equal(residuals, all_residuals[edges])
        feature_changed = (all_features != before["node_features"].flatten(0, 2)).any(-1)
        residual_changed = (all_residuals != before["residuals"].flatten(0, 2)).any(-1)
        assert set(torch.nonzero(feature_changed).flatten().tolist()) <= set(vertices.tolist())
        assert set(torch.nonzero(residual_changed).flatten().tolist()) <= set(edges.tolist())
