"""``popbench run table1 | outliers | scalability | heldout``: the paper's experiments.

Lists are comma-separated (``--datasets intel,mit --robots 3,7``). Finished cells are cached
under ``OUT/cells``, keyed by the cell's options and by what it was computed from (the sha256
of the graph file, a fingerprint of the code, the checkpoint's sha256 for a method whose record
names one): re-running a command recomputes nothing that finished with the same inputs, so an
interrupted run resumes where it stopped; ``--fresh`` recomputes every cell. ``--jobs``,
``--executor``, ``--address`` and ``--threads`` say where the cells run
(:mod:`popbench.harness.executors`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import typer

from popbench.choices import (
    DEFAULT_GROUP_SIZE,
    DEFAULT_STEP_RULE,
    NOISES,
    PARTITIONS,
    ROBUST_KERNELS,
    STEP_RULES,
)
from popbench.cli import options
from popbench.errors import PopbenchError, ValueRangeError
from popbench.harness import defaults
from popbench.harness.defaults import joined
from popbench.harness.executors import Run

app = typer.Typer(
    help="Run the paper's experiments; write CSV, markdown, LaTeX and figures.",
    no_args_is_help=True,
)


def experiment(name: str, *examples: str) -> Callable[[Callable[..., None]], Callable[..., None]]:
    """Register an experiment command as ``popbench run NAME``: its ``--help`` epilog (the
    ``examples``, the cache and parallel notes) and the run options (:func:`options.runs_cells`)."""

    def register(command: Callable[..., None]) -> Callable[..., None]:
        return app.command(name, epilog=options.epilog(*examples))(options.runs_cells(command))

    return register


def wrote(count: int, what: str, out: Path, files: str) -> None:
    """Say what a command wrote: ``COUNT WHAT -> OUT/FILES``."""
    typer.echo(f"{count} {what} -> {out}/{files}")


def with_quick(what: str, default: object, quick: str) -> str:
    """An option's help with its default and its --quick value (popbench.harness.defaults)."""
    value = defaults.TABLE1_QUICK[quick]
    shown = joined(value) if isinstance(value, tuple) else value
    return f"{what} (default: {default}; --quick: {shown})."


@experiment(
    "table1",
    "popbench run table1 --quick                      # mit, n = 3, 100 rounds",
    "popbench run table1 --jobs 1                     # one cell at a time",
    "popbench run table1 --executor ray --address HEAD:6379",
    "popbench run table1 --robots 7 --methods prop-v1,local-lm --training-seeds 0,1,2",
    "popbench run table1 --datasets intel,my.g2o --robots 3,7 --methods mm-pgo --out results/mine",
)
def table1_command(
    *,
    datasets: str = typer.Option(
        None,
        help=with_quick("Datasets, registered names or .g2o paths", "the paper's 8", "datasets"),
        show_default=False,
    ),
    robots: str = typer.Option(
        None,
        help=with_quick("Team sizes", joined(defaults.TABLE1_ROBOTS), "robots"),
        show_default=False,
    ),
    methods: str = typer.Option(
        None,
        help="Methods (default: every registered method that is not centralised; "
        "popbench solve --help lists them).",
        show_default=False,
    ),
    iterations: int = typer.Option(
        None,
        min=1,
        help=with_quick("Rounds for the iterative methods", defaults.ITERATIONS, "iterations"),
        show_default=False,
    ),
    seeds: str = typer.Option("0", help="Seeds (partition, lifting, sampling)."),
    training_seeds: str = typer.Option(
        "0",
        help="Training seeds of the learned methods' actors (0,1,2: the committed ones, "
        "agents/checkpoints/README.md): a learned cell runs once per seed and the table "
        "shows mean ± 95 % CI.",
    ),
    init: options.Init = defaults.INIT,
    partition: str = typer.Option(defaults.PARTITION, help=" | ".join(PARTITIONS) + "."),
    out: Path = typer.Option(
        None,
        help=with_quick("Output folder", defaults.TABLE1_OUT, "out"),
        show_default=False,
    ),
    quick: bool = typer.Option(
        False,
        "--quick",
        help=f"A small subset ({joined(defaults.TABLE1_QUICK['datasets'])}, "
        f"n = {joined(defaults.TABLE1_QUICK['robots'])}, "
        f"{defaults.TABLE1_QUICK['iterations']} iterations) that finishes in about a minute; "
        "--datasets, --robots, --iterations and the other options given replace its defaults.",
    ),
    run: Run,
) -> None:
    """The paper's Table I: datasets × robots × methods, with F* and the gap F/F* − 1.

    Writes OUT/table1.csv (one row per cell), table1.md, table1.tex (ours beside the paper's
    numbers), table1.png/.pdf and one convergence profile per dataset, profile-DATASET-nN.png/.pdf
    (relative gap against parallel time, n = 7 or the largest team). Every dataset is loaded
    and every team size checked before anything is computed.
    """
    from popbench.harness.table1 import Table1Config, run_table1

    settings: dict = {
        "seeds": options.integers(seeds, "seed", 0),
        "training_seeds": options.integers(training_seeds, "training seed", 0),
        "init": options.start(init),
        "partition": options.names(partition, PARTITIONS, "partition")[0],
    }
    if methods is not None:
        settings["methods"] = options.methods(methods)
    if datasets is not None:
        settings["datasets"] = options.names(datasets, None, "dataset")
    if robots is not None:
        settings["robots"] = options.integers(robots, "robots")
    if iterations is not None:
        settings["iterations"] = iterations
    if out is not None:
        settings["out"] = out
    config = Table1Config.quick(**settings) if quick else Table1Config(**settings)
    files = "table1.csv, table1.md, table1.tex, table1.png, table1.pdf, profile-*.png/.pdf"
    wrote(len(run_table1(config, run)), "cells", config.out, files)


