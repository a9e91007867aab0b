"""Held-out evaluation of prop-v1 (issue 5, "Done when" 1) and prop-v1/prop-v2 on Table I datasets.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/eval_prop.py
    (options: --problems 100 --robots 7 --checkpoint PATH --datasets intel,mit,...
     --skip-synthetic --skip-datasets --align)

Part 1 — `--problems` synthetic V2 problems with n robots (60 poses each), seeds
EVAL_SEED_BASE + k, checked disjoint from every problem seed the training streams can draw
(SeedSequence([train_seed, element, episode]) for the committed runs' elements and far more
episodes than they ran). For each problem, from its odometry start:
    initial      the start itself;
    consensus    prop-v1's consensus (ADMM, popbench.consensus, the paper's; with `--align`
                 every row, prop-v1 included, first aligns the robots' frames,
                 popbench.alignment) on the untouched copies: what prop-v1 gets without its
                 actor;
    random       a random policy (uniform unprocessed edge, uniform δ in [−Δmax, Δmax]) for the
                 same episode, then the same consensus;
    prop-v1      the trained actor's episode, then the same consensus;
    greedy       a hand-made policy for the same episode, then the same consensus: every robot
                 takes its unprocessed edges in slot order and corrects each by half its
                 residual (δ = −½ r, clipped to Δmax): what a simple local policy gets;
    actor only   F of prop-v1's copies after the episode, before the consensus (each vertex from
                 its owner's copy; no ATE): against `initial`, what the policy itself did;
and two bounds on what *any* local policy could add before the same consensus:
    local-opt    every robot's local graph solved to its own optimum (`lm`, 100 iterations,
                 from its starting copies, local vertex 0 fixed), then the consensus;
    truth        the ground-truth poses as every robot's copies, then the consensus.
Reported: mean and median of F and of the ground-truth localisation error (ATE: RMS position
error [m] after the least-squares rigid SE(2) alignment of the estimate to the ground truth), and
how often each beats the initial estimate.

Part 2 — datasets at n robots from the odometry start: F and wall time of prop-v1 and prop-v2;
for reference F of `lm` (75 iterations) from the same odometry start and the optimum floor F*
(`lm` from the chordal initialisation, up to 300 iterations), with prop-v2's relative gap to F*;
and mm-pgo's 1000 iterations (baselines.mm_pgo, from the same odometry start, n robots):
F and wall time.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from agents.checkpoint import load_actor
from agents.methods import DEFAULT_CHECKPOINT, solve_prop_v1, solve_prop_v2
from popbench import objective
from popbench.alignment import align_frames
from popbench.consensus import admm_consensus
from popbench.methods import Budget
from popbench.metrics import ate
from popbench.solvers.local_lm import local_optima
from popbench.synthetic import make_problem

EVAL_SEED_BASE = 3_000_000
TRAINING_SEEDS = (0,)  # seeds of the committed runs (agents/checkpoints/README.md)
TRAINING_ELEMENTS = 64  # ≥ num_envs of any committed run
TRAINING_EPISODES = 5_000  # ≥ episodes any committed run drew per element


def training_problem_seeds() -> set[int]:
    """Every problem seed the committed runs' samplers could have drawn (envs.core)."""
    seeds = set()
    for seed in TRAINING_SEEDS:
        for element in range(TRAINING_ELEMENTS):
            for episode in range(TRAINING_EPISODES):
                key = [seed, element, episode]
                seeds.add(int(np.random.SeedSequence(key).generate_state(1)[0]))
    return seeds


def episode_copies(problem, delta_max: np.ndarray, policy: Callable) -> list:
    """Local copies after one episode of the environment (envs.core.PGOCore, measurement
    reward) driven by ``policy(core) -> (edge [n], delta [n, 3])``."""
    from envs.core import PGOCore
    from envs.observation import Dimensions

    n = problem.num_robots
    core = PGOCore(n, Dimensions.of([problem]), 1, delta_max=delta_max.tolist(), reward="F")
    core.load([problem], [0])
    for _ in range(int(core.tensors["num_edges"].max())):
        edge, delta = policy(core)
        core.step(torch.as_tensor(edge).view(1, n), torch.as_tensor(delta).view(1, n, 3))
    return core.local_poses(0)


def random_policy_copies(problem, delta_max: np.ndarray, rng: np.random.Generator) -> list:
    """Local copies after one episode of the uniform random policy."""

    def policy(core):
        mask = core.action_mask()[0].numpy()
        scores = np.where(mask, rng.random(mask.shape), -1.0)
        return scores.argmax(-1), rng.uniform(-delta_max, delta_max, (1, mask.shape[0], 3))

    return episode_copies(problem, delta_max, policy)


def greedy_policy_copies(problem, delta_max: np.ndarray, fraction: float = 0.5) -> list:
    """Local copies after one episode of the hand-made policy: first unprocessed edge,
    δ = −fraction · (its residual) (the environment clips δ to Δmax)."""

    def policy(core):
        residuals = core.tensors["residuals"][0]  # (n, E, 3), in the frame of each edge's tail
        edge = core.action_mask()[0].to(torch.int8).argmax(-1)  # E (no-op) once all are done
        acting = (edge < residuals.shape[1]).unsqueeze(-1)
        r = residuals[torch.arange(edge.numel()), edge.clamp(max=residuals.shape[1] - 1)]
        return edge, torch.where(acting, -fraction * r, torch.zeros_like(r))

    return episode_copies(problem, delta_max, policy)


