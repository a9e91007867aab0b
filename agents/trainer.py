"""GA-SAC training: TorchRL `Collector` (0.14's SyncDataCollector) → uniform replay → GASACLoss.

`train(config)` (what `popbench train` calls) writes into `config.experiment.out_dir`:
    checkpoint.pt   latest state (agents.checkpoint); `resume=True` continues from it
    metrics.csv     one row per collector batch: frames, updates, episodes, episode_return (mean
                    over episodes finished in the batch of the per-agent-mean return), losses,
                    temperatures, edge entropy, mean log π(δ), mean Q of the taken actions,
                    gate mean (last update of the batch), and at eval points eval_f_reduction
    learning_curve.png  episode return and held-out F reduction against frames

Frames are counted as TorchRL does: one frame = one step of one environment of the batch (all
n agents at once), so a transition in the buffer is one joint (multi-agent) step.

Held-out evaluation: `eval_problems` synthetic problems from a seed stream disjoint from training
(seed + EVAL_SEED_OFFSET), rewarded with F, run for one episode with the deterministic policy;
the score is 1 − Σ_i F_i(T) / Σ_i F_i(0) over the agents' local graphs (before consensus).
"""

from __future__ import annotations

import csv
import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from torchrl.objectives import SoftUpdate

from agents.actor import GASACPolicy, HybridActor
from agents.checkpoint import read_checkpoint, save_checkpoint
from agents.config import TrainConfig
from agents.critic import CentralCritic
from agents.loss import GASACLoss

EVAL_SEED_OFFSET = 1_000_003
METRIC_FIELDS = (
    "frames",
    "updates",
    "episodes",
    "episode_return",
    "loss_actor",
    "loss_qvalue",
    "alpha_edge",
    "alpha_delta",
    "entropy_edge",
    "log_prob_delta",
    "q_mean",
    "gate_mean",
    "eval_f_reduction",
    "wall_s",
)


@dataclasses.dataclass
class Session:
    """Everything a run holds (built by `build_session`)."""

    config: TrainConfig
    env: TransformedEnv
    actor: HybridActor
    policy: GASACPolicy
    loss: GASACLoss
    updater: SoftUpdate
    optimisers: dict[str, torch.optim.Optimizer]
    dims: dict[str, int]
    frames: int = 0
    updates: int = 0


def make_env(config: TrainConfig, batch_size: int, seed: int, **options: Any):
    """The synthetic TorchRL env of the experiment (imported lazily: envs pulls torchrl)."""
    from envs import make_torchrl_env

    experiment = config.experiment
    return make_torchrl_env(
        robots=experiment.robots,
        batch_size=batch_size,
        noise=experiment.noise,
        seed=seed,
        device=experiment.device,
        poses_per_robot=experiment.poses_per_robot,
        **options,
    )


def build_session(config: TrainConfig) -> Session:
    """Env (+ recurrent-state primer), actor, critic, loss, target updater and optimisers."""
    experiment, algorithm = config.experiment, config.algorithm
    torch.manual_seed(experiment.seed)
    base_env = make_env(config, experiment.num_envs, experiment.seed)
    delta_max = tuple(float(v) for v in base_env.core.delta_max.cpu())
    config = dataclasses.replace(
        config, model=dataclasses.replace(config.model, delta_max=delta_max)
    )
    observation = base_env.observation_spec["agents", "observation"]
    dims = {
        "node": observation["node_features"].shape[-1],
        "edge": observation["edge_attr"].shape[-1],
        "agents": experiment.robots,
        "choices": base_env.dims.edges + 1,
    }
    actor = HybridActor(dims["node"], dims["edge"], config.model).to(experiment.device)
    critic = CentralCritic(dims["node"], dims["edge"], dims["agents"], config.model)
    policy = GASACPolicy(actor)
    env = TransformedEnv(base_env, policy.primer(dims["agents"], dims["choices"]))
    loss = GASACLoss(actor, critic.to(experiment.device), algorithm).to(experiment.device)
    updater = SoftUpdate(loss, tau=algorithm.tau)
    optimisers = {
        "actor": torch.optim.Adam(loss.actor_parameters(), lr=algorithm.actor_lr),
        "critic": torch.optim.Adam(loss.critic_parameters(), lr=algorithm.critic_lr),
        "alpha": torch.optim.Adam(loss.alpha_parameters(), lr=algorithm.alpha_lr),
    }
    return Session(config, env, actor, policy, loss, updater, optimisers, dims)


def session_state(session: Session) -> dict[str, Any]:
    return {
        "config": session.config.to_dict(),
        "dims": session.dims,
        "actor": session.actor.state_dict(),
        "loss": session.loss.state_dict(),
        "optimisers": {name: opt.state_dict() for name, opt in session.optimisers.items()},
        "frames": session.frames,
        "updates": session.updates,
    }


def restore(session: Session, path: Path) -> None:
    """Load networks, optimisers and progress from a checkpoint into `session`."""
    state = read_checkpoint(path, session.config.experiment.device)
    session.loss.load_state_dict(state["loss"])
    for name, optimiser in session.optimisers.items():
        optimiser.load_state_dict(state["optimisers"][name])
    session.frames, session.updates = int(state["frames"]), int(state["updates"])


def optimise(session: Session, batch: TensorDictBase) -> dict[str, float]:
    """One GA-SAC step on a minibatch: the summed losses reach disjoint parameter groups.

    During the first `critic_warmup_updates` updates only the critic and the temperatures
    learn: the actor's loss is left out, so the actor does not follow the gradient of a critic
    that cannot yet tell one correction from another.
    """
    out = session.loss(batch)
    actor_learns = session.updates >= session.config.algorithm.critic_warmup_updates
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
    return {key: float(value.detach()) for key, value in out.items()}