@experiment(
    "outliers",
    "popbench run outliers --rate 0.025,0.05,0.1       # the paper's Table II",
    "popbench run outliers --datasets intel --seeds 0 --iterations 100 --out results/o",
    "popbench run outliers --model vertigo-random --rate 0.1 --datasets intel,csail,m3500",
    "popbench run outliers --model vertigo-grouped --group-size 10 --rate 0.05",
    "popbench run outliers --datasets mine.g2o --outlier-mask mine.mask   # its own outliers",
)
def outliers_command(
    *,
    rate: str = typer.Option(
        None,
        help="Outlier rates (fractions), e.g. 0.025,0.05,0.1: corrupt: of the candidate edges; "
        f"vertigo-*: added edges per loop closure of the graph "
        f"(default: {joined(defaults.OUTLIERS_RATES)}).",
        show_default=False,
    ),
    model: str = typer.Option(
        "corrupt",
        help="Outlier model: corrupt (the paper's: loop closures' measurements replaced) | "
        "vertigo-random | vertigo-local | vertigo-grouped (false loop closures added, "
        "docs/outliers.md).",
    ),
    group_size: int = typer.Option(
        None,
        min=1,
        help=f"Edges per group of vertigo-grouped (default: {DEFAULT_GROUP_SIZE}).",
        show_default=False,
    ),
    outlier_mask: Path = typer.Option(
        None,
        help="A file with one line per edge of the one dataset, 1 = false loop closure, 0 = "
        "true: score the dataset's own outliers (no injection; not with --rate, --model).",
        show_default=False,
    ),
    datasets: str = typer.Option(joined(defaults.OUTLIERS_DATASETS), help="Datasets."),
    methods: str = typer.Option(
        joined(defaults.OUTLIERS_METHODS), help="Methods (need an inlier mask)."
    ),
    robots: int = typer.Option(defaults.OUTLIERS_ROBOTS, min=1, help="Team size."),
    seeds: str = typer.Option(
        joined(defaults.OUTLIERS_SEEDS), help="Seeds: outlier draw and methods."
    ),
    iterations: options.Iterations = defaults.ITERATIONS,
    kernel: str = typer.Option(
        None,
        help="mm-pgo robust kernel: huber | gm | welsch (default: its registry record's).",
        show_default=False,
    ),
    init: str = typer.Option(
        defaults.INIT,
        help="odometry | chordal (made from the corrupted data) | given (the file's).",
    ),
    candidates: str = typer.Option(
        "loops",
        help="Edges that may be corrupted: loops (loop closures; odometry, incl. cut odometry, "
        "never) | paper (loop closures + every inter-robot edge: breaks the odometry start).",
    ),
    out: options.Out = Path(defaults.OUTLIERS_OUT),
    run: Run,
) -> None:
    """The paper's Table II: F, outlier precision and recall with corrupted loop closures
    (--model corrupt) or with false loop closures added (vertigo-random, vertigo-local,
    vertigo-grouped) or named by a mask file (--outlier-mask).

    Writes OUT/outliers.csv (one row per cell), outliers_summary.csv, outliers.md and outliers.tex
    (mean ± 95 % half-width over seeds beside the paper's numbers). Every dataset is loaded and
    the team size checked before anything is computed.
    """
    from popbench.harness.outliers import OutliersConfig, run_outliers
    from popbench.outliers import CANDIDATE_SETS, CORRUPT, OUTLIER_MODELS

    model = options.names(model, OUTLIER_MODELS, "--model")[0]
    if outlier_mask is not None:
        if not outlier_mask.is_file():
            raise ValueRangeError("--outlier-mask", str(outlier_mask), "an existing file")
        if rate is not None or model != CORRUPT:
            raise PopbenchError("--outlier-mask names the outliers: give no --rate or --model")
    if group_size is not None and model != "vertigo-grouped":
        raise PopbenchError(f"--group-size is for --model vertigo-grouped, not {model}")
    config = OutliersConfig(
        datasets=options.names(datasets, None, "dataset"),
        rates=options.rates(rate or joined(defaults.OUTLIERS_RATES)),
        methods=options.methods(methods),
        robots=robots,
        seeds=options.integers(seeds, "seed", 0),
        iterations=iterations,
        init=options.start(init),
        kernel=None if kernel is None else options.names(kernel, ROBUST_KERNELS, "kernel")[0],
        candidates=options.names(candidates, tuple(CANDIDATE_SETS), "candidates")[0],
        model=model,
        group_size=group_size or DEFAULT_GROUP_SIZE,
        outlier_mask=outlier_mask,
        out=out,
    )
    files = "outliers.csv, outliers_summary.csv, outliers.md, outliers.tex"
    wrote(len(run_outliers(config, run)), "cells", config.out, files)


