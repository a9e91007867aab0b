"""prop-v1 inference speed (docs/prop_speed.md) and prop-v1 vs mm-pgo on city10k.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/bench_prop.py
    (options: --sizes 60,250,1000,2500,10000 (--sizes '' skips part 1) --steps 100
     --full-steps 5 --table-robots 1 --skip-city --checkpoint PATH --threads 1)

Part 1 — per-step time against the local graph size. `--table-robots` robots (default one),
synthetic V2 graphs of P poses per robot (P from 60 to 10,000; ≈ 1.15·P edges). For each P: the
median wall time of one prop-v1 step (incremental actor pass + environment step + cache refresh,
agents.methods.run_episode in the checkpoint's task, first `--steps` steps: the slowest of an
episode, since the edge head scores every unprocessed edge) and, measured in the same run, the
median time of one *full* actor pass over the same graph (what a non-incremental implementation
pays per step). Printed with the ratio full / incremental.

Part 2 — city10k at n = 7 from the odometry start: prop-v1 (whole episode + ADMM consensus) and
mm-pgo's 1000 iterations (baselines.mm_pgo.solve, from the same odometry start), with
F, wall and simulated parallel time, the wall-time ratio mm-pgo / prop-v1 and prop-v1's split of
its wall time: the actor episode (the actor's decisions, IncrementalPolicy.act; the environment
step, PGOCore.step, of which the Gauss–Newton base step of the chosen edges,
envs.basestep.chosen_step; the incremental observation, PGOCore.observation_update +
IncrementalPolicy.observe_update) and the consensus (of which SuperLU's factorisations, splu in
popbench.consensus.system), measured by
wrapping those functions with timers for the run.

The actor is prop-v1's default checkpoint (its record in popbench/methods.py); without it, a
randomly initialised actor of the cpu-small preset's size (timings do not depend on training).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agents.actor import HybridActor
from agents.checkpoint import load_actor, save_checkpoint
from agents.config import CPU_SMALL
from agents.encoder import GraphBatch
from agents.methods import DEFAULT_CHECKPOINT, episode_core, run_episode, solve_prop_v1
from envs.modes import EnvModes
from popbench.methods import Budget
from popbench.problems.synthetic import make_problem


def actor_for(path: Path) -> tuple[HybridActor, EnvModes, Path]:
    """The checkpoint's actor and task, or a random cpu-small one (its preset's task) saved to a
    temporary checkpoint."""
    if path.is_file():
        actor, config = load_actor(path)
        return actor, config.task, path
    torch.manual_seed(0)
    actor = HybridActor(6, 11, CPU_SMALL.model).eval()
    path = Path(tempfile.mkdtemp()) / "random-cpu-small.pt"
    state = {"config": CPU_SMALL.to_dict(), "dims": {"node": 6, "edge": 11}}
    save_checkpoint(path, {**state, "actor": actor.state_dict()})
    return actor, CPU_SMALL.task, path


@torch.no_grad()
def full_pass_seconds(actor: HybridActor, task: EnvModes, problem, repeats: int) -> float:
    """Median time of one full (non-incremental) deterministic actor pass on `problem`, in the
    environment of the actor's `task` (agents.methods.episode_core, as prop-v1's episode)."""
    n = problem.num_robots
    graphs = GraphBatch(**episode_core(actor, problem, task).graph_batch(0))
    memory = actor.initial_memory(n)
    prev_edge = torch.zeros(n, graphs.action_mask.shape[-1])
    prev_delta = torch.zeros(n, 3)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        actor(graphs, memory, prev_edge, prev_delta, deterministic=True)
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def per_step_table(
    actor: HybridActor, task: EnvModes, sizes: list[int], steps: int, full_steps: int, robots: int
) -> None:
    print(f"\nper-step time, {robots} robot(s), synthetic V2 graph of P poses per robot")
    print(f"{'P':>7} {'edges':>7} {'incremental ms':>15} {'full pass ms':>13} {'full/incr':>10}")
    for poses in sizes:
        problem = make_problem(robots=robots, noise="V2", poses_per_robot=poses, seed=0)
        episode = run_episode(actor, problem, max_steps=steps, task=task)
        incremental = float(np.median(episode.step_s))
        full = full_pass_seconds(actor, task, problem, full_steps)
        print(
            f"{poses:>7} {problem.graph.num_edges:>7} {1e3 * incremental:>15.2f} "
            f"{1e3 * full:>13.2f} {full / incremental:>10.1f}"
        )


PHASES = (
    ("actor: decisions (act)", "agents.inference", "IncrementalPolicy.act"),
    ("actor: observation update", "agents.inference", "IncrementalPolicy.observe_update"),
    ("actor: observation update", "envs.core", "PGOCore.observation_update"),
    ("env step (PGOCore.step)", "envs.core", "PGOCore.step"),
    ("  of which Gauss–Newton base", "envs.core", "chosen_step"),
    ("consensus: SuperLU splu", "popbench.consensus.system", "splu"),
)


@contextlib.contextmanager
def phase_timers() -> Iterator[dict[str, float]]:
    """Wrap the functions of :data:`PHASES` with timers while the block runs; yields the
    seconds spent per phase label (summed over calls)."""
    spent: dict[str, float] = dict.fromkeys((label for label, _, _ in PHASES), 0.0)
    restore = []
    for label, module_name, name in PHASES:
        owner: Any = importlib.import_module(module_name)
        *path, attribute = name.split(".")
        for part in path:
            owner = getattr(owner, part)
        original = getattr(owner, attribute)

        def timed(*args, _original=original, _label=label, **kwargs):
            tic = time.perf_counter()
            try:
                return _original(*args, **kwargs)
            finally:
                spent[_label] += time.perf_counter() - tic

        setattr(owner, attribute, timed)
        restore.append((owner, attribute, original))
    try:
        yield spent
    finally:
        for owner, attribute, original in restore:
            setattr(owner, attribute, original)


def city_comparison(robots: int, checkpoint: Path) -> None:
    from baselines import mm_pgo
    from envs import dataset_problem

    problem = dataset_problem("city10k", robots)
    print(f"\ncity10k, n = {robots}, odometry start (F = {problem_f(problem):.4g})")
    print(f"{'method':>22} {'F':>12} {'wall s':>9} {'parallel s':>11} {'iterations':>11}")
    with phase_timers() as spent:
        prop = solve_prop_v1(problem, Budget(), checkpoint=checkpoint)
    mm = mm_pgo.solve(problem, Budget(1000))
    for name, result in (("prop-v1", prop), ("mm-pgo (1000 it.)", mm)):
        print(
            f"{name:>22} {result.F:>12.10g} {result.wall_s:>9.2f} {result.parallel_s:>11.2f} "
            f"{result.iterations:>11}"
        )
    print(
        f"wall-time ratio prop-v1 / mm-pgo = {prop.wall_s / mm.wall_s:.2f}; "
        f"parallel-time ratio = {prop.parallel_s / mm.parallel_s:.2f}; "
        f"consensus iterations {prop.extras['consensus_iterations']}, "
        f"F after the actor (before consensus) {prop.extras['F_actor']:.6g}"
    )
    print(f"\nprop-v1 profile split (wall {prop.wall_s:.2f} s)")
    print(f"{'actor episode (setup + steps)':>32} {prop.extras['actor_s']:>8.2f} s")
    print(f"{'  steps, mean':>32} {prop.extras['step_ms_mean']:>8.2f} ms")
    for label, seconds in spent.items():
        print(f"{label:>32} {seconds:>8.2f} s")
    print(f"{'consensus (alignment + ADMM)':>32} {prop.extras['consensus_s']:>8.2f} s")


def problem_f(problem) -> float:
    from popbench import objective

    return objective.objective(problem.graph, problem.graph.poses)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="60,250,1000,2500,10000")
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--full-steps", type=int, default=5)
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--table-robots", type=int, default=1, help="robots of part 1's graphs")
    parser.add_argument("--skip-city", action="store_true")
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    actor, task, checkpoint = actor_for(args.checkpoint)
    print(f"actor: {checkpoint}; torch threads: {args.threads}")
    sizes = [int(size) for size in args.sizes.split(",") if size]
    if sizes:
        per_step_table(actor, task, sizes, args.steps, args.full_steps, args.table_robots)
    if not args.skip_city:
        city_comparison(args.robots, checkpoint)


if __name__ == "__main__":
    main()
