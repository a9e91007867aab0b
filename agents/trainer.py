"""Training: TorchRL `Collector` (0.14's SyncDataCollector) → GA-SAC (uniform replay → GASACLoss),
or MAPPO / IPPO (agents.ppo_trainer: GAE → ClipPPOLoss), by `TrainConfig.algorithm_name`.

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

Held-out evaluation: `eval_problems` synthetic problems from a seed stream disjoint from training
(seed + EVAL_SEED_OFFSET), rewarded with F, run for one episode with the deterministic policy;
the score is 1 − Σ_i F_i(T) / Σ_i F_i(0) over the agents' local graphs (before consensus).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import signal
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from agents.checkpoint import read_checkpoint, save_checkpoint, save_snapshot
from agents.config import TrainConfig
from agents.diagnostics import critic_probe
from agents.imitation import run_phase as run_imitation_phase
from agents.imitation import start_from_actor
from agents.metrics import METRIC_FIELDS, EpisodeTracker, plot_learning_curve, truncate_metrics
from agents.resume import check_resume_config
from agents.session import Session, build_session, make_env, restore, session_state

EVAL_SEED_OFFSET = 1_000_003


def optimise(session: Session, batch: TensorDictBase) -> dict[str, float]:
    """One GA-SAC step on a minibatch: the summed losses reach disjoint parameter groups.

    Until the critic warm-up is over (`session.actor_learns`, set by the trainer: after
    `critic_warmup_updates` updates, or earlier by `critic_patience`) only the critic and the
    temperatures learn: the actor's loss is left out, so the actor does not follow the gradient
    of a critic that cannot yet tell one correction from another. The anchor's weight follows
    the actor's updates (AlgorithmConfig.anchor_updates).
    """
    algorithm = session.config.algorithm
    actor_learns = session.actor_learns or session.updates >= algorithm.critic_warmup_updates
    session.actor_learns = actor_learns
    decay = 1.0  # anchor_updates 0: the anchor's weight is held
    if algorithm.anchor_updates > 0:
        decay = max(0.0, 1.0 - session.actor_updates / algorithm.anchor_updates)
    session.loss.anchor_scale.fill_(decay)
    out = session.loss(batch)
    total = sum(
        out[key]
        for key in out.keys()
        if key.startswith("loss_") and (actor_learns or key != "loss_actor")
    )
    for optimiser in session.optimisers.values():
        optimiser.zero_grad(set_to_none=True)
    total.backward()
    clip = session.config.algorithm.max_grad_norm
    torch.nn.utils.clip_grad_norm_(session.loss.actor_parameters(), clip)
    torch.nn.utils.clip_grad_norm_(session.loss.critic_parameters(), clip)
    for optimiser in session.optimisers.values():
        optimiser.step()
    session.updater.step()
    session.updates += 1
    session.actor_updates += int(actor_learns)
    return {key: float(value.detach()) for key, value in out.items()}


@torch.no_grad()
def calibrate(session: Session, warmup: TensorDictBase) -> dict[str, float]:
    """At the end of the warm-up (before the first update): the reward scale c = 1 / std of the
    warm-up rewards (auto_reward_scale) and the correction's target entropy = the start
    policy's own on the warm-up states (auto_delta_entropy); returns what was set."""
    algorithm, loss = session.config.algorithm, session.loss
    values = {}
    if algorithm.auto_reward_scale:
        reward = warmup["next", "agents", "reward"].float()
        loss.reward_scale.fill_(1.0 / float(reward.std().clamp(min=1e-6)))
        values["reward_scale"] = float(loss.reward_scale)
    if algorithm.auto_delta_entropy:
        graphs = loss._graphs(warmup, next_=False)
        out = loss._act(warmup, graphs, next_=False)
        acting = loss._acting(out)
        mean_log_prob = (acting * out.delta_log_prob).sum() / acting.sum().clamp(min=1.0)
        loss.delta_target_entropy.fill_(-float(mean_log_prob))
        values["delta_target_entropy"] = float(loss.delta_target_entropy)
    return values


@torch.no_grad()
def held_out_td_error(session: Session, transitions: TensorDictBase) -> float:
    """Mean |TD error| of the critic on `transitions` kept out of the replay buffer."""
    loss = session.loss
    graphs = loss._graphs(transitions, next_=False)
    target = loss.soft_target(transitions, loss._graphs(transitions, next_=True), loss._alphas())
    _, _, td_error = loss.qvalue_loss(transitions, graphs, target)
    return float(td_error.abs().mean())


