"""The outlier gate (agents.outlier_gate, agents.gate_training): the reconciled state shows the
outliers a robot's own episode start hides, the fit, the checkpoint round trip, prop-v1's flags
and ``popbench train-gate``."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import torch

from agents.actor import HybridActor
from agents.checkpoint import (
    add_outlier_gate,
    load_outlier_gate,
    read_checkpoint,
    save_checkpoint,
)
from agents.config import (
    TRAJECTORY_MODES,
    ExperimentConfig,
    OutlierGateConfig,
    TrainConfig,
)
from agents.gate_training import fit_outlier_gate
from agents.methods import cached_actor, run_episode, solve_prop_v1
from agents.outlier_gate import GATE_THRESHOLD, f1_threshold, reconciled_gate, reconciled_state
from popbench.cli import main
from popbench.consensus.reconcile import reconcile
from popbench.graph import EdgeKind
from popbench.outliers import with_outliers
from popbench.problems.synthetic import make_problem
from tests.conftest import tiny_model

TINY = tiny_model()
TINY_FIT = OutlierGateConfig(problems=2, validation=2, epochs=2)


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A random actor of the trajectory environment, trained (nominally) on n = 3, V2."""
    torch.manual_seed(0)
    actor = HybridActor(6, 11, TINY)
    path = tmp_path_factory.mktemp("gate") / "actor.pt"
    experiment = dataclasses.replace(ExperimentConfig(), robots=3, poses_per_robot=12)
    config = TrainConfig(model=TINY, task=TRAJECTORY_MODES, experiment=experiment)
    save_checkpoint(
        path,
        {"config": config.to_dict(), "dims": {"node": 6, "edge": 11}, "actor": actor.state_dict()},
    )
    return path


@pytest.fixture(scope="module")
def fit(checkpoint: Path):
    actor, task = cached_actor(str(checkpoint), "cpu")
    experiment = TrainConfig.from_dict(read_checkpoint(checkpoint)["config"]).experiment
    return fit_outlier_gate(actor, task, TINY_FIT, experiment)


@pytest.fixture(scope="module")
def corrupted():
    problem = make_problem(robots=3, noise="V2", poses_per_robot=20, seed=3)
    return with_outliers(problem, 0.3, seed=3)


def test_the_reconciled_state_shows_outliers_the_episode_start_hides(corrupted) -> None:
    """At the ground truth every injected outlier has a large residual in the reconciled state,
    also an inter-robot loop closure whose separator copy the episode's start places from it."""
    from envs.core import PGOCore

    truth = corrupted.graph.ground_truth
    state = reconciled_state(corrupted, truth, TRAJECTORY_MODES)
    mask = state.edge_mask
    size = state.graphs.residuals.norm(dim=-1)
    outlier = state.outlier & mask
    assert outlier.any()
    assert float(size[outlier].min()) > 2 * float(size[mask & ~state.outlier].max())

    placed = dataclasses.replace(corrupted, graph=corrupted.graph.replace(poses=truth))
    core = PGOCore.for_problems([placed], TRAJECTORY_MODES)
    start = core.observation()["residuals"][0].norm(dim=-1)
    kinds = torch.as_tensor(corrupted.graph.kinds)[state.edge_ids.clamp(min=0)]
    hidden = outlier & (kinds == EdgeKind.INTER_LOOP) & (start < 1e-9)
    assert hidden.any()  # the case the reconciled state exists for


def test_fit_copies_the_encoder_and_keeps_the_best_validation_epoch(
    checkpoint, fit, corrupted
) -> None:
    actor, task = cached_actor(str(checkpoint), "cpu")
    fresh = HybridActor(6, 11, TINY)
    fresh.load_state_dict(read_checkpoint(checkpoint)["actor"])
    assert [epoch["epoch"] for epoch in fit.epochs] == [0, 1, 2]
    aucs = [epoch["validation_auc"] for epoch in fit.epochs]
    assert fit.epochs[fit.best_epoch]["validation_auc"] == max(aucs)
    for key, value in actor.encoder.state_dict().items():  # the actor is not changed
        assert torch.equal(value, fresh.encoder.state_dict()[key])
    assert not any(p.requires_grad for p in fit.gate.encoder.parameters())
    poses = corrupted.graph.ground_truth
    gate = reconciled_gate(fit.gate.encoder, task, corrupted, poses)
    assert gate.shape == (corrupted.graph.num_edges,)
    assert ((gate >= 0) & (gate <= 1)).all()


