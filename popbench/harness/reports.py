"""Paper-ready tables (markdown, LaTeX) and figures from the harness's long-format frames.

Table cells read ``ours (paper)``; the best of our methods per dataset and team size is bold.
Values are means over seeds (and over a learned method's training seeds); where a cell has
several, F and the gap read ``mean ± half-width`` of the 95 % Student-t interval.
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd

from popbench.harness.paper import paper_table1_cell
from popbench.harness.profiles import THRESHOLDS, gap_column
from popbench.methods import METHODS
from popbench.methods import label as method_label
from popbench.metrics import mean_ci
from popbench.plotting import pyplot, save_figure

# (row label, our column, paper index in (F, time), lower is better)
_TABLE1_METRICS = (
    ("F", "F", 0),
    ("gap F/F*−1", "gap", None),
    ("parallel [s]", "parallel_s", 1),
    ("wall [s]", "wall_s", None),
    *((f"t(gap≤{t:g}) [s]", gap_column(t), None) for t in THRESHOLDS),
)


_SPREAD_COLUMNS = ("F", "gap")  # shown as mean ± half-width where a cell has several values


def number(value: float) -> str:
    """Four significant digits; ``–`` for a missing value."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "–"
    return f"{value:.4g}"


def _ordered(values: pd.Series, order: tuple[str, ...] | list) -> list:
    present = list(dict.fromkeys(values))
    return [v for v in order if v in present] + [v for v in present if v not in order]


def _table1_grid(frame: pd.DataFrame, bold: tuple[str, str]) -> list[list[str]]:
    """Rows of cell strings: header rows, then (dataset, metric) rows."""
    groups = frame.groupby(["dataset", "robots", "method"], sort=False)
    means = groups.mean(numeric_only=True)
    spreads = {column: groups[column].agg(lambda v: mean_ci(v)[1]) for column in _SPREAD_COLUMNS}
    datasets = _ordered(frame["dataset"], ())
    robots = sorted(frame["robots"].unique())
    methods = _ordered(frame["method"], list(METHODS))
    header = ["Dataset (poses, edges)", "Metric"] + [
        f"n={n} {method_label(m)}" for n in robots for m in methods
    ]
    grid = [header]
    for dataset in datasets:
        poses = int(frame.loc[frame["dataset"] == dataset, "poses"].iloc[0])
        edges = int(frame.loc[frame["dataset"] == dataset, "edges"].iloc[0])
        for label, column, paper_index in (m for m in _TABLE1_METRICS if m[1] in means):
            row = [f"{dataset} ({poses}, {edges})", label]
            for n in robots:
                values = {m: means[column].get((dataset, n, m), float("nan")) for m in methods}
                finite = [v for v in values.values() if not math.isnan(v)]
                best = min(finite) if finite else None
                for m in methods:
                    text = number(values[m])
                    if best is not None and values[m] == best and len(finite) > 1:
                        text = bold[0] + text + bold[1]
                    spread = spreads[column].get((dataset, n, m)) if column in spreads else None
                    if spread is not None and not math.isnan(spread):
                        text += f" ± {number(spread)}"
                    paper = paper_table1_cell(dataset, int(n), m)
                    if paper_index is not None and paper is not None:
                        text += f" ({number(paper[paper_index])})"
                    row.append(text)
            grid.append(row)
    return grid


def table1_markdown(frame: pd.DataFrame) -> str:
    """Table I as markdown: our value with the paper's in parentheses; bold = best of ours."""
    grid = _table1_grid(frame, ("**", "**"))
    lines = ["| " + " | ".join(grid[0]) + " |", "|" + "---|" * len(grid[0])]
    lines += ["| " + " | ".join(row) + " |" for row in grid[1:]]
    init = ", ".join(sorted(frame["init"].unique()))
    note = (
        f"\nInitial estimate: {init}. Cells: ours (paper). F is eq. 1 with κ/τ weights; F* is "
        "the project's LM optimum from chordal initialisation; parallel = simulated makespan; "
        "t(gap≤g) = the parallel time of the first round whose relative gap is at most g (of F "
        "against F*, or of F_chordal against F_chordal* for the methods whose history records "
        "F_chordal: cc-pgo, ml-pgo, mm-pgo), – where never reached. Bold: best of our methods "
        "per dataset and team size (by the mean). A cell with several seeds (or a learned "
        "method's training seeds) reads mean ± the half-width of its 95 % Student-t interval "
        "in F and the gap.\n"
    )
    return "\n".join(lines) + "\n" + note


