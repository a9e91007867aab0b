"""prop-v1 and prop-v2 behind the method interface (paper §III-D; docs/methods.md).

prop-v1
    1. Every robot holds its local graph (owned poses + separator copies) and runs the shared
       trained actor (actor replication: the n = 7 actor serves any n) deterministically for one
       episode: T = max_i |E_i| steps, each robot correcting one of its unprocessed local edges per
       step (the environment's dynamics, envs.core.PGOCore with the measurement reward), by
       default under the line-search step rule (each executed correction scaled so that it does
       not raise the robot's local F; docs/environment.md, "The step rule").
       The robots' actors are batched into one forward per step and run incrementally
       (agents.inference.IncrementalPolicy: only the L-hop neighbourhood of the moved poses is
       recomputed). A robot keeps its episode's result only where the episode lowered its local
       objective (F of its local graph with its own copies), else its start copy
       (docs/never_worse.md).
    2. The consensus (popbench.consensus.reconcile, `consensus=`): information-weighted ADMM over
       the separators (popbench.consensus.admm; the paper's), by default after a rigid alignment of
       the robots' frames (popbench.consensus.alignment, "aligned-admm"; docs/consensus.md for the
       choice of the default); the global estimate is its output where that lowered F below its
       input's (the kept copies assembled, each pose from its owner), else that input. The registry
       (popbench.methods.never_worse) returns the start where even that is above it.
prop-v2
    prop-v1, then 75 Levenberg–Marquardt iterations (popbench.solvers.lm) from its output.

Result fields and the budget: :func:`solve_prop_v1`.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from agents.actor import HybridActor
from agents.checkpoint import load_actor, load_outlier_gate
from agents.encoder import GraphBatch
from agents.inference import IncrementalPolicy
from agents.outlier_gate import GATE_THRESHOLD, OutlierGate, holder_minimum, reconciled_gate
from envs.modes import PAPER_MODES, EnvModes
from popbench import objective
from popbench.choices import DEFAULT_STEP_RULE
from popbench.consensus.reconcile import (
    DEFAULT_CONSENSUS,
    DEFAULT_CONSENSUS_ITERATIONS,
    check_consensus,
    reconcile,
)
from popbench.methods import Budget, Result, method_record
from popbench.problems.distributed import DistributedProblem

if TYPE_CHECKING:
    from envs.core import PGOCore

DEFAULT_CHECKPOINT = method_record("prop-v1").checkpoint_path()  # the record's checkpoint
CHECKPOINT_DIR = DEFAULT_CHECKPOINT.parent
PROP_V2_LM_ITERATIONS = 75


@dataclasses.dataclass
class Episode:
    """One prop-v1 actor episode (before consensus).

    Attributes:
        local_poses: each robot's local copy, rows in `problem.local_vertices(r)` order.
        gate: (M,) the smallest layer-averaged gate of each global edge over the robots that
            hold it in the final actor pass (1 − gate is the outlier score).
        history: (T + 1,) F of the copies after each step (module docstring).
        step_s: (T,) wall time of each batched step [s].
        setup_s: packing the problem and the first full GNN pass [s].
        start_poses: each robot's local copy at the episode's start (separators placed).
        start_local_F, local_F: (n,) each robot's local objective (F of its local graph, its
            own copies) at the start and after the episode.
        core: the environment the episode ran in (the outlier gate reads the reconciled
            estimate in it, agents.outlier_gate.reconciled_state).
    """

    local_poses: list[np.ndarray]
    gate: np.ndarray
    history: np.ndarray
    step_s: np.ndarray
    setup_s: float
    start_poses: list[np.ndarray]
    start_local_F: np.ndarray
    local_F: np.ndarray
    core: PGOCore

    def kept(self) -> np.ndarray:
        """(n,) bool: the robot's episode lowered its local objective (prop-v1 keeps its
        result; else its start)."""
        return self.local_F < self.start_local_F

    def kept_poses(self) -> list[np.ndarray]:
        """Each robot's result where :meth:`kept`, else its start copy."""
        return [
            poses if keep else start
            for poses, start, keep in zip(
                self.local_poses, self.start_poses, self.kept(), strict=True
            )
        ]


