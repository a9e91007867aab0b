"""The supervised training terms (agents.loss_terms): behaviour cloning during GA-SAC, the
supervised gate loss, the labels the environment stores for them, training outliers, and the
options' round trip through checkpoints."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
from conftest import tiny_model

from agents.config import (
    TRAJECTORY_MODES,
    AlgorithmConfig,
    ExperimentConfig,
    ImitationConfig,
    TrainConfig,
)
from agents.loss_terms import gate_supervision_loss

ROBOTS, POSES = 3, 10


def labelled_env(batch: int = 2, seed: int = 0, rate: float = 0.6):
    """A trajectory-task env of small 3-robot problems with training outliers and labels."""
    from envs import make_torchrl_env

    return make_torchrl_env(
        robots=ROBOTS,
        batch_size=batch,
        seed=seed,
        poses_per_robot=POSES,
        outlier_rate_max=rate,
        labels=True,
        **TRAJECTORY_MODES.core_options(),
    )


def actor_for(env):
    from agents.actor import HybridActor

    observation = env.observation_spec["agents", "observation"]
    bound = tuple(float(v) for v in env.core.action_bound)
    model = dataclasses.replace(tiny_model(), delta_max=bound)
    return HybridActor(
        observation["node_features"].shape[-1], observation["edge_attr"].shape[-1], model
    )


@pytest.fixture(scope="module")
def rollout():
    """(env, actor, rollout [B, T]) of the untrained actor in the labelled env."""
    from torchrl.envs import TransformedEnv

    from agents.actor import GASACPolicy

    torch.manual_seed(0)
    env = labelled_env()
    actor = actor_for(env)
    policy = GASACPolicy(actor)
    wrapped = TransformedEnv(env, policy.primer(ROBOTS, env.dims.edges + 1))
    return env, actor, wrapped.rollout(12, policy, break_when_any_done=False)


# ----- the environment's labels and the training outliers --------------------------------------


def test_labelled_env_passes_the_spec_check_and_carries_the_experts_labels(rollout) -> None:
    from torchrl.envs.utils import check_env_specs

    from envs.expert import Expert

    env, _, data = rollout
    check_env_specs(labelled_env(seed=3))
    labels = data["agents", "labels"]
    # the labels sit outside the observation: a policy never reads them
    assert "labels" not in data["agents", "observation"].keys()
    # the outlier labels are the problems' injected outliers, per local edge
    core = env.core
    outliers = 0
    for element, problem in enumerate(core.problems):
        edge_ids, edge_mask = core.state.edge_ids[element], core.state.edge_mask[element]
        expected = np.zeros(edge_ids.shape, bool)
        expected[edge_mask.numpy()] = problem.outlier_mask[edge_ids[edge_mask].numpy()]
        assert np.array_equal(core.state.outlier[element].numpy(), expected)
        outliers += int(problem.outlier_mask.sum())
    assert outliers > 0
    # the labels of the current state are the expert's
    expert = Expert(core)
    final = env._labels()
    assert torch.equal(final["right"], expert.right_edges())
    assert torch.equal(final["expert_edge"], expert.edge())
    torch.testing.assert_close(final["expert_delta"], expert.actor_delta(expert.edge()))
    assert labels["right"].shape[-1] == env.dims.edges + 1


def test_training_outliers_keep_the_odometry_start_and_the_odometry_placement() -> None:
    from envs import make_problem_source
    from envs.tree import place_separators
    from popbench.graph import EdgeKind
    from popbench.outliers import candidate_mask

    clean_source, _, _ = make_problem_source(7, "V2")
    noisy_source, _, _ = make_problem_source(7, "V2", outlier_rate_max=0.3)
    rates = []
    for seed in range(3):
        clean, noisy = clean_source(seed), noisy_source(seed)
        mask = noisy.outlier_mask
        assert mask is not None and not (mask & ~candidate_mask(noisy.graph)).any()
        rates.append(mask.sum() / candidate_mask(noisy.graph).sum())
        np.testing.assert_array_equal(noisy.graph.poses, clean.graph.poses)  # odometry start
        # a separator copy with a cut odometry edge to an owned pose is placed over it, so a
        # corrupted loop closure never moves it
        for local, a, b in zip(
            clean.local_graphs, place_separators(clean), place_separators(noisy), strict=True
        ):
            graph, owned = local.graph, local.owned_count
            odometry = graph.kinds == EdgeKind.INTER_RELATIVE
            ends = np.concatenate([graph.tails[odometry], graph.heads[odometry]])
            copies = np.unique(ends[ends >= owned])
            np.testing.assert_allclose(a[copies], b[copies])
    assert 0 < min(rates) and max(rates) <= 0.3 + 0.05  # U(0, 0.3) per problem (rounding)
    assert clean_source(0).outlier_mask is None


def test_the_expert_ignores_injected_outliers() -> None:
    from envs import make_problem_source
    from envs.expert import local_optima
    from popbench.solvers.local_lm import local_optima as plain_optima

    source, _, _ = make_problem_source(ROBOTS, "V2", poses_per_robot=POSES, outlier_rate_max=0.8)
    problem = source(1)
    assert problem.outlier_mask.any()
    ignored = local_optima(problem)
    excluded = plain_optima(problem, 200, problem.outlier_mask)[0]
    for a, b in zip(ignored, excluded, strict=True):
        np.testing.assert_allclose(a, b)


# ----- the supervised gate loss ----------------------------------------------------------------


def test_gate_loss_weighs_the_two_classes_equally() -> None:
    logits = torch.zeros(2, 1, 4)
    outlier = torch.tensor([[True, False, False, False]])
    mask = torch.ones(1, 4, dtype=torch.bool)
    assert float(gate_supervision_loss(logits, outlier, mask)) == pytest.approx(math.log(2))
    # a padding edge counts for nothing; an absent class contributes 0
    padded = torch.tensor([[False, True, True, True]])
    loss = gate_supervision_loss(logits, outlier, padded)
    assert float(loss) == pytest.approx(0.5 * math.log(2))


def test_gate_loss_lowers_the_keep_probability_of_labelled_outliers(rollout) -> None:
    from agents.encoder import GraphBatch

    env, _, data = rollout
    torch.manual_seed(1)
    actor = actor_for(env)
    batch = data[:, 0]
    graphs = GraphBatch.from_observation(
        batch["agents", "observation"], batch["agents", "action_mask"]
    )
    outlier = batch["agents", "labels", "outlier"].reshape(graphs.num_graphs, -1)
    outlier_edges, inlier_edges = outlier & graphs.edge_mask, ~outlier & graphs.edge_mask
    assert outlier_edges.any()

    def keep_probability() -> tuple[float, float]:
        with torch.no_grad():
            u = torch.sigmoid(actor.encoder(graphs, deterministic=True).gate_logits)
        return float(u[:, outlier_edges].mean()), float(u[:, inlier_edges].mean())

    before = keep_probability()
    optimiser = torch.optim.Adam(actor.encoder.parameters(), lr=1e-2)
    for _ in range(30):
        encoding = actor.encoder(graphs, deterministic=False)
        loss = gate_supervision_loss(encoding.gate_logits, outlier, graphs.edge_mask)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    after = keep_probability()
    assert after[0] < before[0] - 0.1  # outliers: the gates close
    assert after[0] < after[1]  # and end below the inliers'


# ----- GA-SAC with the supervised terms --------------------------------------------------------


def make_loss(actor, **overrides):
    from agents.critic import CentralCritic
    from agents.loss import GASACLoss

    critic = CentralCritic(actor.encoder.convs[0].bases.in_features, 11, ROBOTS, tiny_model())
    return GASACLoss(actor, critic, AlgorithmConfig(**overrides))


def test_supervised_terms_have_their_own_keys_only_when_weighted(rollout) -> None:
    env, actor, data = rollout
    batch = data.reshape(-1)[:8]
    torch.manual_seed(2)
    plain = make_loss(actor)(batch)
    assert "loss_bc" not in plain.keys() and "loss_gate" not in plain.keys()
    torch.manual_seed(2)
    weighted = make_loss(actor, bc_weight=1.0, gate_weight=1.0)(batch)
    for key in ("loss_bc", "loss_gate"):
        assert weighted[key].shape == () and float(weighted[key]) != 0.0  # the BC part is an NLL
    # the paper's terms and their random stream are unchanged by the supervised ones
    for key in plain.keys():
        torch.testing.assert_close(weighted[key], plain[key])


def test_bc_term_moves_the_actor_towards_the_expert(rollout) -> None:
    from agents.encoder import GraphBatch
    from agents.loss_terms import imitation_losses

    env, _, data = rollout
    torch.manual_seed(3)
    actor = actor_for(env)
    loss = make_loss(actor, bc_weight=1.0)
    batch = data.reshape(-1)[:16]
    graphs = GraphBatch.from_observation(
        batch["agents", "observation"], batch["agents", "action_mask"]
    )
    labels = batch["agents", "labels"]
    choices = graphs.action_mask.shape[-1]
    expert_edge = labels["expert_edge"].reshape(-1)

    def bc_parts() -> tuple[float, float]:
        from agents.actor import recurrent_inputs

        lead = batch["agents", "action_mask"].shape[:-1]
        memory, prev_edge, prev_delta = recurrent_inputs(batch, actor, lead, choices, False)
        with torch.no_grad():
            out = actor(graphs, memory, prev_edge, prev_delta, deterministic=True, edge=expert_edge)
            edge_loss, delta_loss = imitation_losses(
                out.edge_log_probs,
                labels["right"].reshape(-1, choices),
                out.delta_mean,
                out.delta_log_std,
                labels["expert_delta"].reshape(-1, 3),
                expert_edge < choices - 1,
                actor.delta_max,
            )
        return float(edge_loss), float(delta_loss)

    before = bc_parts()
    optimiser = torch.optim.Adam(loss.actor_parameters(), lr=3e-3)
    for _ in range(60):
        optimiser.zero_grad()
        loss.bc_loss(batch, graphs).backward()
        optimiser.step()
    after = bc_parts()
    assert after[0] < before[0] and after[1] < before[1]


def test_a_tiny_run_with_outliers_and_both_terms_logs_them(tmp_path) -> None:
    import csv

    from agents.trainer import train

    config = TrainConfig(
        model=tiny_model(),
        algorithm=AlgorithmConfig(
            warmup_frames=16, batch_size=8, buffer_size=256, bc_weight=0.5, gate_weight=0.5
        ),
        experiment=ExperimentConfig(
            robots=ROBOTS,
            poses_per_robot=POSES,
            num_envs=2,
            frames=32,
            frames_per_batch=16,
            checkpoint_interval=32,
            eval_interval=10_000,
            eval_problems=1,
            out_dir=str(tmp_path),
            progress=False,
            outlier_rate_max=0.3,
        ),
        task=TRAJECTORY_MODES,
    )
    train(config, resume=False)
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert all(math.isfinite(float(row["loss_bc"])) for row in rows)
    assert all(float(row["loss_gate"]) > 0 for row in rows)


def test_imitation_with_outliers_trains_the_gate_on_the_labels() -> None:
    from agents.imitation import imitate, make_core

    experiment = ExperimentConfig(
        robots=ROBOTS, poses_per_robot=POSES, seed=1, outlier_rate_max=0.6
    )
    core, sampler = make_core(TRAJECTORY_MODES, experiment, 1, 0)
    assert sampler.draw(0).outlier_mask is not None
    env = labelled_env()
    actor = actor_for(env)
    config = ImitationConfig(episodes=2, num_envs=2, gate_weight=1.0)
    logs = imitate(actor, TRAJECTORY_MODES, experiment, config)
    assert all(log.gate_loss > 0 for log in logs)


# ----- options through checkpoints -------------------------------------------------------------


def test_new_options_round_trip_and_old_configs_read_as_today() -> None:
    from agents.resume import resume_differences

    config = TrainConfig(
        algorithm=AlgorithmConfig(bc_weight=0.3, gate_weight=0.1),
        experiment=ExperimentConfig(outlier_rate_max=0.2),
        imitation=ImitationConfig(gate_weight=1.0),
    )
    assert TrainConfig.from_dict(config.to_dict()) == config
    old = TrainConfig().to_dict()  # a checkpoint written before the options existed
    del old["algorithm"]["bc_weight"], old["algorithm"]["gate_weight"]
    del old["experiment"]["outlier_rate_max"], old["imitation"]["gate_weight"]
    loaded = TrainConfig.from_dict(old)
    assert loaded == TrainConfig()
    assert resume_differences(loaded, TrainConfig()) == []
    assert resume_differences(loaded, config) != []


def test_the_robust_preset_is_cpu_imitation_with_outliers_and_the_gate_loss() -> None:
    from agents.config import PRESETS

    robust, plain = PRESETS["cpu-imitation-robust"], PRESETS["cpu-imitation"]
    assert robust.experiment.outlier_rate_max == 0.2 and plain.experiment.outlier_rate_max == 0
    assert robust.imitation.gate_weight == robust.algorithm.gate_weight == 1.0
    assert robust.algorithm.bc_weight == plain.algorithm.bc_weight == 0.0
    assert dataclasses.replace(robust.experiment, outlier_rate_max=0.0) == plain.experiment
