"""The layout of the layers: the environment's dynamics (core, base step, correction, read-out,
geometry, observation, tree) import no policy (expert, sweep); no import circle inside envs/ or
agents/ at run time (imports inside functions count; type-only imports under TYPE_CHECKING do
not), none in popbench/ or baselines/ even for types; agents/ never imports the harness or the
command line; and every entry point of the layers above the core that the core loads by a
``"module:attribute"`` string is named in one registry."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENVS = ROOT / "envs"
DYNAMICS = set("core basestep correction readout geometry observation tree state features".split())
POLICIES = {"expert", "sweep"}
PACKAGES = ("popbench", "envs", "agents", "baselines")


def _type_only(tree: ast.AST) -> set[int]:
    return {
        id(node)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and "TYPE_CHECKING" in ast.unparse(block.test)
        for node in ast.walk(block)
    }


def imported_modules(path: Path, types: bool = False) -> set[str]:
    """The dotted modules `path` imports outside `if TYPE_CHECKING:` blocks, or everywhere with
    `types` (`from a import b` counts as `a` and `a.b`)."""
    tree = ast.parse(path.read_text())
    type_only = set() if types else _type_only(tree)
    names = set()
    for node in ast.walk(tree):
        if id(node) in type_only:
            continue
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
        elif isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
    return names


def runtime_imports(path: Path, package: str = "envs") -> set[str]:
    """The modules of `package` that `path` imports at run time."""
    prefix = f"{package}."
    return {
        name.split(".")[1]
        for name in imported_modules(path)
        if name.startswith(prefix) and (ROOT / package / f"{name.split('.')[1]}.py").is_file()
    }


def import_graph(package: str) -> dict[str, set[str]]:
    folder = ROOT / package
    return {
        path.stem: runtime_imports(path, package)
        for path in folder.glob("*.py")
        if path.stem != "__init__"
    }


GRAPH = import_graph("envs")


def test_the_dynamics_import_no_policy() -> None:
    for module in DYNAMICS:
        assert not GRAPH[module] & POLICIES, f"envs.{module} imports {GRAPH[module] & POLICIES}"


def on_circles(graph: dict[str, set[str]]) -> list[str]:
    """The modules of `graph` (module -> the modules it imports) that reach themselves."""

    def reach(start: str) -> set[str]:
        seen, todo = set(), [start]
        while todo:
            for name in graph.get(todo.pop(), set()) - seen:
                seen.add(name)
                todo.append(name)
        return seen

    return sorted(module for module in graph if module in reach(module))


@pytest.mark.parametrize("package", ["envs", "agents"])
def test_no_import_circle_at_run_time(package: str) -> None:
    circles = on_circles(import_graph(package))
    assert not circles, f"{package} modules on an import circle: {circles}"


def _dotted(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def module_graph(package: str, type_only: bool) -> dict[str, set[str]]:
    """Dotted module -> the modules of `package` (sub-packages included) it imports, the longest
    importable prefix of each name; `type_only` counts the TYPE_CHECKING imports too. A module's
    own parent packages are left out (importing a sibling runs them anyway)."""
    paths = {_dotted(path): path for path in (ROOT / package).rglob("*.py")}
    graph = {}
    for module, path in paths.items():
        targets = set()
        for name in imported_modules(path, types=type_only):
            parts = name.split(".")
            found = next(
                (
                    ".".join(parts[:k])
                    for k in range(len(parts), 0, -1)
                    if ".".join(parts[:k]) in paths
                ),
                None,
            )
            if found and found != module and not module.startswith(f"{found}."):
                targets.add(found)
        graph[module] = targets
    return graph


@pytest.mark.parametrize("package", ["popbench", "baselines", "envs", "agents"])
def test_no_import_circle_in_the_library_even_for_types(package: str) -> None:
    """No circle of files in any package (sub-packages included), counting the imports made for
    types only: a circle there is a design one (a private name reached back into, the declared
    state reaching up into the step code), not only a run-time hazard."""
    assert not on_circles(module_graph(package, type_only=True))


def test_the_library_checker_sees_imports() -> None:
    graph = module_graph("popbench", type_only=True)
    assert "popbench.io.format" in graph["popbench.io.limits"]
    assert "popbench.solvers.chordal" in graph["popbench.solvers.initial"]  # inside a function
    assert (
        "popbench.problems.distributed" in graph["popbench.solvers.initial"]
    )  # under TYPE_CHECKING
    assert on_circles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == ["a", "b"]
    assert "envs.state" in module_graph("envs", type_only=True)["envs.basestep"]  # for its type


def test_the_checker_sees_imports() -> None:  # the tests above cannot pass vacuously
    assert {"basestep", "correction", "readout", "tree"} <= GRAPH["core"]
    assert "core" in GRAPH["sweep"] and "expert" in GRAPH["sweep"]
    assert "core" not in GRAPH["readout"]  # imported for its type only
    agents = import_graph("agents")
    assert {"algorithms", "learner"} <= agents["trainer"]  # one inside a function: checkpoint
    assert "checkpoint" in agents["imitation"]


def test_the_base_step_and_the_read_out_are_functions_of_the_state() -> None:
    """envs.basestep and envs.readout take the declared state (envs.state.CoreState), not the
    core: neither names PGOCore, not even for its type."""
    for module in ("basestep", "readout"):
        tree = ast.parse((ENVS / f"{module}.py").read_text())
        names = {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)}
        names |= {a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names}
        assert "PGOCore" not in names, f"envs.{module} names PGOCore"
        assert "CoreState" in names  # the checker reads names


def test_agents_never_import_the_harness_or_the_command_line() -> None:
    offending = {
        path.name: sorted(
            name
            for name in imported_modules(path)
            if name.startswith(("popbench.harness", "popbench.cli"))
        )
        for path in sorted((ROOT / "agents").rglob("*.py"))
    }
    assert not {name: found for name, found in offending.items() if found}


def _entry_strings(path: Path) -> list[str]:
    """String constants of `path` that name an attribute of a project module, "pkg.mod:attr"."""
    tree = ast.parse(path.read_text())
    return [
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and ":" in node.value
        and node.value.split(".")[0] in PACKAGES
        and node.value.partition(":")[2].isidentifier()
        and all(part.isidentifier() for part in node.value.partition(":")[0].split("."))
    ]


def test_string_loaded_entry_points_are_named_in_one_registry() -> None:
    registry = ROOT / "popbench" / "methods.py"
    elsewhere = {
        str(path.relative_to(ROOT)): strings
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if path != registry and (strings := _entry_strings(path))
    }
    assert not elsewhere, f"'module:attribute' strings outside popbench/methods.py: {elsewhere}"
    assert "agents.heldout:evaluate_row" in _entry_strings(registry)  # the scan sees them


def test_every_registered_entry_point_loads() -> None:
    from popbench.methods import ENTRY_POINTS, entry_point

    for name, target in ENTRY_POINTS.items():
        module, _, attribute = target.partition(":")
        assert entry_point(name) is getattr(importlib.import_module(module), attribute)


def test_every_algorithm_has_a_learner_record() -> None:
    from agents.algorithms import LEARNERS
    from agents.config import ALGORITHMS

    assert set(LEARNERS) == set(ALGORITHMS)
    assert len({id(learner) for learner in LEARNERS.values()}) == len(LEARNERS)


MODE_DEFAULTS_HOME = ROOT / "envs" / "modes.py"
STEP_RULES_HOME = ROOT / "popbench" / "choices.py"


def _string_constants(tree: ast.AST) -> list[ast.Constant]:
    """The string constants of ``tree`` other than docstrings."""
    docstrings = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
        and node.body
        and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [
        node
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and id(node) not in docstrings
    ]


def _is_string(node: ast.AST | None) -> bool:
    return isinstance(node, ast.Constant) and isinstance(node.value, str)


def _mode_defaults(tree: ast.AST) -> list[int]:
    """Lines where a mode of envs.modes gets a literal default: a parameter or field named after
    a mode with a string default, or ``.get("step_rule", "…")``."""
    from envs.modes import MODE_NAMES

    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.arguments):
            named = node.posonlyargs + node.args
            pairs = list(zip(named[len(named) - len(node.defaults) :], node.defaults, strict=True))
            pairs += [
                (a, d)
                for a, d in zip(node.kwonlyargs, node.kw_defaults, strict=True)
                if d is not None
            ]
            lines += [d.lineno for a, d in pairs if a.arg in MODE_NAMES and _is_string(d)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            if node.target.id in MODE_NAMES and _is_string(node.value):
                lines.append(node.lineno)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute):
            arguments = node.args
            if (
                node.func.attr == "get"
                and len(arguments) == 2
                and all(_is_string(a) for a in arguments)
            ):
                if arguments[0].value in MODE_NAMES:
                    lines.append(node.lineno)
    return lines


def test_every_mode_default_is_defined_once() -> None:
    """The environment's mode defaults live in envs.modes.EnvModes alone, and the training step
    rule's name is written once (popbench.choices); every other module refers to them."""
    clip, defaults = [], []
    for package in ("popbench", "envs", "agents", "baselines"):
        for path in (ROOT / package).rglob("*.py"):
            tree = ast.parse(path.read_text())
            where = path.relative_to(ROOT)
            if path != STEP_RULES_HOME:
                clip += [
                    f"{where}:{n.lineno}" for n in _string_constants(tree) if n.value == "clip"
                ]
            if path != MODE_DEFAULTS_HOME:
                defaults += [f"{where}:{line}" for line in _mode_defaults(tree)]
    assert not clip, f"the step rule 'clip' written outside popbench/choices.py: {clip}"
    assert not defaults, f"a mode default written outside envs/modes.py: {defaults}"


