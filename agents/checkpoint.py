"""GA-SAC checkpoints: one `.pt` file holding the config, the networks, the optimisers and progress.

Layout (a plain dict, loaded with `torch.load(weights_only=True)`):
    "format": CHECKPOINT_FORMAT, "config": TrainConfig.to_dict(),
    "dims": {"node", "edge", "agents", "choices"},
    "actor": actor state_dict, "loss": GASACLoss state_dict (actor, critic, target critic,
    temperatures), "optimisers": {name: state_dict}, "frames": int, "updates": int.
The replay buffer is not stored: a resumed run refills it (updates restart once it holds one
minibatch). `load_actor` needs only "config", "dims" and "actor" — what prop-v1 uses at inference.
A MAPPO / IPPO checkpoint (agents.ppo_trainer) has the same "config" (its "algorithm_name"),
"dims", "actor", "frames" and "updates"; its "loss" is ClipPPOLoss's state_dict (actor, value
function), "optimisers" {"ppo": …}, and "reward_scale" the run's reward scale c.
Optional "outlier_gate": {"config": OutlierGateConfig as a dict, "encoder": state_dict,
"threshold": float, "epochs": [{epoch, loss, validation_auc}], "best_epoch": int, "seconds":
float}, the fitted outlier gate (agents.gate_training, `add_outlier_gate`).
"""

from __future__ import annotations

import copy
import dataclasses
import os
from pathlib import Path
from typing import Any

import torch

from agents.actor import HybridActor
from agents.config import OutlierGateConfig, TrainConfig
from agents.outlier_gate import OutlierGate
from popbench.errors import PopbenchError

CHECKPOINT_FORMAT = 1


class CheckpointError(PopbenchError):
    """A checkpoint file is missing, unreadable or of another format."""


class ResumeConfigError(CheckpointError):
    """A run directory's checkpoint was trained with other options than those of the resume."""


def save_checkpoint(path: str | Path, state: dict[str, Any]) -> Path:
    """Write `state` (see module docstring) atomically: to a temporary file, then renamed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_suffix(path.suffix + ".tmp")
    torch.save({"format": CHECKPOINT_FORMAT, **state}, temporary)
    os.replace(temporary, path)
    return path


def read_checkpoint(path: str | Path, device: str | torch.device = "cpu") -> dict[str, Any]:
    """The checkpoint dict; a one-line `CheckpointError` if it cannot be used."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint not found")
    try:
        state = torch.load(path, map_location=device, weights_only=True)
    except Exception as error:  # torch raises several types for corrupt/foreign files
        raise CheckpointError(f"{path}: not a readable checkpoint ({error})") from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(f"{path}: not a GA-SAC checkpoint of format {CHECKPOINT_FORMAT}")
    return state


def load_actor(
    path: str | Path, device: str | torch.device = "cpu"
) -> tuple[HybridActor, TrainConfig]:
    """The trained shared actor (eval mode) and its config, for any team size."""
    return actor_of(read_checkpoint(path, device), device)


def actor_of(
    state: dict[str, Any], device: str | torch.device = "cpu"
) -> tuple[HybridActor, TrainConfig]:
    """:func:`load_actor` of an already read checkpoint dict."""
    config = TrainConfig.from_dict(state["config"])
    dims = state["dims"]
    actor = HybridActor(dims["node"], dims["edge"], config.model).to(device)
    actor.load_state_dict(state["actor"])
    return actor.eval(), config


def checkpoint_algorithm(path: str | Path) -> str:
    """The algorithm that trained the checkpoint at ``path`` (its config's ``algorithm_name``:
    ga-sac, mappo, ippo; a checkpoint written before it was recorded reads as ga-sac)."""
    return TrainConfig.from_dict(read_checkpoint(path)["config"]).algorithm_name


ACTOR_KEYS = ("config", "dims", "actor", "frames", "updates")


