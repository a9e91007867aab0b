"""The imitation phase of `popbench train`: DAgger-style behaviour cloning of the expert.

The expert (envs.expert.Expert) knows each agent's local-graph optimum and labels any state: in
the subtree mode every unprocessed spanning-tree edge is a right choice (a correction there
changes only that edge's relative pose, so the order does not matter) and the right Δ on an
edge is the one that gives it the optimum's relative pose (0 on a non-tree edge). On every step
of a batched episode the learner acts deterministically on the state it is in and is trained on
the expert's labels of that state (Ross et al. 2011, DAgger, with one gradient step per visited
state instead of an aggregated dataset):

    L_edge  = −log Σ_{e ∈ right(s)} π(e | s)                      (both heads share the GNN)
    L_delta = −log N(atanh(δ*(s, e_learner) / bound) | μ_θ, σ_θ²)  (the correction's likelihood)

where ``bound`` is the action bound (Δmax, or the whitened bound) (agents.loss_terms). With
``gate_weight`` > 0 and training problems with injected outliers (``outlier_rate_max``) the
supervised gate loss of agents.loss_terms is added, times ``gate_weight``. The executed action
is the expert's with probability β_k = β₀ · decay^k in episode k (per agent), the learner's
otherwise, so the states drift from the expert's towards the learner's own. The recurrent memory
is carried along the episode and detached at every step (truncated back-propagation of length one).

The learner never sees the optimum: it enters only the labels.
"""

from __future__ import annotations

import csv
import dataclasses
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812

from agents.actor import HybridActor
from agents.config import ExperimentConfig, ImitationConfig, TrainConfig
from agents.encoder import GraphBatch
from agents.loss_terms import actor_imitation_losses, gate_supervision_loss
from envs.modes import EnvModes


@dataclasses.dataclass
class EpisodeLog:
    """What one imitation episode measured (means over its steps and acting agents).

    Attributes:
        episode: index k; beta: β_k.
        edge_loss, delta_loss: the two losses.
        right_edge: share of the learner's edge choices that were right.
        local_gain: share of the local error the executed episode removed, 1 − ΣF_T / ΣF_0.
        seconds: wall time of the episode [s].
        gate_loss: the supervised gate loss (0 when its weight is 0).
    """

    episode: int
    beta: float
    edge_loss: float
    delta_loss: float
    right_edge: float
    local_gain: float
    seconds: float
    gate_loss: float = 0.0


def make_core(  # noqa: ANN201
    task: EnvModes, experiment: ExperimentConfig, batch: int, seed: int, first_episode: int = 0
):
    """(core, sampler): a PGOCore with measurement reward over `batch` synthetic problems of the
    experiment's kind (with its training outliers), loaded with episode `first_episode` of its
    seeded problem stream, and the stream, positioned after them."""
    from envs import make_problem_source
    from envs.core import PGOCore
    from envs.sampler import ProblemSampler

    source, dims, _ = make_problem_source(
        experiment.robots,
        experiment.noise,
        poses_per_robot=experiment.poses_per_robot,
        start_noise=experiment.start_noise,
        outlier_rate_max=experiment.outlier_rate_max,
    )
    sampler = ProblemSampler(source, batch, seed, dims)
    sampler.episodes[:] = first_episode
    problems = [sampler.draw(element) for element in range(batch)]
    return PGOCore.for_problems(problems, task, dims=dims), sampler


def imitate(
    actor: HybridActor,
    task: EnvModes,
    experiment: ExperimentConfig,
    config: ImitationConfig,
    on_episode: Callable[[EpisodeLog], None] | None = None,
    start_episode: int = 0,
    optimiser: torch.optim.Optimizer | None = None,
) -> list[EpisodeLog]:
    """Train `actor` in place by the imitation phase (module docstring).

    Args:
        actor: the actor (its `delta_max` must equal the core's action bound).
        task: the environment options; experiment: robots, noise, poses per robot, seed.
        config: the phase's options.
        on_episode: told each episode's log (progress, metrics files, checkpoints).
        start_episode: the first episode index (a resumed phase continues the β schedule and
            the problem stream where it stopped).
        optimiser: an Adam over the actor's parameters to continue (resume); a new one if None.

    Returns:
        The logs of the episodes run.
    """
    from envs.expert import Expert

    core, sampler = make_core(task, experiment, config.num_envs, experiment.seed, start_episode)
    expert = Expert(core)
    bound = core.action_bound.to(torch.float32)
    if not torch.allclose(actor.delta_max, bound):
        raise ValueError(f"actor delta_max {actor.delta_max.tolist()} ≠ action bound {bound}")
    optimiser = optimiser or torch.optim.Adam(actor.parameters(), lr=config.lr)
    generator = torch.Generator().manual_seed(experiment.seed)
    b, n, e = core.batch, core.num_agents, core.dims.edges
    g = b * n
    started = time.perf_counter()
    logs = []
    actor.train()
    for k in range(start_episode, config.episodes):
        if config.seconds is not None and time.perf_counter() - started > config.seconds:
            break
        tick = time.perf_counter()
        if k > start_episode:  # make_core loaded the first episode's problems
            core.load([sampler.draw(element) for element in range(b)], range(b))
        beta = config.beta_start * config.beta_decay**k
        memory = actor.initial_memory(g)
        prev_edge, prev_delta = torch.zeros(g, e + 1), torch.zeros(g, 3)
        initial_loss = float(core.state.loss.sum())
        sums = np.zeros(4)
        steps = core.horizon
        for _ in range(steps):
            graphs = GraphBatch(**core.graph_batch())
            out = actor(graphs, memory, prev_edge, prev_delta, deterministic=True)
            right = expert.right_edges().reshape(g, -1)
            with torch.no_grad():
                label = expert.actor_delta(out.edge.view(b, n)).reshape(g, 3)
                expert_edge = expert.edge()
                expert_delta = expert.actor_delta(expert_edge)
            acting = out.edge < e
            edge_loss, delta_loss = actor_imitation_losses(out, right, label, acting, bound)
            loss = edge_loss + config.delta_weight * delta_loss
            gate_loss = torch.zeros(())
            if config.gate_weight > 0:
                outlier = core.state.outlier.reshape(g, -1)
                gate_loss = gate_supervision_loss(
                    out.encoding.gate_logits, outlier, graphs.edge_mask
                )
                loss = loss + config.gate_weight * gate_loss
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            use_expert = torch.rand(b, n, generator=generator) < beta
            edge = torch.where(use_expert, expert_edge, out.edge.view(b, n))
            delta = torch.where(use_expert.unsqueeze(-1), expert_delta, out.delta.view(b, n, 3))
            delta = delta.detach()
            core.step(edge, delta)
            memory = out.memory.detach()
            prev_edge = F.one_hot(edge.reshape(g), e + 1).to(torch.float32)
            prev_delta = torch.maximum(torch.minimum(delta.reshape(g, 3), bound), -bound)
            chosen_right = torch.gather(right, 1, out.edge.unsqueeze(-1)).float().mean()
            sums += [edge_loss.item(), delta_loss.item(), chosen_right.item(), gate_loss.item()]
        log = EpisodeLog(
            episode=k,
            beta=beta,
            edge_loss=sums[0] / steps,
            delta_loss=sums[1] / steps,
            right_edge=sums[2] / steps,
            local_gain=1.0 - float(core.state.loss.sum()) / max(initial_loss, 1e-12),
            seconds=time.perf_counter() - tick,
            gate_loss=sums[3] / steps,
        )
        logs.append(log)
        if on_episode is not None:
            on_episode(log)
    actor.eval()
    return logs


