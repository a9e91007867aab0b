"""``popbench run heldout``: the learned solver on held-out synthetic problems, row by row.

Every row is an estimate of the same problem brought through the same consensus
(:mod:`popbench.consensus.reconcile`), so the rows differ only in what was done to the robots' local
graphs before it: nothing (``no-op``), a random or greedy policy, the expert, the Gauss–Newton
sweep, the learned actors, every local graph at its own optimum (``local-lm``), or the ground
truth. ``initial`` is the start itself, without a consensus. The rows from ``gn-sweep`` to
``local-lm`` add one learned part each (agents.heldout: the learned edge order, the learned
correction, the GA-SAC fine-tuning), and :func:`paired` compares consecutive ones problem by
problem (:data:`PAIRS`). A user's policy (``HeldoutConfig.policy``, agents.user_policy) adds one
row, compared with :data:`POLICY_REFERENCES` the same way. A row is shown under its label: the
``ga-sac`` row under the algorithm that trained its checkpoint, the policy's under its name.

Held-out problems use the seeds ``HELDOUT_SEED_BASE + k``; the training streams
(``envs.sampler.ProblemSampler``) draw 32-bit seeds, all below the base, so the two never meet.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from popbench.choices import DEFAULT_STEP_RULE, TRAINING_STEP_RULE
from popbench.consensus.reconcile import DEFAULT_CONSENSUS, DEFAULT_CONSENSUS_ITERATIONS
from popbench.harness.cache import code_fingerprint
from popbench.harness.executors import Row, Run, Spec
from popbench.harness.runner import run_experiment
from popbench.methods import entry_point
from popbench.metrics import bootstrap_ci

HELDOUT_SEED_BASE = 2**32
ROWS = (
    "initial",
    "no-op",
    "random",
    "greedy",
    "expert",
    "gn-sweep",
    "learned-order",
    "imitation",
    "ga-sac",
    "local-lm",
    "ground-truth",
)
# Former row names, still accepted (--rows) and read (committed heldout.csv files).
ROW_ALIASES = {"prop-v1": "ga-sac"}
# The paired comparisons (row A, row B) of paired.csv: what each learned part adds.
PAIRS = (("learned-order", "gn-sweep"), ("imitation", "learned-order"), ("ga-sac", "imitation"))
# The rows a user's policy is compared with, problem by problem (those present).
POLICY_REFERENCES = ("no-op", "gn-sweep", "imitation", "ga-sac", "local-lm")
PAIRED_METRICS = ("F_robots", "F_local", "F", "ATE")


@dataclasses.dataclass(frozen=True)
class HeldoutConfig:
    """What ``popbench run heldout`` computes.

    Attributes:
        noise: synthetic noise levels (``V1``/``V2``/``V3``).
        robots: team sizes.
        problems: held-out problems per (noise, robots).
        poses_per_robot: synthetic trajectory length.
        rows: the rows to compute (a subset of :data:`ROWS`, in that order).
        consensus: the consensus every row goes through (one of
            :data:`popbench.consensus.reconcile.CONSENSUS_MODES`).
        consensus_iterations: its ADMM iterations at most (the tables' 200 by default; more to
            see what a converged consensus keeps of each row).
        checkpoint: the actor of the ``ga-sac`` row (None: the committed fine-tuned one).
        imitation_checkpoint: the actor of the ``imitation`` and ``learned-order`` rows (None:
            the committed one).
        out: output folder.
        policy: a user's policy, ``"module:attr"`` or ``"file.py:attr"`` (agents.user_policy),
            scored as one more row; None: none.
        policy_arg: the argument of a policy factory (``attr(policy_arg)`` is the policy).
        policy_name: the policy row's label (None: the attribute's name).
        policy_env: the keyword options of the env the policy acts in (those of
            ``envs.make_torchrl_env``; empty: its defaults).
        outlier_rate: outliers injected into every held-out problem (popbench.outliers, the
            loop-closure candidates; 0 = none, the cells of before); with it the learned rows
            are scored as outlier classifiers (gate_auc, gate_precision, gate_recall).
        step_rule: the environment's step rule in every episode row (envs.core.PGOCore:
            ``"clip"``, the one the actors were trained in, ``"line-search"``, prop-v1's
            default, :data:`popbench.choices.DEFAULT_STEP_RULE`, or one of its variants).
    """

    noise: tuple[str, ...] = ("V2",)
    robots: tuple[int, ...] = (7,)
    problems: int = 100
    poses_per_robot: int = 60
    rows: tuple[str, ...] = ROWS
    consensus: str = DEFAULT_CONSENSUS
    consensus_iterations: int = DEFAULT_CONSENSUS_ITERATIONS
    checkpoint: Path | None = None
    imitation_checkpoint: Path | None = None
    out: Path = Path("results/heldout")
    outlier_rate: float = 0.0
    policy: str | None = None
    policy_arg: str | None = None
    policy_name: str | None = None
    policy_env: dict[str, Any] = dataclasses.field(default_factory=dict)
    step_rule: str = DEFAULT_STEP_RULE


def canonical_rows(rows: tuple[str, ...]) -> tuple[str, ...]:
    """``rows`` with former names (:data:`ROW_ALIASES`) replaced, each once, in their order."""
    return tuple(dict.fromkeys(ROW_ALIASES.get(row, row) for row in rows))


def cell_specs(config: HeldoutConfig) -> list[Spec]:
    """One specification per (noise, robots, problem, row), with the code and, for the learned
    rows, the checkpoint's sha256 it is computed from (for the policy row, its digest); a
    ``label`` where the row is shown under another name. A learned row whose checkpoint does
    not exist is left out of the default rows and refused when asked for by name."""
    checkpoints = entry_point("heldout.checkpoints")(config.checkpoint, config.imitation_checkpoint)
    labels = {
        row: entry_point("heldout.label")(row, found[0])
        for row, found in checkpoints.items()
        if found is not None
    }
    rows = canonical_rows(config.rows)
    extra: dict[str, dict[str, Any]] = {row: {} for row in rows}
    for row, label in labels.items():
        if label != row:
            extra[row]["label"] = label
    if config.policy is not None:
        described = entry_point("heldout.policy")(
            config.policy, config.policy_arg, config.policy_env
        )
        described["label"] = config.policy_name or described["label"]
        taken = {extra[row].get("label", row) for row in rows} | set(ROWS)
        if described["label"] in taken:
            from popbench.errors import ValueRangeError

            name = described["label"]
            raise ValueRangeError("--policy-name", name, f"a name other than {', '.join(taken)}")
        rows, extra["policy"] = (*rows, "policy"), described
    code = code_fingerprint()
    specs = []
    for noise in config.noise:
        for robots in config.robots:
            for k in range(config.problems):
                for row in rows:
                    spec: dict[str, Any] = {
                        "experiment": "heldout",
                        "code": code,
                        "noise": noise,
                        "robots": robots,
                        "poses_per_robot": config.poses_per_robot,
                        "problem_seed": HELDOUT_SEED_BASE + k,
                        "row": row,
                        "consensus": config.consensus,
                    }
                    if config.outlier_rate > 0:  # absent otherwise: earlier cells stay valid
                        spec["outlier_rate"] = config.outlier_rate
                    if config.step_rule != TRAINING_STEP_RULE:  # absent: cells before the option
                        spec["step_rule"] = config.step_rule
                    if config.consensus_iterations != DEFAULT_CONSENSUS_ITERATIONS:
                        spec["consensus_iterations"] = config.consensus_iterations
                    if row in checkpoints:
                        if checkpoints[row] is None:
                            continue
                        spec["checkpoint"], spec["checkpoint_sha256"] = checkpoints[row]
                    specs.append({**spec, **extra[row]})
    return specs


def compute_cell(spec: Spec) -> dict[str, Any]:
    """One row of one held-out problem (``agents.heldout.evaluate_row``) and its wall time; the
    row under its label."""
    started = time.perf_counter()
    measured = entry_point("heldout.row")(spec)
    return {
        "noise": spec["noise"],
        "robots": spec["robots"],
        "problem_seed": spec["problem_seed"],
        "row": spec.get("label", spec["row"]),
        **measured,
        "wall_s": time.perf_counter() - started,
    }


def summary(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (noise, robots, row) of the per-problem ``frame`` (heldout.csv; former row names
    read as today's): mean and median F, ATE, local F (``F_local``, the robots' local copies
    assembled before the consensus) and the robots' own local F (``F_robots``, NaN in files
    written before it) with bootstrap 95 % CIs, and the ratio of the row's median F to the
    no-op's; ``closed_F`` / ``closed_ATE`` give the share of the no-op → local-lm gap the row
    closes in median F and in mean ATE. With outliers (the
    cells have ``gate_auc``), the learned rows add ``gate_auc`` (mean over the problems with an
    outlier, and its CI) and ``gate_precision`` / ``gate_recall`` (pooled over the problems'
    candidate edges: hits / flagged, hits / injected)."""
    frame = frame.assign(row=frame["row"].replace(ROW_ALIASES))
    records = []
    for (noise, robots), group in frame.groupby(["noise", "robots"], sort=False):
        medians = group.groupby("row")["F"].median()
        ate_means = group.groupby("row")["ATE"].mean()
        for row in dict.fromkeys(group["row"]):  # the table's order
            values = group[group["row"] == row]
            f, ate, local = (values[k].to_numpy() for k in ("F", "ATE", "F_local"))
            robots_f = values.get("F_robots", pd.Series(np.nan, index=values.index)).to_numpy()
            record = {
                "noise": noise,
                "robots": robots,
                "row": row,
                "problems": len(values),
                "F_mean": float(f.mean()),
                "F_mean_ci": bootstrap_ci(f, np.mean),
                "F_median": float(np.median(f)),
                "F_median_ci": bootstrap_ci(f, np.median),
                "ATE_mean": float(ate.mean()),
                "ATE_mean_ci": bootstrap_ci(ate, np.mean),
                "ATE_median": float(np.median(ate)),
                "F_local_mean": float(local.mean()),
                "F_local_mean_ci": bootstrap_ci(local, np.mean),
                "F_local_median": float(np.median(local)),
                "F_local_median_ci": bootstrap_ci(local, np.median),
                "F_robots_median": float(np.median(robots_f)),
                "F_robots_median_ci": bootstrap_ci(robots_f, np.median),
                "median_ratio_to_noop": _ratio(medians, row, "no-op"),
                "closed_F": _closed(medians, row),
                "closed_ATE": _closed(ate_means, row),
            }
            if "gate_auc" in values and values["gate_auc"].notna().any():
                record.update(_gate_summary(values))
            records.append(record)
    return pd.DataFrame(records)


