"""prop-v1's actor stage on every registered dataset (issue 14): F at the start, after the
actor's episode (before the consensus) and after the consensus, beside gn-sweep, local-lm and
mm-pgo.

F_episode is F of the assembled estimate (each pose from its owner) after the episode, F_actor
the same after the robots whose episode did not lower their local objective went back to their
start (prop-v1's consensus input; "kept" counts the robots that kept their episode), F_cons F of
the consensus's output, and "prop-v1 F" what the registered method returns (docs/never_worse.md:
the consensus's output or its input, or the start, whichever is lowest); F_copies
is what the robots' episode lowers, F of their local copies with each inter-robot edge half
from each robot (prop-v1's history); F_aligned is F_actor after the consensus's frame
alignment and "no-op F_aligned" the start after the same alignment: with it the comparison is
free of each robot's gauge (its map anchored at its first pose), and "aligned lower" says
whether F_aligned is below it. "gn F_local" / "gn-sweep F" are the same two for the gn-sweep
policy (one root-outward pass, each Δ one Gauss–Newton step, no learning: the held-out row of
agents.heldout) through the same consensus: what the learned part of prop-v1's step must add to.
"lm F_local" is local-lm's assembled estimate: the robots' local optima before the consensus,
the bound a local policy chases.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/eval_prop.py
    (options: --robots 7 --checkpoint PATH --datasets intel,mit,... --consensus admm)

Every method starts from the odometry composition, n robots (METIS, seed 0). The held-out
synthetic evaluation is `popbench run heldout` (popbench.harness.heldout).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from agents.heldout import local_estimates
from agents.methods import DEFAULT_CHECKPOINT
from popbench import objective
from popbench.alignment import align_frames
from popbench.datasets import DATASETS
from popbench.harness.problems import distributed_problem
from popbench.methods import Budget, get_method
from popbench.reconcile import CONSENSUS_MODES, DEFAULT_CONSENSUS, reconcile


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--checkpoint", type=Path, default=DEFAULT_CHECKPOINT)
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--consensus", choices=CONSENSUS_MODES, default=DEFAULT_CONSENSUS)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"checkpoint: {args.checkpoint}; n = {args.robots}; odometry start")
    print(
        f"{'dataset':>12} {'F_init':>11} {'F_copies':>11} {'F_episode':>11} {'kept':>4} "
        f"{'F_actor':>11} {'F_aligned':>11} {'F_cons':>11} {'prop-v1 F':>11} {'v1 s':>6} "
        f"{'gn F_local':>11} {'gn-sweep F':>11} "
        f"{'lm F_local':>11} {'local-lm F':>11} {'mm-pgo F':>11} "
        f"{'no-op F_aligned':>15} {'actor lowers F':>15} {'aligned lower':>14}"
    )
    for name in args.datasets.split(","):
        problem = distributed_problem(name, args.robots, "odometry")
        started = time.perf_counter()
        v1 = get_method("prop-v1")(
            problem, Budget(), checkpoint=args.checkpoint, consensus=args.consensus
        )
        v1_s = time.perf_counter() - started
        sweep = reconcile(problem, local_estimates("gn-sweep", problem, {}), args.consensus)
        sweep_f = objective.objective(problem.graph, sweep.poses)
        local = get_method("local-lm")(problem, Budget(), consensus=args.consensus)
        mm = get_method("mm-pgo")(problem, Budget(1000))
        start = align_frames(problem, local_estimates("no-op", problem, {})).local_poses
        noop_aligned = objective.objective(problem.graph, problem.assemble(start))
        f_init, f_actor = v1.extras["F_init"], v1.extras["F_actor"]
        f_copies = v1.history[-2] if v1.history.size > 1 else f_init  # [-1] is after consensus
        print(
            f"{name:>12} {f_init:>11.5g} {f_copies:>11.5g} {v1.extras['F_episode']:>11.5g} "
            f"{v1.extras['robots_kept_episode']:>4} {f_actor:>11.5g} "
            f"{v1.extras['F_aligned']:>11.5g} {v1.extras['F_consensus']:>11.5g} "
            f"{v1.F:>11.5g} {v1_s:>6.1f} "
            f"{sweep.F_before:>11.5g} {sweep_f:>11.5g} "
            f"{local.extras['F_local']:>11.5g} {local.F:>11.5g} {mm.F:>11.5g} "
            f"{noop_aligned:>15.5g} {str(f_actor < f_init):>15} "
            f"{str(v1.extras['F_aligned'] < noop_aligned):>14}",
            flush=True,
        )


if __name__ == "__main__":
    main()