def test_the_mode_default_checker_sees_literals() -> None:
    tree = ast.parse(
        'def f(step_rule="clip", *, base="none", correction=None):\n    """doc "clip"."""\n'
        "class A:\n    correction: str = 'pose'\n"
        "x = spec.get('step_rule', 'clip')\n"
    )
    assert [node.value for node in _string_constants(tree)].count("clip") == 2
    assert sorted(_mode_defaults(tree)) == [1, 1, 4, 5]


MODULE_MAX_LINES = 550
DOCSTRING_MAX_LINES = 40


def test_modules_and_docstrings_stay_short() -> None:
    """No package module over 550 lines and no class or function docstring over 40 lines: a
    longer one holds two ideas (split the module) or a page of docs (move it to docs/)."""
    long_modules, long_docstrings = [], []
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            text = path.read_text()
            where = path.relative_to(ROOT)
            if text.count("\n") > MODULE_MAX_LINES:
                long_modules.append(f"{where}: {text.count(chr(10))}")
            for node in ast.walk(ast.parse(text)):
                if isinstance(node, ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                    doc = ast.get_docstring(node, clean=False)
                    if doc is not None and doc.count("\n") + 1 > DOCSTRING_MAX_LINES:
                        long_docstrings.append(f"{where}:{node.lineno} {node.name}")
    assert not long_modules, f"modules over {MODULE_MAX_LINES} lines: {long_modules}"
    assert not long_docstrings, f"docstrings over {DOCSTRING_MAX_LINES} lines: {long_docstrings}"