class CriticWarmup:
    """The critic-only phase's stopping rule (AlgorithmConfig.critic_patience): the held-out TD
    error, checked every `every` updates, has not fallen by 1 % for `patience` checks."""

    def __init__(self, patience: int, every: int = 16) -> None:
        self.patience, self.every = patience, every
        self.best, self.stale = float("inf"), 0

    def over(self, session: Session, heldout: TensorDictBase | None) -> bool:
        if self.patience <= 0 or heldout is None or session.updates % self.every:
            return False
        error = held_out_td_error(session, heldout)
        if error < 0.99 * self.best:
            self.best, self.stale = error, 0
        else:
            self.stale += 1
        return self.stale >= self.patience


@torch.no_grad()
def evaluate_f_reduction(session: Session, eval_env) -> float:
    """1 − ΣF(T)/ΣF(0) of one deterministic episode on the held-out problems.

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


@dataclasses.dataclass(frozen=True)
class Learner:
    """How `train` builds, saves, restores and trains one algorithm's session.

    `batches(session)` returns the per-batch learning step of a (possibly resumed) run: a
    `BatchLearner` (e.g. GA-SAC's replay and updates, agents.ppo_trainer's PPO epochs).
    """

    name: str  # the progress bar's label
    build: Callable[[TrainConfig], Any]
    restore: Callable[[Any, dict[str, Any]], None]
    state: Callable[[Any], dict[str, Any]]
    batches: Callable[[Any], BatchLearner]
    fields: tuple[str, ...]  # metrics.csv's columns


def learner_of(config: TrainConfig) -> Learner:
    """The `Learner` of `config.algorithm_name` (the PPO one imported on first use)."""
    if config.algorithm_name == "ga-sac":
        return GASAC
    from agents.ppo_trainer import PPO

    return PPO


def train(config: TrainConfig, resume: bool = True) -> TrainResult:
    """Train `config.algorithm_name` (GA-SAC, MAPPO or IPPO) as configured (module docstring)."""
    started = time.perf_counter()
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


class BatchLearner(Protocol):
    """One algorithm's learning from each collected batch (used by `_run`)."""

    def learn(self, data: TensorDictBase) -> dict[str, Any]:
        """Learn from a collector batch [num_envs, T]; the metrics row's entries it sets."""

    def evaluate(self, eval_env: Any) -> dict[str, Any]:
        """Extra entries of the row at an evaluation point (after the held-out F reduction)."""


class GASACBatches:
    """GA-SAC's per-batch step: replay, warm-up (calibration, held-out transitions for the
    critic warm-up rule) and `updates_per_batch` optimisation steps."""

    def __init__(self, session: Session) -> None:
        experiment, algorithm = session.config.experiment, session.config.algorithm
        self.session = session
        self.buffer = ReplayBuffer(
            storage=LazyTensorStorage(algorithm.buffer_size, device=experiment.device),
            batch_size=algorithm.batch_size,
        )
        # A resumed run has lost its buffer: it needs only one minibatch before updating again.
        warmup = algorithm.warmup_frames if session.frames == 0 else algorithm.batch_size
        self.warmup_end = session.frames + warmup
        self.warmup_rule = CriticWarmup(algorithm.critic_patience)
        self.heldout: TensorDictBase | None = None  # transitions never replayed (warm-up rule)
        if session.frames == 0:  # the fine-tuning's start policy is the anchor's π₀
            session.loss.set_anchor(session.actor)

    def learn(self, data: TensorDictBase) -> dict[str, Any]:
        session, buffer = self.session, self.buffer
        row: dict[str, Any] = {}
        transitions = data.reshape(-1)
        if self.heldout is None and session.updates == 0 and session.frames >= self.warmup_end:
            self.heldout = transitions[: transitions.numel() // 4]  # a quarter, never replayed
            buffer.extend(transitions[transitions.numel() // 4 :])
            row.update(calibrate(session, buffer[:]))
        else:
            buffer.extend(transitions)
        algorithm = session.config.algorithm
        if session.frames >= self.warmup_end and len(buffer) >= algorithm.batch_size:
            for _ in range(algorithm.updates_per_batch):
                if not session.actor_learns and self.warmup_rule.over(session, self.heldout):
                    session.actor_learns = True
                logs = optimise(session, buffer.sample())
                row.update({k: v for k, v in logs.items() if k in METRIC_FIELDS})
        return row

    def evaluate(self, eval_env: Any) -> dict[str, Any]:
        if self.session.updates > 0:
            return {"critic_probe": critic_probe(self.session, eval_env)}
        return {}


GASAC = Learner("GA-SAC", build_session, restore, session_state, GASACBatches, METRIC_FIELDS)


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
