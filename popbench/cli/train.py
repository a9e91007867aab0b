"""``popbench train``: GA-SAC, MAPPO or IPPO actors for the learned methods.

The trainer lives in ``agents/``, a layer above the core: it is named in the core's registry
(:data:`popbench.methods.ENTRY_POINTS`) and imported on first use, as the methods' solve
functions are, so ``popbench`` never imports ``agents`` at import time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from popbench.choices import NOISES
from popbench.cli.errors import Interrupted
from popbench.cli.options import CommandThreads
from popbench.errors import ValueRangeError

TRAIN_ENVS = NOISES
TRAIN_DEVICES = ("cpu", "cuda")


def train_config(
    env: str | None,
    robots: int | None,
    seed: int,
    frames: int | None,
    device: str,
    out: str | None,
    preset: str,
    progress: bool = True,
    init_actor: Path | None = None,
    settings: list[str] | None = None,
    algorithm: str | None = None,
    imitation_episodes: int | None = None,
    task: str | None = None,
):
    """The `TrainConfig` of ``popbench train``: ``preset``, on the benchmark ``task`` when given,
    with the command's values applied (``env``, ``robots``, ``algorithm``,
    ``imitation_episodes``: None keeps the task's or the preset's)."""
    import dataclasses

    from popbench.methods import entry_point

    presets = entry_point("train.presets")  # agents.config.PRESETS
    algorithms = entry_point("train.algorithms")

    tasks = entry_point("train.tasks")  # envs.tasks.TASKS
    if task is not None and task not in tasks:
        raise ValueRangeError("--task", task, " or ".join(tasks))
    if env is not None and env not in TRAIN_ENVS:
        raise ValueRangeError("--env", env, " or ".join(TRAIN_ENVS))
    if robots is not None and robots < 1:
        raise ValueRangeError("--robots", robots, "an integer ≥ 1")
    if frames is not None and frames < 1:
        raise ValueRangeError("--frames", frames, "an integer ≥ 1")
    if device not in TRAIN_DEVICES:
        raise ValueRangeError("--device", device, " or ".join(TRAIN_DEVICES))
    if preset not in presets:
        raise ValueRangeError("--preset", preset, " or ".join(presets))
    if init_actor is not None and not init_actor.is_file():
        raise ValueRangeError("--init-actor", str(init_actor), "an existing actor checkpoint")
    if algorithm is not None and algorithm not in algorithms:
        raise ValueRangeError("--algorithm", algorithm, " or ".join(algorithms))
    if imitation_episodes is not None and imitation_episodes < 0:
        raise ValueRangeError("--imitation-episodes", imitation_episodes, "an integer ≥ 0")
    if device == "cuda":
        import torch

        if not torch.cuda.is_available():
            raise ValueRangeError("--device", device, "cpu (no CUDA device is available)")
    if imitation_episodes is not None:  # a shorthand of --set imitation.episodes=N
        settings = [*(settings or []), f"imitation.episodes={imitation_episodes}"]
    config = presets[preset]
    if task is not None:
        config = entry_point("train.with_task")(config, tasks[task])
    config = entry_point("train.overrides")(config, settings or [])
    if algorithm is not None:
        config = dataclasses.replace(config, algorithm_name=algorithm)
    name = config.algorithm_name
    env = env or config.experiment.noise
    robots = config.experiment.robots if robots is None else robots
    experiment = dataclasses.replace(
        config.experiment,
        noise=env,
        robots=robots,
        seed=seed,
        device=device,
        frames=config.experiment.frames if frames is None else frames,
        out_dir=out or f"runs/{name}-{env}-n{robots}-s{seed}",
        progress=progress,
        init_actor=None if init_actor is None else str(init_actor),
    )
    return dataclasses.replace(config, experiment=experiment)


EPILOG = (
    "Examples:\n\n"
    "  popbench train --env V2 --robots 7 --seed 0\n\n"
    "  popbench train --env V2 --robots 3 --preset cpu-small --frames 20000 --out runs/n3\n\n"
    "  popbench train --preset cpu-residual --init-actor "
    "agents/checkpoints/imitation-V2-n7-residual.pt --out runs/ft\n\n"
    "  popbench train --algorithm mappo --preset cpu-mappo --imitation-episodes 0 --out runs/m\n\n"
    "  popbench train --preset cpu-residual --task noisy --imitation-episodes 0 --out runs/v3\n\n"
    "Writes checkpoint.pt, metrics.csv and learning_curve.png into --out; a rerun with the "
    "same --out resumes from checkpoint.pt unless --no-resume."
)


def train_command(
    env: Annotated[
        str | None,
        typer.Option(
            help="Training problems: V1, V2, V3 (synthetic teams) or SLAM (single-trajectory "
            "maps, popbench.problems.slam_maps; default: the task's, or V2)."
        ),
    ] = None,
    robots: Annotated[
        int | None,
        typer.Option(help="Team size n, the critic is built for n (default: the task's, or 7)."),
    ] = None,
    task: Annotated[
        str | None,
        typer.Option(
            help="Train on a benchmark task (`popbench tasks` lists them): its environment "
            "modes, reward, problems and outliers replace the preset's (default: the preset's)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the environments, torch and replay.")] = 0,
    frames: Annotated[
        int | None, typer.Option(help="Total environment frames (default: the preset's).")
    ] = None,
    device: Annotated[str, typer.Option(help="cpu or cuda.")] = "cpu",
    out: Annotated[
        str | None, typer.Option(help="Run directory (default runs/ALGORITHM-ENV-nN-sS).")
    ] = None,
    resume: Annotated[
        bool, typer.Option("--resume/--no-resume", help="Continue from OUT/checkpoint.pt.")
    ] = True,
    preset: Annotated[
        str,
        typer.Option(
            help="Model/algorithm sizes: paper (5×128 GNN, §IV-A), cpu-small, cpu-imitation "
            "(imitation of the expert first, then GA-SAC), cpu-imitation-robust (the same "
            "on problems with injected outliers, with a supervised gate loss), cpu-residual "
            "(a correction head that reads the base step, GA-SAC on the local F with "
            "a KL anchor to the imitation policy), cpu-mappo or cpu-ippo (MAPPO / IPPO "
            "in cpu-residual's networks, task and imitation phase; docs/algorithms.md)."
        ),
    ] = "paper",
    init_actor: Annotated[
        Path | None,
        typer.Option(
            help="Start from this actor checkpoint (e.g. a committed imitation actor) instead "
            "of the preset's imitation phase; its model and task must be the preset's."
        ),
    ] = None,
    settings: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="Change one setting of the preset, PART.FIELD=VALUE (PART: model, algorithm, "
            "ppo, experiment, task, imitation; agents/config.py documents each field), e.g. "
            "--set algorithm.anchor_weight=0.1; repeatable.",
        ),
    ] = None,
    algorithm: Annotated[
        str | None,
        typer.Option(
            help="ga-sac (soft actor-critic, replay), mappo (PPO, centralised value over all "
            "robots) or ippo (PPO, each robot's own value); all train the same actor. "
            "Default: the preset's (ga-sac, or mappo / ippo for cpu-mappo / cpu-ippo)."
        ),
    ] = None,
    imitation_episodes: Annotated[
        int | None,
        typer.Option(
            help="Episodes of the imitation phase before RL; 0 starts from scratch "
            "(default: the preset's)."
        ),
    ] = None,
    threads: CommandThreads = 1,
) -> None:
    """Train GA-SAC, MAPPO or IPPO actors (TorchRL collector) with checkpoints and curves."""
    from popbench.methods import entry_point
    from popbench.threads import limited_threads

    run_training = entry_point("train.run")  # agents.trainer.train
    config = train_config(
        env,
        robots,
        seed,
        frames,
        device,
        out,
        preset,
        init_actor=init_actor,
        settings=settings,
        algorithm=algorithm,
        imitation_episodes=imitation_episodes,
        task=task,
    )
    with limited_threads(threads):
        try:
            summary = run_training(config, resume=resume).summary()
        except KeyboardInterrupt as interrupt:  # its message says where the checkpoint is
            raise Interrupted(str(interrupt)) from None
    typer.echo(summary)


GATE_EPILOG = (
    "Examples:\n\n"
    "  popbench train-gate agents/checkpoints/imitation-V2-n7-robust.pt\n\n"
    "  popbench train-gate runs/r/imitation-actor.pt --out runs/r/gated.pt --problems 40\n\n"
    "Runs the actor's episode and the consensus on PROBLEMS + VALIDATION synthetic problems "
    "with injected outliers (the actor's team size and noise level), fits a copy of its "
    "encoder to flag the outliers at the reconciled estimate, and writes the checkpoint with "
    "it (prop-v1 then flags from it; docs/outliers.md)."
)


def train_gate_command(
    checkpoint: Annotated[Path, typer.Argument(help="Actor checkpoint (.pt).")],
    out: Annotated[
        Path | None, typer.Option(help="Where to write it (default: over CHECKPOINT).")
    ] = None,
    problems: Annotated[int | None, typer.Option(min=1, help="Training problems.")] = None,
    validation: Annotated[
        int | None, typer.Option(min=1, help="Validation problems, to choose the epoch.")
    ] = None,
    epochs: Annotated[
        int | None, typer.Option(min=1, help="Passes over the training states.")
    ] = None,
    seed: Annotated[
        int | None, typer.Option(help="Seed of the problem streams and shuffling.")
    ] = None,
    threads: CommandThreads = 1,
) -> None:
    """Fit the outlier gate of a trained actor: its gated encoder re-run after the consensus.

    Unset options take agents.config.OutlierGateConfig's values."""
    import dataclasses

    from popbench.methods import entry_point
    from popbench.threads import limited_threads

    given = {"problems": problems, "validation": validation, "epochs": epochs, "seed": seed}
    defaults = entry_point("train.gate_config")()  # agents.config.OutlierGateConfig
    config = dataclasses.replace(defaults, **{k: v for k, v in given.items() if v is not None})
    fit = entry_point("train.fit_gate")  # agents.gate_training.fit_checkpoint
    with limited_threads(threads):
        typer.echo(fit(checkpoint, out or checkpoint, config))