def paired(frame: pd.DataFrame, pairs: tuple[tuple[str, str], ...] = PAIRS) -> pd.DataFrame:
    """Row A − row B problem by problem, per (noise, robots), pair of :data:`PAIRS` whose two
    rows ``frame`` has (former row names read as today's) and metric of
    :data:`PAIRED_METRICS`: over the K problems both rows have, ``diff_mean`` and
    ``diff_median`` of the differences d_k = A_k − B_k with bootstrap 95 % CIs (paired: one
    resample draws whole problems) and ``A_lower``, the share of problems with d_k < 0
    (negative differences favour A in every metric)."""
    frame = frame.assign(row=frame["row"].replace(ROW_ALIASES))
    records = []
    for (noise, robots), group in frame.groupby(["noise", "robots"], sort=False):
        metrics = [metric for metric in PAIRED_METRICS if metric in group]
        wide = group.pivot_table(index="problem_seed", columns="row", values=metrics)
        for a, b in pairs:
            if a not in set(group["row"]) or b not in set(group["row"]):
                continue
            for metric in metrics:
                d = (wide[metric][a] - wide[metric][b]).dropna().to_numpy()
                if d.size == 0:
                    continue
                records.append(
                    {
                        "noise": noise,
                        "robots": robots,
                        "A": a,
                        "B": b,
                        "metric": metric,
                        "problems": d.size,
                        "diff_mean": float(d.mean()),
                        "diff_mean_ci": bootstrap_ci(d, np.mean),
                        "diff_median": float(np.median(d)),
                        "diff_median_ci": bootstrap_ci(d, np.median),
                        "A_lower": float((d < 0).mean()),
                    }
                )
    return pd.DataFrame(records)