def _latex_escape(text: str) -> str:
    return (
        text.replace("≤", r"$\le$")
        .replace("%", r"\%")
        .replace("_", r"\_")
        .replace("−", "$-$")
        .replace("*", "$^*$")
    )


def table1_latex(frame: pd.DataFrame) -> str:
    """Table I as a LaTeX ``tabular`` (booktabs); bold = best of ours."""
    grid = _table1_grid(frame, (r"\textbf{", "}"))
    columns = "ll" + "r" * (len(grid[0]) - 2)
    body = [
        " & ".join(
            _latex_escape(cell) if k < 2 else cell.replace("−", "$-$") for k, cell in enumerate(row)
        )
        + r" \\"
        for row in grid[1:]
    ]
    return "\n".join(
        [
            r"% Table I: ours (paper). Generated by popbench run table1.",
            r"\begin{tabular}{" + columns + "}",
            r"\toprule",
            " & ".join(_latex_escape(cell) for cell in grid[0]) + r" \\",
            r"\midrule",
            *body,
            r"\bottomrule",
            r"\end{tabular}",
            "",
        ]
    )


GAP_FLOOR = 1e-6  # figure floor of F/F* − 1 and of times: "converged" / "instant"


def table1_figure(frame: pd.DataFrame, stem: Path) -> list[Path]:
    """Per dataset: the gap F/F*−1 (top) and parallel time (bottom) per method and team size;
    written as ``stem.png`` and ``stem.pdf``. Gaps below ``GAP_FLOOR`` (converged to F*) are
    drawn at the floor, on a log axis."""
    plt = pyplot()

    means = frame.groupby(["dataset", "robots", "method"], sort=False).mean(numeric_only=True)
    datasets = _ordered(frame["dataset"], ())
    robots = sorted(frame["robots"].unique())
    methods = _ordered(frame["method"], list(METHODS))
    fig, axes = plt.subplots(2, len(datasets), figsize=(3.2 * len(datasets), 5.5), squeeze=False)
    width = 0.8 / max(len(methods), 1)
    for col, dataset in enumerate(datasets):
        for row, (column, label) in enumerate((("gap", "F/F* − 1"), ("parallel_s", "time [s]"))):
            ax = axes[row, col]
            for k, method in enumerate(methods):
                heights = [means[column].get((dataset, n, method), float("nan")) for n in robots]
                positions = [i + (k - (len(methods) - 1) / 2) * width for i in range(len(robots))]
                ax.bar(
                    positions,
                    [max(h, GAP_FLOOR) for h in heights],
                    width,
                    label=method_label(method),
                )
            ax.set_yscale("log")
            ax.set_xticks(range(len(robots)), [f"n={n}" for n in robots])
            ax.set_ylabel(label if col == 0 else "")
            if row == 0:
                ax.set_title(dataset)
    axes[0, 0].legend(fontsize="small")
    fig.text(0.005, 0.005, f"gaps below {GAP_FLOOR:g} drawn at {GAP_FLOOR:g}", fontsize="small")
    fig.tight_layout()
    return save_figure(fig, stem)


# Table II's metrics: (header, column, paper column or None, shown for the reference method)
OUTLIER_METRICS = (
    ("F (inliers)", "F_inliers", "paper_F", True),
    ("gap to GNC", "gap_gnc", None, False),
    ("precision", "precision", "paper_precision", True),
    ("recall", "recall", "paper_recall", True),
    ("flagged", "flagged", None, True),
)
OUTLIER_REFERENCE = "gnc"  # the robust reference: Table II's F floor (gap_gnc)
# A score with nothing to divide by is undefined: precision where nothing was flagged, recall
# where nothing was to be found. (score, the count column whose zero makes it undefined)
UNDEFINED_WHEN_ZERO = (("precision", "flagged"), ("recall", "outliers"))