TASKS_EPILOG = (
    "Examples:\n\n"
    "  popbench tasks\n\n"
    "  popbench train --task actors --preset cpu-residual\n\n"
    "In Python: envs.make_torchrl_env(task=NAME), envs.make_pettingzoo_env(task=NAME) "
    "(docs/environment.md, 'Benchmark tasks')."
)


def tasks_command() -> None:
    """List the benchmark tasks: their problems, environment modes and evaluation."""
    import textwrap

    from popbench.methods import entry_point

    for name, task in entry_point("train.tasks").items():  # envs.tasks.TASKS
        problems = f"n={task.robots} {task.noise}, {task.poses_per_robot} poses/robot"
        if task.outlier_rate_max:
            problems += f", outliers U(0, {task.outlier_rate_max:g})"
        bonus = " + terminal bonus" if task.terminal_bonus else ""
        modes = f"{', '.join(task.core_options().values())}; reward {task.reward or 'localisation'}"
        heldout = f"held-out: {task.eval_problems} problems"
        if task.eval_outlier_rate:
            heldout += f", outlier rate {task.eval_outlier_rate:g}"
        typer.echo(f"{name}\n  {problems}\n  {modes}{bonus}\n  {heldout}")
        typer.echo(textwrap.fill(task.summary, 88, initial_indent="  ", subsequent_indent="  "))
