"""Held-out learning curves over training runs, aggregated over seeds.

A run folder is what ``popbench train`` writes: ``snapshots/actor-FRAMES.pt`` (the actor at the
start, at every checkpoint and at the end) and, once scored, ``heldout/heldout.csv`` (``popbench
run heldout --checkpoint RUN/checkpoint.pt --out RUN/heldout``, the final actor). Scoring a run
(:func:`score_run`) runs each snapshot's ``ga-sac`` row on the first ``problems`` held-out
problems of the run's own task (noise, robots, poses per robot), through the default consensus,
and writes one record per (snapshot, problem) into ``RUN/curve.csv``; the final actor's records
come from ``heldout/heldout.csv`` when it exists (all of its problems: the final table's). A
folder holding only ``curve.csv`` (what ``results/algorithms/`` commits) is read as it is.

:func:`aggregate` gives, per (algorithm, start, frames), the mean over seeds of each run's median
F, mean ATE (and, with a gn-sweep reference, IQM of the normalised score: popbench.harness.scores)
over the first ``problems`` problems, with a 95 % Student-t interval over seeds (mean ±
t₀.₉₇₅,ₙ₋₁ · s / √n; none for one seed). :func:`marl_eval_json` writes the records in marl-eval's
raw-data layout (environment → task → algorithm → run → step) with every held-out problem a
task, negating F and ATE: marl-eval takes every metric as higher-is-better.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pandas as pd

from popbench.choices import TRAINING_STEP_RULE
from popbench.errors import ValueRangeError
from popbench.harness import comparison
from popbench.harness.heldout import HELDOUT_SEED_BASE, ROW_ALIASES, HeldoutConfig, run_heldout
from popbench.harness.scores import PROBLEM_KEY, ZERO_ROW, normalised, optimum
from popbench.harness.stratified import iqm
from popbench.methods import entry_point
from popbench.plotting import pyplot, save_figure

CURVE_COLUMNS = (
    "task",
    "poses_per_robot",
    "algorithm",
    "start",
    "seed",
    "frames",
    "problem_seed",
    "F",
    "ATE",
)
METRICS = {
    "F": "median F over problems",
    "ATE": "mean ATE over problems [m]",
    "score": "IQM of the normalised score over problems",
}


def _interquartile_mean(values: pd.Series) -> float:
    return float(iqm(values.to_numpy()[None]))


# Each run's statistic over the problems: the IQM for the score (robust to a blow-up's score).
STATISTIC = {"F": "median", "ATE": "mean", "score": _interquartile_mean}
# curve.csv files written before the column existed: every committed run's length.
DEFAULT_POSES_PER_ROBOT = HeldoutConfig.poses_per_robot
REFERENCE_ROWS = ("gn-sweep", "imitation", "local-lm")
# The run's snapshots and what they compare, from the agents package (loaded by name: the core
# never imports agents).


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
    if "poses_per_robot" not in done:
        done.insert(1, "poses_per_robot", DEFAULT_POSES_PER_ROBOT)
    found = entry_point("curves.snapshots")(run)
    if not found:
        if done.empty:
            raise ValueRangeError("run folder", str(run), "a folder with snapshots/ or curve.csv")
        return done
    identity = RunIdentity(**entry_point("curves.identity")(next(iter(found.values()))))
    final = max(found)
    heldout_csv = run / "heldout" / "heldout.csv"
    records = [done]
    for point in sorted(set(found) - set(done["frames"])):
        if point == final and heldout_csv.is_file():
            rows = pd.read_csv(heldout_csv)
            named = {"ga-sac", identity.algorithm}  # the checkpoint's row, by its algorithm
            rows = rows[rows["row"].map(lambda row: ROW_ALIASES.get(row, row)).isin(named)]
        else:
            config = HeldoutConfig(
                noise=(identity.noise,),
                robots=(identity.robots,),
                problems=problems,
                poses_per_robot=identity.poses_per_robot,
                rows=("ga-sac",),
                checkpoint=found[point],
                step_rule=TRAINING_STEP_RULE,  # the environment the algorithms are trained in
                out=run / "curve-cells" / f"actor-{point:07d}",
            )
            run_heldout(config)
            rows = pd.read_csv(config.out / "heldout.csv")
        records.append(
            pd.DataFrame(
                {
                    "task": identity.task,
                    "poses_per_robot": identity.poses_per_robot,
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
    metrics = [metric for metric in METRICS if metric in records]
    per_run = first.groupby(["algorithm", "start", "frames", "seed"]).agg(
        **{metric: (metric, STATISTIC[metric]) for metric in metrics}, problems=("F", "size")
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
        for metric in metrics:
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
    metrics = {metric: title for metric, title in METRICS.items() if metric in table}
    fig, axes = plt.subplots(
        len(starts), len(metrics), figsize=(5 * len(metrics), 3.4 * len(starts)), squeeze=False
    )
    algorithms = sorted(table["algorithm"].unique())
    colours = {name: plt.get_cmap("tab10")(i) for i, name in enumerate(algorithms)}
    for panels, start in zip(axes, starts, strict=True):
        for ax, (metric, title) in zip(panels, metrics.items(), strict=True):
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


def marl_eval_json(
    records: pd.DataFrame, problems: int | None = None, frames: list[int] | None = None
) -> dict:
    """The records in marl-eval's raw-data layout, every held-out problem a task:
    ``{"popbench": {TASK-pK: {ALGORITHM-START: {"run_SEED": {"step_I": {"step_count": frames,
    "score": [s], "neg_F": [-F], "neg_ATE": [-ATE]}, …, "absolute_metrics": {…}}}}}}`` (score
    where the records have it; F and ATE negated, marl-eval taking every metric as
    higher-is-better). Steps: the snapshots in ``frames`` (default: every one after the start,
    as marl-eval's loggers count: step_0 is the first evaluation after training began, and its
    evaluation interval is the mean gap from 0 frames to each step); tasks: the first
    ``problems`` problems (default: all), each in every selected snapshot of every run (marl-eval
    needs the same steps everywhere); ``absolute_metrics``: the last step's values."""
    points = sorted(frames or set(records["frames"]) - {0})
    chosen = records[records["frames"].isin(points)]
    if problems is not None:
        chosen = chosen[chosen["problem_seed"] < HELDOUT_SEED_BASE + problems]
    runs = chosen.groupby(["task", "algorithm", "start", "seed"]).ngroups
    complete = chosen.groupby(["task", "problem_seed"])["frames"].transform("size")
    chosen = chosen[complete == runs * len(points)]  # problems scored at every step of every run
    metrics = {"score": 1, "F": -1, "ATE": -1}
    names = {"score": "score", "F": "neg_F", "ATE": "neg_ATE"}
    tasks: dict[str, dict] = {}
    for (task, seed_of_problem, algorithm, start, seed), run in chosen.groupby(
        ["task", "problem_seed", "algorithm", "start", "seed"]
    ):
        steps: dict[str, dict] = {}
        for index, (point, at) in enumerate(run.sort_values("frames").groupby("frames")):
            values = {
                names[m]: [sign * float(at[m].iloc[0])] for m, sign in metrics.items() if m in at
            }
            steps[f"step_{index}"] = {"step_count": int(point), **values}
        steps["absolute_metrics"] = values
        name = f"{task}-p{int(seed_of_problem) - HELDOUT_SEED_BASE:04d}"
        runs_of = tasks.setdefault(name, {}).setdefault(f"{algorithm}-{start}", {})
        runs_of[f"run_{seed}"] = steps
    return {"popbench": tasks}


