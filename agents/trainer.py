"""Training: TorchRL `Collector` (0.14's SyncDataCollector) → the learner of
`TrainConfig.algorithm_name` (agents.algorithms): GA-SAC (agents.gasac_trainer: uniform replay →
GASACLoss) or MAPPO / IPPO (agents.ppo_trainer: GAE → ClipPPOLoss).

`train(config)` (what `popbench train` calls) writes into `config.experiment.out_dir`:
    checkpoint.pt   latest state (agents.checkpoint); `resume=True` continues from it
    snapshots/actor-FRAMES.pt  the actor alone (agents.checkpoint.save_snapshot) at the start
                    (0 frames: the imitation / --init-actor / untrained start), at every
                    checkpoint and at the end: the points of the held-out learning curves
    metrics.csv     one row per collector batch: frames, updates, episodes, episode_return (mean
                    over episodes finished in the batch of the per-agent-mean return), losses,
                    temperatures, edge entropy, mean log π(δ), mean Q of the taken actions,
                    gate mean, loss_bc / loss_gate when weighted (last update of the batch),
                    at eval points eval_f_reduction, and
                    wall_s (seconds of training, summed over resumed calls)
    learning_curve.png, .pdf  episode return and held-out F reduction against frames
    imitation.pt, imitation.csv, imitation-actor.pt  the imitation phase (agents.imitation),
                    which runs first when `config.imitation.episodes` > 0 (with
                    `experiment.init_actor` set, that actor is the start instead, copied to
                    imitation-actor.pt)
and returns a `TrainResult` (frames trained by this call, total frames, updates).

Resuming: the checkpoint's config must match the requested one except for the experiment's
device, frames, out_dir and progress (`ResumeConfigError` otherwise, naming the options).
metrics.csv is cut back to the checkpoint's frames first: a run killed between two periodic
checkpoints has logged batches that the resumed run collects again. Checkpoints and evaluations
fall on multiples of their intervals, whatever frame count a run resumes at.

Interrupts (Ctrl-C): a SIGINT that arrives while the run learns from a batch is held until
that batch's updates are done (a second SIGINT stops at once), so a checkpoint never holds part
of a batch; the run then logs the batch, saves a checkpoint and raises KeyboardInterrupt, whose
message says where the checkpoint is. One that arrives while a batch is collected drops that
batch (the resumed run collects it again). The checkpoint keeps the count of finished episodes;
a resumed run restarts the episodes that were in progress (the environments are not saved).

Frames are counted as TorchRL does: one frame = one step of one environment of the batch (all
n agents at once), so a transition in the buffer is one joint (multi-agent) step.
Memory: `train` keeps freed blocks in the process (agents.allocator; glibc only).
Held-out evaluation: :func:`evaluate_f_reduction`.
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torchrl.collectors import Collector
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from agents.algorithms import learner_of
from agents.allocator import retain_freed_memory
from agents.checkpoint import read_checkpoint, save_checkpoint, save_snapshot
from agents.config import TrainConfig
from agents.imitation import run_phase as run_imitation_phase
from agents.imitation import start_from_actor
from agents.learner import Learner
from agents.metrics import EpisodeTracker, plot_learning_curve, truncate_metrics
from agents.resume import check_resume_config
from agents.session import Session, make_env

EVAL_SEED_OFFSET = 1_000_003


@torch.no_grad()
def evaluate_f_reduction(session: Session, eval_env) -> float:
    """1 − ΣF(T)/ΣF(0) of one deterministic episode on the held-out problems.

    `eval_problems` synthetic problems from a seed stream disjoint from training (seed +
    EVAL_SEED_OFFSET), rewarded with F, run for one episode with the deterministic policy; the
    score is 1 − Σ_i F_i(T) / Σ_i F_i(0) over the agents' local graphs (before consensus).

    Steps past an element's end are harmless: its only valid action is then the no-op.
    """
    env = TransformedEnv(
        eval_env, session.policy.primer(session.dims["agents"], session.dims["choices"])
    )
    env.set_seed(session.config.experiment.seed + EVAL_SEED_OFFSET)
    tensordict = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        for _ in range(session.dims["choices"]):
            tensordict = env.step(session.policy(tensordict))
            if bool(tensordict["next", "done"].all()):
                break
            tensordict = step_mdp(tensordict)
    state = eval_env.core.state
    return float(1.0 - state.loss.sum() / state.initial_loss.sum())


@dataclasses.dataclass(frozen=True)
class TrainResult:
    """What `train` did: `str()` / `os.fspath()` of it is the run directory."""

    out_dir: Path
    frames_trained: int  # environment frames collected by this call
    frames: int  # total frames of the run (the checkpoint's)
    updates: int  # total optimisation steps of the run
    resumed_from: int  # frames of the checkpoint this call resumed from (0: a new run)
    wall_s: float = 0.0  # wall time of this call [s], imitation phase included

    def __str__(self) -> str:
        return str(self.out_dir)

    def __fspath__(self) -> str:
        return str(self.out_dir)

    def summary(self) -> str:
        """One line for the user, e.g. `trained 1024 frames (resumed at 2048; 3072 in total)`."""
        where = f"run directory {self.out_dir}; wall time {self.wall_s:.0f} s"
        if self.frames_trained == 0:
            return f"nothing to train: the run already has {self.frames} frames; {where}"
        if self.resumed_from:
            done = f"resumed at {self.resumed_from}; {self.frames} in total"
            return f"trained {self.frames_trained} frames ({done}); {where}"
        return f"trained {self.frames_trained} frames; {where}"


def train(config: TrainConfig, resume: bool = True) -> TrainResult:
    """Train `config.algorithm_name` (GA-SAC, MAPPO or IPPO) as configured (module docstring)."""
    started = time.perf_counter()
    retain_freed_memory()
    learner = learner_of(config)
    experiment = config.experiment
    out_dir = Path(experiment.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    checkpoint = out_dir / "checkpoint.pt"
    metrics_path = out_dir / "metrics.csv"
    state = None
    if resume and checkpoint.is_file():
        state = read_checkpoint(checkpoint, experiment.device)
        check_resume_config(checkpoint, state, config)
    session = learner.build(config)
    wall_offset = 0.0
    if state is not None:
        learner.restore(session, state)
        wall_offset = truncate_metrics(metrics_path, session.frames, learner.fields)
    elif metrics_path.exists():
        metrics_path.unlink()
    if session.frames == 0:  # before any RL frame: the start policy (GA-SAC's anchor π₀)
        if experiment.init_actor is not None:
            start_from_actor(session, Path(experiment.init_actor), out_dir)
        elif config.imitation.episodes > 0:
            run_imitation_phase(session, out_dir)
        save_snapshot(out_dir, learner.state(session))
    resumed_from = session.frames
    remaining = experiment.frames - session.frames
    tracker = EpisodeTracker(experiment.num_envs, int((state or {}).get("episodes", 0)))
    if remaining > 0:
        _run(session, learner, remaining, checkpoint, metrics_path, wall_offset, tracker)
    final = learner.state(session) | {"episodes": tracker.episodes}
    save_checkpoint(checkpoint, final)
    save_snapshot(out_dir, final)
    plot_learning_curve(metrics_path, out_dir / "learning_curve")
    return TrainResult(
        out_dir,
        session.frames - resumed_from,
        session.frames,
        session.updates,
        resumed_from,
        time.perf_counter() - started,
    )


# ----- the training loop ----------------------------------------------------------------------


def is_interrupt(error: BaseException) -> bool:
    """A KeyboardInterrupt, or an error raised while one was being handled.

    tensordict 0.14's `TensorDictBase.__exit__` returns a TensorDict when a non-Exception
    (KeyboardInterrupt) leaves a `with params.to_module(module):` block, as in agents.loss, and
    Python's truth test of that return value raises `RuntimeError: Converting a tensordict to
    boolean value is not permitted`, with the KeyboardInterrupt as its context.
    """
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__context__
    return False


@contextlib.contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Hold a SIGINT that arrives inside the block until it ends (then raise KeyboardInterrupt);
    a second SIGINT raises at once. A no-op off the main thread or under a custom handler."""
    if (
        threading.current_thread() is not threading.main_thread()
        or signal.getsignal(signal.SIGINT) is not signal.default_int_handler
    ):
        yield
        return
    caught: list[int] = []

    def hold(signum, frame) -> None:
        if caught:
            signal.default_int_handler(signum, frame)
        caught.append(signum)

    previous = signal.signal(signal.SIGINT, hold)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
    if caught:
        raise KeyboardInterrupt


def _next_multiple(frames: int, interval: int) -> int:
    return (frames // interval + 1) * interval


def _run(
    session: Any,
    learner: Learner,
    remaining: int,
    checkpoint: Path,
    metrics_path: Path,
    wall_offset: float,
    tracker: EpisodeTracker,
) -> None:
    """Collect `remaining` more frames (rounded up to whole batches), learning and logging."""
    experiment = session.config.experiment
    frames_per_batch = max(experiment.num_envs, experiment.frames_per_batch)
    frames_per_batch -= frames_per_batch % experiment.num_envs
    collector = Collector(
        session.env,
        session.policy,
        frames_per_batch=frames_per_batch,
        total_frames=math.ceil(remaining / frames_per_batch) * frames_per_batch,
        device=experiment.device,
        auto_register_policy_transforms=False,  # the policy needs only its own primer
    )
    batches = learner.batches(session)
    eval_env = make_env(
        session.config, experiment.eval_problems, experiment.seed + EVAL_SEED_OFFSET, reward="F"
    )
    next_checkpoint = _next_multiple(session.frames, experiment.checkpoint_interval)
    next_eval = _next_multiple(session.frames, experiment.eval_interval)
    start = time.perf_counter() - wall_offset
    progress = _progress(learner.name, experiment.progress, experiment.frames, session.frames)
    pending: dict[str, Any] | None = None  # the row of a batch counted but not yet logged
    try:
        with metrics_path.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, learner.fields)
            if handle.tell() == 0:
                writer.writeheader()
            try:
                for data in collector:
                    session.frames += data.numel()
                    returns = tracker.update(data)
                    pending = dict.fromkeys(learner.fields, "")
                    pending.update(
                        frames=session.frames,
                        updates=session.updates,
                        episodes=tracker.episodes,
                        episode_return=sum(returns) / len(returns) if returns else "",
                    )
                    updates = session.updates
                    with interrupts_deferred():  # a batch is learnt from whole or not at all
                        pending.update(batches.learn(data), updates=session.updates)
                    if session.updates > updates:
                        collector.update_policy_weights_()
                    if session.frames >= next_eval:
                        pending["eval_f_reduction"] = evaluate_f_reduction(session, eval_env)
                        pending.update(batches.evaluate(eval_env))
                        next_eval = _next_multiple(session.frames, experiment.eval_interval)
                    row, pending = pending, None
                    row["wall_s"] = round(time.perf_counter() - start, 3)
                    writer.writerow(row)
                    handle.flush()
                    if session.frames >= next_checkpoint:
                        state = learner.state(session) | {"episodes": tracker.episodes}
                        save_checkpoint(checkpoint, state)
                        save_snapshot(checkpoint.parent, state)
                        next_checkpoint = _next_multiple(
                            session.frames, experiment.checkpoint_interval
                        )
                    if progress is not None:
                        progress.update(data.numel())
                        progress.set_postfix(ret=row["episode_return"], upd=session.updates)
            except BaseException as error:
                if not is_interrupt(error):
                    raise
                if pending is not None:  # log the interrupted batch so the CSV matches
                    pending["updates"] = session.updates  # those done, should it be cut short
                    pending["wall_s"] = round(time.perf_counter() - start, 3)
                    writer.writerow(pending)
                save_checkpoint(checkpoint, learner.state(session) | {"episodes": tracker.episodes})
                raise KeyboardInterrupt(
                    f"checkpoint of {session.frames} frames saved in {checkpoint}"
                ) from None
    finally:
        if progress is not None:
            progress.close()
        collector.shutdown()


def _progress(name: str, enabled: bool, total: int, initial: int):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, unit="frame", desc=name)
