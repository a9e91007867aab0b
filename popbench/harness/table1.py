"""The paper's Table I: datasets × robots × methods, with the optimum F* as the floor.

Every method starts from the same initial estimate (``init``, default the odometry composition,
the standard hard start) and runs ``iterations`` rounds (the paper: 1000 for the baselines); the
learned methods run their own fixed schedule. F* is the best F of the project's LM from chordal
initialisation, and ``gap = F / F* − 1``. Each cell's row carries its history and the parallel
time of each entry, from which the times to a relative gap of 1e-1, 1e-2 and 1e-3 are read
(:mod:`popbench.harness.profiles`).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from pathlib import Path
from typing import Any

import pandas as pd

from popbench.errors import ValueRangeError
from popbench.harness import defaults, problems, profiles, reports
from popbench.harness.cache import grid_specs, provenance
from popbench.harness.executors import Row, Run, Spec
from popbench.harness.paper import paper_table1_cell
from popbench.harness.profiles import GAP_COLUMNS
from popbench.harness.refining import solve_cell
from popbench.harness.runner import run_experiment
from popbench.methods import METHODS, Budget, Result, distributed_methods
from popbench.problems.distributed import DistributedProblem

DATASETS, ROBOTS = defaults.TABLE1_DATASETS, defaults.TABLE1_ROBOTS
# Methods computed at some team sizes only: the warm-started mm-pgo rows
# (popbench.solvers.warm_start) at n = 7, which keeps a fresh `make run` within its 10 minutes
# (docs/harness.md).
METHOD_ROBOTS: dict[str, tuple[int, ...]] = {"prop-v1+mm-pgo": (7,), "local-lm+mm-pgo": (7,)}
QUICK = {**defaults.TABLE1_QUICK, "out": Path(defaults.TABLE1_QUICK["out"])}


@dataclasses.dataclass(frozen=True)
class Table1Config:
    """What ``popbench run table1`` computes."""

    datasets: tuple[str, ...] = DATASETS
    robots: tuple[int, ...] = ROBOTS
    # default: every registered method that is not centralised (the paper's five, local-lm)
    methods: tuple[str, ...] = dataclasses.field(default_factory=distributed_methods)
    iterations: int = defaults.ITERATIONS
    seeds: tuple[int, ...] = (0,)
    # the learned methods' actors: one cell per training seed (MethodRecord.seed_checkpoints)
    training_seeds: tuple[int, ...] = (0,)
    init: str = defaults.INIT
    partition: str = defaults.PARTITION
    out: Path = Path(defaults.TABLE1_OUT)
    # the team sizes a method is restricted to (the others: every size of `robots`)
    method_robots: dict[str, tuple[int, ...]] = dataclasses.field(
        default_factory=lambda: dict(METHOD_ROBOTS)
    )

    @classmethod
    def quick(cls, **overrides: Any) -> Table1Config:
        """A small subset that finishes in about a minute (CI, first contact); written to
        ``results/table1-quick`` unless ``out`` is given, so the committed Table I is kept."""
        return cls(**{**QUICK, **overrides})


def cell_specs(config: Table1Config) -> list[Spec]:
    """One specification per table cell, in table order, with what it is computed from
    (:func:`popbench.harness.cache.grid_specs`: dataset file, code and actor checkpoint)."""
    axes = {
        "dataset": config.datasets,
        "robots": config.robots,
        "method": config.methods,
        "seed": config.seeds,
    }
    shared = {"iterations": config.iterations, "init": config.init, "partition": config.partition}
    specs = grid_specs("table1", axes, shared, config.training_seeds)
    sizes = config.method_robots
    return [spec for spec in specs if spec["robots"] in sizes.get(spec["method"], config.robots)]


def check_training_seeds(config: Table1Config) -> None:
    """ValueRangeError unless every learned method of ``config`` names an actor for each of
    its ``training_seeds`` (:attr:`popbench.methods.MethodRecord.seed_checkpoints`)."""
    for method in config.methods:
        for training_seed in config.training_seeds:
            path = METHODS[method].checkpoint_path(training_seed)
            if path is not None and not path.is_file():
                what = f"actor of {method} for training seed {training_seed}"
                raise ValueRangeError(what, str(path), "an existing checkpoint file")


def optimum_spec(dataset: str) -> Spec:
    return {"experiment": "optimum", "dataset": dataset, **provenance(dataset)}


def compute_optimum(spec: Spec) -> dict[str, Any]:
    start = time.perf_counter()
    return {
        "dataset": spec["dataset"],
        "F_star": problems.optimum(spec["dataset"]),
        "F_chordal_star": problems.chordal_optimum(spec["dataset"]),
        "wall_s": time.perf_counter() - start,
    }


def compute(spec: Spec) -> dict[str, Any]:
    """An optimum (``experiment`` "optimum") or a table cell: what every executor runs."""
    return compute_optimum(spec) if spec["experiment"] == "optimum" else compute_cell(spec)


def compute_cell(spec: Spec) -> dict[str, Any]:
    """Run one method on one split dataset and measure it (a refining method starts from the
    refined method's cell: :mod:`popbench.harness.refining`)."""
    problem = problems.distributed_problem(
        spec["dataset"], spec["robots"], spec["init"], spec["partition"], spec["seed"]
    )
    budget = Budget(iterations=spec["iterations"])
    options: dict[str, Any] = {"seed": spec["seed"]}
    if spec.get("training_seed", 0) != 0:  # seed 0's actor is the one the method loads itself
        record = METHODS[spec["method"]]
        options["checkpoint"] = str(record.checkpoint_path(spec["training_seed"]))
    result = solve_cell(spec, problem, budget, options, cell_row)
    return cell_row(spec, problem, result)


def cell_row(spec: Spec, problem: DistributedProblem, result: Result) -> dict[str, Any]:
    """The table row of ``result``, ``spec``'s method run on ``problem``."""
    graph = problem.graph
    return {
        "dataset": spec["dataset"],
        "poses": graph.num_poses,
        "edges": graph.num_edges,
        "robots": spec["robots"],
        "method": spec["method"],
        "init": spec["init"],
        "seed": spec["seed"],
        "training_seed": spec.get("training_seed"),  # None: not a learned method
        **result.summary(),
        # the convergence profile (popbench.harness.profiles.HISTORY_FIELDS)
        "history": result.history.tolist(),
        "history_s": None if result.history_s is None else result.history_s.tolist(),
        "history_objective": result.history_objective,
    }


def run_table1(config: Table1Config, run: Run | None = None) -> pd.DataFrame:
    """Compute (or reuse) the optima and every cell as ``run`` says (default: serially in this
    process; :func:`popbench.harness.runner.run_experiment`), then write ``table1.csv``,
    ``table1.md``, ``table1.tex``, ``table1.png``/``.pdf``, the convergence profiles
    ``profile-DATASET-nN.png``/``.pdf`` (:mod:`popbench.harness.profiles`) and
    ``manifest.json`` into ``config.out``.

    Every dataset is loaded and every team size checked against its poses before anything is
    computed (:func:`popbench.harness.problems.check_inputs`).
    """

    def cells() -> list[Spec]:
        problems.check_inputs(config.datasets, config.robots)
        check_training_seeds(config)
        return [*(optimum_spec(d) for d in config.datasets), *cell_specs(config)]

    write = functools.partial(write_table1, config)
    return run_experiment(config.out, cells, compute, write, run)


def write_table1(config: Table1Config, computed: list[Row]) -> pd.DataFrame:
    """Table I of the optima's and the cells' rows (in :func:`run_table1`'s order), written
    into ``config.out``."""
    optima = {row["dataset"]: row for row in computed[: len(config.datasets)]}
    rows = computed[len(config.datasets) :]
    frame = pd.DataFrame(rows)
    frame["F_star"] = frame["dataset"].map(lambda dataset: optima[dataset]["F_star"])
    frame["gap"] = frame["F"] / frame["F_star"] - 1.0
    frame["F_chordal_star"] = frame["dataset"].map(
        lambda dataset: optima[dataset].get("F_chordal_star", float("nan"))
    )
    frame = pd.concat([frame, profiles.time_to_gap_columns(rows, optima)], axis=1)
    paper = [
        paper_table1_cell(d, n, m)
        for d, n, m in zip(frame["dataset"], frame["robots"], frame["method"], strict=True)
    ]
    frame["paper_F"] = [cell[0] if cell else float("nan") for cell in paper]
    frame["paper_time_s"] = [cell[1] if cell else float("nan") for cell in paper]
    columns = [
        "dataset",
        "poses",
        "edges",
        "robots",
        "method",
        "init",
        "F",
        "F_chordal",
        "chi2",
        "F_star",
        "F_chordal_star",
        "gap",
        "wall_s",
        "parallel_s",
        "iterations",
        "messages",
        "seed",
        "training_seed",
        "paper_F",
        "paper_time_s",
        *GAP_COLUMNS,
    ]
    frame = frame[columns]
    frame.to_csv(config.out / "table1.csv", index=False, float_format="%.10g")
    (config.out / "table1.md").write_text(reports.table1_markdown(frame))
    (config.out / "table1.tex").write_text(reports.table1_latex(frame))
    reports.table1_figure(frame, config.out / "table1")
    profiles.profile_figures(rows, optima, config.out)
    return frame