class EpisodeTracker:
    """Per-environment running returns (mean over agents) across collector batches."""

    def __init__(self, num_envs: int) -> None:
        self.running = torch.zeros(num_envs)
        self.episodes = 0

    def update(self, data: TensorDictBase) -> list[float]:
        """Returns of the episodes that finished in `data` ([num_envs, T])."""
        reward = data["next", "agents", "reward"].mean(dim=(-2, -1)).cpu()  # [num_envs, T]
        done = data["next", "done"].reshape(reward.shape).cpu()
        finished = []
        for step in range(reward.shape[1]):  # T steps of a batch, vectorised over envs
            self.running += reward[:, step]
            ended = done[:, step]
            finished.extend(self.running[ended].tolist())
            self.running[ended] = 0.0
        self.episodes += len(finished)
        return finished


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
    core = eval_env.core.tensors
    return float(1.0 - core["loss"].sum() / core["initial_loss"].sum())


def train(config: TrainConfig, resume: bool = True) -> Path:
    """Train GA-SAC as configured; returns the run directory. See the module docstring."""
    experiment = config.experiment
    out_dir = Path(experiment.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    checkpoint = out_dir / "checkpoint.pt"
    metrics_path = out_dir / "metrics.csv"
    session = build_session(config)
    if resume and checkpoint.is_file():
        restore(session, checkpoint)
    elif metrics_path.exists():
        metrics_path.unlink()
    remaining = experiment.frames - session.frames
    if remaining > 0:
        _run(session, remaining, checkpoint, metrics_path)
    save_checkpoint(checkpoint, session_state(session))
    plot_learning_curve(metrics_path, out_dir / "learning_curve.png")
    return out_dir


def _run(session: Session, remaining: int, checkpoint: Path, metrics_path: Path) -> None:
    experiment, algorithm = session.config.experiment, session.config.algorithm
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
    buffer = ReplayBuffer(
        storage=LazyTensorStorage(algorithm.buffer_size, device=experiment.device),
        batch_size=algorithm.batch_size,
    )
    # A resumed run has lost its buffer: it needs only one minibatch before updating again.
    warmup = algorithm.warmup_frames if session.frames == 0 else algorithm.batch_size
    warmup_end = session.frames + warmup
    eval_env = make_env(
        session.config, experiment.eval_problems, experiment.seed + EVAL_SEED_OFFSET, reward="F"
    )
    tracker = EpisodeTracker(experiment.num_envs)
    next_checkpoint = session.frames + experiment.checkpoint_interval
    next_eval = session.frames + experiment.eval_interval
    start = time.perf_counter()
    progress = _progress(experiment.progress, experiment.frames, session.frames)
    with metrics_path.open("a", newline="") as handle:
        writer = csv.DictWriter(handle, METRIC_FIELDS)
        if handle.tell() == 0:
            writer.writeheader()
        for data in collector:
            session.frames += data.numel()
            returns = tracker.update(data)
            buffer.extend(data.reshape(-1))
            logs: dict[str, float] = {}
            if session.frames >= warmup_end and len(buffer) >= algorithm.batch_size:
                for _ in range(algorithm.updates_per_batch):
                    logs = optimise(session, buffer.sample())
                collector.update_policy_weights_()
            row = {key: logs.get(key, "") for key in METRIC_FIELDS}
            row.update(
                frames=session.frames,
                updates=session.updates,
                episodes=tracker.episodes,
                episode_return=sum(returns) / len(returns) if returns else "",
                wall_s=round(time.perf_counter() - start, 3),
            )
            if session.frames >= next_eval:
                row["eval_f_reduction"] = evaluate_f_reduction(session, eval_env)
                next_eval += experiment.eval_interval
            writer.writerow(row)
            handle.flush()
            if session.frames >= next_checkpoint:
                save_checkpoint(checkpoint, session_state(session))
                next_checkpoint += experiment.checkpoint_interval
            if progress is not None:
                progress.update(data.numel())
                progress.set_postfix(ret=row["episode_return"], upd=session.updates)
    collector.shutdown()
    if progress is not None:
        progress.close()


def _progress(enabled: bool, total: int, initial: int):
    if not enabled:
        return None
    from tqdm.auto import tqdm

    return tqdm(total=total, initial=initial, unit="frame", desc="GA-SAC")


def plot_learning_curve(metrics_path: Path, png_path: Path) -> Path | None:
    """Episode return and held-out F reduction against frames (skipped when there is no data)."""
    if not metrics_path.is_file():
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with metrics_path.open() as handle:
        rows = list(csv.DictReader(handle))

    def series(name: str) -> tuple[list[float], list[float]]:
        points = [(float(r["frames"]), float(r[name])) for r in rows if r.get(name)]
        return [p[0] for p in points], [p[1] for p in points]

    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 3.5))
    left.plot(*series("episode_return"), ".-", ms=3)
    left.set(xlabel="frames", ylabel="episode return (mean over agents)", title="training")
    right.plot(*series("eval_f_reduction"), "o-", ms=3)
    right.set(xlabel="frames", ylabel="1 − F(T)/F(0)", title="held-out F reduction")
    figure.tight_layout()
    figure.savefig(png_path, dpi=120)
    plt.close(figure)
    return png_path
