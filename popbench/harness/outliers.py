"""The paper's Table II: F, outlier precision and recall with corrupted loop closures.

For each dataset, rate and seed, outliers are made by the ``model`` (:mod:`popbench.outliers`):

* ``corrupt`` (default, the paper's): a fraction of the candidate edges of the split dataset
  (the loop closures by default, ``candidates="paper"`` adds the cut odometry edges) is
  corrupted (:func:`popbench.outliers.inject_outliers`);
* ``vertigo-random | vertigo-local | vertigo-grouped``: false loop closures are added to the
  dataset's graph (:func:`popbench.outliers.add_false_loop_closures`, ``rate`` = added edges
  as a fraction of its loop closures), which is then split among the robots (METIS of the graph
  with the false edges: the team splits the graph it is given);
* ``mask``: the dataset already holds false loop closures, named by a mask file
  (``outlier_mask``, :func:`popbench.outliers.read_outlier_mask`); ``rate`` is then the marked
  edges as a fraction of the other loop closures.

The initial estimate is then made from the *corrupted* measurements, as a real system would.
Each method's ``inlier_mask`` is scored against the outlier mask over the candidate set's edges
(the loop closures, for every model but ``corrupt`` with ``candidates="paper"``).

The table (:mod:`popbench.harness.reports`, :func:`~popbench.harness.reports.outliers_summary`)
reports per (dataset, rate, method) the mean and 95 % Student-t half-width over seeds of
``F_inliers`` (eq. 1 over the edges that were not corrupted: what a rejected outlier costs is not
counted, a fitted one distorts the inliers), ``gap_gnc`` (``F_inliers`` over the robust reference
``gnc``'s on the same problem, − 1), precision and recall; ``outliers.csv`` keeps every cell
(with ``F`` over every edge), ``outliers_summary.csv`` the table's numbers.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from popbench.datasets import file_sha256
from popbench.errors import ValueRangeError
from popbench.harness import defaults, problems, reports
from popbench.harness.cache import grid_specs
from popbench.harness.executors import Row, Run, Spec
from popbench.harness.paper import paper_table2_cell
from popbench.harness.runner import run_experiment
from popbench.methods import Budget, get_method, method_options, method_record, named_path
from popbench.objective import objective
from popbench.outliers import (
    CORRUPT,
    DEFAULT_GROUP_SIZE,
    add_false_loop_closures,
    candidate_mask,
    inject_outliers,
    precision_recall,
    read_outlier_mask,
)
from popbench.problems.distributed import DistributedProblem
from popbench.solvers.initial import with_start

DATASETS, METHODS = defaults.OUTLIERS_DATASETS, defaults.OUTLIERS_METHODS
MASK = "mask"  # the model of a dataset whose false loop closures a mask file names


@dataclasses.dataclass(frozen=True)
class OutliersConfig:
    """What ``popbench run outliers`` computes."""

    datasets: tuple[str, ...] = DATASETS
    rates: tuple[float, ...] = defaults.OUTLIERS_RATES
    methods: tuple[str, ...] = METHODS
    robots: int = defaults.OUTLIERS_ROBOTS
    seeds: tuple[int, ...] = defaults.OUTLIERS_SEEDS
    iterations: int = defaults.ITERATIONS
    init: str = defaults.INIT
    kernel: str | None = None  # None: each method's registry record (outlier_options)
    candidates: str = "loops"
    model: str = CORRUPT  # popbench.outliers.OUTLIER_MODELS, or MASK (set by outlier_mask)
    group_size: int = DEFAULT_GROUP_SIZE  # vertigo-grouped only
    outlier_mask: Path | None = None  # a mask file: model MASK, one dataset, rates unused
    out: Path = Path(defaults.OUTLIERS_OUT)

    def __post_init__(self) -> None:
        if self.outlier_mask is not None:
            if len(self.datasets) != 1:
                raise ValueRangeError(
                    "--datasets with --outlier-mask", ",".join(self.datasets), "one dataset"
                )
            object.__setattr__(self, "model", MASK)
        if self.model != CORRUPT and self.candidates != "loops":
            raise ValueRangeError(
                f"--candidates with the model {self.model}", self.candidates, "loops"
            )


def cell_specs(config: OutliersConfig) -> list[Spec]:
    axes = {
        "dataset": config.datasets,
        "rate": config.rates if config.outlier_mask is None else (mask_rate(config),),
        "method": config.methods,
        "seed": config.seeds,
    }
    shared = {
        "robots": config.robots,
        "iterations": config.iterations,
        "init": config.init,
        "candidates": config.candidates,
        **model_options(config),
    }
    specs = grid_specs("outliers", axes, shared)
    for spec in specs:
        spec["options"] = method_outlier_options(spec["method"], config.kernel)
        if "checkpoint" in spec["options"]:  # Table II's actor: its file keys the cell
            spec["checkpoint_sha256"] = file_sha256(named_path(spec["options"]["checkpoint"]))
    return specs


def model_options(config: OutliersConfig) -> dict[str, Any]:
    """What a cell needs of the outlier model beyond today's keys (nothing for ``corrupt``, so
    its cells are specified as before): the model, the group size of ``vertigo-grouped``, the
    mask file and its sha256 (an edited mask recomputes the cells)."""
    if config.model == CORRUPT:
        return {}
    options: dict[str, Any] = {"model": config.model}
    if config.model == "vertigo-grouped":
        options["group_size"] = config.group_size
    if config.outlier_mask is not None:
        options["outlier_mask"] = str(config.outlier_mask.resolve())  # for worker processes
        options["outlier_mask_sha256"] = file_sha256(config.outlier_mask)
    return options


def mask_rate(config: OutliersConfig) -> float:
    """The mask's false loop closures as a fraction of the dataset's other loop closures."""
    graph = problems.load_graph(config.datasets[0])
    mask = read_outlier_mask(config.outlier_mask, graph.num_edges)
    loops = candidate_mask(graph, "loops")
    return float((mask & loops).sum() / max((~mask & loops).sum(), 1))


def method_outlier_options(method: str, kernel: str | None = None) -> dict[str, Any]:
    """The options Table II runs ``method`` with: its record's ``outlier_options``, the kernel
    replaced by ``kernel`` (when given, for a method with a ``kernel`` option)."""
    options = dict(method_record(method).outlier_options)
    if kernel is not None and "kernel" in method_options(method):
        options["kernel"] = kernel
    return options


def corrupted_problem(
    dataset: str,
    robots: int,
    rate: float,
    seed: int,
    init: str,
    candidates: str = "loops",
    model: str = CORRUPT,
    group_size: int = DEFAULT_GROUP_SIZE,
    outlier_mask: str | Path | None = None,
) -> DistributedProblem:
    """The split dataset with the outliers of ``model`` (module docstring; ``candidates`` for
    ``corrupt``, ``group_size`` for ``vertigo-grouped``, the mask file for ``mask``) and its
    ``init`` start made from them (:func:`popbench.solvers.initial.with_start`)."""
    if model == CORRUPT:
        clean = problems.distributed_problem(dataset, robots, "given")  # the file's poses
        graph, mask = inject_outliers(clean, rate, seed, candidates)
        return with_start(DistributedProblem(graph, "given", mask), init)
    if model == MASK:
        split = problems.distributed_problem(dataset, robots, "given")
        mask = read_outlier_mask(outlier_mask, split.graph.num_edges)
        return with_start(DistributedProblem(split.graph, "given", mask), init)
    graph, mask = add_false_loop_closures(
        problems.load_graph(dataset), rate, model, seed, group_size
    )
    split = DistributedProblem.from_graph(graph, robots, start="given", outlier_mask=mask)
    return with_start(split, init)


def compute_cell(spec: Spec) -> dict[str, Any]:
    candidates = spec.get("candidates", "loops")
    model = spec.get("model", CORRUPT)
    problem = corrupted_problem(
        spec["dataset"],
        spec["robots"],
        spec["rate"],
        spec["seed"],
        spec["init"],
        candidates,
        model,
        spec.get("group_size", DEFAULT_GROUP_SIZE),
        spec.get("outlier_mask"),
    )
    options: dict[str, Any] = {"seed": spec["seed"], **spec["options"]}
    if "checkpoint" in options:
        options["checkpoint"] = str(named_path(options["checkpoint"]))
    result = get_method(spec["method"])(problem, Budget(iterations=spec["iterations"]), **options)
    among = candidate_mask(problem.graph, candidates)
    outliers = int((problem.outlier_mask & among).sum())
    if result.inlier_mask is None:
        precision = recall = float("nan")
        flagged = flagged_other = None
    else:
        precision, recall = precision_recall(~result.inlier_mask, problem.outlier_mask, among)
        flagged = int((~result.inlier_mask & among).sum())
        flagged_other = int((~result.inlier_mask & ~among).sum())
        precision = precision if flagged else float("nan")  # undefined: nothing flagged
        recall = recall if outliers else float("nan")  # undefined: nothing to find
    return {
        "dataset": spec["dataset"],
        "rate": spec["rate"],
        "robots": spec["robots"],
        "method": spec["method"],
        "seed": spec["seed"],
        "init": spec["init"],
        "candidates": candidates,
        "model": model,
        "group_size": spec.get("group_size", 1),
        "options": ", ".join(f"{k}={v}" for k, v in spec["options"].items()),
        "outliers": outliers,
        "F": result.F,
        "F_inliers": objective(problem.graph.edge_subset(~problem.outlier_mask), result.poses),
        "F_chordal": result.F_chordal,
        "precision": precision,
        "recall": recall,
        "flagged": flagged,  # among the candidates (precision's denominator)
        "flagged_other": flagged_other,  # outside them: not scored
        "wall_s": result.wall_s,
        "parallel_s": result.parallel_s,
        "iterations": result.iterations,
    }


def run_outliers(config: OutliersConfig, run: Run | None = None) -> pd.DataFrame:
    """Compute (or reuse) every cell as ``run`` says (default: serially in this process;
    :func:`popbench.harness.runner.run_experiment`); write ``outliers.csv``, ``.md``, ``.tex``
    and the manifest. The datasets and team size are checked first."""

    def cells() -> list[Spec]:
        problems.check_inputs(config.datasets, (config.robots,))
        return cell_specs(config)

    write = functools.partial(write_outliers, config)
    return run_experiment(config.out, cells, compute_cell, write, run)


def gaps_to_reference(frame: pd.DataFrame) -> np.ndarray:
    """``F_inliers / F_inliers(gnc) − 1`` per row ``(len(frame),)``, against the reference's
    cell of the same dataset, rate and seed (NaN where it was not run)."""
    keys = ["dataset", "rate", "seed"]
    reference = frame[frame["method"] == reports.OUTLIER_REFERENCE].set_index(keys)["F_inliers"]
    matched = reference.reindex(pd.MultiIndex.from_frame(frame[keys])).to_numpy(dtype=float)
    return frame["F_inliers"].to_numpy(dtype=float) / matched - 1.0


def write_outliers(config: OutliersConfig, rows: list[Row]) -> pd.DataFrame:
    """Table II of the cells' rows beside the paper's numbers, written into ``config.out``."""
    frame = pd.DataFrame(rows)
    paper = [
        paper_table2_cell(d, r, m) if config.model == CORRUPT else None  # the paper's model only
        for d, r, m in zip(frame["dataset"], frame["rate"], frame["method"], strict=True)
    ]
    for k, name in enumerate(("paper_F", "paper_precision", "paper_recall")):
        frame[name] = [cell[k] if cell else float("nan") for cell in paper]
    frame["gap_gnc"] = gaps_to_reference(frame)
    frame.to_csv(config.out / "outliers.csv", index=False, float_format="%.10g")
    summary = reports.outliers_summary(frame)
    summary.to_csv(config.out / "outliers_summary.csv", index=False, float_format="%.10g")
    (config.out / "outliers.md").write_text(reports.outliers_markdown(frame))
    (config.out / "outliers.tex").write_text(reports.outliers_latex(frame))
    return frame
