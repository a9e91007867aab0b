"""Held-out learning curves over training runs, aggregated over seeds (issue 29).

A run folder is what ``popbench train`` writes: ``snapshots/actor-FRAMES.pt`` (the actor at the
start, at every checkpoint and at the end) and, once scored, ``heldout/heldout.csv`` (``popbench
run heldout --checkpoint RUN/checkpoint.pt --out RUN/heldout``, the final actor). Scoring a run
(:func:`score_run`) runs each snapshot's ``ga-sac`` row on the first ``problems`` held-out
problems of the run's own task (noise, robots, poses per robot), through the default consensus,
and writes one record per (snapshot, problem) into ``RUN/curve.csv``; the final actor's records
come from ``heldout/heldout.csv`` when it exists (all of its problems: the final table's). A
folder holding only ``curve.csv`` (what ``results/algorithms/`` commits) is read as it is.

:func:`aggregate` gives, per (algorithm, start, frames), the mean over seeds of each run's median
F and mean ATE over the first ``problems`` problems, with a 95 % Student-t interval over seeds
(mean ± t₀.₉₇₅,ₙ₋₁ · s / √n; none for one seed). :func:`marl_eval_json` writes the records in
marl-eval's raw-data layout (environment → task → algorithm → run → step), negating F and ATE:
marl-eval takes every metric as higher-is-better.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from popbench.errors import ValueRangeError
from popbench.harness.heldout import HELDOUT_SEED_BASE, ROW_ALIASES, HeldoutConfig, run_heldout
from popbench.harness.plotting import pyplot, save_figure
from popbench.methods import load_object

CURVE_COLUMNS = ("task", "algorithm", "start", "seed", "frames", "problem_seed", "F", "ATE")
METRICS = {"F": "median F over problems", "ATE": "mean ATE over problems [m]"}
STATISTIC = {"F": "median", "ATE": "mean"}
REFERENCE_ROWS = ("gn-sweep", "imitation", "local-lm")
# The run's snapshots and what they compare, from the agents package (loaded by name: the core
# never imports agents).
SNAPSHOTS_FUNCTION = "agents.checkpoint:run_snapshots"
IDENTITY_FUNCTION = "agents.checkpoint:snapshot_identity"


@dataclasses.dataclass(frozen=True)
class RunIdentity:
    """What a run compares (agents.checkpoint.snapshot_identity): its algorithm, its start
    ("imitation" or "scratch"), its seed and the task its actor is scored on."""

    algorithm: str
    start: str
    seed: int
    noise: str
    robots: int
    poses_per_robot: int

    @property
    def task(self) -> str:
        """NOISE-nROBOTS, e.g. V2-n7."""
        return f"{self.noise}-n{self.robots}"


def score_run(run: Path, problems: int) -> pd.DataFrame:
    """The run's curve records (:data:`CURVE_COLUMNS`), scoring the snapshots not yet in
    ``run/curve.csv`` and appending them there (module docstring)."""
    curve_path = run / "curve.csv"
    done = pd.read_csv(curve_path) if curve_path.is_file() else pd.DataFrame(columns=CURVE_COLUMNS)
    found = load_object(SNAPSHOTS_FUNCTION)(run)
    if not found:
        if done.empty:
            raise ValueRangeError("run folder", str(run), "a folder with snapshots/ or curve.csv")
        return done
    identity = RunIdentity(**load_object(IDENTITY_FUNCTION)(next(iter(found.values()))))
    final = max(found)
    heldout_csv = run / "heldout" / "heldout.csv"
    records = [done]
    for point in sorted(set(found) - set(done["frames"])):
        if point == final and heldout_csv.is_file():
            rows = pd.read_csv(heldout_csv)
            rows = rows[rows["row"].map(lambda row: ROW_ALIASES.get(row, row)) == "ga-sac"]
        else:
            config = HeldoutConfig(
                noise=(identity.noise,),
                robots=(identity.robots,),
                problems=problems,
                poses_per_robot=identity.poses_per_robot,
                rows=("ga-sac",),
                checkpoint=found[point],
                out=run / "curve-cells" / f"actor-{point:07d}",
            )
            run_heldout(config)
            rows = pd.read_csv(config.out / "heldout.csv")
        records.append(
            pd.DataFrame(
                {
                    "task": identity.task,
                    "algorithm": identity.algorithm,
                    "start": identity.start,
                    "seed": identity.seed,
                    "frames": point,
                    "problem_seed": rows["problem_seed"].to_numpy(),
                    "F": rows["F"].to_numpy(),
                    "ATE": rows["ATE"].to_numpy(),
                }
            )
        )
        curve = pd.concat(records, ignore_index=True)
        curve.to_csv(curve_path, index=False, float_format="%.10g")
    return pd.concat(records, ignore_index=True)


def aggregate(records: pd.DataFrame, problems: int) -> pd.DataFrame:
    """Per (algorithm, start, frames): each metric's seed mean and 95 % t-interval (module
    docstring) over the runs' statistic on the first ``problems`` problems, and the seeds."""
    from scipy import stats

    first = records[records["problem_seed"] < HELDOUT_SEED_BASE + problems]
    per_run = first.groupby(["algorithm", "start", "frames", "seed"]).agg(
        F=("F", STATISTIC["F"]), ATE=("ATE", STATISTIC["ATE"]), problems=("F", "size")
    )
    short = per_run[per_run["problems"] < problems]
    if not short.empty:
        algorithm, start, frames, seed = short.index[0]
        raise ValueRangeError(
            f"problems scored for {algorithm}/{start} seed {seed} at {frames} frames",
            int(short["problems"].iloc[0]),
            f"at least --problems {problems}",
        )
    rows = []
    for (algorithm, start, frames), group in per_run.groupby(level=[0, 1, 2]):
        row = {"algorithm": algorithm, "start": start, "frames": frames, "seeds": len(group)}
        for metric in METRICS:
            values = group[metric].to_numpy()
            mean = float(values.mean())
            half = np.nan
            if values.size > 1:
                t = stats.t.ppf(0.975, values.size - 1)
                half = float(t * values.std(ddof=1) / np.sqrt(values.size))
            row |= {metric: mean, f"{metric}_lo": mean - half, f"{metric}_hi": mean + half}
        rows.append(row)
    return pd.DataFrame(rows)