def defined_scores(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with precision NaN where ``flagged`` is 0 and recall NaN where ``outliers`` is
    0, and the bool columns ``precision_undefined``, ``recall_undefined`` marking them. Cells
    written before they were NaN there hold 1 (:func:`popbench.outliers.precision_recall`'s
    convention), so the counts decide, not the value."""
    frame = frame.copy()
    for score, count in UNDEFINED_WHEN_ZERO:
        undefined = (frame[count] == 0) if count in frame else pd.Series(False, frame.index)
        frame[f"{score}_undefined"] = undefined
        frame.loc[undefined, score] = math.nan
    return frame


def outliers_summary(frame: pd.DataFrame) -> pd.DataFrame:
    """Table II's cells: per (dataset, rate, method), over seeds, the mean and the half-width
    of the 95 % Student-t interval (``NAME`` and ``NAME_ci95``) of ``F_inliers``, ``gap_gnc``,
    ``precision``, ``recall``, ``flagged`` (candidate edges flagged) and ``F`` (every edge), with
    the options the method ran with, the seed count, the mean number of outliers and the
    paper's values. Precision and recall are averaged over the seeds where they are defined
    (:func:`defined_scores`); ``precision_undefined`` and ``recall_undefined`` count the
    others. Methods in the order they first appear."""
    summary = []
    frame = defined_scores(frame)
    for (dataset, rate, method), group in frame.groupby(["dataset", "rate", "method"], sort=False):
        row = {
            "dataset": dataset,
            "rate": rate,
            "method": method,
            "options": group["options"].fillna("").iloc[0] if "options" in group else "",
            "seeds": group["seed"].nunique(),
            "outliers": float(group["outliers"].mean()) if "outliers" in group else math.nan,
        }
        for column in ("F_inliers", "gap_gnc", "precision", "recall", "flagged", "F"):
            values = group[column] if column in group else pd.Series(dtype=float)
            row[column], row[f"{column}_ci95"] = mean_ci(values.to_numpy(dtype=float))
        for score, _ in UNDEFINED_WHEN_ZERO:
            row[f"{score}_undefined"] = int(group[f"{score}_undefined"].sum())
        for column in ("paper_F", "paper_precision", "paper_recall"):
            row[column] = float(group[column].iloc[0]) if column in group else math.nan
        summary.append(row)
    return pd.DataFrame(summary)


def _method_header(method: str, options: str) -> str:
    """``MM-PGO (huber, authors)``: the label and the values of the options it ran with."""
    values = [part.partition("=")[2] for part in options.split(", ") if part]
    return method_label(method) + (f" ({', '.join(values)})" if values else "")


def _outliers_grid(summary: pd.DataFrame) -> list[list[str]]:
    """Rows of cells: per (dataset, rate), each metric of :data:`OUTLIER_METRICS` per method,
    ``mean ± 95 % half-width [undefined k/K] (paper)``: ``–`` where no seed has a value, the
    bracket where ``k`` of the ``K`` seeds have an undefined score."""
    methods = _ordered(summary["method"], ())
    options = {m: summary.loc[summary["method"] == m, "options"].iloc[0] for m in methods}
    columns = [
        (header, column, paper, m)
        for header, column, paper, reference in OUTLIER_METRICS
        for m in methods
        if reference or m != OUTLIER_REFERENCE
    ]
    grid = [
        ["Dataset", "%", "outliers"]
        + [f"{h} {_method_header(m, options[m])}" for h, _, _, m in columns]
    ]
    for (dataset, rate), group in summary.groupby(["dataset", "rate"], sort=False):
        row = [str(dataset), f"{100 * rate:g}", number(float(group["outliers"].mean()))]
        for _, column, paper, method in columns:
            cell = group[group["method"] == method]
            undefined = (
                int(cell[f"{column}_undefined"].iloc[0])
                if not cell.empty and (f"{column}_undefined" in cell)
                else 0
            )
            if cell.empty or (math.isnan(cell[column].iloc[0]) and not undefined):
                row.append("–")
                continue
            text = number(float(cell[column].iloc[0]))
            if not math.isnan(cell[f"{column}_ci95"].iloc[0]):
                text += f" ± {number(float(cell[f'{column}_ci95'].iloc[0]))}"
            if undefined:
                text += f" [undefined {undefined}/{int(cell['seeds'].iloc[0])}]"
            if paper is not None and not math.isnan(cell[paper].iloc[0]):
                text += f" ({number(float(cell[paper].iloc[0]))})"
            row.append(text)
        grid.append(row)
    return grid


OUTLIERS_NOTE = (
    "Mean ± half-width of the 95 % Student-t interval over {seeds} seed(s); the paper's value in "
    "parentheses. F (inliers) = eq. 1 over the edges that were not corrupted (the paper does not "
    "say which edges its F sums); gap to GNC = F (inliers) / GNC's F (inliers) of the same "
    "problem − 1. Precision and recall score the edges a method flags as outliers against the "
    "injected ones, over the corrupted candidate set's edges ({candidates}); flagged = candidate "
    "edges flagged; outliers = injected per problem. Precision is undefined where a method "
    "flags nothing, recall where there is no outlier: such a seed is left out of the mean and "
    "counted in [undefined k/K] (– where no seed has a value). Outlier model: {model}."
)
OUTLIER_MODEL_NOTES = {
    "corrupt": "corrupt (existing loop closures' measurements replaced, popbench.outliers)",
    "vertigo-random": "vertigo-random (false loop closures added between random poses)",
    "vertigo-local": "vertigo-local (false loop closures added between poses 2 to 20 apart)",
    "vertigo-grouped": "vertigo-grouped (groups of {group_size} mutually consistent false loop "
    "closures added)",
    "mask": "mask (the dataset's own false loop closures, named by a mask file)",
}


def outliers_markdown(frame: pd.DataFrame) -> str:
    """Table II as markdown (:func:`outliers_summary`): ``mean ± 95 % half-width (paper)``."""
    grid = _outliers_grid(outliers_summary(frame))
    lines = ["| " + " | ".join(grid[0]) + " |", "|" + "---|" * len(grid[0])]
    lines += ["| " + " | ".join(row) + " |" for row in grid[1:]]
    note = OUTLIERS_NOTE.format(
        seeds=frame["seed"].nunique(), candidates=_candidates(frame), model=_model(frame)
    )
    return "\n".join(lines) + "\n\n" + note + "\n"


def _candidates(frame: pd.DataFrame) -> str:
    return ", ".join(sorted(frame["candidates"].unique())) if "candidates" in frame else "loops"


def _model(frame: pd.DataFrame) -> str:
    """The note on the frame's outlier model(s); ``corrupt`` for frames without the column."""
    if "model" not in frame:
        return OUTLIER_MODEL_NOTES["corrupt"]
    pairs = frame[["model", "group_size"]].drop_duplicates().itertuples(index=False)
    return "; ".join(
        OUTLIER_MODEL_NOTES[model].format(group_size=int(size)) for model, size in pairs
    )


def outliers_latex(frame: pd.DataFrame) -> str:
    """Table II as a LaTeX ``tabular`` (booktabs), the cells of :func:`outliers_markdown`."""
    grid = _outliers_grid(outliers_summary(frame))
    columns = "lr" + "r" * (len(grid[0]) - 2)

    def line(row: list[str]) -> str:
        return " & ".join(_latex_escape(c).replace("±", r"$\pm$") for c in row) + r" \\"

    return "\n".join(
        [
            r"% Table II: mean ± 95 % half-width over seeds (paper). Generated by popbench.",
            r"\begin{tabular}{" + columns + "}",
            r"\toprule",
            line(grid[0]),
            r"\midrule",
            *[line(row) for row in grid[1:]],
            r"\bottomrule",
            r"\end{tabular}",
            "",
        ]
    )
