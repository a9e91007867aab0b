"""The Gauss–Newton base step of every candidate edge from subtree sums (envs.basestep) against
forward differences of the whole local F, on random states, in every correction mode."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from envs.basestep import upper_to_matrix
from envs.core import PGOCore
from envs.geometry import _gather_rows, residuals
from envs.observation import Dimensions
from envs.tree import lowest_common_ancestors, spanning_tree
from popbench.problems.synthetic import make_problem

SMALL = {"robots": 3, "poses_per_robot": 16}
MODES = [  # correction modes with the base step, metric and whitened
    {"correction": "subtree"},
    {"correction": "subtree", "action_scale": "whitened"},
    {"correction": "pose", "action_scale": "whitened"},
]


def local_f(core: PGOCore, poses: torch.Tensor) -> torch.Tensor:
    """(G,) every agent's local F at ``poses (G, V+1, 3)``."""
    t = core.state
    g = poses.shape[0]
    tails, heads = t.tails.view(g, -1), t.heads.view(g, -1)
    r = residuals(
        _gather_rows(poses, tails), _gather_rows(poses, heads), t.measurements.view(g, -1, 3)
    )
    weight = torch.stack([t.tau.view(g, -1)] * 2 + [t.kappa.view(g, -1)], -1)
    return (weight * r * r).sum((-1, -2))


def finite_difference_model(core: PGOCore, edge: int, step: float = 1e-5):
    """(G, 3) the gradient of ½ F in the action Δ of slot ``edge`` by central differences of
    the moved local F (the model is F ≈ F₀ + 2gᵀΔ + ΔᵀHΔ)."""
    t = core.state
    g = core.batch * core.num_agents
    poses = t.poses.view(g, -1, 3)
    slots = torch.full((g, 1), edge)

    def f(delta: torch.Tensor) -> torch.Tensor:
        metric = core.metric_delta(slots, delta.expand(g, 1, 3).clone())
        moved, _ = core.subtree_move(poses, slots, metric)
        return local_f(core, moved)

    eye = torch.eye(3, dtype=torch.float64) * step
    gradient = torch.stack([(f(eye[k]) - f(-eye[k])) / (4 * step) for k in range(3)], -1)
    return gradient


@pytest.mark.parametrize("modes", MODES)
def test_base_gradient_matches_finite_differences(modes: dict) -> None:
    problems = [make_problem(seed=seed, **SMALL) for seed in (3, 4)]
    core = PGOCore(3, Dimensions.of(problems), 2, reward="F", **modes)
    core.load(problems, range(2))
    generator = torch.Generator().manual_seed(0)
    for _ in range(4):  # a few random moves so that residuals are not the start's
        mask = core.action_mask()
        edge = torch.where(mask, torch.rand(mask.shape, generator=generator), -1.0).argmax(-1)
        core.step(edge, 0.5 * torch.randn(2, 3, 3, generator=generator, dtype=torch.float64))
    model = core.base_model()
    on_tree = core.state.tree_edge.view(6, -1) if modes["correction"] == "subtree" else None
    checked = 0
    for edge in range(core.dims.edges):
        real = core.state.edge_mask.view(6, -1)[:, edge]
        if on_tree is not None:
            real = real & on_tree[:, edge]
        if not bool(real.any()):
            continue
        expected = finite_difference_model(core, edge)
        got = model.gradient[:, edge]
        scale = float(expected[real].abs().max()) + 1e-3
        assert torch.allclose(got[real], expected[real], atol=1e-6 * scale, rtol=1e-5)
        checked += int(real.sum())
    assert checked > 20
    # Gauss–Newton: the step is the solution of H Δ = −g, shortened along it to fit the bounds
    h, grad, step = upper_to_matrix(model.hessian), model.gradient, model.step
    moving = grad.abs().amax(-1) > 1e-9 * grad.abs().max()
    solution = -torch.linalg.solve(h[moving], grad[moving].unsqueeze(-1)).squeeze(-1)
    factor = (step[moving] * solution).sum(-1) / (solution * solution).sum(-1)
    assert bool(((factor > 0) & (factor <= 1 + 1e-9)).all())
    torch.testing.assert_close(step[moving], factor.unsqueeze(-1) * solution, rtol=1e-6, atol=1e-9)
    assert bool((step.abs() <= core.action_bound + 1e-9).all())


def test_lowest_common_ancestors_against_parent_walks() -> None:
    problem = make_problem(seed=9, **SMALL)
    graph = problem.local_graphs[1].graph
    tree = spanning_tree(graph)
    rng = np.random.default_rng(0)
    a, b = rng.integers(0, graph.num_poses, (2, 200))

    def ancestors(v: int) -> list[int]:
        path = [v]
        while tree.parent[path[-1]] >= 0:
            path.append(int(tree.parent[path[-1]]))
        return path

    pairs = zip(a, b, strict=True)
    expected = [next(x for x in ancestors(i) if x in set(ancestors(j))) for i, j in pairs]
    np.testing.assert_array_equal(lowest_common_ancestors(tree, a, b), expected)


@pytest.mark.parametrize("modes", MODES)
def test_chosen_model_equals_every_candidates_model(modes: dict) -> None:
    """The model of the chosen edge alone (sums over its crossing edges, what the environment
    executes and prop-v1 reads) equals that edge's row of the subtree-sum model of every
    candidate, to 1e-9 of the field's largest entry, on random states."""
    problems = [make_problem(seed=seed, **SMALL) for seed in (5, 6)]
    core = PGOCore(3, Dimensions.of(problems), 2, reward="F", **modes)
    core.load(problems, range(2))
    generator = torch.Generator().manual_seed(1)
    checked = 0
    for _ in range(6):
        model = core.base_model()
        for _ in range(8):  # random candidates, padding and the no-op included
            edge = torch.randint(0, core.dims.edges + 1, (2, 3), generator=generator)
            chosen = core.chosen_base_model(edge)
            rows = edge.view(6, 1)
            for field in ("gradient", "hessian", "step"):
                expected = _gather_rows(getattr(model, field), rows)
                got = getattr(chosen, field)
                scale = float(getattr(model, field).abs().max())  # prefix sums cancel
                torch.testing.assert_close(got, expected, rtol=1e-9, atol=1e-9 * scale)
            torch.testing.assert_close(chosen.local_f, model.local_f, rtol=1e-12, atol=0.0)
            assert torch.equal(core.base_step(edge).view(6, 1, 3), chosen.step)  # step alone
            checked += int((chosen.step.abs().sum((-1, -2)) > 0).sum())
        mask = core.action_mask()
        edge = torch.where(mask, torch.rand(mask.shape, generator=generator), -1.0).argmax(-1)
        core.step(edge, 0.5 * torch.randn(2, 3, 3, generator=generator, dtype=torch.float64))
    assert checked > 30
