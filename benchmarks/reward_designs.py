"""Candidate per-robot rewards scored against what survives the consensus, on held-out problems.

Every robot's episode ends in local copies (owned poses + separator copies); the consensus
(popbench.consensus.reconcile, aligned-admm) then scores the team. The per-robot designs:

* ``R0``: Σ_r F_r, each robot's local F at its own copies (the current reward; optimum local-lm).
* ``R1``: Σ_r F_r with the copies held at their owners' estimates, here the problem's start
  ``problem.graph.poses`` (a one-pass episode exchanges nothing); optimum ``R1-opt``.
* ``R2-w``: R0 plus w · a prior per copy at that estimate with the information of the copy's
  edges (popbench.solvers.local_lm.copy_priors); optimum ``R2-w-opt``. R1 is w → ∞.
* ``R1x``: as R1 with the owners' estimates after one exchange: each owner's pose at its own
  local optimum (local-lm's owned poses, each robot's frame); optimum ``R1x-opt``.
* ``R2r-w`` / ``R2rx-w``: R0 plus w · priors on the copies' relative poses per owner
  (local_lm.relative_priors: their shape, free of the owners' frames) at the start / at the
  owners' local optima; optima ``R2r-w-opt`` / ``R2rx-w-opt``.
* ``R3``: F (eq. 1) after the consensus, the team score the tables report.

Rows (end states): no-op, gn-sweep, learned-order and imitation (the committed imitation actor,
agents.heldout) and the optima local-lm (R0), R1-opt, R1x-opt, R2-w-opt, R2r-w-opt, R2rx-w-opt
(local_lm.local_optima with ``copy_weight``). Each row is scored under every design. Per
problem ``rows.csv``; ``summary.md`` / ``summary.json``: F after the consensus per row with
paired bootstrap CIs against local-lm and learned-order, the within-problem Spearman
correlation with R3 across the rows (mean over problems) of each design and of ``F_aligned``
(eq. 1 of the assembled copies once the consensus has moved every robot's map rigidly, before
its ADMM), and imitation − learned-order under each of them. Problems already in ``rows.csv``
are kept (a run resumes).

    PYTHONPATH=. .venv/bin/python benchmarks/reward_designs.py --poses-per-robot 250 \\
        --problems 30 --out results/reward-designs/p250
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import torch
from scipy.stats import spearmanr

from agents.heldout import (
    IMITATION_CHECKPOINT,
    class_policy,
    episode,
    learned_episode,
    robots_local_f,
)
from popbench import objective
from popbench.consensus.reconcile import DEFAULT_CONSENSUS, reconcile
from popbench.harness.heldout import HELDOUT_SEED_BASE
from popbench.metrics import ate, bootstrap_ci
from popbench.problems.distributed import DistributedProblem
from popbench.problems.synthetic import make_problem
from popbench.solvers.local_lm import copy_priors, local_optima, relative_priors

WEIGHTS = (0.1, 1.0)
RELATIVE_WEIGHTS = (1.0, 100.0)
EPISODE_ROWS = ("no-op", "gn-sweep", "learned-order", "imitation")


def designs(weights: tuple[float, ...]) -> list[str]:
    """The per-robot designs' column names, then R3."""
    relative = [f"R2{t}-{w:g}" for t in ("r", "rx") for w in RELATIVE_WEIGHTS]
    return ["R0", "R1", "R1x", *(f"R2-{w:g}" for w in weights), *relative, "R3"]


def end_states(
    problem: DistributedProblem, weights: tuple[float, ...], exchanged: np.ndarray
) -> dict:
    """``{row: (local copies [(n_r, 3)], seconds)}`` of every row on ``problem``
    (``exchanged``: ``(N, 3)`` the owners' local optima, R1x's targets)."""
    from envs.sweep import GaussNewtonSweep
    from envs.tree import place_separators

    makers = {
        "no-op": lambda: place_separators(problem),
        "gn-sweep": lambda: episode(problem, class_policy(GaussNewtonSweep)),
        "learned-order": lambda: (
            learned_episode("learned-order", problem, IMITATION_CHECKPOINT).local_poses
        ),
        "imitation": lambda: (
            learned_episode("imitation", problem, IMITATION_CHECKPOINT).local_poses
        ),
        "local-lm": lambda: local_optima(problem)[0],
        "R1-opt": lambda: local_optima(problem, copy_weight=np.inf)[0],
        "R1x-opt": lambda: local_optima(problem, copy_weight=np.inf, copy_targets=exchanged)[0],
    }
    for w in weights:
        makers[f"R2-{w:g}-opt"] = lambda w=w: local_optima(problem, copy_weight=w)[0]
    for name, targets in (("r", problem.graph.poses), ("rx", exchanged)):
        for w in RELATIVE_WEIGHTS:
            makers[f"R2{name}-{w:g}-opt"] = lambda w=w, t=targets: local_optima(
                problem, copy_weight=w, copy_targets=t, copy_relative=True
            )[0]
    states = {}
    for row, make in makers.items():
        started = time.perf_counter()
        states[row] = ([np.asarray(p, dtype=float) for p in make()], time.perf_counter() - started)
    return states


