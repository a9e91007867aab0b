"""Final actors compared on the normalised score (popbench.harness.scores), held-out problems as
tasks: rliable's interquartile mean, probabilities of improvement and performance profiles
(popbench.harness.stratified), as ``popbench plot curves`` writes them.

The input is one record per (algorithm, start, seed, problem) with its ``score``. For each
(algorithm, start), the score matrix is ``(seeds, problems)``; every run of one start must hold
the same problems. :func:`iqm_table` gives each (algorithm, start)'s IQM, :func:`improvement_table`
P(A > B) for every pair of algorithms of one start (A after B in name order), each with two 95 %
intervals: ``runs`` (rliable's stratified bootstrap) and ``seeds`` (the seeds drawn once for all
problems, the problems drawn too; wider). A difference is called real when the ``seeds``
interval of P excludes ½, and one that holds for these runs only when only the ``runs`` interval
does. P compares the runs of a problem with each other, so it does not depend on the
normalisation (any increasing map of a problem's scores gives the same P); the IQM and the
profiles do.
"""

from __future__ import annotations

from itertools import combinations
from pathlib import Path

import numpy as np
import pandas as pd

from popbench.harness import stratified
from popbench.harness.stratified import SCHEMES
from popbench.plotting import pyplot, save_figure

REPS = 2000
TAUS = np.linspace(-0.5, 1.0, 151)  # the profiles' thresholds on the score


def score_matrix(final: pd.DataFrame) -> np.ndarray:
    """The ``(seeds, problems)`` scores of one (algorithm, start)'s records, problems in seed
    order."""
    return final.pivot(index="seed", columns="problem_seed", values="score").to_numpy()


def _intervals(statistic, *matrices: np.ndarray) -> dict[str, float]:
    row: dict[str, float] = {}
    for scheme in SCHEMES:
        value, low, high = stratified.interval(statistic, *matrices, reps=REPS, scheme=scheme)
        row |= {"value": float(value), f"lo_{scheme}": float(low), f"hi_{scheme}": float(high)}
    return row


def iqm_table(final: pd.DataFrame) -> pd.DataFrame:
    """Per (algorithm, start): seeds, problems, the IQM of the score and its intervals."""
    rows = []
    for (algorithm, start), group in final.groupby(["algorithm", "start"], sort=True):
        matrix = score_matrix(group)
        rows.append(
            {
                "algorithm": algorithm,
                "start": start,
                "seeds": matrix.shape[0],
                "problems": matrix.shape[1],
                **_intervals(stratified.iqm, matrix),
            }
        )
    return pd.DataFrame(rows)


def improvement_table(final: pd.DataFrame) -> pd.DataFrame:
    """Per start and pair (A, B) of its algorithms: P(A > B) with its intervals and ``real``
    (module docstring: "yes", "these runs" or "no")."""
    rows = []
    for start, runs in final.groupby("start", sort=True):
        matrices = {name: score_matrix(group) for name, group in runs.groupby("algorithm")}
        for b, a in combinations(sorted(matrices), 2):
            row = {
                "start": start,
                "a": a,
                "b": b,
                **_intervals(stratified.improvement, *[matrices[a], matrices[b]]),
            }
            outside = {s: not row[f"lo_{s}"] <= 0.5 <= row[f"hi_{s}"] for s in SCHEMES}
            row["real"] = "yes" if outside["seeds"] else "these runs" if outside["runs"] else "no"
            rows.append(row)
    columns = ["start", "a", "b", "value", *(f"{e}_{s}" for s in SCHEMES for e in ("lo", "hi"))]
    return pd.DataFrame(rows, columns=[*columns, "real"])


def markdown(iqms: pd.DataFrame, improvements: pd.DataFrame) -> str:
    """The two tables as markdown."""

    def cell(row: pd.Series, scheme: str) -> str:
        return f"[{row[f'lo_{scheme}']:.3f}, {row[f'hi_{scheme}']:.3f}]"

    lines = [
        "Normalised score (0 at gn-sweep, 1 at the problem's optimum F*), held-out problems as "
        "tasks: interquartile mean over (seed, problem) [95 % stratified-bootstrap interval: "
        "runs | seeds].",
        "",
        "| algorithm | start | seeds | problems | IQM score | runs | seeds |",
        "|---|---|---:|---:|---:|---|---|",
    ]
    for _, row in iqms.iterrows():
        lines.append(
            f"| {row.algorithm} | {row.start} | {row.seeds} | {row.problems} "
            f"| {row.value:.3f} | {cell(row, 'runs')} | {cell(row, 'seeds')} |"
        )
    lines += [
        "",
        "Probability of improvement P(A > B) (per problem, the share of seed pairs where A's F "
        "is lower; mean over problems) [95 % intervals: runs | seeds]; real: the seeds interval "
        'excludes 0.5 ("these runs": only the runs interval does).',
        "",
        "| start | P(A > B) | value | runs | seeds | real |",
        "|---|---|---:|---|---|---|",
    ]
    for _, row in improvements.iterrows():
        lines.append(
            f"| {row.start} | P({row.a} > {row.b}) | {row.value:.3f} | {cell(row, 'runs')} "
            f"| {cell(row, 'seeds')} | {row.real} |"
        )
    return "\n".join(lines) + "\n"


def plot_comparison(final: pd.DataFrame, improvements: pd.DataFrame, out: Path) -> list[Path]:
    """One row per start: the performance profiles (share of (seed, problem) scores above τ,
    with the runs-bootstrap band) and P(A > B) with both intervals. PNG + PDF."""
    plt = pyplot()
    starts = sorted(final["start"].unique())
    fig, axes = plt.subplots(len(starts), 2, figsize=(10, 3.4 * len(starts)), squeeze=False)
    algorithms = sorted(final["algorithm"].unique())
    colours = {name: plt.get_cmap("tab10")(i) for i, name in enumerate(algorithms)}
    for (left, right), start in zip(axes, starts, strict=True):
        for algorithm, group in final[final["start"] == start].groupby("algorithm"):
            matrix = score_matrix(group)
            _, low, high = stratified.interval(
                lambda m: stratified.profile(m, TAUS), matrix, reps=REPS
            )
            colour = colours[algorithm]
            left.plot(TAUS, stratified.profile(matrix, TAUS), color=colour, label=algorithm)
            left.fill_between(TAUS, low, high, color=colour, alpha=0.2, linewidth=0)
        left.set_xlabel("normalised score τ")
        left.set_ylabel("fraction of runs × problems > τ")
        left.set_title(f"from {start}: performance profiles", fontsize="small")
        left.legend(fontsize="x-small")
        pairs = improvements[improvements["start"] == start].reset_index(drop=True)
        for y, row in pairs.iterrows():
            right.plot([row.lo_seeds, row.hi_seeds], [y, y], color="0.7", linewidth=6)
            right.plot([row.lo_runs, row.hi_runs], [y, y], color="C0", linewidth=3)
            right.plot([row.value], [y], "k|", markersize=12)
        right.axvline(0.5, color="0.4", linewidth=1, dashes=(2, 2))
        right.set_yticks(range(len(pairs)), [f"P({r.a} > {r.b})" for r in pairs.itertuples()])
        right.set_xlim(0, 1)
        right.set_title(f"from {start}: P(A > B), runs (blue) | seeds (grey)", fontsize="small")
    fig.suptitle(
        "Final actors, held-out problems as tasks (95 % bootstrap intervals)", fontsize="small"
    )
    fig.tight_layout()
    return save_figure(fig, out)