IMITATION_CHECKPOINT = "imitation.pt"  # the phase's state, in the run directory
IMITATION_ACTOR = "imitation-actor.pt"  # the imitation-only actor (load_actor format)
IMITATION_METRICS = "imitation.csv"


def run_phase(session, out_dir: Path) -> None:  # noqa: ANN001 - agents.session.Session
    """The imitation phase of `popbench train` on `session.actor`, resumable: its state after
    every episode in ``out_dir/imitation.pt``, one line per episode in ``imitation.csv``, and,
    once finished, the imitation-only actor in ``imitation-actor.pt`` (what the held-out
    evaluation's "imitation" row loads). A finished phase only reloads its actor."""
    from agents.checkpoint import read_checkpoint, save_actor, save_checkpoint

    config = session.config
    path, metrics = out_dir / IMITATION_CHECKPOINT, out_dir / IMITATION_METRICS
    optimiser = torch.optim.Adam(session.actor.parameters(), lr=config.imitation.lr)
    start = 0
    if path.is_file():
        state = read_checkpoint(path, config.experiment.device)
        session.actor.load_state_dict(state["actor"])
        optimiser.load_state_dict(state["optimiser"])
        start = int(state["episodes"])
        if state["done"]:
            return
    elif metrics.exists():
        metrics.unlink()
    fields = [field.name for field in dataclasses.fields(EpisodeLog)]
    if metrics.is_file():  # a resumed phase keeps the columns its file was started with
        with metrics.open(newline="") as handle:
            fields = next(csv.reader(handle), fields)

    def save(episodes: int, done: bool) -> None:
        state = {
            "config": config.to_dict(),
            "dims": session.dims,
            "actor": session.actor.state_dict(),
            "optimiser": optimiser.state_dict(),
            "episodes": episodes,
            "done": done,
        }
        save_checkpoint(path, state)

    def record(log: EpisodeLog) -> None:
        new = not metrics.exists()
        with metrics.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=fields, extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerow(dataclasses.asdict(log))
        save(log.episode + 1, False)

    imitate(
        session.actor,
        config.task,
        config.experiment,
        config.imitation,
        on_episode=record,
        start_episode=start,
        optimiser=optimiser,
    )
    save(config.imitation.episodes, True)
    save_actor(out_dir / IMITATION_ACTOR, config, session.dims, session.actor)


def start_from_actor(session, path: Path, out_dir: Path) -> None:  # noqa: ANN001 - Session
    """Load a trained actor (e.g. a committed imitation actor) into `session.actor` in place of
    the imitation phase, and write it as the run's ``imitation-actor.pt`` (the held-out
    "imitation" row's actor). The checkpoint's model (but its action bound, which the
    environment sets) and task must be the run's: a one-line `CheckpointError` otherwise."""
    from agents.checkpoint import CheckpointError, read_checkpoint, save_actor

    state = read_checkpoint(path, session.config.experiment.device)
    stored = TrainConfig.from_dict(state["config"])
    model = dataclasses.replace(stored.model, delta_max=session.config.model.delta_max)
    differing = [
        f"{part}.{field.name}"
        for part, ours, theirs in (
            ("model", session.config.model, model),
            ("task", session.config.task, stored.task),
        )
        for field in dataclasses.fields(ours)
        if getattr(ours, field.name) != getattr(theirs, field.name)
    ]
    if differing or state["dims"] != session.dims:
        what = ", ".join(differing) or "the environment's dimensions"
        raise CheckpointError(f"{path}: the actor was trained with another {what} than this run")
    session.actor.load_state_dict(state["actor"])
    save_actor(out_dir / IMITATION_ACTOR, session.config, session.dims, session.actor)