def plot_curves(
    table: pd.DataFrame, out: Path, references: pd.DataFrame | None = None
) -> list[Path]:
    """One row of panels per start, one panel per metric: each algorithm against frames, its
    seed mean with the 95 % band (clipped to the axes, which fit the means and the reference
    lines: the full intervals are in the table); each row of ``references`` (:func:`aggregate`
    of reference records) a grey horizontal line; F on a log axis where a diverging run's F
    is more than 3 times the others'. PNG + PDF."""
    plt = pyplot()
    starts = sorted(table["start"].unique())
    fig, axes = plt.subplots(
        len(starts), len(METRICS), figsize=(5 * len(METRICS), 3.4 * len(starts)), squeeze=False
    )
    algorithms = sorted(table["algorithm"].unique())
    colours = {name: plt.get_cmap("tab10")(i) for i, name in enumerate(algorithms)}
    for panels, start in zip(axes, starts, strict=True):
        for ax, (metric, title) in zip(panels, METRICS.items(), strict=True):
            shown = []
            for algorithm, group in table[table["start"] == start].groupby("algorithm"):
                group = group.sort_values("frames")
                colour = colours[algorithm]
                label = f"{algorithm} ({group['seeds'].min()} seeds)"
                ax.plot(group["frames"], group[metric], "-", color=colour, marker=".", label=label)
                ax.fill_between(
                    group["frames"],
                    group[f"{metric}_lo"],
                    group[f"{metric}_hi"],
                    color=colour,
                    alpha=0.15,
                    linewidth=0,
                )
                shown += list(group[metric])
            for dashes, (_, row) in zip(((1, 1), (4, 2), (1, 3)), _rows(references), strict=False):
                ax.axhline(
                    row[metric], color="0.4", linewidth=1, dashes=dashes, label=row.algorithm
                )
                shown.append(row[metric])
            low, high = min(shown), max(shown)
            if metric == "F" and high > 3 * low:
                ax.set_yscale("log")
                ax.set_ylim(low / 1.3, high * 1.3)
            else:
                pad = 0.08 * (high - low) + 0.01 * abs(high)
                ax.set_ylim(low - pad, high + pad)
            ax.set_xlabel("frames")
            ax.set_title(f"from {start}: {title}", fontsize="small")
        panels[0].legend(fontsize="x-small")
    fig.suptitle("Held-out learning curves, mean over seeds ± 95 % t-interval", fontsize="small")
    fig.tight_layout()
    return save_figure(fig, out)


def marl_eval_json(records: pd.DataFrame, problems: int) -> dict:
    """The records in marl-eval's raw-data layout: ``{"popbench": {TASK: {ALGORITHM-START:
    {"run_SEED": {"step_I": {"step_count": frames, "neg_F": [...], "neg_ATE": [...]}, …,
    "absolute_metrics": {...}}}}}}``, steps over the first ``problems`` problems, the absolute
    metrics over every problem of the final snapshot."""
    tasks: dict[str, dict] = {}
    for (task, algorithm, start, seed), run in records.groupby(
        ["task", "algorithm", "start", "seed"]
    ):
        steps: dict[str, dict] = {}
        points = sorted(run["frames"].unique())
        for index, frames in enumerate(points):
            at = run[run["frames"] == frames]
            first = at[at["problem_seed"] < HELDOUT_SEED_BASE + problems]
            steps[f"step_{index}"] = {"step_count": int(frames), **_negated(first)}
        steps["absolute_metrics"] = _negated(run[run["frames"] == points[-1]])
        tasks.setdefault(task, {}).setdefault(f"{algorithm}-{start}", {})[f"run_{seed}"] = steps
    return {"popbench": tasks}