def _gate_summary(values: pd.DataFrame) -> dict[str, Any]:
    """gate_auc (mean, CI) and pooled gate_precision / gate_recall of one row's cells."""
    auc = values["gate_auc"].dropna().to_numpy()
    hits, flagged, true = (
        float(values[k].sum()) for k in ("gate_hits", "gate_flagged", "gate_true")
    )
    return {
        "gate_auc": float(auc.mean()),
        "gate_auc_ci": bootstrap_ci(auc, np.mean),
        "gate_precision": hits / flagged if flagged else 1.0,
        "gate_recall": hits / true if true else 1.0,
    }


def _ratio(values: pd.Series, row: str, reference: str) -> float:
    return float(values[row] / values[reference]) if reference in values else float("nan")


def _closed(values: pd.Series, row: str) -> float:
    """(v_no-op − v_row) / (v_no-op − v_local-lm); NaN without both references or when local-lm
    is not below the no-op (then there is no gap to close)."""
    if "no-op" not in values or "local-lm" not in values:
        return float("nan")
    gap = values["no-op"] - values["local-lm"]
    return float((values["no-op"] - values[row]) / gap) if gap > 0 else float("nan")


def markdown(table: pd.DataFrame, pairs: pd.DataFrame | None = None) -> str:
    """The summary (and the paired differences ``pairs``, :func:`paired`, if given) as markdown
    tables per (noise, robots)."""
    lines = []
    for (noise, robots), group in table.groupby(["noise", "robots"], sort=False):
        count = int(group["problems"].max())
        lines += [
            f"### {noise}, n = {robots} ({count} held-out problems, 95 % bootstrap CIs)",
            "",
            "| row | F mean | F median [95 % CI] | robots' local F median [95 % CI] "
            "| ATE mean [m] [95 % CI] | median F / no-op | gap closed (F, ATE) |",
            "|---|---:|---:|---:|---:|---:|---:|",
        ]
        gated = group[group["gate_auc"].notna()] if "gate_auc" in group else group.iloc[:0]
        for record in group.itertuples():
            lines.append(
                f"| {record.row} | {record.F_mean:.4g} | {record.F_median:.4g} "
                f"[{record.F_median_ci[0]:.4g}, {record.F_median_ci[1]:.4g}] "
                f"| {record.F_robots_median:.4g} [{record.F_robots_median_ci[0]:.4g}, "
                f"{record.F_robots_median_ci[1]:.4g}] "
                f"| {record.ATE_mean:.3f} [{record.ATE_mean_ci[0]:.3f}, "
                f"{record.ATE_mean_ci[1]:.3f}] | {record.median_ratio_to_noop:.3f} "
                f"| {record.closed_F:.2f}, {record.closed_ATE:.2f} |"
            )
        lines.append("")
        if pairs is not None and len(pairs):
            lines += _paired_markdown(
                pairs[(pairs["noise"] == noise) & (pairs["robots"] == robots)]
            )
        if len(gated):
            lines += [
                "Gate as an outlier classifier (loop closures; flagged: gate ≤ 0.5):",
                "",
                "| row | ROC AUC [95 % CI] | precision | recall |",
                "|---|---:|---:|---:|",
            ]
            for record in gated.itertuples():
                lines.append(
                    f"| {record.row} | {record.gate_auc:.3f} [{record.gate_auc_ci[0]:.3f}, "
                    f"{record.gate_auc_ci[1]:.3f}] | {record.gate_precision:.3f} "
                    f"| {record.gate_recall:.3f} |"
                )
            lines.append("")
    return "\n".join(lines)


