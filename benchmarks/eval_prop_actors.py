"""prop-v1 (its defaults: the line-search step rule, the aligned consensus) with several actors on
registered maps, against local-lm: F after the consensus, its ratio to local-lm's F, and the
number of robots whose episode lowered their local F (the keep rule's count).

    POPBENCH_DATA=... python benchmarks/eval_prop_actors.py --datasets intel,mit \
        --actors actor-V2-n7-residual.pt,imitation-SLAM100-n7-ls-s1.pt

Every row starts from the odometry composition, n = 7 robots (METIS, seed 0). Actors are
file names under agents/checkpoints or paths. Used for docs/training.md, "Training on the SLAM
maps under the line search" (maps the actors never trained on; not a choice of default).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from agents.methods import CHECKPOINT_DIR, solve_prop_v1
from popbench.harness.problems import distributed_problem
from popbench.solvers.local_lm import solve as solve_local_lm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--datasets", required=True, help="comma-separated registered names")
    parser.add_argument("--actors", required=True, help="comma-separated checkpoint files")
    parser.add_argument("--robots", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    actors = [a if Path(a).is_file() else str(CHECKPOINT_DIR / a) for a in args.actors.split(",")]
    for name in args.datasets.split(","):
        problem = distributed_problem(name, args.robots, "odometry")
        started = time.perf_counter()
        reference = solve_local_lm(problem).F
        cells = [f"{name:>9} local-lm {reference:.5g}"]
        for actor in actors:
            result = solve_prop_v1(problem, checkpoint=actor)
            kept = result.extras["robots_kept_episode"]
            label = Path(actor).stem
            cells.append(f"{label} {result.F:.5g} ({result.F / reference:.2f}x, kept {kept})")
        print(" | ".join(cells), f"{time.perf_counter() - started:.0f} s", flush=True)


if __name__ == "__main__":
    main()
