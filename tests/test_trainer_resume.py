"""GA-SAC trainer: resuming (metrics rows, option checks), frames reporting and Ctrl-C.

Tiny runs (3 robots × 10 poses, 4 envs, 32-frame batches, one update per batch): each `train`
call takes a few seconds on one CPU core.
"""

from __future__ import annotations

import csv
import dataclasses
import os
import signal

import pytest
from conftest import tiny_model

from agents.checkpoint import ResumeConfigError, read_checkpoint
from agents.config import PRESETS, AlgorithmConfig, ExperimentConfig, TrainConfig

TINY = tiny_model()


def tiny(out_dir, frames: int, **experiment) -> TrainConfig:
    """One update per 32-frame batch from the first batch on; checkpoints every 64 frames."""
    options = dict(
        robots=3,
        poses_per_robot=10,
        num_envs=4,
        frames=frames,
        frames_per_batch=32,
        checkpoint_interval=64,
        eval_interval=10_000,
        eval_problems=2,
        out_dir=str(out_dir),
        progress=False,
    )
    options.update(experiment)
    return TrainConfig(
        model=TINY,
        algorithm=AlgorithmConfig(warmup_frames=32, batch_size=8, buffer_size=256),
        experiment=ExperimentConfig(**options),
    )


def metric_frames(out_dir) -> list[int]:
    with (out_dir / "metrics.csv").open() as handle:
        return [int(row["frames"]) for row in csv.DictReader(handle)]


def fail_at_update(monkeypatch, number: int, action) -> None:
    """Make the `number`-th optimisation step of the next run call `action()` first."""
    import agents.gasac_trainer as trainer

    original, calls = trainer.optimise, [0]

    def optimise(session, batch):
        calls[0] += 1
        if calls[0] == number:
            action()
        return original(session, batch)

    monkeypatch.setattr(trainer, "optimise", optimise)


def test_resume_after_a_crash_logs_each_batch_once_and_reports_frames(
    tmp_path, monkeypatch
) -> None:
    from agents.trainer import train

    # A run that dies in its 4th batch (after the checkpoint at 64 frames, with the batch at 96
    # frames logged) — what `kill -9` between two checkpoints leaves.
    def crash() -> None:
        raise OSError("simulated crash")

    with monkeypatch.context() as patch:
        fail_at_update(patch, 4, crash)
        with pytest.raises(OSError, match="simulated crash"):
            train(tiny(tmp_path, 128), resume=False)
    assert read_checkpoint(tmp_path / "checkpoint.pt")["frames"] == 64
    assert metric_frames(tmp_path) == [32, 64, 96]

    result = train(tiny(tmp_path, 128), resume=True)
    assert metric_frames(tmp_path) == [32, 64, 96, 128]
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["updates"]) for r in rows] == [1, 2, 3, 4]
    walls = [float(r["wall_s"]) for r in rows]
    assert walls == sorted(walls)  # wall_s continues across the resume
    assert (result.frames_trained, result.frames, result.resumed_from) == (64, 128, 64)
    assert result.summary() == (
        f"trained 64 frames (resumed at 64; 128 in total); run directory {tmp_path}; "
        f"wall time {result.wall_s:.0f} s"
    )
    assert result.wall_s > 0
    assert str(result) == os.fspath(result) == str(tmp_path)

    # Asking for fewer frames than the run has trains nothing and says so.
    nothing = train(tiny(tmp_path, 100), resume=True)
    assert (nothing.frames_trained, nothing.frames) == (0, 128)
    assert nothing.summary().startswith("nothing to train: the run already has 128 frames")
    assert metric_frames(tmp_path) == [32, 64, 96, 128]


def test_frames_trained_counts_whole_batches(tmp_path) -> None:
    from agents.trainer import train

    result = train(tiny(tmp_path, 1), resume=False)
    assert (result.frames_trained, result.frames, result.resumed_from) == (32, 32, 0)
    assert result.summary() == (
        f"trained 32 frames; run directory {tmp_path}; wall time {result.wall_s:.0f} s"
    )


