"""What prop-v1's gap to local-lm is made of on the real maps: the rows of eval_prop.py plus the
former default actor, each robot's local F before and after every actor episode, F*, and the
log-ratio decomposition of F(ga-sac) / F(local-lm) (docs/training.md, "The gap to local-lm on
Table I's maps, decomposed").

Rows (n robots, METIS seed 0, odometry start, the default consensus; F without a keep rule):
gn-sweep, learned-order, imitation, ga-sac and local-lm as in eval_prop.py, and ``former``: the
former default actor (``--former-checkpoint``, ``imitation-V2-n7-robust.pt``) run as prop-v1
runs its actor (its own task, with its correction). Per row: F after the consensus, its ratio
to local-lm's F, F_aligned; per episode row (gn-sweep and the actors): the robots' local F
summed at the episode's start and end (each robot's F of its local graph at its own copies, the
core's running ``loss``: ``Episode.start_local_F`` / ``local_F``), the robots whose local F
rose (robot, start, end), and F_keep: F after the consensus of the copies under prop-v1's keep
rule (a robot whose local F did not fall hands its start copy on); ga-sac's F_keep is prop-v1.
F* is the harness's optimum (LM from chordal, popbench.harness.problems.optimum); where
results/table1/table1.csv has it, that value.

Decomposition (natural logs, summing to log F_prop / F_ll): one pass of GN steps vs the local
optimum log(F_gn / F_ll), the learned order log(F_lo / F_gn), the learned correction
log(F_im / F_lo), the fine-tuning log(F_ga / F_im), the keep rule log(F_prop / F_ga); and
F_ll / F*, the consensus's own share.

``--passes 1,2,4,8``: instead, the multi-pass probe (measurement only): gn-sweep and the ga-sac
actor run K episodes in turn, each under prop-v1's keep rule (a robot whose local F did not
fall keeps its start copy) and from the previous one's kept copies assembled (each pose from its
owner; the separators re-placed from the robot's own neighbours at each episode's start), and F
(and F_aligned) after the consensus of the K-th episode's kept copies, with the robots' local F
summed after each pass against local-lm's.

    POPBENCH_DATA=/work/shared/datasets .venv/bin/python benchmarks/eval_gap.py \
        --json results/gap-decomposition/gap.json
    (options: --robots 7 --datasets m3500,... --passes 1,2,4,8)
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from agents.heldout import (
    GA_SAC_CHECKPOINT,
    IMITATION_CHECKPOINT,
    POLICY_TASK,
    class_policy,
    learned_episode,
    local_estimates,
)
from agents.methods import CHECKPOINT_DIR
from popbench import objective
from popbench.consensus.reconcile import DEFAULT_CONSENSUS, reconcile
from popbench.harness.defaults import TABLE1_DATASETS
from popbench.harness.problems import distributed_problem, optimum
from popbench.problems.distributed import DistributedProblem

DATASETS = (*TABLE1_DATASETS, "fr079", "frh")
FORMER_CHECKPOINT = CHECKPOINT_DIR / "imitation-V2-n7-robust.pt"
TABLE1_CSV = Path(__file__).resolve().parents[1] / "results" / "table1" / "table1.csv"
ROWS = ("gn-sweep", "learned-order", "imitation", "ga-sac", "former", "local-lm")
# (label, numerator row, denominator row) of the decomposition, in order
PARTS = (
    ("one-pass", "gn-sweep", "local-lm"),
    ("order", "learned-order", "gn-sweep"),
    ("correction", "imitation", "learned-order"),
    ("fine-tune", "ga-sac", "imitation"),
)

Copies = list[np.ndarray]


def gn_sweep(problem: DistributedProblem) -> tuple[Copies, np.ndarray, np.ndarray, Copies]:
    """gn-sweep's episode (agents.heldout's ``gn-sweep`` row): its copies, the robots' ``(n,)``
    local F at its start and end (read from the core as for an actor's Episode) and the copies
    under prop-v1's keep rule (a robot whose local F did not fall keeps its start copy)."""
    from envs.core import PGOCore
    from envs.sweep import GaussNewtonSweep

    n = problem.num_robots
    core = PGOCore.for_problems([problem], POLICY_TASK)
    start = core.state.loss[0].numpy().copy()
    start_poses = [poses.copy() for poses in core.local_poses(0)]
    step = class_policy(GaussNewtonSweep)(core)
    for _ in range(core.horizon):
        edge, delta = step(core)
        core.step(torch.as_tensor(edge).view(1, n), torch.as_tensor(delta).view(1, n, 3))
    end = core.state.loss[0].numpy().copy()
    copies = core.local_poses(0)
    kept = [c if f < f0 else s for c, s, f, f0 in zip(copies, start_poses, end, start, strict=True)]
    return copies, start, end, kept


def run_row(
    row: str, problem: DistributedProblem, checkpoints: dict[str, Path]
) -> tuple[Copies, np.ndarray | None, np.ndarray | None, Copies]:
    """``(copies, start local F (n,), end local F (n,), copies under the keep rule)`` of
    ``row`` (None, None and the copies themselves for local-lm)."""
    if row == "gn-sweep":
        return gn_sweep(problem)
    if row == "local-lm":
        copies = local_estimates("local-lm", problem)
        return copies, None, None, copies
    learned = "ga-sac" if row == "former" else row  # the former default runs as prop-v1's actor
    episode = learned_episode(learned, problem, checkpoints[row])
    return episode.local_poses, episode.start_local_F, episode.local_F, episode.kept_poses()


def f_star(name: str) -> tuple[float, str]:
    """F* of ``name`` and where it was read: Table I's committed csv, else computed."""
    if TABLE1_CSV.is_file():
        with TABLE1_CSV.open() as handle:
            for line in csv.DictReader(handle):
                if line["dataset"] == name:
                    return float(line["F_star"]), "table1.csv"
    return optimum(name), "computed"


def measure(name: str, robots: int, checkpoints: dict[str, Path], consensus: str) -> dict[str, Any]:
    """Every row of the module docstring on one dataset: ``{"F_star", "rows": {row: {...}}}``."""
    problem = distributed_problem(name, robots, "odometry")
    star, source = f_star(name)
    record: dict[str, Any] = {"dataset": name, "F_star": star, "F_star_from": source, "rows": {}}
    print(
        f"{name}: F_init {objective.objective(problem.graph, problem.graph.poses):.6g}; "
        f"F* {star:.6g} ({source})",
        flush=True,
    )
    for row in ROWS:
        started = time.perf_counter()
        copies, start, end, kept = run_row(row, problem, checkpoints)
        reconciled = reconcile(problem, copies, consensus)
        cells: dict[str, Any] = {
            "F": objective.objective(problem.graph, reconciled.poses),
            "F_aligned": reconciled.F_aligned,
            "F_local": reconciled.F_before,
        }
        if start is not None:
            reverted = np.flatnonzero(~(end < start))
            cells["F_keep"] = cells["F"]
            if reverted.size:
                keep = reconcile(problem, kept, consensus).poses
                cells["F_keep"] = objective.objective(problem.graph, keep)
            cells["reverted"] = reverted.tolist()
            rose = np.flatnonzero(end > start)
            cells |= {
                "start_local_F": start.tolist(),
                "local_F": end.tolist(),
                "robots_rose": int(rose.size),
                "rises": [[int(r), float(start[r]), float(end[r])] for r in rose],
            }
        cells["s"] = time.perf_counter() - started
        record["rows"][row] = cells
        local = ""
        if start is not None:
            rises = ", ".join(f"r{r}: {a:.6g} -> {b:.6g}" for r, a, b in cells["rises"])
            local = f" local F {sum(start):.6g} -> {sum(end):.6g}, rose {cells['robots_rose']}"
            local += f" ({rises})" if rises else ""
            local += f"; with the keep rule F {cells['F_keep']:.6g}"
        print(
            f"  {row:>13} F {cells['F']:.6g} F_aligned {cells['F_aligned']:.6g}"
            f"{local} [{cells['s']:.1f} s]",
            flush=True,
        )
    return record


def print_tables(records: list[dict[str, Any]]) -> None:
    """The ratio table and the decomposition table (markdown) of the measured datasets."""
    print("\n| map | F* | local-lm | " + " | ".join(f"{r} / ll" for r in ROWS[:-1]), end=" | ")
    print("prop-v1 / ll | former + keep / ll | robots rose (lo, im, ga, former) |")
    print("|---|---:|---:|" + "---:|" * (len(ROWS) + 2))
    for record in records:
        rows = record["rows"]
        ll = rows["local-lm"]["F"]
        ratios = " | ".join(f"{rows[r]['F'] / ll:.2f}" for r in ROWS[:-1])
        keep = f"{rows['ga-sac']['F_keep'] / ll:.2f} | {rows['former']['F_keep'] / ll:.2f}"
        rose = ", ".join(str(rows[r]["robots_rose"]) for r in ROWS[1:5])
        print(
            f"| {record['dataset']} | {record['F_star']:.5g} | {ll:.5g} | {ratios} | {keep} "
            f"| {rose} |"
        )
    print(
        "\n| map | " + " | ".join(label for label, _, _ in PARTS) + " | keep rule |"
        " sum = log(prop/ll) | ll / F* |"
    )
    print("|---|" + "---:|" * (len(PARTS) + 3))
    for record in records:
        rows = record["rows"]
        parts = [math.log(rows[a]["F"] / rows[b]["F"]) for _, a, b in PARTS]
        parts.append(math.log(rows["ga-sac"]["F_keep"] / rows["ga-sac"]["F"]))
        consensus = rows["local-lm"]["F"] / record["F_star"]
        cells = " | ".join(f"{p:+.2f}" for p in parts)
        print(f"| {record['dataset']} | {cells} | {sum(parts):+.2f} | {consensus:.2f} |")


def multi_pass(
    name: str, robots: int, counts: list[int], checkpoint: Path, consensus: str
) -> dict[str, Any]:
    """F after the consensus after K passes, for each K in ``counts``, of gn-sweep and the
    actor of ``checkpoint`` (module docstring, keep rule in every pass), with F_aligned there,
    and per pass the robots' local F summed at its start and kept end and the number of robots
    whose episode raised theirs; local-lm's F and summed local F as the reference."""
    from agents.heldout import robots_local_f

    problem = distributed_problem(name, robots, "odometry")
    optima = local_estimates("local-lm", problem)
    record: dict[str, Any] = {
        "dataset": name,
        "local-lm": {
            "F": objective.objective(problem.graph, reconcile(problem, optima, consensus).poses),
            "local_F": robots_local_f(problem, optima),
        },
    }
    for row in ("gn-sweep", "ga-sac"):
        current, started = problem, time.perf_counter()
        cells: dict[str, Any] = {"F": {}, "F_aligned": {}, "start_local_F": [], "local_F": []}
        cells["robots_rose"] = []
        for k in range(1, max(counts) + 1):
            _, start, end, copies = run_row(row, current, {"ga-sac": checkpoint})
            cells["robots_rose"].append(int(np.count_nonzero(end > start)))
            cells["start_local_F"].append(float(start.sum()))
            cells["local_F"].append(float(np.minimum(start, end).sum()))  # the kept copies'
            if k in counts:
                reconciled = reconcile(problem, copies, consensus)
                cells["F"][k] = objective.objective(problem.graph, reconciled.poses)
                cells["F_aligned"][k] = reconciled.F_aligned
                print(
                    f"{name:>10} {row:>8} K={k} F {cells['F'][k]:.6g} F_aligned "
                    f"{reconciled.F_aligned:.6g} local F {cells['local_F'][-1]:.6g} "
                    f"[{time.perf_counter() - started:.1f} s]",
                    flush=True,
                )
            current = DistributedProblem(
                problem.graph.replace(poses=problem.assemble(copies)), "given", problem.outlier_mask
            )
        cells["s"] = time.perf_counter() - started
        record[row] = cells
    reference = record["local-lm"]
    print(f"{name:>10} local-lm F {reference['F']:.6g} local F {reference['local_F']:.6g}")
    return record


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--datasets", default=",".join(DATASETS))
    parser.add_argument("--checkpoint", type=Path, default=GA_SAC_CHECKPOINT, help="ga-sac")
    parser.add_argument("--imitation-checkpoint", type=Path, default=IMITATION_CHECKPOINT)
    parser.add_argument("--former-checkpoint", type=Path, default=FORMER_CHECKPOINT)
    parser.add_argument("--consensus", default=DEFAULT_CONSENSUS)
    parser.add_argument("--passes", default="", help="e.g. 1,2,4,8: the multi-pass probe")
    parser.add_argument("--json", type=Path, help="write the measurements here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    checkpoints = {
        "learned-order": args.imitation_checkpoint,
        "imitation": args.imitation_checkpoint,
        "ga-sac": args.checkpoint,
        "former": args.former_checkpoint,
    }
    print(
        f"n = {args.robots}; odometry start; consensus {args.consensus}; "
        + "; ".join(f"{row}: {path}" for row, path in checkpoints.items())
    )
    names = args.datasets.split(",")
    if args.passes:
        counts = sorted(int(k) for k in args.passes.split(","))
        records = [
            multi_pass(name, args.robots, counts, args.checkpoint, args.consensus) for name in names
        ]
    else:
        records = [measure(name, args.robots, checkpoints, args.consensus) for name in names]
        print_tables(records)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(records, indent=1) + "\n")


if __name__ == "__main__":
    main()
