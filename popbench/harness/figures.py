"""Trajectory plots (the paper's Fig. 4) and learning curves from training CSVs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from popbench.errors import ValueRangeError
from popbench.harness import problems
from popbench.harness.plotting import pyplot, save_figure
from popbench.methods import Budget, get_method


def plot_trajectories(
    dataset: str,
    robots: int,
    methods: tuple[str, ...],
    out: Path,
    iterations: int = 1000,
    init: str = "odometry",
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


def read_metrics(path: Path, x: str = "frames") -> pd.DataFrame:
    """A training metrics CSV (``popbench train`` writes ``OUT/metrics.csv``) with an ``x`` column
    and at least one other numeric column."""
    expected = f"a training metrics CSV with a '{x}' column and another numeric column"
    try:
        frame = pd.read_csv(path)
    except (ValueError, UnicodeDecodeError) as error:  # pandas' ParserError is a ValueError
        raise ValueRangeError("CSV file", str(path), expected) from error
    numeric = set(frame.select_dtypes("number").columns)
    if x not in frame or not numeric - {x}:
        raise ValueRangeError("CSV file", str(path), expected)
    return frame


def line_labels(paths: list[Path]) -> list[str]:
    """One distinct name per file: its stem, or where two stems are equal (runs' metrics.csv)
    the folder that holds it, or else the whole path; a file given twice is a one-line
    ``ValueRangeError``."""
    resolved = [path.resolve() for path in paths]
    twice = [str(path) for path, r in zip(paths, resolved, strict=True) if resolved.count(r) > 1]
    if twice:
        raise ValueRangeError("training CSVs", twice[0], "each file once")
    for name in (lambda p: p.stem, lambda p: p.parent.name):
        labels = [name(path) for path in paths]
        if len(set(labels)) == len(labels):
            return labels
    return [str(path) for path in resolved]


def plot_learning_curves(
    csv_paths: list[Path], out: Path, x: str = "frames", columns: tuple[str, ...] | None = None
) -> list[Path]:
    """The training CSVs' ``columns`` (default: every numeric column) against ``x``, one panel
    per column, one line per file; PNG + PDF (``out.png``, ``out.pdf``). A file that is not such
    a CSV is a one-line ``ValueRangeError``. ``popbench train`` draws its run's curve with it.
    Each line is named by :func:`line_labels`."""
    frames = {
        label: read_metrics(path, x)
        for label, path in zip(line_labels(csv_paths), csv_paths, strict=True)
    }
    plt = pyplot()
    if columns is None:
        columns = tuple(
            sorted(
                {c for f in frames.values() for c in f.select_dtypes("number").columns if c != x}
            )
        )
    fig, axes = plt.subplots(1, len(columns), figsize=(4 * len(columns), 3.4), squeeze=False)
    for ax, column in zip(axes[0], columns, strict=True):
        for label, frame in frames.items():
            if column in frame and x in frame:
                points = frame[[x, column]].dropna()
                ax.plot(points[x], points[column], ".-", ms=3, label=label)
        ax.set_xlabel(x)
        ax.set_title(column, fontsize="small")
    axes[0, 0].legend(fontsize="small")
    fig.tight_layout()
    return save_figure(fig, out)
