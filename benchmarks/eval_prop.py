"""The learned parts of prop-v1's actor stage on every registered dataset: the
held-out rows gn-sweep, learned-order, imitation, ga-sac and local-lm (agents.heldout) on the
Table I graphs, each through the same consensus.

Rows (docs/training.md, "What each learned part adds"): gn-sweep (one root-outward pass, each Δ
one Gauss–Newton step, no learning); learned-order (the imitation actor's own edge choices, each
with Δ := 0 on the Gauss–Newton base step); imitation (the same actor with its correction:
prop-v1's default actor); ga-sac (the GA-SAC fine-tuned actor of the same training run); local-lm
(every robot's local optimum, the bound a local policy chases).

Columns: F_local is F of the assembled local copies (each pose from its owner) handed to the
consensus; F_aligned the same after the consensus's frame alignment (= F_local with plain
ADMM); F after the consensus; s the row's wall time (episode + consensus). The header line of
each dataset gives F at the start and the no-op's F_aligned (the start after the same
alignment: with it the comparison is free of each robot's gauge).

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/eval_prop.py
    (options: --robots 7 --checkpoint GA-SAC.pt --imitation-checkpoint IMITATION.pt
     --datasets intel,mit,... --consensus admm)

Every row starts from the odometry composition, n robots (METIS, seed 0). The held-out
synthetic evaluation is `popbench run heldout` (popbench.harness.heldout).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from agents.heldout import GA_SAC_CHECKPOINT, IMITATION_CHECKPOINT, local_estimates, row_checkpoints
from popbench import objective
from popbench.consensus.alignment import align_frames
from popbench.consensus.reconcile import CONSENSUS_MODES, DEFAULT_CONSENSUS, reconcile
from popbench.datasets import DATASETS
from popbench.harness.problems import distributed_problem

ROWS = ("gn-sweep", "learned-order", "imitation", "ga-sac", "local-lm")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--checkpoint", type=Path, default=GA_SAC_CHECKPOINT, help="ga-sac")
    parser.add_argument(
        "--imitation-checkpoint",
        type=Path,
        default=IMITATION_CHECKPOINT,
        help="imitation and learned-order",
    )
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--consensus", choices=CONSENSUS_MODES, default=DEFAULT_CONSENSUS)
    args = parser.parse_args()
    torch.set_num_threads(1)
    checkpoints = row_checkpoints(args.checkpoint, args.imitation_checkpoint)
    for row, found in checkpoints.items():
        print(f"{row}: {found[0] if found else 'missing: row left out'}")
    print(f"n = {args.robots}; odometry start; consensus {args.consensus}")
    print(f"{'dataset':>12} {'row':>14} {'F_local':>11} {'F_aligned':>11} {'F':>11} {'s':>7}")
    for name in args.datasets.split(","):
        problem = distributed_problem(name, args.robots, "odometry")
        f_init = objective.objective(problem.graph, problem.graph.poses)
        start = align_frames(problem, local_estimates("no-op", problem)).local_poses
        noop_aligned = objective.objective(problem.graph, problem.assemble(start))
        print(f"{name:>12} {'(start)':>14} F {f_init:.5g}; no-op F_aligned {noop_aligned:.5g}")
        for row in ROWS:
            if checkpoints.get(row, ()) is None:
                continue
            checkpoint = checkpoints[row][0] if row in checkpoints else None
            started = time.perf_counter()
            copies = local_estimates(row, problem, checkpoint=checkpoint)
            reconciled = reconcile(problem, copies, args.consensus)
            seconds = time.perf_counter() - started
            f = objective.objective(problem.graph, reconciled.poses)
            print(
                f"{name:>12} {row:>14} {reconciled.F_before:>11.5g} "
                f"{reconciled.F_aligned:>11.5g} {f:>11.5g} {seconds:>7.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
