"""Training metrics I/O: the columns of metrics.csv, per-environment episode returns, cutting
the CSV back to a checkpoint on resume, and the run's learning-curve figure."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path

import torch
from tensordict import TensorDictBase

LEARNING_CURVE_COLUMNS = ("episode_return", "eval_f_reduction")
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
    "loss_bc",
    "loss_gate",
    "loss_anchor",
    "td_error",
    "critic_probe",
    "reward_scale",
    "delta_target_entropy",
    "eval_f_reduction",
    "wall_s",
)

# metrics.csv of a MAPPO / IPPO run (agents.ppo_trainer): the losses of ClipPPOLoss (mean over
# the batch's minibatches and epochs), its entropy, approximate KL, clip fraction and the value
# function's explained variance, and the reward scale set on the first batch.
PPO_METRIC_FIELDS = (
    "frames",
    "updates",
    "episodes",
    "episode_return",
    "loss_objective",
    "loss_critic",
    "loss_entropy",
    "entropy",
    "kl_approx",
    "clip_fraction",
    "explained_variance",
    "reward_scale",
    "eval_f_reduction",
    "wall_s",
)


class EpisodeTracker:
    """Per-environment running returns (mean over agents) across collector batches, and the
    count of finished episodes (``episodes``: a resumed run's starts at its checkpoint's)."""

    def __init__(self, num_envs: int, episodes: int = 0) -> None:
        self.running = torch.zeros(num_envs)
        self.episodes = episodes

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


def truncate_metrics(
    metrics_path: Path, frames: int, fields: tuple[str, ...] = METRIC_FIELDS
) -> float:
    """Keep the metrics rows up to `frames` (a checkpoint's); their last wall_s (0 if none).

    A run stopped between two checkpoints has logged batches past its checkpoint; the resumed
    run collects those frames again, so their rows go. The file is rewritten atomically (with
    the current columns `fields`, the run's algorithm's, should an older run have written
    others)."""
    if not metrics_path.is_file():
        return 0.0
    with metrics_path.open(newline="") as handle:
        reader = csv.DictReader(handle)
        rows = list(reader)
        fieldnames = reader.fieldnames

    def frames_of(row: dict[str, str]) -> float:
        try:
            return float(row.get("frames") or "nan")
        except ValueError:
            return math.nan

    kept = [row for row in rows if frames_of(row) <= frames]
    if len(kept) < len(rows) or tuple(fieldnames or ()) != fields:
        temporary = metrics_path.with_suffix(".csv.tmp")
        with temporary.open("w", newline="") as handle:
            writer = csv.DictWriter(handle, fields, extrasaction="ignore", restval="")
            writer.writeheader()
            writer.writerows(kept)
        os.replace(temporary, metrics_path)
    try:
        return float(kept[-1]["wall_s"]) if kept else 0.0
    except (KeyError, TypeError, ValueError):
        return 0.0


def plot_learning_curve(metrics_path: Path, stem: Path) -> list[Path]:
    """Episode return and held-out F reduction against frames, as ``stem.png`` and ``stem.pdf``
    (popbench.plotting.plot_learning_curves); [] when no row has been logged."""
    from popbench.errors import ValueRangeError
    from popbench.plotting import plot_learning_curves

    if not metrics_path.is_file():
        return []
    try:
        return plot_learning_curves([metrics_path], stem, columns=LEARNING_CURVE_COLUMNS)
    except ValueRangeError:  # a header without rows
        return []