def test_prop_v1_flags_from_the_outlier_gate_when_the_checkpoint_has_one(
    checkpoint, fit, corrupted, tmp_path: Path
) -> None:
    assert load_outlier_gate(checkpoint) is None
    actor, task = cached_actor(str(checkpoint), "cpu")
    gated = tmp_path / "gated.pt"
    add_outlier_gate(checkpoint, gated, TINY_FIT, fit.gate, fit.epochs, fit.best_epoch, 1.0)
    loaded = load_outlier_gate(gated)
    assert loaded.threshold == fit.gate.threshold
    for key, value in fit.gate.encoder.state_dict().items():
        assert torch.equal(loaded.encoder.state_dict()[key], value)

    plain = solve_prop_v1(corrupted, checkpoint=checkpoint)
    flagged = solve_prop_v1(corrupted, checkpoint=gated)
    np.testing.assert_array_equal(flagged.poses, plain.poses)  # the flags change nothing else
    with torch.no_grad():
        episode = run_episode(actor, corrupted, task=task)
    reconciled = reconcile(corrupted, episode.local_poses, "aligned-admm")
    gate = reconciled_gate(fit.gate.encoder, task, corrupted, reconciled.poses)
    expected = gate > fit.gate.threshold
    np.testing.assert_array_equal(flagged.inlier_mask, expected)
    np.testing.assert_array_equal(plain.inlier_mask, episode.gate > GATE_THRESHOLD)


def test_cli_train_gate_writes_the_checkpoint(checkpoint, tmp_path: Path, capsys) -> None:
    out = tmp_path / "cli.pt"
    args = ["train-gate", str(checkpoint), "--out", str(out), "--problems", "2"]
    assert main([*args, "--validation", "1", "--epochs", "1"]) == 0
    assert "kept epoch" in capsys.readouterr().out
    assert load_outlier_gate(out) is not None


def test_f1_threshold_on_a_hand_made_case() -> None:
    # gates of 6 edges, 2 outliers: flagging gate ≤ 0.25 hits both with one false alarm (F1
    # 0.8); ≤ 0.15 one hit, no false alarm (F1 0.67); ≤ 0.5 two hits, 3 false (F1 0.57)
    gates = [np.array([0.1, 0.2, 0.3, 0.6, 0.7]), np.array([0.4])]
    outliers = [np.array([True, False, True, False, False]), np.array([False])]
    assert f1_threshold(gates, outliers) == pytest.approx(0.35)
    assert f1_threshold([np.array([0.2, 0.9])], [np.array([False, False])]) == 0.5


def test_the_gate_in_the_episode_core_equals_the_gate_in_a_fresh_core(
    checkpoint, fit, corrupted
) -> None:
    """prop-v1 reads the gate in its episode's core, restarted at the reconciled estimate: the
    same gate, bit for bit, as a core built for it, and the episode's poses are kept."""
    actor, task = cached_actor(str(checkpoint), "cpu")
    with torch.no_grad():
        episode = run_episode(actor, corrupted, task=task)
    kept = [poses.copy() for poses in episode.local_poses]
    poses = reconcile(corrupted, episode.local_poses, "aligned-admm").poses
    fresh = reconciled_gate(fit.gate.encoder, task, corrupted, poses)
    reused = reconciled_gate(fit.gate.encoder, task, corrupted, poses, episode.core)
    np.testing.assert_array_equal(reused, fresh)
    for before, after in zip(kept, episode.local_poses, strict=True):
        np.testing.assert_array_equal(before, after)
    state = reconciled_state(corrupted, poses, task, episode.core)
    assert not state.graphs.processed.any()  # restarted: every edge open again
