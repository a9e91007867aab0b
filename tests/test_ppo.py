"""MAPPO / IPPO (agents.ppo_trainer): the hybrid distribution, the value functions' inputs,
tiny training runs that resume, and the held-out evaluation of their actors.

Tiny problems (3 robots × 10 poses, 2 envs, 16-frame batches); each test takes seconds.
"""

from __future__ import annotations

import csv
import dataclasses
import math

import pytest
import torch
from conftest import tiny_model
from torch.distributions import Categorical, Independent, Normal, TanhTransform
from torch.distributions import TransformedDistribution as Transformed

from agents.config import PRESETS, TrainConfig
from agents.hybrid_distribution import HybridActionDistribution
from agents.metrics import PPO_METRIC_FIELDS

TINY = dataclasses.replace(tiny_model(), base_features=True)


def tiny(out_dir, algorithm: str, frames: int, imitation_episodes: int = 0) -> TrainConfig:
    """cpu-mappo / cpu-ippo on a tiny problem: 16-frame batches, 2 epochs of 8-step minibatches."""
    preset = PRESETS[f"cpu-{algorithm}"]
    experiment = dataclasses.replace(
        preset.experiment,
        robots=3,
        poses_per_robot=10,
        num_envs=2,
        frames=frames,
        frames_per_batch=16,
        checkpoint_interval=32,
        eval_interval=32,
        eval_problems=2,
        out_dir=str(out_dir),
        progress=False,
    )
    return dataclasses.replace(
        preset,
        model=TINY,
        experiment=experiment,
        imitation=dataclasses.replace(preset.imitation, episodes=imitation_episodes, num_envs=2),
        ppo=dataclasses.replace(preset.ppo, epochs=2, minibatch_size=8),
    )


# ----- the composite distribution ---------------------------------------------------------------


def random_distribution(generator: torch.Generator) -> HybridActionDistribution:
    """[5, 3] robots over 6 choices; row 0 of each batch element has only the no-op left."""
    mask = torch.rand(5, 3, 6, generator=generator) < 0.6
    mask[..., -1] = False
    mask[:, 1:, 0] = True  # every other robot has at least one real edge
    mask[:, 0, :-1] = False
    mask[:, 0, -1] = True
    logits = torch.randn(5, 3, 6, generator=generator)
    log_probs = torch.log_softmax(logits.masked_fill(~mask, -math.inf), -1)
    mean = torch.randn(5, 3, 3, generator=generator)
    log_std = torch.randn(5, 3, 3, generator=generator).clamp(-1.5, 0.5)
    return HybridActionDistribution(log_probs, mask, mean, log_std, torch.tensor([0.5, 0.5, 0.2]))


def squashed(dist: HybridActionDistribution) -> Independent:
    """torch.distributions' tanh(N(mean, std²)) on δ/Δmax (an independent reference)."""
    normal = Normal(dist.delta_mean, dist.delta_log_std.exp())
    return Independent(Transformed(normal, [TanhTransform()]), 1)


def test_log_prob_is_the_sum_of_the_parts() -> None:
    from tensordict import TensorDict

    generator = torch.Generator().manual_seed(0)
    dist = random_distribution(generator)
    edge = Categorical(logits=dist.edge_log_probs).sample()
    unit = squashed(dist).sample().clamp(-0.999, 0.999)
    action = TensorDict({"edge": edge, "delta": unit * dist.delta_max}, [5, 3])

    edge_part = Categorical(logits=dist.edge_log_probs).log_prob(edge)
    delta_part = squashed(dist).log_prob(unit)
    acting = edge < 5
    expected = edge_part + torch.where(acting, delta_part, 0.0)
    assert not acting[:, 0].any() and acting[:, 1:].all()
    assert torch.allclose(dist.log_prob(action), expected, atol=1e-4)
    # the no-op rows: log π(no-op) = 0, δ ignored
    assert torch.allclose(dist.log_prob(action)[:, 0], torch.zeros(5))


def test_entropy_is_the_sum_of_the_parts() -> None:
    generator = torch.Generator().manual_seed(1)
    dist = random_distribution(generator)
    edge_entropy = Categorical(logits=dist.edge_log_probs).entropy()
    # the squashed Gaussian's entropy has no closed form: a Monte-Carlo reference
    torch.manual_seed(1)
    samples = squashed(dist).sample((100_000,)).clamp(-1 + 1e-6, 1 - 1e-6)
    delta_entropy = -squashed(dist).log_prob(samples).mean(0)
    assert torch.allclose(dist.delta_entropy(), delta_entropy, atol=0.03)
    entropy = dist.entropy()
    assert torch.allclose(entropy[:, 0], torch.zeros(5), atol=1e-6)  # only the no-op left
    assert torch.allclose(entropy[:, 1:], (edge_entropy + delta_entropy)[:, 1:], atol=0.03)


# ----- the policy and the value functions -------------------------------------------------------


