"""Named benchmark tasks (envs.tasks): the envs they build, `popbench train --task` and
`popbench tasks`, and the observation declared once (envs.features) against the code and the
docs."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

import envs
from agents.config import PRESETS, with_task
from envs.core import PGOCore
from envs.features import EDGE, ENTRIES, NODE, markdown_table
from envs.modes import PAPER_MODES, TRAJECTORY_MODES
from envs.tasks import ACTORS, PAPER, TASKS, get_task
from popbench.cli import main
from popbench.cli.train import train_config
from popbench.errors import ValueRangeError
from popbench.problems.synthetic import make_problem

DOCS = Path(__file__).resolve().parents[1] / "docs" / "environment.md"
SMALL = {"robots": 3, "poses_per_robot": 12}  # overrides that keep the probes quick


def test_the_registry_has_the_paper_game_the_actors_task_and_harder_tasks() -> None:
    assert {"paper", "actors", "big-maps", "noisy", "outliers", "team"} <= set(TASKS)
    for name, task in TASKS.items():
        assert task.name == name and task.summary
    harder = [task for task in TASKS.values() if task.name not in ("paper", "actors", "team")]
    for task in harder:  # each changes the actors' task in its problems only (team: its reward)
        assert task.core_options() == ACTORS.core_options()
        assert (task.reward, task.terminal_bonus) == (ACTORS.reward, ACTORS.terminal_bonus)
    with pytest.raises(ValueRangeError, match="paper, actors"):
        get_task("actor")


@pytest.mark.parametrize("preset", ["cpu-residual", "cpu-mappo", "cpu-ippo"])
def test_the_actors_task_is_what_the_shipped_algorithms_train_on(preset: str) -> None:
    config = PRESETS[preset]
    assert with_task(config, ACTORS) == config


def test_make_torchrl_env_builds_the_task_and_keywords_override_it() -> None:
    env = envs.make_torchrl_env(task="actors", batch_size=2, **SMALL)
    core = env.core
    assert core.modes == TRAJECTORY_MODES == ACTORS.modes
    assert (core.reward_kind, core.terminal_bonus, core.num_agents) == ("F", False, 3)
    assert env.reset()["agents", "observation", "base_step"].shape[:2] == (2, 3)
    paper = envs.make_torchrl_env(batch_size=1, **SMALL).core  # no task: the paper's game
    assert (paper.modes, paper.reward_kind) == (PAPER_MODES, "localisation")
    assert envs.make_torchrl_env(task=PAPER, batch_size=1, **SMALL).core.terminal_bonus


def test_make_pettingzoo_env_builds_the_task() -> None:
    env = envs.make_pettingzoo_env(task="outliers", seed=1, **SMALL)
    env.reset(seed=1)
    assert env.core.problems[0].outlier_mask is not None  # the task's training outliers
    assert env.core.modes.correction == "subtree" and len(env.possible_agents) == 3


def test_popbench_train_takes_a_task_and_explicit_options_override_it() -> None:
    config = train_config(None, None, 0, None, "cpu", None, "cpu-small", task="noisy")
    assert config.experiment.noise == "V3" and config.experiment.robots == 7
    assert config.task.core_options() == ACTORS.core_options()
    assert (config.algorithm.reward, config.algorithm.terminal_bonus) == ("F", False)
    assert config.model == PRESETS["cpu-small"].model  # the networks stay the preset's
    config = train_config("V1", 3, 0, None, "cpu", None, "cpu-small", task="noisy")
    assert (config.experiment.noise, config.experiment.robots) == ("V1", 3)
    plain = train_config(None, None, 0, None, "cpu", None, "cpu-small")
    assert (plain.experiment.noise, plain.experiment.robots) == ("V2", 7)
    assert plain.task == PRESETS["cpu-small"].task
    with pytest.raises(ValueRangeError, match="--task"):
        train_config(None, None, 0, None, "cpu", None, "cpu-small", task="nope")


def test_popbench_tasks_lists_every_task(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["tasks"]) == 0
    printed = capsys.readouterr().out
    for name in TASKS:
        assert name in printed
    assert main(["train", "--task", "nope"]) == 2


def test_the_declared_observation_is_what_the_core_observes() -> None:
    problem = make_problem(3, "V2", 12, seed=0)
    core = PGOCore.for_problems([problem], ACTORS)
    observation = core.observation()
    assert [entry.name for entry in ENTRIES] == list(observation)
    dims = {"V": core.dims.vertices, "E": core.dims.edges}
    for entry in ENTRIES:
        shape = tuple(
            dims.get(size, None) or int(size) for size in re.findall(r"[VE]|\d+", entry.shape)
        )
        assert tuple(observation[entry.name].shape[2:]) == shape, entry.name
        assert str(observation[entry.name].dtype) == f"torch.{entry.dtype}", entry.name
    paper = PGOCore.for_problems([problem]).observation()
    assert [entry.name for entry in ENTRIES if not entry.base_step_only] == list(paper)
    padding = ~observation["edge_mask"]
    assert (
        observation["edge_index"][padding.unsqueeze(-2).expand_as(observation["edge_index"])] == 0
    ).all()


def test_the_docs_tables_are_the_declared_features() -> None:
    text = DOCS.read_text()
    assert markdown_table(NODE) in text
    assert markdown_table(EDGE) in text
    for entry in ENTRIES:
        assert f"| `{entry.name}` | {entry.shape} | {entry.dtype} |" in text