def training_state(
    session: Any, optimisers: dict[str, torch.optim.Optimizer], **progress: Any
) -> dict[str, Any]:
    """A training session's checkpoint (the module docstring's layout): its config, dims,
    actor, loss, ``optimisers`` by name, frames and updates, then the learner's own
    ``progress`` entries."""
    return {
        "config": session.config.to_dict(),
        "dims": session.dims,
        "actor": session.actor.state_dict(),
        "loss": session.loss.state_dict(),
        "optimisers": {name: optimiser.state_dict() for name, optimiser in optimisers.items()},
        "frames": session.frames,
        "updates": session.updates,
        **progress,
    }


def save_actor(
    path: str | Path,
    config: TrainConfig,
    dims: dict[str, int],
    actor: torch.nn.Module,
    frames: int = 0,
    updates: int = 0,
) -> Path:
    """Write an actor-only checkpoint (:data:`ACTOR_KEYS`): what :func:`load_actor` needs."""
    state = {"config": config.to_dict(), "dims": dims, "actor": actor.state_dict()}
    return save_checkpoint(path, {**state, "frames": frames, "updates": updates})


def save_snapshot(out_dir: str | Path, state: dict[str, Any]) -> Path:
    """Write the actor-only part of a training state as `out_dir/snapshots/actor-FRAMES.pt`
    (FRAMES zero-padded to 7 digits): the actor as it was after that many frames, which
    `popbench run heldout --checkpoint` scores (the learning curves over held-out problems)."""
    path = Path(out_dir) / "snapshots" / f"actor-{int(state['frames']):07d}.pt"
    return save_checkpoint(path, {key: state[key] for key in ACTOR_KEYS})


def run_snapshots(out_dir: str | Path) -> dict[int, Path]:
    """A training run's actor snapshots (:func:`save_snapshot`) by frames, in frame order."""
    found = Path(out_dir).glob("snapshots/actor-*.pt")
    return dict(sorted((int(path.stem.removeprefix("actor-")), path) for path in found))


def snapshot_identity(path: str | Path) -> dict[str, Any]:
    """What a snapshot's training config says the run compares: "algorithm" (with "-team" or
    "-team-shaped" when it trained on a team reward, envs.team), "start" ("imitation" with
    --init-actor or an imitation phase, else "scratch"), "seed", and the task its actor is scored
    on: "noise", "robots", "poses_per_robot" (the team task's held-out problems are the actors'
    task's: both are scored by F after the consensus)."""
    config = TrainConfig.from_dict(read_checkpoint(path)["config"])
    experiment = config.experiment
    imitated = experiment.init_actor is not None or config.imitation.episodes > 0
    team = {"none": "", "consensus": "-team", "consensus+shaping": "-team-shaped"}
    return {
        "algorithm": config.algorithm_name + team[config.task.team_reward],
        "start": "imitation" if imitated else "scratch",
        "seed": experiment.seed,
        "noise": experiment.noise,
        "robots": experiment.robots,
        "poses_per_robot": experiment.poses_per_robot,
    }


def add_outlier_gate(
    path: str | Path,
    out: str | Path,
    config: OutlierGateConfig,
    gate: OutlierGate,
    epochs: list[dict[str, float]],
    best_epoch: int,
    seconds: float,
) -> Path:
    """Write checkpoint ``path`` to ``out`` (which may be ``path``) with the fitted outlier
    gate (module docstring; agents.gate_training.GateFit's fields); a previous one is
    replaced."""
    state = read_checkpoint(path)
    state["outlier_gate"] = {
        "config": dataclasses.asdict(config),
        "encoder": gate.encoder.state_dict(),
        "threshold": gate.threshold,
        "epochs": epochs,
        "best_epoch": best_epoch,
        "seconds": seconds,
    }
    return save_checkpoint(out, state)


def load_outlier_gate(path: str | Path, device: str | torch.device = "cpu") -> OutlierGate | None:
    """The fitted outlier gate of a checkpoint (its encoder in eval mode), or None without one."""
    state = read_checkpoint(path, device)
    if "outlier_gate" not in state:
        return None
    actor, _ = actor_of(state, device)
    encoder = copy.deepcopy(actor.encoder)
    encoder.load_state_dict(state["outlier_gate"]["encoder"])
    return OutlierGate(encoder.eval(), float(state["outlier_gate"]["threshold"]))