SCALABILITY_ROBOTS = joined(defaults.SCALABILITY_ROBOTS)  # the command line's form


@experiment(
    "scalability",
    "popbench run scalability                            # m3500, n = 1 … 70",
    "popbench run scalability --dataset intel --robots 1,3,7 --methods mm-pgo --out results/s",
)
def scalability_command(
    *,
    dataset: str = typer.Option(defaults.SCALABILITY_DATASET, help="Dataset."),
    robots: options.TeamSizes = SCALABILITY_ROBOTS,
    methods: str = typer.Option(joined(defaults.SCALABILITY_METHODS), help="Methods."),
    iterations: options.Iterations = defaults.ITERATIONS,
    init: options.Init = defaults.INIT,
    out: options.Out = Path(defaults.SCALABILITY_OUT),
    run: Run,
) -> None:
    """The paper's Fig. 5: F and time against team size, actors replicated.

    Writes OUT/scalability.csv and scalability.png/.pdf. The dataset is loaded and every team
    size checked before anything is computed.
    """
    from popbench.harness.scalability import ScalabilityConfig, run_scalability

    config = ScalabilityConfig(
        dataset=dataset,
        robots=options.integers(robots, "robots"),
        methods=options.methods(methods),
        iterations=iterations,
        init=options.start(init),
        out=out,
    )
    files = "scalability.csv, scalability.png/.pdf"
    wrote(len(run_scalability(config, run)), "cells", config.out, files)


HELDOUT_NOISE = NOISES  # the synthetic levels and the SLAM-shaped maps