def consensus(problem, copies: list[np.ndarray], align: bool) -> np.ndarray:
    """prop-v1's consensus of local ``copies``: frame alignment (if ``align``), then ADMM."""
    if align:
        copies = align_frames(problem, copies).local_poses
    return admm_consensus(problem, copies).poses


def synthetic_table(checkpoint: Path, problems: int, robots: int, align: bool) -> None:
    actor, _ = load_actor(checkpoint)
    delta_max = actor.delta_max.numpy().astype(np.float64)
    excluded = training_problem_seeds()
    seeds = [EVAL_SEED_BASE + k for k in range(problems)]
    assert not excluded.intersection(seeds), "evaluation seeds overlap training seeds"
    rng = np.random.default_rng(0)
    rows: dict[str, list[tuple[float, float]]] = {
        "initial": [],
        "consensus": [],
        "random": [],
        "prop-v1": [],
        "greedy": [],
        "actor only": [],
        "local-opt": [],
        "truth": [],
    }
    started = time.perf_counter()
    for seed in seeds:
        problem = make_problem(robots=robots, noise="V2", poses_per_robot=60, seed=seed)
        graph, truth = problem.graph, problem.graph.ground_truth

        def record(name: str, poses: np.ndarray, graph=graph, truth=truth) -> None:
            f = objective.objective(graph, poses)
            rows[name].append((f, ate(poses, truth)))

        record("initial", graph.poses)
        record("consensus", consensus(problem, problem.split(), align))
        record("random", consensus(problem, random_policy_copies(problem, delta_max, rng), align))
        prop_v1 = solve_prop_v1(problem, Budget(), checkpoint=checkpoint, align_frames=align)
        record("prop-v1", prop_v1.poses)
        rows["actor only"].append((prop_v1.extras["F_actor"], np.nan))
        record("greedy", consensus(problem, greedy_policy_copies(problem, delta_max), align))
        record("local-opt", consensus(problem, local_optima(problem)[0], align))
        record("truth", consensus(problem, problem.split(truth), align))
    print(
        f"\n{problems} held-out synthetic V2 problems, n = {robots}, 60 poses/robot "
        f"(seeds {seeds[0]}..{seeds[-1]}; consensus {'with' if align else 'without'} frame "
        f"alignment; {time.perf_counter() - started:.0f} s)"
    )
    print(
        f"{'estimate':>10} {'F mean':>10} {'F median':>10} {'ATE mean m':>11} "
        f"{'ATE median':>11} {'F<initial':>10} {'ATE<initial':>12}"
    )
    initial = np.array(rows["initial"])
    for name, values in rows.items():
        values = np.array(values)
        f_columns = f"{name:>10} {values[:, 0].mean():>10.4g} {np.median(values[:, 0]):>10.4g} "
        better_f = f"{np.mean(values[:, 0] < initial[:, 0]):>10.0%}"
        if np.isnan(values[:, 1]).all():  # no ATE for this row
            print(f"{f_columns}{'-':>11} {'-':>11} {better_f} {'-':>12}")
            continue
        better_ate = np.mean(values[:, 1] < initial[:, 1])
        print(
            f"{f_columns}{values[:, 1].mean():>11.4f} {np.median(values[:, 1]):>11.4f} "
            f"{better_f} {better_ate:>12.0%}"
        )


def dataset_table(checkpoint: Path, names: list[str], robots: int, align: bool) -> None:
    from baselines import mm_pgo
    from envs import dataset_problem
    from popbench.solvers.chordal import chordal_initialisation
    from popbench.solvers.lm import solve_graph

    print(f"\nTable I datasets, n = {robots}, odometry start")
    print(
        f"{'dataset':>9} {'F start':>11} {'prop-v1 F':>11} {'v1 wall s':>10} {'prop-v2 F':>11} "
        f"{'v2 wall s':>10} {'lm75 F':>11} {'F*':>11} {'v2 gap':>8} {'flagged':>8} "
        f"{'mm-pgo F':>11} {'mm wall s':>10}"
    )
    for name in names:
        problem = dataset_problem(name, robots)
        start = objective.objective(problem.graph, problem.graph.poses)
        v2 = solve_prop_v2(problem, Budget(), checkpoint=checkpoint, align_frames=align)
        lm = solve_graph(problem.graph, problem.graph.poses, iterations=75)
        optimum = solve_graph(problem.graph, chordal_initialisation(problem.graph), 300).F
        mm = mm_pgo.solve(problem, Budget(1000))
        v1_f, v1_wall = v2.extras["F_prop_v1"], v2.extras["prop_v1_wall_s"]
        print(
            f"{name:>9} {start:>11.5g} {v1_f:>11.5g} {v1_wall:>10.1f} {v2.F:>11.5g} "
            f"{v2.wall_s:>10.1f} {lm.F:>11.5g} {optimum:>11.5g} {v2.F / optimum - 1:>8.1e} "
            f"{v2.extras['flagged_outliers']:>8} {mm.F:>11.5g} {mm.wall_s:>10.1f}",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=100)
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument(
        "--datasets", default="mit,intel,csail,m3500,m3500b,m3500c,grid1000,city10k"
    )
    parser.add_argument("--skip-synthetic", action="store_true")
    parser.add_argument("--skip-datasets", action="store_true")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument(
        "--align", action="store_true", help="align the robots' frames before every consensus"
    )
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"checkpoint: {args.checkpoint}")
    if not args.skip_synthetic:
        synthetic_table(args.checkpoint, args.problems, args.robots, args.align)
    if not args.skip_datasets:
        dataset_table(args.checkpoint, args.datasets.split(","), args.robots, args.align)


if __name__ == "__main__":
    main()