@pytest.fixture(scope="module")
def rollout(tmp_path_factory):
    """A MAPPO session and a 4-step rollout of its policy (sampling) in its 2 envs."""
    from agents.ppo_trainer import MAPPO

    session = MAPPO.build(tiny(tmp_path_factory.mktemp("ppo"), "mappo", 16))
    return session, session.env.rollout(4, session.policy, break_when_any_done=False)


def test_rollout_log_prob_is_the_loss_log_prob(rollout) -> None:
    """The log-probability written at collection is the one ClipPPOLoss recomputes: before an
    update every importance ratio is 1 (the distribution uses noise-free gates)."""
    from agents.ppo_actor import ACTION_KEY, SAMPLE_LOG_PROB_KEY

    session, data = rollout
    with torch.no_grad():
        recomputed = session.policy.get_dist(data).log_prob(data.get(ACTION_KEY))
    stored = data.get(SAMPLE_LOG_PROB_KEY)
    assert stored.shape == (2, 4, 3)  # envs, steps, robots
    assert torch.isfinite(stored).all()
    assert torch.allclose(recomputed, stored, atol=1e-5)


def perturbed_values(rollout, algorithm: str):
    """[n] values of the first step before and after robot 1's node features are moved."""
    from agents.value import TeamValue, ValueOperator

    session, data = rollout
    torch.manual_seed(0)
    network = TeamValue(session.dims["node"], session.dims["edge"], 3, TINY, algorithm == "mappo")
    value = ValueOperator(network)
    step = data[:, 0].clone()  # the first step of both envs
    with torch.no_grad():
        before = value(step.clone()).get(("agents", "state_value"))[0, :, 0]
        features = step.get(("agents", "observation", "node_features"))
        features[:, 1] += torch.randn_like(features[:, 1])
        after = value(step).get(("agents", "state_value"))[0, :, 0]
    return before, after


def test_mappo_value_sees_every_robot(rollout) -> None:
    before, after = perturbed_values(rollout, "mappo")
    assert (before - after).abs().min() > 0  # robots 0 and 2 see robot 1's change too


def test_ippo_value_sees_only_its_robot(rollout) -> None:
    before, after = perturbed_values(rollout, "ippo")
    assert before[1] != after[1]
    assert torch.equal(before[[0, 2]], after[[0, 2]])


# ----- training runs ----------------------------------------------------------------------------


def metrics(out_dir) -> list[dict[str, str]]:
    with (out_dir / "metrics.csv").open() as handle:
        reader = csv.DictReader(handle)
        assert tuple(reader.fieldnames) == PPO_METRIC_FIELDS
        return list(reader)


@pytest.mark.parametrize("algorithm", ["mappo", "ippo"])
def test_training_is_finite_and_resumes(tmp_path, algorithm: str) -> None:
    from agents.checkpoint import load_actor, read_checkpoint
    from agents.trainer import train

    first = train(tiny(tmp_path, algorithm, 32))
    rows = metrics(tmp_path)
    assert [int(row["frames"]) for row in rows] == [16, 32]
    assert [int(row["updates"]) for row in rows] == [4, 8]  # 2 epochs × 16 / 8
    for name in ("loss_objective", "loss_critic", "loss_entropy", "kl_approx"):
        assert all(math.isfinite(float(row[name])) for row in rows)
    assert (tmp_path / "learning_curve.png").is_file()
    assert rows[-1]["eval_f_reduction"] != ""

    state = read_checkpoint(tmp_path / "checkpoint.pt")
    assert state["config"]["algorithm_name"] == algorithm
    assert (state["frames"], state["updates"]) == (first.frames, first.updates) == (32, 8)
    actor, config = load_actor(tmp_path / "checkpoint.pt")
    assert config.algorithm_name == algorithm
    for name, tensor in actor.state_dict().items():
        assert torch.equal(tensor, state["actor"][name])
    snapshots = sorted(path.name for path in (tmp_path / "snapshots").iterdir())
    assert snapshots == ["actor-0000000.pt", "actor-0000032.pt"]  # the start, each checkpoint
    final, _ = load_actor(tmp_path / "snapshots" / "actor-0000032.pt")
    start, _ = load_actor(tmp_path / "snapshots" / "actor-0000000.pt")
    for name, tensor in final.state_dict().items():
        assert torch.equal(tensor, state["actor"][name])
    assert any(not torch.equal(start.state_dict()[k], t) for k, t in final.state_dict().items())

    resumed = train(tiny(tmp_path, algorithm, 64))
    assert (resumed.resumed_from, resumed.frames, resumed.updates) == (32, 64, 16)
    rows = metrics(tmp_path)
    assert [int(row["frames"]) for row in rows] == [16, 32, 48, 64]
    assert float(rows[2]["reward_scale"]) == float(rows[0]["reward_scale"])  # kept on resume
    moved = read_checkpoint(tmp_path / "checkpoint.pt")["actor"]
    assert any(not torch.equal(moved[name], state["actor"][name]) for name in moved)
    assert (tmp_path / "snapshots" / "actor-0000064.pt").is_file()


