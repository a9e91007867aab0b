"""The public policy API: the hybrid action's distribution under TorchRL's ProbabilisticActor,
and ``popbench run heldout --policy`` (a plain callable, a TorchRL actor module, the examples/
REINFORCE) scored exactly as the shipped rows are."""

from __future__ import annotations

import dataclasses
import doctest
import importlib.util
import json
import math
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torch.distributions import Categorical, Normal, TanhTransform, TransformedDistribution

from popbench.cli import main
from popbench.harness import heldout
from popbench.harness.executors import Run

REINFORCE = Path(__file__).parents[1] / "examples" / "reinforce.py"
PARAMS = [("agents", name) for name in ("edge_logits", "delta_mean", "delta_log_std")]
METRICS = ["F", "ATE", "F_local", "F_robots"]


def test_the_docstring_example_runs() -> None:
    import agents.hybrid_distribution as module

    result = doctest.testmod(module)
    assert result.attempted > 0 and result.failed == 0


class EdgeParameters(nn.Module):
    """Per edge, a linear map of its attributes to (logit, mean [3], log-std [3]); the no-op
    row zeros: every edge has its own Gaussian."""

    def __init__(self, edge_dim: int) -> None:
        super().__init__()
        self.linear = nn.Linear(edge_dim, 7)

    def forward(self, edge_attr: torch.Tensor):  # noqa: ANN201
        out = self.linear(edge_attr)
        out = torch.cat([out, torch.zeros_like(out[..., :1, :])], -2)
        return out[..., 0], 2.0 * out[..., 1:4], out[..., 4:].clamp(-2.0, 0.5)


def probabilistic_actor(env, delta_max: torch.Tensor):  # noqa: ANN001, ANN201
    from torchrl.modules import ProbabilisticActor

    from agents import HybridActionDistribution

    edge_dim = env.observation_spec["agents", "observation", "edge_attr"].shape[-1]
    module = TensorDictModule(
        EdgeParameters(edge_dim), [("agents", "observation", "edge_attr")], PARAMS
    )
    return ProbabilisticActor(
        module,
        in_keys={key[1]: key for key in [*PARAMS, ("agents", "action_mask")]},
        out_keys=[("agents", "action", "edge"), ("agents", "action", "delta")],
        distribution_class=HybridActionDistribution,
        distribution_kwargs={"delta_max": delta_max},
        return_log_prob=True,
        log_prob_keys=[("agents", "sample_log_prob")],  # one joint log-probability
    )