def last_snapshots(records: pd.DataFrame) -> pd.DataFrame:
    """The records of each run's final snapshot (all its problems)."""
    run = ["algorithm", "start", "seed"]
    return records[records["frames"] == records.groupby(run)["frames"].transform("max")]


def final_table(records: pd.DataFrame) -> pd.DataFrame:
    """Per (algorithm, start): the final snapshot's statistics over all its problems, mean over
    seeds with the 95 % t-interval (as :func:`aggregate`)."""
    last = last_snapshots(records)
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


def with_scores(records: pd.DataFrame, known: pd.DataFrame) -> list[pd.DataFrame]:
    """``records`` and the reference records ``known`` (their problems: the runs' poses per
    robot) with the normalised score (popbench.harness.scores): the zero is ``known``'s
    gn-sweep row, the one each problem's F*."""
    poses = records.groupby("task")["poses_per_robot"].unique()
    if poses.map(len).max() > 1:
        raise ValueRangeError("runs' poses per robot", str(poses.to_dict()), "one value")
    known = known.assign(poses_per_robot=known["task"].map(poses.map(lambda v: v[0])))
    frames = []
    for frame in (records, known):
        task = frame["task"].str.extract(r"^(?P<noise>.+)-n(?P<robots>\d+)$")
        frames.append(frame.assign(noise=task["noise"], robots=task["robots"].astype(int)))
    best = optimum(pd.concat(frames)[list(PROBLEM_KEY)].dropna())
    zero = frames[1][frames[1]["algorithm"] == ZERO_ROW]
    return [normalised(frame, zero, best).drop(columns=["noise", "robots"]) for frame in frames]


def run_identity(run: Path) -> tuple[str, str, int]:
    """(algorithm, start, seed) of a run folder, from its snapshots or its curve.csv."""
    found = entry_point("curves.snapshots")(run)
    if found:
        identity = entry_point("curves.identity")(next(iter(found.values())))
        return identity["algorithm"], identity["start"], int(identity["seed"])
    curve = run / "curve.csv"
    if not curve.is_file():
        raise ValueRangeError("run folder", str(run), "a folder with snapshots/ or curve.csv")
    first = pd.read_csv(curve, nrows=1).iloc[0]
    return first["algorithm"], first["start"], int(first["seed"])


