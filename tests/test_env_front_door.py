"""The environment's front door (envs.core.PGOCore.for_problems) and its declared state
(envs.state.CoreState): a misspelt entry fails at once, and no code outside envs/ reads the
core's state by a string key."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
import torch

from envs.core import PGOCore
from envs.observation import Dimensions, pack_problem
from envs.state import PACKED, CoreState, check_packed, names
from envs.tree import pack_trees
from popbench.problems.synthetic import make_problem

ROOT = Path(__file__).resolve().parents[1]
OUTSIDE_ENVS = ("agents", "popbench", "benchmarks")
STATE_ATTRIBUTES = {"state", "tensors"}  # the core's state, and the dict it replaced


def string_keyed_reads(source: str) -> list[str]:
    """The expressions of ``source`` that index a core's state by a string: ``x.state["k"]``,
    ``x.tensors[...]`` (any use of the old dict), ``getattr(x.state, "k")``, and ``t["k"]``
    where ``t = x.state``."""
    tree = ast.parse(source)
    aliases = {
        target.id
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign)
        and isinstance(node.value, ast.Attribute)
        and node.value.attr in STATE_ATTRIBUTES
        for target in node.targets
        if isinstance(target, ast.Name)
    }

    def is_state(node: ast.AST) -> bool:
        return (isinstance(node, ast.Attribute) and node.attr in STATE_ATTRIBUTES) or (
            isinstance(node, ast.Name) and node.id in aliases
        )

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and node.attr == "tensors":
            found.append(ast.unparse(node))
        elif isinstance(node, ast.Subscript) and is_state(node.value):
            key = node.slice
            if isinstance(key, ast.Constant) and isinstance(key.value, str):
                found.append(ast.unparse(node))
        elif (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Name)
            and node.func.id in {"getattr", "setattr"}
            and node.args
            and is_state(node.args[0])
        ):
            found.append(ast.unparse(node))
    return found


def test_no_code_outside_envs_indexes_the_state_by_a_string_key() -> None:
    offending = {
        str(path.relative_to(ROOT)): reads
        for folder in OUTSIDE_ENVS
        for path in sorted((ROOT / folder).rglob("*.py"))
        if (reads := string_keyed_reads(path.read_text()))
    }
    assert not offending, f"string-keyed reads of the core's state: {offending}"


def test_the_checker_finds_string_keyed_reads() -> None:  # the test above cannot pass vacuously
    source = (
        "a = core.state['poses']\n"
        "b = core.tensors\n"
        "t = env.core.state\n"
        "c = t['loss']\n"
        "d = getattr(core.state, 'loss')\n"
        "e = core.state.loss\n"  # declared: fine
        "f = checkpoint['config']\n"  # not the core's state: fine
    )
    assert len(string_keyed_reads(source)) == 4


@pytest.fixture(scope="module")
def problems():
    return [make_problem(3, "V2", 12, seed=seed) for seed in (1, 2)]


def test_for_problems_builds_a_loaded_core_with_its_horizon(problems) -> None:
    core = PGOCore.for_problems(problems)
    assert (core.batch, core.num_agents, core.dims) == (2, 3, Dimensions.of(problems))
    assert core.problems == problems
    largest = max(local.graph.num_edges for p in problems for local in p.local_graphs)
    assert core.horizon == largest
    steps = 0
    while not bool((core.state.remaining == 0).all()):
        core.step(core.action_mask().to(torch.int8).argmax(-1), torch.zeros(2, 3, 3))
        steps += 1
    assert steps == core.horizon  # every episode ends exactly at the horizon


def test_for_problems_takes_the_task_s_modes(problems) -> None:
    class Task:
        def core_options(self) -> dict[str, str]:
            return {"correction": "subtree", "action_scale": "whitened", "base": "gauss-newton"}

    core = PGOCore.for_problems(problems[:1], Task(), delta_max=(0.2, 0.2, 0.1))
    modes = ("subtree", "whitened", "gauss-newton")
    assert (core.modes.correction, core.modes.action_scale, core.modes.base) == modes
    assert core.delta_max.tolist() == pytest.approx([0.2, 0.2, 0.1])
    assert core.reward_kind == "F"
    graphs = core.graph_batch(0)
    assert graphs["base_step"].shape == (3, core.dims.edges, 3)
    assert graphs["action_mask"].shape == (3, core.dims.edges + 1)
    flat = core.graph_batch()
    for key, value in graphs.items():
        assert torch.equal(flat[key], value)  # B = 1: the same graphs


def test_a_misspelt_entry_fails_at_once(problems) -> None:
    core = PGOCore.for_problems(problems)
    with pytest.raises(AttributeError):
        core.state.pose  # noqa: B018
    with pytest.raises(AttributeError):
        core.state.pose = core.state.poses
    with pytest.raises(TypeError):
        core.state["poses"]  # noqa: B018
    with pytest.raises(RuntimeError, match="load problems first"):
        PGOCore(3, Dimensions.of(problems), 1).state  # noqa: B018


def test_the_packed_entries_are_the_packs_keys(problems) -> None:
    problem, dims = problems[0], Dimensions.of(problems)
    pack = pack_problem(problem, dims) | pack_trees(problem, dims.vertices, dims.edges)
    assert set(pack) == set(PACKED)
    check_packed(pack)
    with pytest.raises(KeyError, match="undeclared"):
        check_packed(pack | {"posse": pack["poses"]})
    kinds = [names(kind) for kind in ("packed", "derived", "dynamic")]
    assert sum(len(k) for k in kinds) == len(CoreState.__slots__)
