"""Local F after one episode of the environment's non-learned policies (docs/environment.md).

On held-out synthetic problems (seeds ``popbench.harness.heldout.HELDOUT_SEED_BASE + k``, above
every training stream's 32-bit seeds), each row runs one episode of :class:`envs.core.PGOCore`
(measurement reward, so an agent's ``L`` is the F of its local graph) over all problems at once
and reports the sum over agents of the local F per problem (mean, median), the share of the
no-op → local-optimum gap it closes (in mean F) and the fraction of corrections the core clipped
to Δmax. No consensus: this measures the local stage only. Rows:

* ``initial``: the odometry start, separators at the global chain's values (no placement);
* ``no-op``: the start with the separators placed (:func:`envs.tree.place_separators`);
* ``gn-sweep`` / ``gn-sweep pose``: :class:`envs.sweep.GaussNewtonSweep` in each mode;
* ``expert`` / ``expert pose``: :class:`envs.expert.Expert` in each mode;
* ``local optimum``: each agent's LM optimum (the expert's target).

Every row but ``initial`` starts from the placed separators.

    PYTHONPATH=. .venv/bin/python benchmarks/eval_env_policies.py [--problems 30] [--robots 7]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from envs.core import PGOCore
from envs.expert import Expert, local_optima
from envs.observation import Dimensions
from envs.sweep import GaussNewtonSweep
from envs.tree import place_separators
from popbench import objective
from popbench.harness.heldout import HELDOUT_SEED_BASE
from popbench.problems.synthetic import make_problem


def episode(problems, dims, correction: str, place: bool, policy_class) -> tuple[np.ndarray, float]:
    """``(local F per problem after one episode, fraction of clipped corrections)``."""
    core = PGOCore.for_problems(problems, dims=dims, correction=correction, place_separators=place)
    policy = None if policy_class is None else policy_class(core)
    clipped = total = 0
    for _ in range(core.horizon):
        if policy is None:
            edge = core.action_mask().to(torch.int8).argmax(-1)
            delta = torch.zeros(edge.shape + (3,), dtype=core.dtype)
        else:
            edge, delta = policy.act()
        real = edge < dims.edges
        clipped += int(((delta.abs() > core.delta_max).any(-1) & real).sum())
        total += int(real.sum())
        core.step(edge, delta)
    return core.state.loss.sum(-1).numpy(), clipped / max(total, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", type=int, default=30)
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--noise", default="V2")
    parser.add_argument("--json", action="store_true", help="print the rows as JSON last")
    args = parser.parse_args()
    torch.set_num_threads(1)
    started = time.perf_counter()
    problems = [
        make_problem(args.robots, args.noise, seed=HELDOUT_SEED_BASE + k)
        for k in range(args.problems)
    ]
    dims = Dimensions.of(problems)
    rows: dict[str, tuple[np.ndarray, float]] = {
        "initial": episode(problems, dims, "pose", False, None),
        "no-op": episode(problems, dims, "pose", True, None),
        "gn-sweep": episode(problems, dims, "subtree", True, GaussNewtonSweep),
        "gn-sweep pose": episode(problems, dims, "pose", True, GaussNewtonSweep),
        "expert": episode(problems, dims, "subtree", True, Expert),
        "expert pose": episode(problems, dims, "pose", True, Expert),
    }
    optimum = np.array(
        [
            sum(
                objective.objective(local.graph, poses)
                for local, poses in zip(
                    problem.local_graphs,
                    local_optima(problem, place_separators(problem)),
                    strict=True,
                )
            )
            for problem in problems
        ]
    )
    rows["local optimum"] = (optimum, 0.0)
    noop, best = rows["no-op"][0].mean(), optimum.mean()
    print(
        f"{args.problems} held-out {args.noise} problems, n = {args.robots}, local F summed over"
        f" agents, one episode, no consensus ({time.perf_counter() - started:.0f} s)"
    )
    print("| row | F mean | F median | gap closed (mean) | clipped |\n|---|---:|---:|---:|---:|")
    summary = []
    for name, (values, clipped) in rows.items():
        closed = (noop - values.mean()) / (noop - best)
        print(
            f"| {name} | {values.mean():,.1f} | {np.median(values):,.1f} | {100 * closed:.1f} % |"
            f" {100 * clipped:.1f} % |"
        )
        summary.append(
            {
                "row": name,
                "F_mean": float(values.mean()),
                "F_median": float(np.median(values)),
                "gap_closed": float(closed),
                "clipped": clipped,
            }
        )
    if args.json:
        print(json.dumps({"rows": summary}))


if __name__ == "__main__":
    main()
