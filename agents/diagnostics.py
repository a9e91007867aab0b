"""Checks that the correction head learned something, measured on held-out states.

:func:`correction_probe` runs the deterministic actor for one episode on held-out synthetic
problems (the experiment's kind, a seed stream disjoint from training) and, on every step where
an agent corrects a spanning-tree edge, records the expert's Δ on the chosen edge, the base step
Δ_GN and the executed correction clip(δ + Δ_GN) (clip(δ) in an environment without the base
step). It reports

* ``corr_executed``: correlation of the executed correction with the expert's Δ (over states
  and the three components, whitened units);
* ``corr_linear_base``: the same for the best linear map of Δ_GN to the expert's Δ (least
  squares with intercept, fitted on the same states: an upper bound for "Δ_GN alone");
* ``delta_std``: the spread of the head's δ across states (0 for a constant head);
* ``dead_units``: share of the correction MLP's hidden units never active on these states;
* ``local_gain`` / ``local_gain_zero``: 1 − ΣF_T/ΣF_0 of the robots' local F after the episode
  with the head's δ and with δ := 0 (the learned edge order and the base step alone), each
  episode from the same problems.

:func:`critic_probe` asks whether GA-SAC's critic can tell corrections apart: on states of a
deterministic held-out episode it tries several corrections of each agent's chosen edge, steps a
copy of the environment with each to get the true one-step reward, and correlates the critic's
Q_i with it across the corrections of the same state (the trainer logs it as
``critic_probe``; near 0 means the actor follows noise).
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import torch

from agents.actor import HybridActor
from agents.config import ExperimentConfig
from agents.encoder import GraphBatch
from agents.imitation import make_core
from envs.modes import EnvModes

PROBE_SEED_OFFSET = 2_000_003  # disjoint from training and from the trainer's evaluation


@torch.no_grad()
def _episode(actor: HybridActor, core, expert, zero: bool) -> dict:  # noqa: ANN001
    """One deterministic episode on the loaded core; the per-step arrays of the docstring."""
    b, n, e = core.batch, core.num_agents, core.dims.edges
    g = b * n
    memory = actor.initial_memory(g)
    prev_edge, prev_delta = torch.zeros(g, e + 1), torch.zeros(g, 3)
    start = float(core.state.loss.sum())
    rows: dict[str, list] = {"expert": [], "base": [], "executed": [], "delta": []}
    bound = core.action_bound.to(torch.float32)
    for _ in range(core.horizon):
        graphs = GraphBatch(**core.graph_batch())
        out = actor(graphs, memory, prev_edge, prev_delta, deterministic=True)
        edge = out.edge.view(b, n)
        base = core.base_step(edge).reshape(g, 3).to(torch.float32)
        added = base if core.modes.base == "gauss-newton" else torch.zeros_like(base)
        delta = torch.zeros_like(out.delta) if zero else out.delta
        on_tree = torch.gather(core.state.tree_edge.view(g, -1), 1, out.edge[:, None])[:, 0]
        keep = on_tree & (out.edge < e)
        rows["expert"].append(expert.delta(edge).reshape(g, 3)[keep].to(torch.float32))
        rows["base"].append(base[keep])
        rows["executed"].append(torch.clamp(delta + added, -bound, bound)[keep])
        rows["delta"].append(out.delta[keep])
        core.step(edge, delta.view(b, n, 3))
        memory, prev_edge, prev_delta = out.memory, out.edge_weights, delta
    gain = 1.0 - float(core.state.loss.sum()) / max(start, 1e-12)
    return {key: torch.cat(value).numpy() for key, value in rows.items()} | {"gain": gain}


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a.ravel() - a.mean(), b.ravel() - b.mean()
    return float((a @ b) / max(np.sqrt((a @ a) * (b @ b)), 1e-12))


def correction_probe(
    actor: HybridActor,
    task: EnvModes,
    experiment: ExperimentConfig,
    problems: int = 16,
    seed: int = 0,
) -> dict[str, float]:
    """The measurements of the module docstring on ``problems`` held-out problems."""
    from envs.expert import Expert

    experiment = dataclasses.replace(experiment, seed=seed + PROBE_SEED_OFFSET)
    core, _ = make_core(task, experiment, problems, experiment.seed)
    batch = list(core.problems)
    layers = [m for m in actor.correction_head if isinstance(m, torch.nn.ReLU)]
    hidden: dict[int, list] = {id(layer): [] for layer in layers}
    handles = [
        layer.register_forward_hook(lambda m, i, o: hidden[id(m)].append(o > 0)) for layer in layers
    ]
    was_training = actor.training
    actor.eval()
    try:
        core.load(batch, range(problems))
        learned = _episode(actor, core, Expert(core), False)
    finally:
        for handle in handles:
            handle.remove()
    core.load(batch, range(problems))
    zero = _episode(actor, core, Expert(core), True)
    actor.train(was_training)
    expert, base = learned["expert"], learned["base"]
    design = np.concatenate([base, np.ones((len(base), 1))], 1)
    fit = design @ np.linalg.lstsq(design, expert, rcond=None)[0]
    ever = [torch.cat(values).any(0) for values in hidden.values() if values]
    active = torch.cat(ever) if ever else torch.zeros(0, dtype=torch.bool)
    return {
        "corr_executed": _correlation(learned["executed"], expert),
        "corr_linear_base": _correlation(fit, expert),
        "delta_std": float(learned["delta"].std(0).mean()),
        "dead_units": float((~active).float().mean()) if active.numel() else float("nan"),
        "local_gain": learned["gain"],
        "local_gain_zero": zero["gain"],
        "states": float(len(expert)),
    }


@torch.no_grad()
def critic_probe(
    session,  # noqa: ANN001 - agents.session.Session
    eval_env,  # noqa: ANN001 - envs.torchrl_env.PGOEnv
    states: int = 4,
    corrections: int = 8,
    spread: float = 0.5,
) -> float:
    """Mean over acting agents and `states` states of the correlation, across `corrections`
    corrections δ + spread · bound · N(0, 1) of the policy's own δ (the first is δ itself), of
    min_k Q_k,i with agent i's true one-step reward (module docstring)."""
    from tensordict.nn import InteractionType, set_interaction_type
    from torchrl.envs import TransformedEnv
    from torchrl.envs.utils import step_mdp

    from agents.actor import DELTA_ACTION_KEY, EDGE_ACTION_KEY
    from agents.encoder import GraphBatch

    loss = session.loss
    env = TransformedEnv(eval_env, session.policy.primer(*session.dims_pair()))
    env.set_seed(session.config.experiment.seed + PROBE_SEED_OFFSET)
    tensordict = env.reset()
    generator = torch.Generator().manual_seed(session.config.experiment.seed)
    bound = eval_env.core.action_bound.to(torch.float32)
    scores = []
    for _ in range(states):
        with set_interaction_type(InteractionType.DETERMINISTIC):
            tensordict = session.policy(tensordict)
        edge, delta = tensordict.get(EDGE_ACTION_KEY), tensordict.get(DELTA_ACTION_KEY)
        graphs = GraphBatch.from_observation(
            tensordict["agents", "observation"], tensordict["agents", "action_mask"]
        )
        weights = torch.nn.functional.one_hot(edge.reshape(-1), graphs.action_mask.shape[-1])
        rewards, values = [], []
        for k in range(corrections):
            noise = torch.randn(delta.shape, generator=generator) * spread * bound
            tried = delta + (noise if k else 0.0)
            rewards.append(copy.deepcopy(eval_env.core).step(edge, tried).reward.float())
            q, _ = loss.critic_network_apply(graphs, weights.float(), tried.reshape(-1, 3))
            values.append(q.min(-1).values)
        reward, value = torch.stack(rewards, -1), torch.stack(values, -1)  # (B, n, K)
        acting = edge < graphs.action_mask.shape[-1] - 1
        reward = reward - reward.mean(-1, keepdim=True)
        value = value - value.mean(-1, keepdim=True)
        norm = (reward.norm(dim=-1) * value.norm(dim=-1)).clamp(min=1e-12)
        scores.append(((reward * value).sum(-1) / norm)[acting])
        tensordict = step_mdp(env.step(tensordict))
    return float(torch.cat(scores).mean()) if scores else float("nan")