@lru_cache(maxsize=4)
def cached_actor(path: str, device: str) -> tuple[HybridActor, EnvModes]:
    """The actor of a checkpoint file and the environment it was trained in, loaded once per
    process."""
    actor, config = load_actor(path, device)
    return actor, config.task


@lru_cache(maxsize=4)
def cached_outlier_gate(path: str, device: str) -> OutlierGate | None:
    """The fitted outlier gate of a checkpoint file (None without one), loaded once per
    process."""
    return load_outlier_gate(path, device)


def flag_gate(
    problem: DistributedProblem,
    episode: Episode,
    poses: np.ndarray,
    checkpoint: str | Path,
    task: EnvModes,
    device: str = "cpu",
) -> tuple[np.ndarray, float]:
    """``(gate, threshold)``: the ``(M,)`` gate prop-v1 flags outliers from (an edge is
    flagged when its gate is ≤ ``threshold``; 1 − gate is the outlier score) — the
    checkpoint's outlier gate at the reconciled ``poses`` ``(N, 3)`` with its threshold when it
    has one (agents.outlier_gate), else ``episode.gate`` and ½."""
    fitted = cached_outlier_gate(str(checkpoint), device)
    if fitted is None:
        return episode.gate, GATE_THRESHOLD
    gate = reconciled_gate(fitted.encoder, task, problem, poses, episode.core)
    return gate, fitted.threshold


def episode_core(actor: HybridActor, problem: DistributedProblem, task: EnvModes) -> PGOCore:
    """The one-problem environment (``B = 1``, reward F) of the actor's `task`, loaded with
    `problem`, in which prop-v1's episode runs (no team reward: the episode's caller runs the
    consensus itself)."""
    from envs.core import PGOCore

    options: dict[str, object] = {"team_reward": "none"}
    if task.action_scale == "metric":  # the actor's bound is Δmax itself
        options["delta_max"] = actor.delta_max.tolist()
    # else the actor's bound is the whitened one; the environment keeps its metric Δmax
    return PGOCore.for_problems([problem], task, **options)