def test_probabilistic_actor_samples_valid_actions_with_the_factorised_log_prob() -> None:
    """On the env (paper's game): every sampled edge is allowed, |δ| ≤ Δmax, and the written
    log-probability is log π(e) + log π(δ | s, e) by torch.distributions, with the Gaussian
    of the *sampled* edge (TorchRL's CompositeDistribution would take e and δ independent)."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type
    from torchrl.objectives import ClipPPOLoss

    from envs import make_torchrl_env

    torch.manual_seed(0)
    env = make_torchrl_env(3, 2, poses_per_robot=10, seed=0)
    bound = env.full_action_spec["agents", "action", "delta"].space.high.reshape(-1, 3)[0]
    actor = probabilistic_actor(env, bound)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        steps = env.rollout(6, actor)  # [B = 2, T = 6]
    edge, delta = steps["agents", "action", "edge"], steps["agents", "action", "delta"]
    mask = steps["agents", "action_mask"]
    assert mask.gather(-1, edge.unsqueeze(-1)).all()
    assert (delta.abs() <= bound).all()
    assert edge.unique().numel() > 3  # sampled, not one arg-max

    logits, mean, log_std = (steps[key] for key in PARAMS)
    by_edge = edge[..., None, None].expand(*edge.shape, 1, 3)
    mean, log_std = (value.gather(-2, by_edge).squeeze(-2) for value in (mean, log_std))
    edge_part = Categorical(logits=logits.masked_fill(~mask, -math.inf)).log_prob(edge)
    squashed = TransformedDistribution(Normal(mean, log_std.exp()), [TanhTransform()])
    delta_part = squashed.log_prob((delta / bound).clamp(-1 + 1e-6, 1 - 1e-6)).sum(-1)
    expected = edge_part + torch.where(edge < mask.shape[-1] - 1, delta_part, 0.0)
    assert torch.allclose(steps["agents", "sample_log_prob"], expected, atol=1e-4)
    with torch.no_grad():  # ClipPPOLoss's call: log_prob of the action sub-tensordict
        dist = actor.get_dist(steps)
        assert torch.allclose(dist.log_prob(steps["agents", "action"]), expected, atol=1e-4)
        # another edge's Gaussian gives another density: the correction depends on the edge
        other = torch.where(edge > 0, edge - 1, edge + 1)
        assert not torch.allclose(dist.delta_log_prob(delta, other), delta_part, atol=1e-2)
        deterministic_edge, deterministic_delta = dist.deterministic_sample
        assert torch.equal(deterministic_edge, logits.masked_fill(~mask, -math.inf).argmax(-1))

    # TorchRL's ClipPPOLoss takes the actor as it is: ratio 1 on its own samples, a gradient
    loss = ClipPPOLoss(actor, critic_network=None, critic_coeff=None, entropy_coeff=0.01)
    loss.set_keys(
        action=("agents", "action"),
        sample_log_prob=("agents", "sample_log_prob"),
        advantage=("agents", "advantage"),
    )
    steps["agents", "advantage"] = torch.randn(*edge.shape, 1)
    out = loss(steps)
    assert float(out["mean_ratio"]) == pytest.approx(1.0, abs=1e-5)
    (out["loss_objective"] + out["loss_entropy"]).backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())


def test_per_edge_entropy_is_the_expected_sum_of_the_parts() -> None:
    """H(e) + Σ_e π(e) H(δ | e) against a Monte-Carlo estimate −E[log π(e, δ)]."""
    from agents import HybridActionDistribution

    generator = torch.Generator().manual_seed(0)
    mask = torch.rand(4, 6, generator=generator) < 0.7
    mask[:, 0], mask[:, -1] = True, False
    dist = HybridActionDistribution(
        torch.randn(4, 6, generator=generator),
        mask,
        torch.randn(4, 6, 3, generator=generator),
        torch.randn(4, 6, 3, generator=generator).clamp(-1.5, 0.5),
        torch.tensor([0.5, 0.5, 0.2]),
    )
    torch.manual_seed(0)
    edge, delta = dist.sample((50_000,))
    assert mask.expand(50_000, -1, -1).gather(-1, edge.unsqueeze(-1)).all()
    estimate = -dist.log_prob(edge, delta).mean(0)
    assert torch.allclose(dist.entropy(), estimate, atol=0.05)


# ----- popbench run heldout --policy ----------------------------------------------------------


def greedy_half(agents):  # noqa: ANN001, ANN201
    """The greedy row's rule over the observation: the first unprocessed edge, Δ = −½ of its
    observed residual (in the action's units)."""
    mask, residuals = agents["action_mask"], agents["observation", "residuals"]
    edge = mask.to(torch.int8).argmax(-1)
    last = residuals.shape[-2]
    chosen = residuals[torch.arange(edge.numel()), edge.clamp(max=last - 1)]
    return edge, torch.where((edge < last).unsqueeze(-1), -0.5 * chosen, 0.0)


def shipped_actor(path: str):  # noqa: ANN201
    """A factory: the recurrent TorchRL actor module of a committed checkpoint, its memory
    primed TorchRL's way (``make_tensordict_primer``) for the test's n = 3, 12 poses."""
    from agents.actor import GASACPolicy
    from agents.checkpoint import load_actor
    from agents.user_policy import default_padding

    class Primed(GASACPolicy):
        def make_tensordict_primer(self):  # noqa: ANN202
            return self.primer(3, default_padding(3, "V2", 12)[1] + 1)

    return Primed(load_actor(path)[0])


def rows_of(config: heldout.HeldoutConfig) -> pd.DataFrame:
    heldout.run_heldout(config, Run(progress=False))
    return pd.read_csv(config.out / "heldout.csv").set_index(["row", "problem_seed"])


def test_a_plain_callable_is_scored_as_the_shipped_greedy_row(tmp_path) -> None:
    """The same rule as a user's plain callable, in the greedy row's environment (its task and
    the protocol's step rule): the same F,
    ATE and local F on every problem (the episode, the consensus and the scoring are the
    protocol's), and its row is paired against the references."""
    from agents.heldout import POLICY_TASK

    config = heldout.HeldoutConfig(
        robots=(3,),
        problems=2,
        poses_per_robot=12,
        rows=("no-op", "greedy"),
        out=tmp_path,
        policy=f"{__file__}:greedy_half",
        policy_env={
            **dataclasses.asdict(POLICY_TASK),
            "step_rule": heldout.HeldoutConfig.step_rule,
        },
    )
    frame = rows_of(config)
    mine, shipped = frame.loc["greedy_half", METRICS], frame.loc["greedy", METRICS]
    assert np.allclose(mine.to_numpy(), shipped.to_numpy(), rtol=1e-6)
    assert not np.allclose(mine["F_robots"], frame.loc["no-op", "F_robots"])
    pairs = pd.read_csv(tmp_path / "paired.csv")
    assert set(pairs.loc[pairs["A"] == "greedy_half", "B"]) == {"no-op"}


def test_a_torchrl_actor_module_is_scored_as_the_shipped_ga_sac_row(tmp_path) -> None:
    """The committed GA-SAC actor as a TensorDictModule (GASACPolicy) run on the TorchRL env of
    its task, under the protocol's step rule, gives the ga-sac row's numbers (which run it
    incrementally on the core)."""
    from agents.heldout import GA_SAC_CHECKPOINT
    from agents.methods import cached_actor

    task = cached_actor(str(GA_SAC_CHECKPOINT), "cpu")[1]
    config = heldout.HeldoutConfig(
        robots=(3,),
        problems=2,
        poses_per_robot=12,
        rows=("ga-sac",),
        out=tmp_path,
        policy=f"{__file__}:shipped_actor",
        policy_arg=str(GA_SAC_CHECKPOINT),
        policy_name="mine",
        policy_env={**dataclasses.asdict(task), "step_rule": heldout.HeldoutConfig.step_rule},
    )
    frame = rows_of(config)
    mine, shipped = frame.loc["mine", METRICS], frame.loc["ga-sac", METRICS]
    assert np.allclose(mine.to_numpy(), shipped.to_numpy(), rtol=1e-4)


def test_a_checkpoint_row_carries_its_algorithm(tmp_path) -> None:
    from agents.checkpoint import read_checkpoint, save_checkpoint
    from agents.heldout import GA_SAC_CHECKPOINT

    state = read_checkpoint(GA_SAC_CHECKPOINT)
    state["config"]["algorithm_name"] = "mappo"
    save_checkpoint(tmp_path / "mappo.pt", state)
    config = heldout.HeldoutConfig(
        robots=(3,),
        problems=1,
        poses_per_robot=12,
        rows=("imitation", "ga-sac"),
        checkpoint=tmp_path / "mappo.pt",
        out=tmp_path / "out",
    )
    table = heldout.run_heldout(config, Run(progress=False))
    assert list(table["row"]) == ["imitation", "mappo"]
    pairs = pd.read_csv(config.out / "paired.csv")
    assert set(zip(pairs["A"], pairs["B"], strict=True)) == {("mappo", "imitation")}
    default = dataclasses.replace(config, checkpoint=None)
    assert "label" not in heldout.cell_specs(default)[-1]  # the committed GA-SAC actor


def test_bad_policy_options_are_one_line(tmp_path, capsys) -> None:
    policy = ("--policy", f"{__file__}:greedy_half")
    for args, phrase in (
        (("--policy", "no_such_module:act"), "invalid --policy 'no_such_module:act'"),
        (("--policy", f"{__file__}:missing"), "no 'missing'"),
        (("--policy", "act"), "MODULE:ATTR"),
        ((*policy, "--policy-env", "colour=red"), "invalid --policy-env 'colour'"),
        ((*policy, "--policy-env", "{oops"), "a JSON object"),
        ((*policy, "--policy-name", "no-op"), "invalid --policy-name 'no-op'"),
        (("--policy-env", "base=none"), "need --policy"),
    ):
        code = main(["run", "heldout", *args, "--rows", "no-op", "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 2, (args, err)
        assert len(err.strip().splitlines()) == 1 and phrase in err, err
    assert not (tmp_path / "o").exists()


def test_the_reinforce_example_trains_and_is_scored_by_the_cli(tmp_path, capsys) -> None:
    """examples/reinforce.py (public API only) trains for two updates; ``popbench run heldout
    --policy`` scores it on 10 held-out problems beside gn-sweep and local-lm."""
    started = time.process_time()
    spec = importlib.util.spec_from_file_location("reinforce_example", REINFORCE)
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    weights = example.train(2, tmp_path / "run", robots=3, envs=4, poses=10)
    args = ["run", "heldout", "--robots", "3", "--poses-per-robot", "10", "--problems", "10"]
    args += ["--rows", "gn-sweep,local-lm", "--policy", f"{REINFORCE}:load_policy"]
    args += ["--policy-arg", str(weights), "--policy-env", json.dumps(example.TASK)]
    args += ["--policy-name", "reinforce", "--jobs", "1", "--out", str(tmp_path / "heldout")]
    code = main(args)
    assert code == 0, capsys.readouterr().err
    frame = pd.read_csv(tmp_path / "heldout" / "heldout.csv")
    assert frame.groupby("row").size().to_dict() == {
        "gn-sweep": 10,
        "local-lm": 10,
        "reinforce": 10,
    }
    assert np.isfinite(frame[METRICS].to_numpy()).all()
    pairs = pd.read_csv(tmp_path / "heldout" / "paired.csv")
    assert set(pairs.loc[pairs["A"] == "reinforce", "B"]) == {"gn-sweep", "local-lm"}
    print(f"reinforce example: {time.process_time() - started:.1f} s CPU")