def test_resume_with_other_options_is_a_one_line_error(tmp_path) -> None:
    from agents.trainer import train

    train(tiny(tmp_path, 32), resume=False)
    before = (tmp_path / "metrics.csv").read_text()

    for changed, expected in (
        (dict(robots=2), ["--robots 3 (requested 2)"]),
        (dict(noise="V1", seed=5), ["--env V2 (requested V1)", "--seed 0 (requested 5)"]),
        (dict(num_envs=2), ["experiment.num_envs 4 (requested 2)"]),
    ):
        config = tiny(tmp_path, 64, **changed)
        with pytest.raises(ResumeConfigError) as error:
            train(config, resume=True)
        message = str(error.value)
        assert "\n" not in message and len(message) < 400, message
        assert all(part in message for part in expected), message
        assert "--no-resume" in message and "--out" in message
    model = dataclasses.replace(TINY, hidden=16)
    with pytest.raises(ResumeConfigError, match=r"model\.hidden 8 \(requested 16\)"):
        train(dataclasses.replace(tiny(tmp_path, 64), model=model), resume=True)
    assert (tmp_path / "metrics.csv").read_text() == before  # nothing was appended

    # the environment's task and the imitation phase are part of the run, as the networks are
    from agents.resume import resume_differences

    stored = tiny(tmp_path, 32)
    task = dataclasses.replace(stored.task, base="gauss-newton")
    imitation = dataclasses.replace(stored.imitation, episodes=3)
    assert resume_differences(stored, dataclasses.replace(stored, task=task)) == [
        "task.base none (requested gauss-newton)"
    ]
    assert resume_differences(stored, dataclasses.replace(stored, imitation=imitation)) == [
        "imitation.episodes 0 (requested 3)"
    ]

    # device, frames, out_dir and progress may change; --no-resume starts a new run.
    free = dataclasses.replace(
        stored.experiment, device="cuda", frames=10**6, out_dir="elsewhere", progress=True
    )
    assert resume_differences(stored, dataclasses.replace(stored, experiment=free)) == []
    fresh = train(tiny(tmp_path, 32, robots=2), resume=False)
    assert (fresh.frames_trained, fresh.resumed_from) == (32, 0)


def test_resume_names_a_changed_preset() -> None:
    from agents.resume import resume_differences

    paper, small = PRESETS["paper"], PRESETS["cpu-small"]
    assert resume_differences(paper, small) == ["--preset paper (requested cpu-small)"]
    assert resume_differences(small, small) == []


def test_ctrl_c_during_an_update_finishes_it_saves_and_raises(tmp_path, monkeypatch) -> None:
    """SIGINT in an optimisation step: the step completes, then checkpoint + KeyboardInterrupt."""
    from agents.trainer import train

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT has a custom handler in this process")
    fail_at_update(monkeypatch, 3, lambda: os.kill(os.getpid(), signal.SIGINT))
    with pytest.raises(KeyboardInterrupt, match="checkpoint of 96 frames saved"):
        train(tiny(tmp_path, 256), resume=False)
    state = read_checkpoint(tmp_path / "checkpoint.pt")
    assert (state["frames"], state["updates"]) == (96, 3)  # the 3rd step was not cut short
    assert metric_frames(tmp_path) == [32, 64, 96]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_keyboard_interrupt_inside_the_loss_stays_a_keyboard_interrupt(
    tmp_path, monkeypatch
) -> None:
    """A KeyboardInterrupt raised inside `with params.to_module(...)` (agents.loss) became
    `RuntimeError: Converting a tensordict to boolean value` (tensordict 0.14's __exit__)."""
    from agents.actor import HybridActor
    from agents.trainer import train

    forward, armed = HybridActor.forward, [False]

    def interrupted_forward(self, *args, **kwargs):
        if armed[0]:
            raise KeyboardInterrupt
        return forward(self, *args, **kwargs)

    def arm() -> None:
        armed[0] = True

    monkeypatch.setattr(HybridActor, "forward", interrupted_forward)
    fail_at_update(monkeypatch, 3, arm)
    with pytest.raises(KeyboardInterrupt, match="checkpoint of 96 frames saved"):
        train(tiny(tmp_path, 256), resume=False)
    state = read_checkpoint(tmp_path / "checkpoint.pt")
    assert (state["frames"], state["updates"]) == (96, 2)
    assert metric_frames(tmp_path) == [32, 64, 96]

    armed[0] = False
    result = train(tiny(tmp_path, 128), resume=True)
    assert (result.resumed_from, result.frames) == (96, 128)
    assert metric_frames(tmp_path) == [32, 64, 96, 128]