def run_episode(
    actor: HybridActor,
    problem: DistributedProblem,
    seconds: float | None = None,
    max_steps: int | None = None,
    on_step: Callable[[int], None] | None = None,
    task: EnvModes = PAPER_MODES,
    correction: bool = True,
) -> Episode:
    """Run the actor for one episode on every robot's local graph (module docstring, step 1);
    `seconds` / `max_steps` cut it short (benchmarks); `on_step`, if given, is told the number
    of steps done after each step (progress display); `task` is the environment the actor was
    trained in (its checkpoint's); `correction=False` executes Δ := 0 on the actor's edge (in a
    `base="gauss-newton"` task: the base step alone; the actor's memory still reads its own Δ)."""
    start = time.perf_counter()
    n = problem.num_robots
    core = episode_core(actor, problem, task)
    t = core.state
    policy = IncrementalPolicy(actor, GraphBatch(**core.graph_batch(0)), t.incident[0])
    num_edges = core.dims.edges
    edge_ids, edge_mask = t.edge_ids[0], t.edge_mask[0]
    holders = np.bincount(edge_ids[edge_mask].numpy(), minlength=problem.graph.num_edges)
    share = torch.zeros(n, num_edges, dtype=t.costs.dtype)
    share[edge_mask] = torch.as_tensor(
        1.0 / holders[edge_ids[edge_mask].numpy()], dtype=share.dtype
    )

    def copies_objective() -> float:
        return float((t.costs[0][:, :num_edges] * share).sum())

    history = [copies_objective()]
    start_poses = [poses.copy() for poses in core.local_poses(0)]  # views of the live state
    start_local_F = t.loss[0].numpy().copy()
    setup_s = time.perf_counter() - start
    step_s = []
    horizon = core.horizon if max_steps is None else min(core.horizon, max_steps)
    base = None
    if actor.config.base_features:

        def base(edge: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            return core.chosen_base_observation(edge.view(1, n))

    for _ in range(horizon):
        tick = time.perf_counter()
        edge, delta = policy.act(core.action_mask()[0], base)
        delta = delta if correction else torch.zeros_like(delta)
        core.step(edge.view(1, n), delta.view(1, n, 3))
        policy.observe_update(*core.observation_update())
        step_s.append(time.perf_counter() - tick)
        history.append(copies_objective())
        if on_step is not None:
            on_step(len(step_s))
        if seconds is not None and time.perf_counter() - start > seconds:
            break

    gate = holder_minimum(policy.gate_means(), edge_ids, edge_mask, problem.graph.num_edges)
    return Episode(
        core.local_poses(0),
        gate,
        np.array(history),
        np.array(step_s),
        setup_s,
        start_poses,
        start_local_F,
        t.loss[0].numpy().copy(),
        core,
    )


def solve_prop_v1(
    problem: DistributedProblem,
    budget: Budget | None = None,
    seed: int = 0,
    checkpoint: str | Path | None = None,
    device: str = "cpu",
    consensus: str = DEFAULT_CONSENSUS,
    consensus_iterations: int = DEFAULT_CONSENSUS_ITERATIONS,
    step_rule: str | None = DEFAULT_STEP_RULE,
    **_: object,
) -> Result:
    """prop-v1: replicated trained actors on every local graph, then the consensus.

    Args:
        problem: the distributed problem (any number of robots); the episode starts from its
            start, problem.graph.poses.
        budget: see Budget below (only `seconds` is used).
        seed: seeds torch (inference is deterministic; kept for the interface).
        checkpoint: actor checkpoint (default: the prop-v1 record's); the episode
            runs in the environment the checkpoint was trained in (its `task`).
        device: torch device of the actor ("cpu").
        consensus: one of popbench.consensus.reconcile.CONSENSUS_MODES ("admm": the paper's plain
            ADMM; "aligned-admm": the robots' frames aligned first).
        consensus_iterations: ADMM iterations at most.
        step_rule: the environment's step rule (envs.core.PGOCore, popbench.choices.STEP_RULES,
            :data:`DEFAULT_STEP_RULE`: no step raises a robot's local F; None: the checkpoint's
            own, "clip" for every committed actor).

    Result fields (iterations, history, inlier_mask, messages, parallel_s, extras): their
        meaning for prop-v1 and prop-v2 is docs/methods.md, "prop-v1's result fields".
    Budget: the episode has a fixed length; `budget.iterations` does not truncate it (harness
        callers pass a Budget for every method); `budget.seconds`, if given, stops the episode
        early.
    """
    check_consensus(consensus)
    budget = budget or Budget()
    started = time.perf_counter()
    torch.manual_seed(seed)
    checkpoint = str(checkpoint or DEFAULT_CHECKPOINT)
    actor, task = cached_actor(checkpoint, device)
    if step_rule is not None:
        task = dataclasses.replace(task, step_rule=step_rule)
    with torch.no_grad():
        episode = run_episode(actor, problem, budget.seconds, on_step=budget.round_done, task=task)
    graph = problem.graph
    local_poses = episode.kept_poses()
    reconciled = reconcile(problem, local_poses, consensus, consensus_iterations)
    poses, kept = reconciled.poses, "consensus"
    costs = consensus_costs = objective.evaluate(graph, poses)
    if not consensus_costs.F < reconciled.F_before:  # the consensus did not lower F: its input
        poses, kept = problem.assemble(local_poses), "episode"
        costs = objective.evaluate(graph, poses)
    gate, threshold = flag_gate(problem, episode, poses, checkpoint, task, device)
    inlier_mask = gate > threshold
    history = episode.history.copy()
    history[-1] = costs.F
    n = problem.num_robots
    # the makespan at each step of the episode; the last entry is after the consensus
    history_s = (episode.setup_s + np.concatenate([[0.0], np.cumsum(episode.step_s)])) / n
    history_s[-1] += reconciled.parallel_s
    return Result(
        poses=poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=time.perf_counter() - started,
        parallel_s=float(history_s[-1]),
        iterations=int(episode.step_s.size),
        history=history,
        history_s=history_s,
        inlier_mask=inlier_mask,
        messages=reconciled.messages,
        extras={
            "F_init": objective.objective(graph, graph.poses),
            "F_episode": objective.objective(graph, problem.assemble(episode.local_poses)),
            "F_actor": reconciled.F_before,
            "F_aligned": reconciled.F_aligned,
            "F_consensus": consensus_costs.F,
            "kept": kept,
            "local_F_start": float(episode.start_local_F.sum()),
            "local_F_episode": float(episode.local_F.sum()),
            "robots_kept_episode": int(episode.kept().sum()),
            "robots_reverted": [int(r) for r in np.flatnonzero(~episode.kept())],
            "consensus_iterations": reconciled.iterations,
            "consensus_converged": reconciled.converged,
            "step_ms_mean": 1e3 * float(episode.step_s.mean()) if episode.step_s.size else 0.0,
            "actor_s": episode.setup_s + float(episode.step_s.sum()),
            "consensus_s": reconciled.wall_s,
            "flagged_outliers": int(np.count_nonzero(~inlier_mask)),
        },
    )


def solve_prop_v2(
    problem: DistributedProblem,
    budget: Budget | None = None,
    lm_iterations: int = PROP_V2_LM_ITERATIONS,
    refined: Result | None = None,
    objective: str = "F",
    **options: object,
) -> Result:
    """prop-v2: prop-v1 (with ``options``: seed, checkpoint, device, consensus, …), then
    `lm_iterations` (75) Levenberg–Marquardt iterations on ``objective`` ("F", eq. 1, or "chi2",
    g2o's with the full information; `status` is the LM's).

    `refined`: prop-v1's Result on this problem with these options (the harness passes its
    cached cell, popbench.harness.refining); None runs prop-v1 first. Either way wall_s and
    parallel_s are prop-v1's plus the LM's [s].
    """
    from popbench.objective import evaluate
    from popbench.solvers.lm import solve_graph
    from popbench.status import measure

    first = refined or solve_prop_v1(problem, budget, **options)
    started = time.perf_counter()
    refined = solve_graph(problem.graph, first.poses, iterations=lm_iterations, cost=objective)
    lm_s = time.perf_counter() - started
    costs = evaluate(problem.graph, refined.poses)
    history_s = None
    if first.history_s is not None:  # the last entry is the returned estimate, at parallel_s
        history_s = np.concatenate([first.history_s, first.parallel_s + refined.history_s[1:]])
        history_s[-1] = first.parallel_s + lm_s
    return Result(
        poses=refined.poses,
        **costs._asdict(),  # F, F_chordal, chi2
        wall_s=first.wall_s + lm_s,
        parallel_s=first.parallel_s + lm_s,
        iterations=first.iterations + int(refined.iterations),
        history=np.concatenate([first.history, refined.history[1:]]),
        history_s=history_s,
        inlier_mask=first.inlier_mask,
        messages=first.messages,
        extras={
            **first.extras,
            "F_prop_v1": first.F,
            "prop_v1_wall_s": first.wall_s,
            "lm_iterations": int(refined.iterations),
        },
        history_objective=objective,
        status=measure(
            problem.graph,
            refined.poses,
            objective,
            refined.converged,
            first.iterations + int(refined.iterations),
        ),
    )