def _negated(rows: pd.DataFrame) -> dict[str, list[float]]:
    ordered = rows.sort_values("problem_seed")
    return {f"neg_{metric}": (-ordered[metric]).tolist() for metric in METRICS}


def final_table(records: pd.DataFrame) -> pd.DataFrame:
    """Per (algorithm, start): the final snapshot's statistics over all its problems, mean over
    seeds with the 95 % t-interval (as :func:`aggregate`)."""
    last = records[
        records["frames"]
        == records.groupby(["algorithm", "start", "seed"])["frames"].transform("max")
    ]
    problems = int(last.groupby(["algorithm", "start", "seed"]).size().min())
    table = aggregate(last, problems)
    return table.drop(columns="frames").assign(problems=problems)


def reference_records(folders: list[Path], rows: tuple[str, ...] = REFERENCE_ROWS) -> pd.DataFrame:
    """The ``rows`` of ``popbench run heldout`` folders as final records (start "—"), one seed
    per folder (the imitation row is one seed's imitation actor; the classical rows repeat)."""
    records = []
    for seed, folder in enumerate(folders):
        path = folder / "heldout.csv"
        if not path.is_file():
            raise ValueRangeError("reference folder", str(folder), "a popbench run heldout folder")
        frame = pd.read_csv(path)
        frame = frame[frame["row"].isin(rows)]
        records.append(
            pd.DataFrame(
                {
                    "task": frame["noise"] + "-n" + frame["robots"].astype(str),
                    "algorithm": frame["row"],
                    "start": "—",
                    "seed": seed,
                    "frames": 0,
                    "problem_seed": frame["problem_seed"],
                    "F": frame["F"],
                    "ATE": frame["ATE"],
                }
            )
        )
    return pd.concat(records, ignore_index=True)


def write_curves(
    runs: list[Path], out: Path, problems: int, references: list[Path] | None = None
) -> list[Path]:
    """Score ``runs`` and write ``out``.csv (every record), ``out``.md (the final table, with the
    :data:`REFERENCE_ROWS` of the ``references`` held-out folders, and the curve points),
    ``out``.marl-eval.json and the figure ``out``.png / .pdf."""
    records = pd.concat([score_run(run, problems) for run in runs], ignore_index=True)
    if records["task"].nunique() > 1:
        raise ValueRangeError("runs' tasks", ",".join(sorted(records["task"].unique())), "one task")
    table, final, lines = aggregate(records, problems), final_table(records), None
    if references:
        known = reference_records(references)
        final = pd.concat([final, final_table(known)], ignore_index=True)  # all their problems
        lines = aggregate(known, problems)  # the curves' problems
    out.parent.mkdir(parents=True, exist_ok=True)
    records.to_csv(out.with_suffix(".csv"), index=False, float_format="%.10g")
    json_path = out.with_suffix(".marl-eval.json")
    json_path.write_text(json.dumps(marl_eval_json(records, problems)))
    md_path = out.with_suffix(".md")
    md_path.write_text(_markdown(table, final, problems))
    return [out.with_suffix(".csv"), md_path, json_path, *plot_curves(table, out, lines)]


def _rows(frame: pd.DataFrame | None):
    return () if frame is None else frame.iterrows()


def _markdown(curve: pd.DataFrame, final: pd.DataFrame, problems: int) -> str:
    def cell(row: pd.Series, metric: str, digits: int) -> str:
        if np.isnan(row[f"{metric}_lo"]):
            return f"{row[metric]:.{digits}f}"
        return (
            f"{row[metric]:.{digits}f} [{row[f'{metric}_lo']:.{digits}f}, "
            f"{row[f'{metric}_hi']:.{digits}f}]"
        )

    lines = [
        f"Final actors ({int(final['problems'].min())} held-out problems each): each run's "
        "median F and mean ATE, mean over seeds [95 % t-interval over seeds].",
        "",
        "| algorithm | start | seeds | median F | mean ATE [m] |",
        "|---|---|---:|---:|---:|",
    ]
    for _, row in final.iterrows():
        lines.append(
            f"| {row.algorithm} | {row.start} | {row.seeds} | {cell(row, 'F', 1)} "
            f"| {cell(row, 'ATE', 3)} |"
        )
    lines += [
        "",
        f"Learning curves (the first {problems} held-out problems at every snapshot):",
        "",
        "| algorithm | start | frames | seeds | median F | mean ATE [m] |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for _, row in curve.sort_values(["algorithm", "start", "frames"]).iterrows():
        lines.append(
            f"| {row.algorithm} | {row.start} | {row.frames} | {row.seeds} "
            f"| {cell(row, 'F', 1)} | {cell(row, 'ATE', 3)} |"
        )
    return "\n".join(lines) + "\n"
