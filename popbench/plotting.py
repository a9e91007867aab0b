"""Matplotlib, imported lazily (a slow import) with a file-only backend, one way to save, and the
learning curves of a training log (``popbench train``'s ``metrics.csv``, ``popbench plot
learning-curves``): core, so that the harness, the command line and ``agents`` share them."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from popbench.errors import ValueRangeError

if TYPE_CHECKING:
    import pandas as pd


def pyplot() -> Any:
    """``matplotlib.pyplot`` on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig: Any, stem: Path) -> list[Path]:
    """Write ``fig`` as ``stem.png`` (150 dpi) and ``stem.pdf``, close it, return the paths."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = [stem.with_suffix(".png"), stem.with_suffix(".pdf")]
    for path in paths:
        fig.savefig(path, dpi=150)
    pyplot().close(fig)
    return paths


def read_metrics(path: Path, x: str = "frames") -> pd.DataFrame:
    """A training metrics CSV (``popbench train`` writes ``OUT/metrics.csv``) with an ``x`` column
    and at least one other numeric column."""
    import pandas as pd

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
