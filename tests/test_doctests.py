"""The runnable examples at the top of the main public entry points run and give what they show."""

from __future__ import annotations

import doctest
import importlib

import pytest

ENTRY_POINTS = (
    "popbench.methods",
    "popbench.objective",
    "popbench.sparse",
    "envs",
    "baselines.rbcd.relaxation",
    "baselines.rbcd.driver",
    "baselines.mm_pgo.driver",
)


@pytest.mark.parametrize("name", ENTRY_POINTS)
def test_the_module_example_runs(name: str) -> None:
    module = importlib.import_module(name)
    assert ">>>" in (module.__doc__ or ""), f"{name} has no example in its docstring"
    outcome = doctest.testmod(module, optionflags=doctest.ELLIPSIS)
    assert outcome.attempted > 0 and outcome.failed == 0, f"{name}: {outcome}"
