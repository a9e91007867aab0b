"""Convergence profiles: the relative gap of a method's history against its simulated parallel
time, the time each cell needs to reach a given gap, and one figure per dataset.

A cell's row carries its method's ``history`` (the objective after each round), ``history_s``
(the cumulative simulated parallel time at each entry [s], the last entry the cell's
``parallel_s``) and ``history_objective`` (``"F"`` or ``"F_chordal"``,
:class:`popbench.methods.Result`). The relative gap of an entry is ``h / h* − 1`` with ``h*`` the
dataset's optimum *of that objective* (``F_star`` or ``F_chordal_star``, the optimum cell).

**Time to a gap** (:func:`time_to_gap`): the ``history_s`` of the *first* entry whose gap is at
or below the threshold — no interpolation between rounds, and a later rise above the threshold
(a restart) does not undo it. NaN when no entry reaches it, or when the row has no times.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from popbench.methods import METHODS
from popbench.methods import label as method_label
from popbench.plotting import pyplot, save_figure

THRESHOLDS = (1e-1, 1e-2, 1e-3)
PROFILE_ROBOTS = 7  # the team size of the figures (the largest in the table when absent)
HISTORY_FIELDS = ("history", "history_s", "history_objective")  # of a cell's row
GAP_FLOOR = 1e-9  # gaps below it (at the optimum, or below an uncertified one) are drawn here
OPTIMUM_COLUMNS = {"F": "F_star", "F_chordal": "F_chordal_star"}


def gap_column(threshold: float) -> str:
    """The table column of the time to ``threshold``: ``time_gap_1e-2_s`` for 0.01."""
    mantissa, exponent = f"{threshold:.0e}".split("e")
    return f"time_gap_{mantissa}e{int(exponent)}_s"


GAP_COLUMNS = tuple(gap_column(threshold) for threshold in THRESHOLDS)


def relative_gaps(history: Sequence[float], optimum: float) -> np.ndarray:
    """``(K,)`` relative gaps ``h / optimum − 1`` of a ``(K,)`` history (dimensionless)."""
    return np.asarray(history, dtype=np.float64) / optimum - 1.0


def time_to_gap(
    history: Sequence[float] | None,
    history_s: Sequence[float] | None,
    optimum: float,
    thresholds: Sequence[float] = THRESHOLDS,
) -> np.ndarray:
    """``(len(thresholds),)`` parallel times [s] at which ``history`` ``(K,)`` first reaches a
    relative gap ``≤`` each threshold (its ``history_s`` ``(K,)`` entry; module docstring); NaN
    where it never does, or where ``history`` or ``history_s`` is missing."""
    limits = np.asarray(thresholds, dtype=np.float64)
    if history is None or history_s is None or len(history) == 0:
        return np.full(limits.shape, np.nan)
    times = np.asarray(history_s, dtype=np.float64)
    reached = relative_gaps(history, optimum)[:, None] <= limits[None, :]  # (K, thresholds)
    first = np.argmax(reached, axis=0)
    return np.where(reached.any(axis=0), times[first], np.nan)


def _optimum(row: Mapping[str, Any], optima: Mapping[str, Mapping[str, float]]) -> float:
    """The optimum of ``row``'s history objective on its dataset (NaN when unknown)."""
    column = OPTIMUM_COLUMNS.get(row.get("history_objective", "F"), "")
    return float(optima.get(row["dataset"], {}).get(column, np.nan))


def time_to_gap_columns(
    rows: Sequence[Mapping[str, Any]], optima: Mapping[str, Mapping[str, float]]
) -> pd.DataFrame:
    """One row per cell row, one column per :data:`GAP_COLUMNS` [s]; ``optima`` maps a dataset
    to its ``F_star`` and ``F_chordal_star``. Rows without a history (cached before it was
    recorded) get NaN."""
    values = [
        time_to_gap(row.get("history"), row.get("history_s"), _optimum(row, optima)) for row in rows
    ]
    return pd.DataFrame(np.reshape(values, (len(rows), len(THRESHOLDS))), columns=GAP_COLUMNS)


def profile_robots(robots: Sequence[int]) -> int:
    """The team size the figures show: :data:`PROFILE_ROBOTS` if the table has it, else its
    largest."""
    return PROFILE_ROBOTS if PROFILE_ROBOTS in robots else max(robots)


def profile_figures(
    rows: Sequence[Mapping[str, Any]],
    optima: Mapping[str, Mapping[str, float]],
    folder: Path,
) -> list[Path]:
    """Per dataset, ``folder/profile-DATASET-nN.png`` and ``.pdf``: relative gap against
    parallel time [s], log-log, one line per method (each seed its own line, one label) at
    the team size of :func:`profile_robots`; a refining method (prop-v2) dashed, over the
    method it refines. Entries at time 0 are left out (log axis); gaps below :data:`GAP_FLOOR`
    are drawn at it. Returns the written paths."""
    plt = pyplot()
    robots = profile_robots([int(row["robots"]) for row in rows])
    shown = [row for row in rows if row["robots"] == robots and row.get("history_s") is not None]
    datasets = list(dict.fromkeys(row["dataset"] for row in shown))
    order = {name: k for k, name in enumerate(METHODS)}
    paths: list[Path] = []
    for dataset in datasets:
        fig, ax = plt.subplots(figsize=(5.5, 4))
        cells = sorted(
            (row for row in shown if row["dataset"] == dataset),
            key=lambda row: order.get(row["method"], len(order)),
        )
        colours: dict[str, Any] = {}
        for row in cells:
            times = np.asarray(row["history_s"], dtype=np.float64)
            gaps = np.maximum(relative_gaps(row["history"], _optimum(row, optima)), GAP_FLOOR)
            method = row["method"]
            label = None if method in colours else method_label(method)
            keep = times > 0
            style = "--" if METHODS.get(method) and METHODS[method].refines else "-"
            (line,) = ax.plot(
                times[keep], gaps[keep], style, color=colours.get(method), lw=1.2, label=label
            )
            colours.setdefault(method, line.get_color())
        for threshold in THRESHOLDS:
            ax.axhline(threshold, color="0.8", lw=0.6, zorder=0)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("simulated parallel time [s]")
        ax.set_ylabel("relative gap h/h* − 1")
        ax.set_title(f"{dataset}, n = {robots}")
        ax.legend(fontsize="small")
        fig.text(
            0.005,
            0.005,
            f"h: F (eq. 1), or F_chordal for the RBCD / MM baselines; gaps < {GAP_FLOOR:g} "
            "drawn at it",
            fontsize="x-small",
        )
        fig.tight_layout()
        paths += save_figure(fig, folder / f"profile-{dataset}-n{robots}")
    return paths