def keyword_options(text: str, option: str) -> dict[str, Any]:
    """``KEY=VALUE,…`` (each VALUE read as JSON where it is: numbers, true/false, [lists], else
    a string) or a JSON object, as a dict."""
    if text.lstrip().startswith("{"):
        try:
            return dict(json.loads(text))
        except ValueError as error:
            raise ValueRangeError(option, text, f"a JSON object ({error})") from None
    options = {}
    for item in re.split(r",(?![^\[]*\])", text) if text else []:  # commas outside [...]
        key, equals, value = item.partition("=")
        if not equals or not key.strip():
            raise ValueRangeError(option, item, "KEY=VALUE")
        try:
            options[key.strip()] = json.loads(value)
        except ValueError:
            options[key.strip()] = value.strip()
    return options


@experiment(
    "heldout",
    "popbench run heldout                               # V2, n = 7, 100 problems, every row",
    "popbench run heldout --rows no-op,ga-sac,local-lm --checkpoint runs/a/actor.pt",
    "popbench run heldout --problems 30 --rows gn-sweep,learned-order,imitation,ga-sac,local-lm",
    "popbench run heldout --noise V1,V3 --robots 3,7 --problems 30 --consensus admm",
    "popbench run heldout --robots 3 --problems 2 --rows initial,no-op,local-lm --json",
    "popbench run heldout --problems 30 --rows no-op,ga-sac --outlier-rate 0.1",
    "popbench run heldout --problems 30 --rows gn-sweep,ga-sac,local-lm --policy mine.py:act "
    "--policy-env correction=subtree,observation=invariant",
    "popbench run heldout --problems 10 --rows gn-sweep,local-lm --policy "
    "examples/reinforce.py:load_policy --policy-arg runs/reinforce/policy.pt "
    '--policy-env "$(python examples/reinforce.py --env)" --policy-name reinforce',
)
def heldout_command(
    *,
    noise: str = typer.Option(
        "V2", help="Synthetic noise levels: V1, V2, V3, SLAM (single-trajectory maps; comma list)."
    ),
    robots: options.TeamSizes = "7",
    problems: int = typer.Option(
        100, min=1, help="Held-out problems per (noise, team size); seeds 2^32 + k."
    ),
    poses_per_robot: int = typer.Option(
        60, min=2, help="Poses of each robot's synthetic trajectory."
    ),
    rows: str = typer.Option(
        None,
        help="Rows (comma list, computed in the table's order; default: every row, a learned "
        "row left out when its checkpoint is missing): initial, no-op, random, greedy, "
        "expert, gn-sweep, learned-order, imitation, ga-sac, local-lm, ground-truth "
        "(prop-v1: the former name of ga-sac).",
        show_default=False,
    ),
    checkpoint: Path = typer.Option(
        None,
        help="The ga-sac row's actor, any training checkpoint or snapshot; the row is shown "
        "under the algorithm that trained it (ga-sac, mappo, ippo; default: prop-v1's, the "
        "cpu-residual recipe's GA-SAC actor actor-V2-n7-residual.pt; agents/checkpoints).",
        show_default=False,
    ),
    imitation_checkpoint: Path = typer.Option(
        None,
        help="The actor of the imitation and learned-order rows (default: the imitation phase "
        "of the ga-sac row's recipe, imitation-V2-n7-residual.pt).",
        show_default=False,
    ),
    consensus: str | None = typer.Option(
        None,
        help="The consensus every row goes through: admm | aligned-admm (default: the one "
        "prop-v1 and local-lm use, popbench.consensus.reconcile.DEFAULT_CONSENSUS).",
        show_default=False,
    ),
    consensus_iterations: int = typer.Option(
        None,
        min=1,
        help="The consensus's ADMM iterations at most (default: the tables' 200, "
        "popbench.consensus.reconcile.DEFAULT_CONSENSUS_ITERATIONS); more shows what a converged "
        "consensus keeps of each row.",
        show_default=False,
    ),
    out: options.Out = Path("results/heldout"),
    outlier_rate: float = typer.Option(
        0.0,
        min=0.0,
        max=1.0,
        help="Outliers injected into every problem (share of the loop closures); adds the "
        "learned rows' gate_auc, gate_precision and gate_recall.",
    ),
    step_rule: str = typer.Option(
        DEFAULT_STEP_RULE,
        help="The environment's step rule in every episode row: line-search (prop-v1's: the "
        "executed correction unclipped, scaled so that no step raises a robot's local F) | clip "
        "(clipped to its bounds, as the actors were trained; the tables before 2026-12-05) | "
        "nonmonotone, search-with-clip (two measured variants of the line search); "
        "docs/environment.md.",
    ),
    policy: str = typer.Option(
        None,
        help="Score your own policy as one more row: MODULE:ATTR or path/to/file.py:ATTR, a "
        "TorchRL actor module or a callable (agents) -> (edge (n,), delta (n, 3)); with "
        "--policy-arg, a factory ATTR(ARG) returning one (docs/algorithms.md).",
        show_default=False,
    ),
    policy_arg: str = typer.Option(
        None, help="The argument of a --policy factory (e.g. a weights file).", show_default=False
    ),
    policy_name: str = typer.Option(
        None, help="The --policy row's name (default: ATTR).", show_default=False
    ),
    policy_env: str = typer.Option(
        None,
        help="The env the --policy acts in: envs.make_torchrl_env's keyword options as "
        "KEY=VALUE,… or a JSON object (default: its defaults, the paper's game).",
        show_default=False,
    ),
    run: Run,
    json_output: bool = typer.Option(
        False, "--json", help="Print the summary as one JSON object, the last line on stdout."
    ),
) -> None:
    """The learned solver on held-out synthetic problems, row by row, through one consensus.

    Every row is an estimate of the same problem brought through the same consensus, so the
    rows differ only in what was done to the local graphs before it (nothing, a baseline
    policy, the expert, the learned actors, the local optima, the ground truth). Writes
    OUT/heldout.csv (one line per problem and row), summary.csv (mean and median F, local F
    and ATE with bootstrap 95 % CIs, the share of the no-op → local-lm gap each row closes),
    paired.csv (learned-order − gn-sweep, imitation − learned-order, ga-sac − imitation
    problem by problem, with 95 % CIs; a --policy row against no-op, gn-sweep, imitation,
    ga-sac and local-lm), heldout.md, heldout.png/.pdf and manifest.json.
    """
    from popbench.consensus.reconcile import (
        CONSENSUS_MODES,
        DEFAULT_CONSENSUS,
        DEFAULT_CONSENSUS_ITERATIONS,
    )
    from popbench.harness.heldout import (
        ROW_ALIASES,
        ROWS,
        HeldoutConfig,
        canonical_rows,
        run_heldout,
        summary_json,
    )

    if policy is None and (policy_arg, policy_name, policy_env) != (None, None, None):
        raise PopbenchError("--policy-arg, --policy-name and --policy-env need --policy")
    for path, what in (
        (checkpoint, "--checkpoint"),
        (imitation_checkpoint, "--imitation-checkpoint"),
    ):
        if path is not None and not path.is_file():
            raise ValueRangeError(what, str(path), "an existing checkpoint file")
    config = HeldoutConfig(
        noise=options.names(noise, HELDOUT_NOISE, "--noise"),
        robots=options.integers(robots, "--robots"),
        problems=problems,
        poses_per_robot=poses_per_robot,
        rows=ROWS
        if rows is None
        else canonical_rows(options.names(rows, ROWS + tuple(ROW_ALIASES), "--rows")),
        consensus=options.names(consensus or DEFAULT_CONSENSUS, CONSENSUS_MODES, "--consensus")[0],
        consensus_iterations=consensus_iterations or DEFAULT_CONSENSUS_ITERATIONS,
        checkpoint=checkpoint,
        imitation_checkpoint=imitation_checkpoint,
        out=out,
        outlier_rate=outlier_rate,
        step_rule=options.names(step_rule, STEP_RULES, "--step-rule")[0],
        policy=policy,
        policy_arg=policy_arg,
        policy_name=policy_name,
        policy_env=keyword_options(policy_env or "", "--policy-env"),
    )
    table = run_heldout(config, run)
    if json_output:
        typer.echo(summary_json(table))
    else:
        files = "heldout.csv, summary.csv, paired.csv, heldout.md, heldout.png, heldout.pdf"
        wrote(len(table), "rows", config.out, files)
