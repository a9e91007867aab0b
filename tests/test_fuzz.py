"""Fuzzing ``popbench solve``: mutated g2o and TORO files (truncated lines, NaN/inf, words for
numbers, missing or repeated vertices, self-loops, information that is not positive definite,
huge values, empty files, disconnected graphs, unknown tags, …), made with a fixed seed from
small valid files, through the CLI for every registered method. Each case must either be solved
(exit 0, a finite F) or refused with one ``popbench: error:`` line and exit status 2: never a
traceback, never an "internal error"."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from conftest import grid_g2o, ring_g2o

from popbench import cli
from popbench.io import read_graph, write_toro
from popbench.methods import METHODS

Lines = list[str]
Mutation = Callable[[Lines, np.random.Generator], Lines]

BAD_NUMBERS = ("nan", "NaN", "inf", "-inf", "1e999", "abc", "0x1p3", "1,5", "", "--1", "1e-400")
HUGE_NUMBERS = ("1e300", "-1e300", "1e154", "1e-300", "1e16", "3.4e38")


def _choice(rng: np.random.Generator, options: tuple[str, ...]) -> str:
    """One of ``options`` (a Python str: NumPy's strings drop a trailing NUL)."""
    return options[int(rng.integers(len(options)))]


def _pick(lines: Lines, rng: np.random.Generator, prefix: str) -> int:
    """The index of a random line starting with ``prefix`` (a VERTEX or EDGE tag)."""
    rows = [k for k, line in enumerate(lines) if line.startswith(prefix)]
    return int(rng.choice(rows))


def _set_token(lines: Lines, rng: np.random.Generator, prefix: str, value: str, first: int = 1):
    """A copy of ``lines`` with one token (index ≥ ``first``) of a ``prefix`` line set to
    ``value``."""
    lines = list(lines)
    k = _pick(lines, rng, prefix)
    tokens = lines[k].split()
    tokens[int(rng.integers(first, len(tokens)))] = value
    lines[k] = " ".join(tokens)
    return lines


def truncate(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    k = int(rng.integers(len(lines)))
    tokens = lines[k].split()
    lines[k] = " ".join(tokens[: int(rng.integers(0, len(tokens)))])
    return lines


def extra_token(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    k = int(rng.integers(len(lines)))
    lines[k] += " 7"
    return lines


def bad_number(lines: Lines, rng: np.random.Generator) -> Lines:
    prefix = "VERTEX" if rng.random() < 0.3 else "EDGE"
    return _set_token(lines, rng, prefix, _choice(rng, BAD_NUMBERS))


def huge_number(lines: Lines, rng: np.random.Generator) -> Lines:
    """A huge or tiny (finite) value in a pose, a measurement or an information entry."""
    prefix = "VERTEX" if rng.random() < 0.3 else "EDGE"
    return _set_token(
        lines, rng, prefix, _choice(rng, HUGE_NUMBERS), first=2 if prefix == "VERTEX" else 3
    )


def scale_information(lines: Lines, rng: np.random.Generator) -> Lines:
    """Every information number of one edge (or of all) times a huge or tiny factor: still
    positive definite."""
    factor = float(_choice(rng, ("1e-200", "1e-20", "1e20", "1e200")))
    every = rng.random() < 0.5
    k = _pick(lines, rng, "EDGE")
    out = []
    for row, line in enumerate(lines):
        tokens = line.split()
        if line.startswith("EDGE") and (every or row == k):
            tokens[6:] = [f"{float(t) * factor:.17g}" for t in tokens[6:]]
        out.append(" ".join(tokens))
    return out


def ill_conditioned(lines: Lines, rng: np.random.Generator) -> Lines:
    """One edge's information made diagonal with a condition number of 1e20 or more."""
    lines = list(lines)
    k = _pick(lines, rng, "EDGE")
    tokens = lines[k].split()
    big, small = _choice(rng, ("1e12", "1e15", "1e30")), _choice(rng, ("1e-8", "1e-12"))
    info = [big, "0", "0", small, "0", "1"]  # g2o order: I11 I12 I13 I22 I23 I33
    if tokens[0] == "EDGE2":  # TORO order: I11 I12 I22 I33 I13 I23
        info = [big, "0", small, "1", "0", "0"]
    tokens[6:] = info
    lines[k] = " ".join(tokens)
    return lines


def bad_vertex_id(lines: Lines, rng: np.random.Generator) -> Lines:
    """A negative, fractional, absent or out-of-range vertex id in a VERTEX or EDGE line."""
    lines = list(lines)
    k = _pick(lines, rng, _choice(rng, ("VERTEX", "EDGE")))
    tokens = lines[k].split()
    slot = 1 if tokens[0].startswith("VERTEX") else int(rng.integers(1, 3))
    tokens[slot] = _choice(rng, ("-1", "1.5", "999", "2147483648", "1e20", "3.0"))
    lines[k] = " ".join(tokens)
    return lines


def missing_vertex(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    del lines[_pick(lines, rng, "VERTEX")]
    return lines


def duplicate_vertex(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    return [*lines, lines[_pick(lines, rng, "VERTEX")]]


def duplicate_edge(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    return [*lines, lines[_pick(lines, rng, "EDGE")]]


def reversed_edge(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    k = _pick(lines, rng, "EDGE")
    tokens = lines[k].split()
    tokens[1], tokens[2] = tokens[2], tokens[1]
    lines[k] = " ".join(tokens)
    return lines


def self_loop(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    k = _pick(lines, rng, "EDGE")
    tokens = lines[k].split()
    tokens[2] = tokens[1]
    lines[k] = " ".join(tokens)
    return lines


def bad_information(lines: Lines, rng: np.random.Generator) -> Lines:
    """Negative, zero, indefinite or tiny information on one edge (tokens 6… are Λ)."""
    lines = list(lines)
    k = _pick(lines, rng, "EDGE")
    tokens = lines[k].split()
    choice = int(rng.integers(4))
    if choice == 0:
        tokens[6:] = ["0"] * 6
    elif choice == 1:
        tokens[6] = "-" + tokens[6]
    elif choice == 2:
        tokens[7] = "1e6"  # an off-diagonal far larger than the diagonal: indefinite
    else:
        tokens[6:] = ["1e-300"] * 6
    lines[k] = " ".join(tokens)
    return lines


def drop_edges_of_a_vertex(lines: Lines, rng: np.random.Generator) -> Lines:
    """A disconnected graph: one vertex keeps its VERTEX line but loses every edge."""
    vertex = lines[_pick(lines, rng, "VERTEX")].split()[1]
    return [line for line in lines if not (line.startswith("EDGE") and vertex in line.split()[1:3])]


def drop_all_edges(lines: Lines, rng: np.random.Generator) -> Lines:
    return [line for line in lines if not line.startswith("EDGE")]


def drop_all_vertices(lines: Lines, rng: np.random.Generator) -> Lines:
    return [line for line in lines if not line.startswith("VERTEX")]


def empty(lines: Lines, rng: np.random.Generator) -> Lines:
    return [] if rng.random() < 0.5 else ["", "# only a comment", "   "]


def unknown_tag(lines: Lines, rng: np.random.Generator) -> Lines:
    lines = list(lines)
    tag = _choice(
        rng, ("FOO 1 2 3", "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1", "EQUIV 0 1", "\x00", "FIX 0")
    )
    lines.insert(int(rng.integers(len(lines) + 1)), tag)
    return lines


def whitespace(lines: Lines, rng: np.random.Generator) -> Lines:
    """Tabs, blank lines, comments, CRLF: all legal, the graph unchanged."""
    lines = [line.replace(" ", "\t  ") for line in lines]
    return ["# header", "", *[line + "\r" for line in lines], "   "]


def huge_graph_values(lines: Lines, rng: np.random.Generator) -> Lines:
    """Every measurement scaled by 1e150 (finite, but its squares overflow)."""
    out = []
    for line in lines:
        tokens = line.split()
        if line.startswith("EDGE"):
            tokens[3:5] = [f"{float(t) * 1e150:.17g}" for t in tokens[3:5]]
        out.append(" ".join(tokens))
    return out


def binary(lines: Lines, rng: np.random.Generator) -> Lines:
    return ["\udcff\udcfe garbage"]


MUTATIONS: tuple[Mutation, ...] = (
    truncate,
    extra_token,
    bad_number,
    huge_number,
    bad_vertex_id,
    missing_vertex,
    duplicate_vertex,
    duplicate_edge,
    reversed_edge,
    self_loop,
    bad_information,
    scale_information,
    ill_conditioned,
    drop_edges_of_a_vertex,
    drop_all_edges,
    drop_all_vertices,
    empty,
    unknown_tag,
    whitespace,
    huge_graph_values,
    binary,
)


def base_files(folder: Path) -> dict[str, Path]:
    """The valid files mutations start from: a 20-pose g2o grid, the same grid as TORO, and an
    8-pose g2o ring (the learned methods' tiny graph) — each read back once, so a base file is
    known to be valid."""
    grid = grid_g2o(folder / "grid.g2o")
    toro = folder / "grid.graph"
    write_toro(read_graph(grid), toro)
    files = {"grid.g2o": grid, "grid.graph": toro, "ring.g2o": ring_g2o(folder / "ring.g2o")}
    for path in files.values():
        read_graph(path)
    return files


def cases(base: Path, rounds: int, seed: int) -> list[tuple[str, str]]:
    """``(name, text)`` of ``rounds`` mutants per mutation (one or two mutations each) of
    ``base``, from the fixed ``seed``."""
    rng = np.random.default_rng(seed)
    lines = base.read_text().splitlines()
    made = []
    for round_ in range(rounds):
        for k, mutation in enumerate(MUTATIONS):
            mutated = mutation(lines, rng)
            names = [mutation.__name__]
            if round_ % 2 and mutated:  # every other round: a second, random mutation
                second = MUTATIONS[int(rng.integers(len(MUTATIONS)))]
                try:
                    mutated = second(mutated, rng)
                    names.append(second.__name__)
                except ValueError:  # nothing for it to pick (no VERTEX or EDGE line left)
                    pass
            made.append((f"{base.stem}-{round_}-{k}-{'+'.join(names)}", "\n".join(mutated)))
    return made


def failure(
    capsys: pytest.CaptureFixture, folder: Path, suffix: str, name: str, text: str, method: str
) -> str | None:
    """Run ``popbench solve`` on the case; None if it was solved (exit 0, a finite F) or refused
    (exit 2, one ``popbench: error:`` line naming the file), else what went wrong."""
    path = folder / f"{name}{suffix}"
    path.write_text(text + "\n", errors="surrogateescape")
    args = ["solve", str(path), "--method", method, "--robots", "2", "--iterations", "5", "--json"]
    code = cli.main(args)
    out, err = capsys.readouterr()
    if "Traceback" in err or "internal error" in err:
        pass
    elif code == 0 and np.isfinite(json.loads(out)["F"]):
        return None
    elif code == 2 and err.count("\n") == 1 and err.startswith(f"popbench: error: {path}:"):
        return None
    return f"{method} on {path.name}: exit {code}, stderr {err.strip()!r}, stdout {out[:80]!r}"


def run_cases(
    capsys: pytest.CaptureFixture, folder: Path, base: Path, method: str, rounds: int, seed: int
) -> None:
    """Every case of :func:`cases` through ``popbench solve --method method``; the test fails
    listing every case that was neither solved nor refused properly."""
    failures = [
        failure(capsys, folder, base.suffix, name, text, method)
        for name, text in cases(base, rounds, seed)
    ]
    failures = [text for text in failures if text is not None]
    assert not failures, "\n".join(failures)


CHEAP = tuple(name for name, record in METHODS.items() if not record.learned)
LEARNED = tuple(name for name, record in METHODS.items() if record.learned)


@pytest.mark.parametrize("method", CHEAP)
@pytest.mark.parametrize("key", ["grid.g2o", "grid.graph"])
def test_cheap_methods_survive_mutated_files(
    capsys: pytest.CaptureFixture, tmp_path: Path, method: str, key: str
) -> None:
    base = base_files(tmp_path)[key]
    run_cases(capsys, tmp_path, base, method, rounds=2, seed=len(key))


@pytest.mark.parametrize("method", LEARNED)
def test_learned_methods_survive_mutated_files(
    capsys: pytest.CaptureFixture, tmp_path: Path, method: str
) -> None:
    # The learned methods on the 8-pose ring (their first call loads torch and the actor).
    run_cases(capsys, tmp_path, base_files(tmp_path)["ring.g2o"], method, rounds=1, seed=11)
