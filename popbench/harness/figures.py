"""Trajectory plots (the paper's Fig. 4); training CSVs' learning curves: popbench.plotting."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from popbench.harness import defaults, problems
from popbench.methods import Budget, get_method
from popbench.plotting import pyplot, save_figure


def plot_trajectories(
    dataset: str,
    robots: int,
    methods: tuple[str, ...],
    out: Path,
    iterations: int = 1000,
    init: str = defaults.INIT,
) -> list[Path]:
    """One panel per estimate (initial, then each method), one colour per robot; PNG + PDF."""
    plt = pyplot()
    problem = problems.distributed_problem(dataset, robots, init)
    estimates = [(f"initial ({init})", problem.graph.poses)]
    for method in methods:
        result = get_method(method)(problem, Budget(iterations=iterations))
        estimates.append((f"{method}: F = {result.F:.4g}", result.poses))
    fig, axes = plt.subplots(1, len(estimates), figsize=(4 * len(estimates), 4), squeeze=False)
    colours = plt.get_cmap("tab10" if robots <= 10 else "turbo")(
        np.linspace(0, 1, robots) if robots > 10 else np.arange(robots)
    )
    for ax, (title, poses) in zip(axes[0], estimates, strict=True):
        for robot in range(robots):
            owned = problem.owned(robot)
            ax.plot(poses[owned, 0], poses[owned, 1], ".", markersize=1.5, color=colours[robot])
        ax.set_title(title, fontsize="small")
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{dataset}, n = {robots}")
    fig.tight_layout()
    return save_figure(fig, out)
