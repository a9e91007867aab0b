"""The paper's Fig. 5: F and time against the team size n with replicated actors.

The paper does not name its dataset; ours defaults to m3500 (3500 poses: 50 per robot at
n = 70). Cells are Table I cells (same problem construction, same measurements).
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

import pandas as pd

from popbench.harness import defaults, problems, table1
from popbench.harness.executors import Row, Run, Spec
from popbench.harness.profiles import HISTORY_FIELDS
from popbench.harness.runner import run_experiment
from popbench.plotting import pyplot, save_figure

ROBOTS, METHODS = defaults.SCALABILITY_ROBOTS, defaults.SCALABILITY_METHODS


@dataclasses.dataclass(frozen=True)
class ScalabilityConfig:
    """What ``popbench run scalability`` computes."""

    dataset: str = defaults.SCALABILITY_DATASET
    robots: tuple[int, ...] = ROBOTS
    methods: tuple[str, ...] = METHODS
    iterations: int = defaults.ITERATIONS
    seed: int = 0
    init: str = defaults.INIT
    partition: str = defaults.PARTITION
    out: Path = Path(defaults.SCALABILITY_OUT)


def cell_specs(config: ScalabilityConfig) -> list[Spec]:
    """Table I's cells of the dataset, one per team size and method, in that order."""
    return table1.cell_specs(
        table1.Table1Config(
            datasets=(config.dataset,),
            robots=config.robots,
            methods=config.methods,
            iterations=config.iterations,
            seeds=(config.seed,),
            init=config.init,
            partition=config.partition,
        )
    )


def run_scalability(config: ScalabilityConfig, run: Run | None = None) -> pd.DataFrame:
    """Compute (or reuse) the optimum and every cell as ``run`` says (default: serially in this
    process; :func:`popbench.harness.runner.run_experiment`); write ``scalability.csv``,
    ``scalability.png``/``.pdf`` and the manifest. The dataset and team sizes are checked
    first."""

    def cells() -> list[Spec]:
        problems.check_inputs((config.dataset,), config.robots)
        return [table1.optimum_spec(config.dataset), *cell_specs(config)]

    write = functools.partial(write_scalability, config)
    return run_experiment(config.out, cells, table1.compute, write, run)


def write_scalability(config: ScalabilityConfig, computed: list[Row]) -> pd.DataFrame:
    """The table of the optimum's and the cells' rows (in :func:`run_scalability`'s order) and
    its figure, written into ``config.out``."""
    optimum = computed[0]["F_star"]
    frame = pd.DataFrame(computed[1:]).drop(columns=list(HISTORY_FIELDS), errors="ignore")
    frame["F_star"] = optimum
    frame["gap"] = frame["F"] / optimum - 1.0
    frame.to_csv(config.out / "scalability.csv", index=False, float_format="%.10g")
    scalability_figure(frame, config.out / "scalability")
    return frame


def scalability_figure(frame: pd.DataFrame, stem: Path) -> list[Path]:
    """F (left) and parallel time (right) against n, one line per method; PNG and PDF."""
    plt = pyplot()

    fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.6))
    for method, group in frame.groupby("method", sort=False):
        group = group.sort_values("robots")
        left.plot(group["robots"], group["F"], marker="o", label=method)
        right.plot(group["robots"], group["parallel_s"], marker="o", label=method)
    left.axhline(float(frame["F_star"].iloc[0]), color="k", linestyle="--", label="F*")
    for ax, label in ((left, "F"), (right, "parallel time [s]")):
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("robots n")
        ax.set_ylabel(label)
    left.legend(fontsize="small")
    left.set_title(f"{frame['dataset'].iloc[0]}: objective")
    right.set_title("time")
    fig.tight_layout()
    return save_figure(fig, stem)