def scores(
    problem: DistributedProblem, local: list, weights: tuple[float, ...], exchanged: np.ndarray
) -> dict:
    """One end state ``local`` under the designs of :func:`designs` but R3 (the caller's)."""
    held, held_x, penalised = 0.0, 0.0, dict.fromkeys(weights, 0.0)
    shape = {f"R2{t}-{w:g}": 0.0 for t in ("r", "rx") for w in RELATIVE_WEIGHTS}
    for graph_r, poses in zip(problem.local_graphs, local, strict=True):
        targets = problem.graph.poses[graph_r.separator_ids]
        copies = poses.copy()
        copies[graph_r.owned_count :] = targets
        held += objective.objective(graph_r.graph, copies)
        copies[graph_r.owned_count :] = exchanged[graph_r.separator_ids]
        held_x += objective.objective(graph_r.graph, copies)
        for w in weights:
            priors = copy_priors(graph_r, targets, w)
            penalised[w] += objective.objective(priors, np.vstack([poses, targets]))
        for name, source in (("r", problem.graph.poses), ("rx", exchanged)):
            for w in RELATIVE_WEIGHTS:
                tied = relative_priors(graph_r, source[graph_r.separator_ids], w)
                shape[f"R2{name}-{w:g}"] += objective.objective(tied, poses)
    return {
        "R0": robots_local_f(problem, local),
        "R1": held,
        "R1x": held_x,
        **{f"R2-{w:g}": value for w, value in penalised.items()},
        **shape,
    }


def problem_rows(args: argparse.Namespace, k: int) -> list[dict]:
    """The rows of held-out problem ``k`` (seed 2³² + k)."""
    seed = HELDOUT_SEED_BASE + k
    problem = make_problem(args.robots, args.noise, args.poses_per_robot, seed=seed)
    exchanged = problem.assemble(local_optima(problem)[0])
    records = []
    for row, (local, seconds) in end_states(problem, args.weights, exchanged).items():
        started = time.perf_counter()
        reconciled = reconcile(problem, local, args.consensus, args.consensus_iterations)
        graph = problem.graph
        records.append(
            {
                "problem_seed": seed,
                "row": row,
                **scores(problem, local, args.weights, exchanged),
                "R3": objective.objective(graph, reconciled.poses),
                "F_aligned": reconciled.F_aligned,
                "ATE": ate(reconciled.poses, graph.ground_truth),
                "row_s": seconds,
                "consensus_s": time.perf_counter() - started,
                "consensus_iterations": reconciled.iterations,
                "consensus_converged": reconciled.converged,
            }
        )
    return records


def centre(values: np.ndarray, prefix: str = "") -> dict[str, object]:
    """Median and mean of ``values (K,)`` with their bootstrap 95 % CIs, keys prefixed."""
    return {
        f"{prefix}median": float(np.median(values)),
        f"{prefix}median_ci": bootstrap_ci(values, np.median),
        f"{prefix}mean": float(values.mean()),
        f"{prefix}mean_ci": bootstrap_ci(values, np.mean),
    }


def paired_table(frame: pd.DataFrame, pairs: list[tuple[str, str]], metrics: list[str]) -> list:
    """A − B per problem for each pair and metric: median / mean with bootstrap 95 % CIs and
    the share of problems with A < B."""
    records = []
    for a, b in pairs:
        for metric in metrics:
            wide = frame.pivot(index="problem_seed", columns="row", values=metric)
            d = (wide[a] - wide[b]).dropna().to_numpy()
            records.append(
                {
                    "A": a,
                    "B": b,
                    "metric": metric,
                    "problems": int(d.size),
                    **centre(d),
                    "A_lower": float((d < 0).mean()),
                }
            )
    return records