def check_distinct(runs: list[Path]) -> None:
    """A one-line ValueRangeError if two of ``runs`` are the same (algorithm, start, seed)."""
    seen: dict[tuple[str, str, int], Path] = {}
    for run in runs:
        key = run_identity(run)
        if key in seen:
            raise ValueRangeError(
                "run folders",
                f"{seen[key]} and {run}",
                f"one run per (algorithm, start, seed): both are {key[0]} from {key[1]}, "
                f"seed {key[2]}",
            )
        seen[key] = run


def write_curves(
    runs: list[Path], out: Path, problems: int, references: list[Path] | None = None
) -> list[Path]:
    """Score ``runs`` and write ``out``.csv (every record), ``out``.md (the final table, with the
    :data:`REFERENCE_ROWS` of the ``references`` held-out folders, and the curve points), the
    figure ``out``.png / .pdf and marl-eval's JSON (:func:`marl_eval_json`): ``out``.marl-eval.json
    (the final actors, every problem a task) and ``out``.learning.marl-eval.json (every snapshot
    after the start, the first ``problems`` problems as tasks). With a gn-sweep row in the
    references, the records carry the normalised score (:func:`with_scores`) and the final
    actors' comparison (popbench.harness.comparison) joins the table, drawn in
    ``out``-comparison.png / .pdf."""
    check_distinct(runs)
    records = pd.concat([score_run(run, problems) for run in runs], ignore_index=True)
    if records["task"].nunique() > 1:
        raise ValueRangeError("runs' tasks", ",".join(sorted(records["task"].unique())), "one task")
    known = reference_records(references) if references else None
    if known is not None and (known["algorithm"] == ZERO_ROW).any():
        records, known = with_scores(records, known)
    table, final, lines = aggregate(records, problems), final_table(records), None
    if known is not None:
        final = pd.concat([final, final_table(known)], ignore_index=True)  # all their problems
        lines = aggregate(known, problems)  # the curves' problems
    out.parent.mkdir(parents=True, exist_ok=True)
    records.to_csv(out.with_suffix(".csv"), index=False, float_format="%.10g")
    last = last_snapshots(records)
    json_paths = [out.with_suffix(".marl-eval.json"), out.with_suffix(".learning.marl-eval.json")]
    json_paths[0].write_text(json.dumps(marl_eval_json(last, frames=[int(last["frames"].max())])))
    json_paths[1].write_text(json.dumps(marl_eval_json(records, problems)))
    text = _markdown(table, final, problems)
    figures = plot_curves(table, out, lines)
    if "score" in records:
        improvements = comparison.improvement_table(last)
        everything = last if known is None else pd.concat([last, known], ignore_index=True)
        text += "\n" + comparison.markdown(comparison.iqm_table(everything), improvements)
        stem = out.with_name(f"{out.name}-comparison")
        figures += comparison.plot_comparison(last, improvements, stem)
    md_path = out.with_suffix(".md")
    md_path.write_text(text)
    return [out.with_suffix(".csv"), md_path, *json_paths, *figures]


def _rows(frame: pd.DataFrame | None):
    return () if frame is None else frame.iterrows()


def _markdown(curve: pd.DataFrame, final: pd.DataFrame, problems: int) -> str:
    columns = {"F": ("median F", 1), "ATE": ("mean ATE [m]", 3), "score": ("IQM score", 3)}
    shown = {metric: columns[metric] for metric in METRICS if metric in final}

    def cells(row: pd.Series) -> str:
        out = []
        for metric, (_, digits) in shown.items():
            value = f"{row[metric]:.{digits}f}"
            if not np.isnan(row[f"{metric}_lo"]):
                value += f" [{row[f'{metric}_lo']:.{digits}f}, {row[f'{metric}_hi']:.{digits}f}]"
            out.append(value)
        return " | ".join(out)

    header = " | ".join(label for label, _ in shown.values())
    rule = "---:|" * len(shown)
    lines = [
        f"Final actors ({int(final['problems'].min())} held-out problems each): each run's "
        f"{', '.join(label for label, _ in shown.values())}, mean over seeds [95 % t-interval "
        "over seeds].",
        "",
        f"| algorithm | start | seeds | {header} |",
        f"|---|---|---:|{rule}",
    ]
    for _, row in final.iterrows():
        lines.append(f"| {row.algorithm} | {row.start} | {row.seeds} | {cells(row)} |")
    lines += [
        "",
        f"Learning curves (the first {problems} held-out problems at every snapshot):",
        "",
        f"| algorithm | start | frames | seeds | {header} |",
        f"|---|---|---:|---:|{rule}",
    ]
    for _, row in curve.sort_values(["algorithm", "start", "frames"]).iterrows():
        lines.append(
            f"| {row.algorithm} | {row.start} | {row.frames} | {row.seeds} | {cells(row)} |"
        )
    return "\n".join(lines) + "\n"