def _paired_markdown(pairs: pd.DataFrame) -> list[str]:
    """The markdown lines of one (noise, robots) group's paired differences."""
    if not len(pairs):
        return []
    lines = [
        "Paired differences A − B over the same problems (negative favours A; 95 % bootstrap "
        "CIs over problems):",
        "",
        "| A − B | metric | problems | median of A − B [95 % CI] | mean of A − B [95 % CI] "
        "| A lower |",
        "|---|---|---:|---:|---:|---:|",
    ]
    for record in pairs.itertuples():
        lines.append(
            f"| {record.A} − {record.B} | {record.metric} | {record.problems} "
            f"| {record.diff_median:.4g} [{record.diff_median_ci[0]:.4g}, "
            f"{record.diff_median_ci[1]:.4g}] | {record.diff_mean:.4g} "
            f"[{record.diff_mean_ci[0]:.4g}, {record.diff_mean_ci[1]:.4g}] "
            f"| {record.A_lower:.2f} |"
        )
    return [*lines, ""]


def figure(frame: pd.DataFrame, stem: Path) -> list[Path]:
    """F per row (box plot over problems, log scale), one panel per (noise, robots)."""
    from popbench.plotting import pyplot, save_figure

    plt = pyplot()
    groups = list(frame.groupby(["noise", "robots"], sort=False))
    fig, axes = plt.subplots(1, len(groups), figsize=(6.5 * len(groups), 4.0), squeeze=False)
    for axis, ((noise, robots), group) in zip(axes[0], groups, strict=True):
        rows = list(dict.fromkeys(group["row"]))
        axis.boxplot([group.loc[group["row"] == r, "F"] for r in rows], showfliers=False)
        axis.set_xticks(range(1, len(rows) + 1), rows, rotation=40, ha="right")
        axis.set_yscale("log")
        axis.set_ylabel("F after the consensus (eq. 1)")
        axis.set_title(f"held-out {noise}, n = {robots}")
    fig.tight_layout()
    return save_figure(fig, stem)


