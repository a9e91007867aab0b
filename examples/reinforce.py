"""REINFORCE on popbench's benchmark task, written only against the public API.

The env comes from ``envs.make_torchrl_env``, the hybrid action's distribution from
``agents.HybridActionDistribution``, everything else from TorchRL (``TensorDictModule``,
``ProbabilisticActor``, ``env.rollout``; a ``Collector`` works as well, docs/environment.md).
The policy scores every edge from its own features
and its endpoints' (no message passing: a deliberately small model). Train, then score it on
the held-out problems as the shipped rows are scored (docs/algorithms.md)::

    python examples/reinforce.py --updates 20 --out runs/reinforce
    popbench run heldout --policy examples/reinforce.py:load_policy \\
        --policy-arg runs/reinforce/policy.pt --policy-env "$(python examples/reinforce.py --env)"
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import ProbabilisticActor

from agents import HybridActionDistribution
from envs import make_torchrl_env

# The actors' task (docs/environment.md): subtree correction, invariant observation, whitened
# action, Gauss–Newton base step, local-F reward, no terminal bonus.
TASK = {"correction": "subtree", "observation": "invariant", "action_scale": "whitened"}
TASK |= {"base": "gauss-newton", "reward": "F", "terminal_bonus": False}
OBS = ("node_features", "edge_index", "edge_attr", "residuals")


class EdgeScorer(nn.Module):
    """Per edge: [tail node ‖ head node ‖ edge attributes ‖ asinh residual] → MLP → (logit,
    mean [3], log-std [3]); the no-op (the last choice) gets a learned logit and Δ's mean 0."""

    def __init__(self, node_dim: int, edge_dim: int, hidden: int = 64) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Linear(2 * node_dim + edge_dim + 3, hidden), nn.Tanh(), nn.Linear(hidden, 7)
        )
        nn.init.zeros_(self.net[-1].weight)  # untrained: uniform edges, Δ = 0 (base step only)
        nn.init.zeros_(self.net[-1].bias)
        nn.init.constant_(self.net[-1].bias[4:], -2.0)  # log-std: pre-tanh noise 0.14
        self.noop = nn.Parameter(torch.zeros(7))

    def forward(self, nodes, edge_index, edge_attr, residuals):  # noqa: ANN001, ANN201
        # nodes [*, V, F], edge_index [*, 2, E] (padding edges: masked by the action mask)
        index = edge_index.unsqueeze(-1).expand(*edge_index.shape, nodes.shape[-1])
        ends = nodes.unsqueeze(-3).expand(*index.shape[:-2], *nodes.shape[-2:]).gather(-2, index)
        x = torch.cat([ends[..., 0, :, :], ends[..., 1, :, :], edge_attr, residuals.asinh()], -1)
        out = self.net(x)
        out = torch.cat([out, self.noop.expand(*out.shape[:-2], 1, 7)], -2)  # [*, E + 1, 7]
        return out[..., 0], out[..., 1:4], out[..., 4:].clamp(-5.0, 1.0)


def make_actor(node_dim: int, edge_dim: int, delta_max: torch.Tensor) -> ProbabilisticActor:
    """The stochastic policy: EdgeScorer's outputs → HybridActionDistribution → the action."""
    params = [("agents", name) for name in ("edge_logits", "delta_mean", "delta_log_std")]
    scorer = TensorDictModule(
        EdgeScorer(node_dim, edge_dim), [("agents", "observation", k) for k in OBS], params
    )
    return ProbabilisticActor(
        scorer,
        in_keys={name[1]: name for name in [*params, ("agents", "action_mask")]},
        out_keys=[("agents", "action", "edge"), ("agents", "action", "delta")],
        distribution_class=HybridActionDistribution,
        distribution_kwargs={"delta_max": delta_max},
    )


def train(updates: int, out: Path, robots: int = 3, envs: int = 8, poses: int = 20) -> Path:
    """`updates` REINFORCE steps, each on one episode of `envs` problems; writes out/policy.pt."""
    torch.manual_seed(0)
    env = make_torchrl_env(robots, envs, "V2", seed=0, poses_per_robot=poses, **TASK)
    observation = env.observation_spec["agents", "observation"]
    dims = [observation[k].shape[-1] for k in ("node_features", "edge_attr")]
    delta_max = env.full_action_spec["agents", "action", "delta"].space.high.reshape(-1, 3)[0]
    actor = make_actor(*dims, delta_max)
    optimiser = torch.optim.Adam(actor.parameters(), lr=3e-4)
    horizon = observation["edge_mask"].shape[-1]  # E: no episode is longer
    for update in range(updates):
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):  # sample actions
            batch = env.rollout(horizon, actor, break_when_any_done=False)  # [B, T]
        done = batch["next", "done"].squeeze(-1).long()  # [B, T]
        first = (done.cumsum(-1) - done) == 0  # each problem's first episode (then a new one)
        reward = batch["next", "agents", "reward"].squeeze(-1) * first.unsqueeze(-1)  # [B, T, n]
        to_go = reward.flip(1).cumsum(1).flip(1)  # undiscounted return from each step
        advantage = (to_go - to_go[first].mean()) / (to_go[first].std() + 1e-8)
        log_prob = actor.get_dist(batch).log_prob(batch["agents", "action"])  # [B, T, n]
        loss = -(log_prob * advantage * first.unsqueeze(-1)).sum() / first.sum()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        episode_return = reward.sum((1, 2)).mean()
        print(f"update {update + 1}: return {episode_return:.4g}, loss {loss.item():.4g}")
    out.mkdir(parents=True, exist_ok=True)
    state = {"actor": actor.state_dict(), "dims": dims, "delta_max": delta_max}
    torch.save(state, out / "policy.pt")
    return out / "policy.pt"


def load_policy(path: str) -> ProbabilisticActor:
    """The trained actor of `path` (``popbench run heldout --policy …:load_policy
    --policy-arg PATH`` runs its deterministic action: arg-max edge, Δmax·tanh(mean))."""
    state = torch.load(path, weights_only=True)
    actor = make_actor(*state["dims"], state["delta_max"])
    actor.load_state_dict(state["actor"])
    return actor.eval()


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path("runs/reinforce"))
    parser.add_argument("--env", action="store_true", help="print TASK (JSON) for --policy-env")
    arguments = parser.parse_args()
    if arguments.env:
        print(json.dumps(TASK))
    else:
        print(f"wrote {train(arguments.updates, arguments.out)}")
