"""The layout of envs/ (issue 27, item 4): the environment's dynamics (core, base step,
read-out, geometry, observation, tree) import no policy (expert, sweep) and have no import
circle at run time; type-only imports (under TYPE_CHECKING) do not count."""

from __future__ import annotations

import ast
from pathlib import Path

ENVS = Path(__file__).resolve().parents[1] / "envs"
DYNAMICS = {"core", "basestep", "readout", "geometry", "observation", "tree", "state", "features"}
POLICIES = {"expert", "sweep"}


def runtime_imports(path: Path) -> set[str]:
    """The envs modules `path` imports outside `if TYPE_CHECKING:` blocks."""
    tree = ast.parse(path.read_text())
    type_only = {
        id(node)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for node in ast.walk(block)
    }
    names = set()
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("envs."):
            names.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            names |= {a.name.split(".")[1] for a in node.names if a.name.startswith("envs.")}
    return names


GRAPH = {path.stem: runtime_imports(path) for path in ENVS.glob("*.py") if path.stem != "__init__"}


def test_the_dynamics_import_no_policy() -> None:
    for module in DYNAMICS:
        assert not GRAPH[module] & POLICIES, f"envs.{module} imports {GRAPH[module] & POLICIES}"


def test_no_import_circle_at_run_time() -> None:
    def reach(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for name in GRAPH.get(todo.pop(), set()) - seen:
                seen.add(name)
                todo.append(name)
        return seen

    circles = sorted(module for module in GRAPH if module in reach(module))
    assert not circles, f"modules on an import circle: {circles}"


def test_the_checker_sees_imports() -> None:  # the two tests above cannot pass vacuously
    assert {"basestep", "readout", "tree"} <= GRAPH["core"]
    assert "core" in GRAPH["sweep"] and "expert" in GRAPH["sweep"]
    assert "core" not in GRAPH["readout"]  # imported for its type only


def test_the_base_step_and_the_read_out_are_functions_of_the_state() -> None:
    """envs.basestep and envs.readout take the declared state (envs.state.CoreState), not the
    core: neither names PGOCore, not even for its type."""
    for module in ("basestep", "readout"):
        tree = ast.parse((ENVS / f"{module}.py").read_text())
        names = {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert "PGOCore" not in names, f"envs.{module} names PGOCore"
        assert "CoreState" in names  # the checker reads names