def summary_json(table: pd.DataFrame) -> str:
    """The summary as one JSON object ``{"rows": [...], "paired": [...]}`` (CIs as
    ``[lo, hi]``; ``paired``: :func:`paired`'s records, which :func:`write_heldout` keeps in
    ``table.attrs["paired"]``; empty without them)."""
    pairs = table.attrs.get("paired")
    records = {
        "rows": table,
        "paired": pd.DataFrame() if pairs is None else pairs,
    }
    return json.dumps(
        {key: json.loads(value.to_json(orient="records")) for key, value in records.items()}
    )


def run_heldout(config: HeldoutConfig, run: Run | None = None) -> pd.DataFrame:
    """Compute (or reuse) every cell as ``run`` says (default: serially in this process;
    :func:`popbench.harness.runner.run_experiment`), then write ``heldout.csv`` (one line per
    problem and row), ``summary.csv``, ``paired.csv`` (:func:`paired`), ``heldout.md``,
    ``heldout.png``/``.pdf`` and ``manifest.json`` into ``config.out``; returns the summary
    (with the paired differences in ``attrs["paired"]``)."""

    labels: dict[str, str] = {}

    def cells() -> list[Spec]:
        unknown = sorted(set(canonical_rows(config.rows)) - set(ROWS))
        if unknown:
            from popbench.errors import ValueRangeError

            raise ValueRangeError("heldout rows", ",".join(unknown), ", ".join(ROWS))
        specs = cell_specs(config)
        labels.update((spec["row"], spec.get("label", spec["row"])) for spec in specs)
        return specs

    def write(rows: list[Row]) -> pd.DataFrame:
        return write_heldout(config, rows, labelled_pairs(labels))

    return run_experiment(config.out, cells, compute_cell, write, run)


def labelled_pairs(labels: dict[str, str]) -> tuple[tuple[str, str], ...]:
    """:data:`PAIRS` and, with a ``policy`` row, (policy, reference) for each of
    :data:`POLICY_REFERENCES`, every row under its label (``labels``: row -> label)."""
    pairs = list(PAIRS)
    if "policy" in labels:
        pairs += [("policy", reference) for reference in POLICY_REFERENCES]
    return tuple((labels.get(a, a), labels.get(b, b)) for a, b in pairs)


def write_heldout(
    config: HeldoutConfig, rows: list[Row], pairs: tuple[tuple[str, str], ...] = PAIRS
) -> pd.DataFrame:
    """The per-problem table of ``rows``, its summary (returned, the paired differences of
    ``pairs`` in its ``attrs["paired"]``) and figure, written into ``config.out``."""
    frame = pd.DataFrame(rows)
    table, pairs = summary(frame), paired(frame, pairs)
    table.attrs["paired"] = pairs
    frame.to_csv(config.out / "heldout.csv", index=False, float_format="%.10g")
    table.to_csv(config.out / "summary.csv", index=False, float_format="%.10g")
    pairs.to_csv(config.out / "paired.csv", index=False, float_format="%.10g")
    (config.out / "heldout.md").write_text(markdown(table, pairs))
    figure(frame, config.out / "heldout")
    return table