def test_init_actor_starts_from_that_actor_and_refuses_another_model(tmp_path) -> None:
    """`init_actor` replaces the imitation phase: the run's imitation-actor.pt and the anchor's
    start are the given actor's weights; an actor of another model is refused in one line."""
    import torch

    from agents.checkpoint import CheckpointError, save_checkpoint
    from agents.trainer import train

    first = tmp_path / "first"
    train(tiny(first, 32), resume=False)
    start = read_checkpoint(first / "checkpoint.pt")
    with torch.no_grad():  # an actor that a fresh one (same seed) cannot equal
        start["actor"] = {key: value + 0.01 for key, value in start["actor"].items()}
    given = save_checkpoint(tmp_path / "given.pt", start)
    second = tmp_path / "second"
    train(tiny(second, 32, init_actor=str(given)), resume=False)
    copied = read_checkpoint(second / "imitation-actor.pt")["actor"]
    assert all(torch.equal(copied[key], start["actor"][key]) for key in start["actor"])

    other = dataclasses.replace(tiny(second, 32), model=dataclasses.replace(TINY, hidden=12))
    with pytest.raises(CheckpointError, match="model.hidden"):
        train(
            dataclasses.replace(
                other,
                experiment=dataclasses.replace(
                    other.experiment, out_dir=str(tmp_path / "third"), init_actor=str(given)
                ),
            ),
            resume=False,
        )


def test_ctrl_c_in_a_ppo_batch_finishes_the_batch_and_resume_keeps_the_counts(
    tmp_path, monkeypatch
) -> None:
    """SIGINT in the 2nd of a batch's 4 PPO steps: the batch's 4 steps complete, its row logs
    them, and the resumed run continues the updates and the finished episodes' count."""
    from test_ppo import tiny as tiny_ppo

    import agents.ppo_trainer as ppo_trainer
    from agents.trainer import train

    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        pytest.skip("SIGINT has a custom handler in this process")
    original, calls = ppo_trainer.optimise_ppo, [0]

    def optimise_ppo(session, minibatch):
        calls[0] += 1
        if calls[0] == 10:  # the 2nd step of the 3rd batch (4 steps per 16-frame batch)
            os.kill(os.getpid(), signal.SIGINT)
        return original(session, minibatch)

    with monkeypatch.context() as patch:
        patch.setattr(ppo_trainer, "optimise_ppo", optimise_ppo)
        with pytest.raises(KeyboardInterrupt, match="checkpoint of 48 frames saved"):
            train(tiny_ppo(tmp_path, "mappo", 128), resume=False)
    state = read_checkpoint(tmp_path / "checkpoint.pt")
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert (state["frames"], state["updates"]) == (48, 12)  # the whole 3rd batch
    assert [int(row["updates"]) for row in rows] == [4, 8, 12]
    assert state["episodes"] == int(rows[-1]["episodes"]) > 0

    train(tiny_ppo(tmp_path, "mappo", 80), resume=True)
    with (tmp_path / "metrics.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert [int(row["updates"]) for row in rows] == [4, 8, 12, 16, 20]
    episodes = [int(row["episodes"]) for row in rows]
    assert episodes == sorted(episodes) and episodes[3] >= state["episodes"]
    assert read_checkpoint(tmp_path / "checkpoint.pt")["episodes"] == episodes[-1]


def test_popbench_train_prints_where_the_checkpoint_is_after_ctrl_c(
    tmp_path, monkeypatch, capsys
) -> None:
    """typer turns a KeyboardInterrupt into a bare exit status 130; the message must print."""
    import agents.trainer
    from popbench.cli import main

    def interrupted(config, resume):  # noqa: ARG001 - train's signature
        raise KeyboardInterrupt(f"checkpoint of 96 frames saved in {tmp_path}/checkpoint.pt")

    monkeypatch.setattr(agents.trainer, "train", interrupted)
    code = main(["train", "--robots", "3", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 130
    assert err.strip() == (
        f"popbench: interrupted (checkpoint of 96 frames saved in {tmp_path}/checkpoint.pt)"
    )