def summarise(frame: pd.DataFrame, weights: tuple[float, ...]) -> dict:
    """The three tables of the module docstring."""
    rows = list(dict.fromkeys(frame["row"]))
    optima = [r for r in rows if r == "local-lm" or r.endswith("-opt")]
    per_row = []
    for row in rows:
        f = frame.loc[frame["row"] == row, "R3"].to_numpy()
        per_row.append(
            {
                "row": row,
                "problems": int(f.size),
                **centre(f, "F_"),
                "row_s_mean": float(frame.loc[frame["row"] == row, "row_s"].mean()),
            }
        )
    pairs = [(r, "local-lm") for r in optima if r != "local-lm"]
    pairs += [(r, "learned-order") for r in optima]
    against = paired_table(frame, pairs, ["R3"])
    names = designs(weights)
    correlation = []
    for design in [*names[:-1], "F_aligned"]:
        rho = np.array(
            [
                spearmanr(group[design], group["R3"]).statistic
                for _, group in frame.groupby("problem_seed")
            ]
        )
        learned = frame[frame["row"].isin(EPISODE_ROWS)]
        rho_base = np.array(
            [spearmanr(g[design], g["R3"]).statistic for _, g in learned.groupby("problem_seed")]
        )
        correlation.append(
            {
                "design": design,
                "rho_mean": float(np.nanmean(rho)),
                "rho_mean_ci": bootstrap_ci(rho, np.mean),
                "rho_episode_rows_mean": float(np.nanmean(rho_base)),
                "rho_episode_rows_ci": bootstrap_ci(rho_base, np.mean),
            }
        )
    gain = paired_table(frame, [("imitation", "learned-order")], [*names[:-1], "F_aligned", "R3"])
    return {"rows": per_row, "paired": against, "spearman": correlation, "imitation": gain}


def markdown(tables: dict) -> str:
    """The tables of :func:`summarise` in markdown."""

    def ci(pair: list | tuple) -> str:
        return f"[{pair[0]:.4g}, {pair[1]:.4g}]"

    lines = [
        "| row | problems | F median [95 % CI] | F mean [95 % CI] | row time [s] |",
        "|---|---:|---:|---:|---:|",
    ]
    for r in tables["rows"]:
        lines.append(
            f"| {r['row']} | {r['problems']} | {r['F_median']:.4g} {ci(r['F_median_ci'])} "
            f"| {r['F_mean']:.4g} {ci(r['F_mean_ci'])} | {r['row_s_mean']:.2f} |"
        )
    lines += [
        "",
        "| A − B (F after the consensus) | median [95 % CI] | mean [95 % CI] | A lower |",
        "|---|---:|---:|---:|",
    ]
    for r in tables["paired"]:
        lines.append(
            f"| {r['A']} − {r['B']} | {r['median']:.4g} {ci(r['median_ci'])} "
            f"| {r['mean']:.4g} {ci(r['mean_ci'])} | {r['A_lower']:.2f} |"
        )
    lines += [
        "",
        "| design | Spearman ρ with R3, all rows [95 % CI] | episode rows only [95 % CI] |",
        "|---|---:|---:|",
    ]
    for r in tables["spearman"]:
        lines.append(
            f"| {r['design']} | {r['rho_mean']:.3f} {ci(r['rho_mean_ci'])} "
            f"| {r['rho_episode_rows_mean']:.3f} {ci(r['rho_episode_rows_ci'])} |"
        )
    lines += [
        "",
        "| imitation − learned-order under | median [95 % CI] | mean [95 % CI] | imitation lower |",
        "|---|---:|---:|---:|",
    ]
    for r in tables["imitation"]:
        lines.append(
            f"| {r['metric']} | {r['median']:.4g} {ci(r['median_ci'])} "
            f"| {r['mean']:.4g} {ci(r['mean_ci'])} | {r['A_lower']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poses-per-robot", type=int, default=250)
    parser.add_argument("--problems", type=int, default=20)
    parser.add_argument("--robots", type=int, default=7)
    parser.add_argument("--noise", default="V2")
    parser.add_argument("--consensus", default=DEFAULT_CONSENSUS)
    parser.add_argument("--consensus-iterations", type=int, default=200, help="ADMM at most")
    parser.add_argument(
        "--weights", type=lambda s: tuple(map(float, s.split(","))), default=WEIGHTS
    )
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "rows.csv"
    frame = pd.read_csv(path) if path.exists() else pd.DataFrame()
    done = set(frame["problem_seed"]) if len(frame) else set()
    for k in range(args.problems):
        if HELDOUT_SEED_BASE + k in done:
            continue
        started = time.perf_counter()
        frame = pd.concat([frame, pd.DataFrame(problem_rows(args, k))], ignore_index=True)
        frame.to_csv(path, index=False, float_format="%.10g")
        print(f"problem {k}: {time.perf_counter() - started:.1f} s", flush=True)
    tables = summarise(frame, args.weights)
    (args.out / "summary.json").write_text(json.dumps(tables, indent=1))
    (args.out / "summary.md").write_text(markdown(tables))
    print(markdown(tables))


if __name__ == "__main__":
    main()
