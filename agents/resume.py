"""Resuming a run: the checkpoint's config must match the requested one except for the options
in `RESUME_FREE_FIELDS`; `check_resume_config` names the options that differ."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from agents.algorithms import learner_of
from agents.checkpoint import CheckpointError, ResumeConfigError
from agents.config import PRESETS, TrainConfig

# Options that a resumed run may change; everything else must match the checkpoint's config.
RESUME_FREE_FIELDS = ("device", "frames", "out_dir", "progress")
_CLI_OPTIONS = {"noise": "--env", "robots": "--robots", "seed": "--seed"}


def _comparable(config: TrainConfig, drop_cli: bool) -> dict[str, Any]:
    """Flat {"part.field": value} of the fields a resumed run must keep, the environment's task
    and the imitation phase included (delta_max comes from the environment, not the request);
    `drop_cli` also leaves out --env/--robots/--seed. A learner's own parts (its record's
    `config_parts`, e.g. PPO's options) count only for its runs."""
    dropped = set(RESUME_FREE_FIELDS) | (set(_CLI_OPTIONS) if drop_cli else set())
    flat: dict[str, Any] = {"algorithm_name": config.algorithm_name}
    parts = ("model", "algorithm", "experiment", "task", "imitation")
    parts += learner_of(config).config_parts
    for part in parts:
        for name, value in dataclasses.asdict(getattr(config, part)).items():
            if (part, name) == ("model", "delta_max"):
                continue
            if part == "experiment" and name in dropped:
                continue
            flat[f"{part}.{name}"] = tuple(value) if isinstance(value, list) else value
    return flat


def _preset_name(config: TrainConfig) -> str | None:
    fields = _comparable(config, drop_cli=True)
    for name, preset in PRESETS.items():
        if _comparable(preset, drop_cli=True) == fields:
            return name
    return None


def resume_differences(stored: TrainConfig, requested: TrainConfig) -> list[str]:
    """The options in which `requested` differs from a checkpoint's `stored` config, each as
    `--option OLD (requested NEW)`; [] when the run can be resumed."""
    differences = []
    for name, option in _CLI_OPTIONS.items():
        old, new = getattr(stored.experiment, name), getattr(requested.experiment, name)
        if old != new:
            differences.append(f"{option} {old} (requested {new})")
    old_fields = _comparable(stored, drop_cli=True)
    new_fields = _comparable(requested, drop_cli=True)
    changed = [key for key in new_fields if old_fields.get(key) != new_fields[key]]
    changed += [key for key in old_fields if key not in new_fields]
    if changed:
        old_preset, new_preset = _preset_name(stored), _preset_name(requested)
        if old_preset and new_preset:
            differences.append(f"--preset {old_preset} (requested {new_preset})")
        else:
            shown = [f"{k} {old_fields.get(k)} (requested {new_fields.get(k)})" for k in changed]
            more = f" and {len(shown) - 3} more settings" if len(shown) > 3 else ""
            differences.append(", ".join(shown[:3]) + more)
    return differences


def check_resume_config(path: Path, state: dict[str, Any], requested: TrainConfig) -> None:
    """Raise a one-line `ResumeConfigError` if the checkpoint's run differs from `requested`."""
    try:
        stored = TrainConfig.from_dict(state["config"])
    except (KeyError, TypeError, ValueError) as error:
        raise CheckpointError(f"{path}: unreadable run config ({error})") from None
    differences = resume_differences(stored, requested)
    if differences:
        raise ResumeConfigError(
            f"{path} holds a run trained with other options: {'; '.join(differences)}. "
            "Pass the run's options to resume it, or start a new run with --no-resume "
            "(which overwrites it) or another --out"
        )