def test_another_algorithm_does_not_resume_the_run(tmp_path) -> None:
    from agents.checkpoint import ResumeConfigError
    from agents.trainer import train

    train(tiny(tmp_path, "ippo", 16))
    with pytest.raises(ResumeConfigError, match="algorithm_name ippo"):
        train(tiny(tmp_path, "mappo", 32))


def test_ppo_from_imitation_runs_the_phase_first_and_is_evaluated_held_out(tmp_path) -> None:
    from agents.checkpoint import read_checkpoint
    from agents.trainer import train
    from popbench.harness import heldout
    from popbench.harness.executors import Run

    train(tiny(tmp_path, "mappo", 16, imitation_episodes=1))
    imitation = read_checkpoint(tmp_path / "imitation-actor.pt")["actor"]
    trained = read_checkpoint(tmp_path / "checkpoint.pt")["actor"]
    assert any(not torch.equal(trained[name], imitation[name]) for name in trained)

    config = heldout.HeldoutConfig(
        robots=(3,),
        problems=2,
        poses_per_robot=10,
        rows=("ga-sac",),
        checkpoint=tmp_path / "checkpoint.pt",
        out=tmp_path / "heldout",
    )
    table = heldout.run_heldout(config, Run(progress=False))
    assert list(table["row"]) == ["mappo"]  # the checkpoint's row, under its algorithm
    assert math.isfinite(float(table["F_local_median"].iloc[0]))


def test_cli_options_select_the_algorithm_and_start() -> None:
    from popbench.cli.train import train_config
    from popbench.errors import ValueRangeError

    config = train_config("V2", 3, 0, 100, "cpu", None, "cpu-residual", algorithm="ippo")
    assert config.algorithm_name == "ippo"
    assert config.experiment.out_dir == "runs/ippo-V2-n3-s0"
    assert config.imitation.episodes == PRESETS["cpu-residual"].imitation.episodes
    scratch = train_config("V2", 3, 0, 100, "cpu", None, "cpu-mappo", imitation_episodes=0)
    assert (scratch.algorithm_name, scratch.imitation.episodes) == ("mappo", 0)
    default = train_config("V2", 3, 0, 100, "cpu", None, "cpu-residual")
    assert default.algorithm_name == "ga-sac"
    assert default.experiment.out_dir == "runs/ga-sac-V2-n3-s0"
    with pytest.raises(ValueRangeError, match="--algorithm"):
        train_config("V2", 3, 0, 100, "cpu", None, "cpu-residual", algorithm="sac")


@pytest.mark.parametrize("algorithm", ["mappo", "ippo"])
def test_popbench_train_runs_the_algorithm(tmp_path, capsys, algorithm: str) -> None:
    """The command end to end: cpu-mappo / cpu-ippo sizes, 2 robots, one 128-frame batch
    from scratch; the rerun finds the run's checkpoint."""
    from agents.checkpoint import read_checkpoint
    from popbench.cli import main

    args = ["train", "--algorithm", algorithm, "--preset", f"cpu-{algorithm}", "--robots", "2"]
    args += ["--imitation-episodes", "0", "--frames", "128", "--out", str(tmp_path)]
    assert main(args) == 0
    assert capsys.readouterr().out.startswith("trained 128 frames")
    state = read_checkpoint(tmp_path / "checkpoint.pt")
    assert (state["config"]["algorithm_name"], state["frames"], state["updates"]) == (
        algorithm,
        128,
        8,
    )
    assert main(args) == 0
    assert capsys.readouterr().out.startswith("nothing to train: the run already has 128")
    assert main(["train", "--algorithm", "sac"]) == 2
    assert "--algorithm" in capsys.readouterr().err


def test_ppo_starts_from_a_given_actor(tmp_path) -> None:
    """`--init-actor` starts a PPO run as it starts a GA-SAC one (the comparison's protocol)."""
    from agents.checkpoint import read_checkpoint, save_checkpoint
    from agents.trainer import train

    train(tiny(tmp_path / "first", "ippo", 32), resume=False)
    start = read_checkpoint(tmp_path / "first" / "checkpoint.pt")
    start["actor"] = {key: value + 0.01 for key, value in start["actor"].items()}
    given = save_checkpoint(tmp_path / "given.pt", start)
    config = tiny(tmp_path / "mappo", "mappo", 32)
    config = dataclasses.replace(
        config, experiment=dataclasses.replace(config.experiment, init_actor=str(given))
    )
    train(config, resume=False)
    copied = read_checkpoint(tmp_path / "mappo" / "imitation-actor.pt")["actor"]
    assert all(torch.equal(copied[key], start["actor"][key]) for key in start["actor"])
