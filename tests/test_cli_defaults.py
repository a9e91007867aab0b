"""The command line's defaults are the experiments' configs' (one fact, one place): a default
changed in popbench.harness.defaults reaches both, and one restated in the CLI fails here."""

from __future__ import annotations

import inspect
from pathlib import Path

from popbench.cli import run
from popbench.harness.outliers import OutliersConfig
from popbench.harness.scalability import ScalabilityConfig
from popbench.harness.table1 import QUICK, Table1Config


def defaults_of(command) -> dict[str, object]:
    """The command's options' defaults (typer.Option's ``default`` or the plain default)."""
    parameters = inspect.signature(command).parameters.values()
    return {p.name: getattr(p.default, "default", p.default) for p in parameters}


def listed(values) -> str:
    return ",".join(map(str, values))


def test_outliers_and_scalability_defaults_are_their_configs() -> None:
    cli, config = defaults_of(run.outliers_command), OutliersConfig()
    assert cli["datasets"] == listed(config.datasets)
    assert cli["methods"] == listed(config.methods)
    assert (cli["robots"], cli["iterations"]) == (config.robots, config.iterations)
    assert cli["seeds"] == listed(config.seeds) and Path(cli["out"]) == config.out
    cli, config = defaults_of(run.scalability_command), ScalabilityConfig()
    assert (cli["dataset"], cli["robots"]) == (config.dataset, listed(config.robots))
    assert cli["methods"] == listed(config.methods) and cli["iterations"] == config.iterations
    assert Path(cli["out"]) == config.out


def test_table1_help_states_its_configs_defaults() -> None:
    parameters = inspect.signature(run.table1_command).parameters
    config, quick = Table1Config(), Table1Config.quick()
    robots = parameters["robots"].default.help
    assert f"default: {listed(config.robots)}; --quick: {listed(QUICK['robots'])}" in robots
    iterations = parameters["iterations"].default.help
    assert f"default: {config.iterations}; --quick: {quick.iterations}" in iterations
    assert f"default: {config.out}; --quick: {quick.out}" in parameters["out"].default.help


def test_start_partition_and_group_size_defaults_are_the_configs() -> None:
    from popbench.cli import plot, solve
    from popbench.outliers import add_false_loop_closures

    table1, config = defaults_of(run.table1_command), Table1Config()
    assert (table1["init"], table1["partition"]) == (config.init, config.partition)
    outliers, config = defaults_of(run.outliers_command), OutliersConfig()
    assert outliers["init"] == config.init
    group_size = inspect.signature(run.outliers_command).parameters["group_size"].default.help
    assert f"(default: {config.group_size})" in group_size
    assert (
        config.group_size
        == inspect.signature(add_false_loop_closures).parameters["group_size"].default
    )
    scalability, config = defaults_of(run.scalability_command), ScalabilityConfig()
    assert (scalability["init"], config.partition) == (config.init, Table1Config().partition)
    from popbench.harness.solve import build_problem

    commands = (solve.solve_command, solve.solve_record, build_problem)
    for command in (*commands, plot.trajectories_command):
        assert defaults_of(command)["init"] == config.init, command.__name__
    for command in commands[:2]:
        assert defaults_of(command)["partition"] == config.partition, command.__name__
