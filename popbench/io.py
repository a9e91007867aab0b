"""Read and write planar pose graphs: g2o (``VERTEX_SE2``/``EDGE_SE2``) and TORO
(``VERTEX2``/``EDGE2``).

g2o edge: ``EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33`` (upper triangle, (x, y, θ) order).
TORO edge: ``EDGE2 i j dx dy dθ I11 I12 I22 I33 I13 I23``; TORO's translation error is not in
the measurement frame, so the cost-preserving conversion is ``Λ_g2o = Bᵀ Λ_TORO B`` with
``B = blkdiag(R(θ̃), 1)``.

TORO ``EQUIV i j`` (as in Olson's ``w10000.graph``) declares vertices ``i`` and ``j`` to be the
same pose. They are merged, not tied by a tight edge: an infinitely stiff constraint is exactly
the identification of the two variables, and a finite stand-in would only add a badly
conditioned edge. Each class of equivalent ids (EQUIV lines chain) keeps its smallest id and that
vertex's pose; the other vertices are removed, their edges are redirected to the kept vertex,
and an edge that ends up joining a vertex to itself is dropped (with a :class:`ReadWarning` that
counts them). :func:`read_vertices` applies the same merge, so a ground-truth file with the same
EQUIV lines stays aligned.

Vertex ids are any integers ``0 … 2⁶⁴−1`` (GTSAM keys), in any order, with gaps: internal
indices ``0 … N−1`` follow the ascending ids (so edge kinds, :func:`popbench.graph.
single_robot_kinds`, see consecutive ids), ``PoseGraph.vertex_ids`` keeps the ids and every
writer writes them back. ``FIX id…`` lines give ``PoseGraph.fixed``; lines of other tags are
skipped and counted (:class:`ReadWarning`). Edges written ``i > j`` are kept as
written. Files without VERTEX lines get the odometry composition of their edges
(:func:`popbench.graph.odometry_composition`).
"""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np

from popbench import se2
from popbench.errors import DataFormatError, ValueRangeError
from popbench.graph import (
    EdgeKind,
    PoseGraph,
    make_graph,
    odometry_composition,
    unconnected_vertices,
)

_FORMATS = {
    # format: (vertex tag, edge tag)
    "g2o": ("VERTEX_SE2", "EDGE_SE2"),
    "toro": ("VERTEX2", "EDGE2"),
}
# Upper-triangle (row, col) of each of the six information numbers, per format.
_G2O_ENTRIES = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
_TORO_ENTRIES = [(0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2)]
# The pose-graph tags of each format: one of them in a file of the other format is refused
# (a mixed file), never skipped.
_FORMAT_OF_TAG = {"VERTEX_SE2": "g2o", "EDGE_SE2": "g2o", "VERTEX2": "toro", "EDGE2": "toro"}


class ReadWarning(UserWarning):
    """What reading a file left out, in one line: lines of kinds popbench does not model
    (landmarks, 3D, any other tag; each tag with its count), or edges that a TORO EQUIV merge
    made self-loops. ``popbench solve`` prints each on stderr."""


def detect_format(path: Path) -> str:
    """``"toro"`` for ``.graph`` files or files whose first tag is VERTEX2/EDGE2, else ``"g2o"``."""
    if path.suffix == ".graph":
        return "toro"
    with path.open(encoding="utf-8", errors="replace") as handle:
        for line in handle:
            tag = line.split(maxsplit=1)[0] if line.strip() else ""
            if tag in ("VERTEX2", "EDGE2"):
                return "toro"
            if tag in ("VERTEX_SE2", "EDGE_SE2"):
                return "g2o"
    return "g2o"


def _wrap_out_of_range(theta: np.ndarray) -> np.ndarray:
    """Angles [rad] wrapped to ``[-π, π)``, leaving those already in range bit-exact
    (``se2.wrap`` moves in-range angles by an ulp, which would break exact round trips)."""
    return np.where((theta >= -np.pi) & (theta < np.pi), theta, se2.wrap(theta))


# Field names after the tag, per tag (for messages).
_FIELDS = {
    "VERTEX_SE2": ("id", "x", "y", "theta"),
    "VERTEX2": ("id", "x", "y", "theta"),
    "EDGE_SE2": ("i", "j", "dx", "dy", "dtheta", "I11", "I12", "I13", "I22", "I23", "I33"),
    "EDGE2": ("i", "j", "dx", "dy", "dtheta", "I11", "I12", "I22", "I33", "I13", "I23"),
    "EQUIV": ("i", "j"),
}
# TORO: ``EQUIV i j`` declares vertices i and j the same pose (merged on reading).
_EQUIV_TAG = "EQUIV"
# g2o: ``FIX id…`` holds those poses fixed (also read in TORO files, where popbench writes it).
_FIX_TAG = "FIX"
# Vertex ids are unsigned 64-bit integers written in decimal digits (GTSAM keys, ``Symbol``s).
MAX_VERTEX_ID = 2**64 - 1


def _parse_id(path: Path, lineno: int, tag: str, field: str, token: str) -> int:
    """The vertex id ``token`` of field ``field`` as an exact int in ``0 … MAX_VERTEX_ID``."""
    if token.isdigit() and token.isascii():
        value = int(token)
        if value <= MAX_VERTEX_ID:
            return value
        why = f"is out of range (0 to {MAX_VERTEX_ID}, 64 bits)"
    else:
        why = "is not an integer ≥ 0 written in decimal digits"
    raise DataFormatError(path, lineno, f"{tag} field {field}: vertex id {token!r} {why}")


def _parse_line(
    path: Path, lineno: int, tokens: list[str], count: int, tag: str
) -> tuple[list[int], list[float]]:
    """The vertex ids (exact) and the numbers of a VERTEX, EDGE or EQUIV line of ``count``
    tokens, the tag included."""
    if len(tokens) != count:
        raise DataFormatError(
            path, lineno, f"{tag} needs {count - 1} values after the tag, found {len(tokens) - 1}"
        )
    fields = _FIELDS[tag]
    id_count = 1 if tag.startswith("VERTEX") else 2
    try:
        values = [float(token) for token in tokens[1 + id_count :]]
    except ValueError:
        values = []
    if len(values) != count - 1 - id_count or not all(map(math.isfinite, values)):
        _refuse_numbers(path, lineno, tokens, tag, id_count)
    ids = [_parse_id(path, lineno, tag, fields[k], tokens[k + 1]) for k in range(id_count)]
    if id_count == 2 and ids[0] == ids[1]:
        why = (
            "an EQUIV line names two different vertices"
            if tag == _EQUIV_TAG
            else ("pose-graph edges join two different poses")
        )
        message = f"{tag} joins vertex {ids[0]} to itself ({why})"
        raise DataFormatError(path, lineno, message)
    return ids, values


def _refuse_numbers(path: Path, lineno: int, tokens: list[str], tag: str, id_count: int) -> None:
    """Raise the DataFormatError for the first number of the line that is not a finite float."""
    fields, count = _FIELDS[tag], len(tokens) - 1
    for k in range(id_count, count):
        token = tokens[k + 1]
        where = f"{tag} field {fields[k]} (value {k + 1} of {count})"
        try:
            value = float(token)
        except ValueError:
            message = f"{where} is {token!r}: expected a number"
            raise DataFormatError(path, lineno, message) from None
        if not math.isfinite(value):
            raise DataFormatError(path, lineno, f"{where} is non-finite ({token!r})")


class _Lines(NamedTuple):
    """The parsed lines of one file, with their 1-based line numbers; ids exact, as written."""

    vertex_ids: np.ndarray  # (V,) uint64
    vertices: np.ndarray  # (V, 3) x, y, θ
    vertex_lines: np.ndarray  # (V,)
    edge_ids: np.ndarray  # (E, 2) uint64 i, j
    edges: np.ndarray  # (E, 9) dx, dy, dθ, six information numbers
    edge_lines: np.ndarray  # (E,)
    equivs: np.ndarray  # (Q, 2) uint64 i, j of the TORO EQUIV lines
    equiv_lines: np.ndarray  # (Q,)
    fixes: np.ndarray  # (K,) uint64 ids of the FIX lines (a line may name several)
    fix_lines: np.ndarray  # (K,)
    skipped: dict[str, int]  # tag → count of the lines of kinds popbench does not model


def _scan(path: Path, fmt: str, parse_edges: bool = True) -> _Lines:
    vertex_tag, edge_tag = _FORMATS[fmt]
    # tag → (kind, tokens per line); EQUIV is a TORO tag only.
    kinds = {vertex_tag: ("vertex", 5), edge_tag: ("edge", 12)}
    if fmt == "toro":
        kinds[_EQUIV_TAG] = ("equiv", 3)
    ids: dict[str, list[list[int]]] = {"vertex": [], "edge": [], "equiv": [], "fix": []}
    numbers: dict[str, list[list[float]]] = {"vertex": [], "edge": [], "equiv": []}
    line_numbers: dict[str, list[int]] = {"vertex": [], "edge": [], "equiv": [], "fix": []}
    skipped: dict[str, int] = {}
    lineno = 0
    try:
        with path.open(encoding="utf-8") as handle:
            for lineno, line in enumerate(handle, start=1):  # noqa: B007 - used after the loop
                tokens = line.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                tag = tokens[0]
                if tag in kinds:
                    kind, count = kinds[tag]
                    if kind != "edge" or parse_edges:
                        line_ids, values = _parse_line(path, lineno, tokens, count, tag)
                        ids[kind].append(line_ids)
                        numbers[kind].append(values)
                    line_numbers[kind].append(lineno)
                elif tag == _FIX_TAG:
                    if len(tokens) < 2:
                        raise DataFormatError(path, lineno, "FIX needs at least one vertex id")
                    ids["fix"].extend([_parse_id(path, lineno, tag, "id", t)] for t in tokens[1:])
                    line_numbers["fix"].extend([lineno] * (len(tokens) - 1))
                elif tag in _FORMAT_OF_TAG or tag == _EQUIV_TAG:
                    other = _FORMAT_OF_TAG.get(tag, "toro")
                    raise DataFormatError(
                        path,
                        lineno,
                        f"unknown tag {tag!r} in a {fmt} file ({tag} is a {other} tag; expected "
                        f"{vertex_tag} or {edge_tag}: one format per file, detected from a "
                        ".graph suffix or the first VERTEX/EDGE tag)",
                    )
                else:
                    skipped[tag] = skipped.get(tag, 0) + 1
    except UnicodeDecodeError:
        raise DataFormatError(path, lineno + 1, "not a text file") from None

    def exact(kind: str, width: int) -> np.ndarray:
        return np.asarray(ids[kind], dtype=np.uint64).reshape(-1, width)

    def real(kind: str, width: int) -> np.ndarray:
        return np.asarray(numbers[kind], dtype=np.float64).reshape(-1, width)

    def where(kind: str) -> np.ndarray:
        return np.asarray(line_numbers[kind], dtype=np.int64)

    return _Lines(
        exact("vertex", 1)[:, 0],
        real("vertex", 3),
        where("vertex"),
        exact("edge", 2),
        real("edge", 9),
        where("edge"),
        exact("equiv", 2),
        where("equiv"),
        exact("fix", 1)[:, 0],
        where("fix"),
        skipped,
    )


def _id_range(ids: np.ndarray) -> str:
    """``"ids 0–5"`` for ascending ``ids`` without gaps, else ``"6 ids from 1 to 40"``."""
    first, last = int(ids[0]), int(ids[-1])
    if last - first + 1 == ids.size:
        return f"ids {first}–{last}"
    return f"{ids.size} ids from {first} to {last}"


def _vertex_table(path: Path, lines: _Lines) -> tuple[np.ndarray, np.ndarray | None]:
    """The graph's vertex ids, ascending ``(N,)`` uint64, and their ``(N, 3)`` poses: those of
    the VERTEX lines (an id repeated is refused), or, in a file without VERTEX lines, every id
    that an edge names (poses None). Internal index ``k`` is the vertex with the ``k``-th
    smallest id."""
    if not lines.vertex_ids.size:
        return np.unique(lines.edge_ids), None
    order = np.argsort(lines.vertex_ids, kind="stable")
    ids = lines.vertex_ids[order]
    repeated = np.flatnonzero(ids[1:] == ids[:-1])
    if repeated.size:
        k = order[repeated[0] + 1]
        message = f"vertex id {lines.vertex_ids[k]} repeated"
        raise DataFormatError(path, int(lines.vertex_lines[k]), message)
    poses = lines.vertices[order]
    poses[:, 2] = _wrap_out_of_range(poses[:, 2])
    return ids, poses


def _indices(
    path: Path, tag: str, missing: str, ids: np.ndarray, wanted: np.ndarray, line_numbers
) -> np.ndarray:
    """The internal indices (int64, the shape of ``wanted``) of the file ids ``wanted`` among
    the ascending vertex ``ids``; a DataFormatError on the line of the first (in file order)
    that is not a vertex, naming it and ending in ``missing`` (why it is not)."""
    slots = np.searchsorted(ids, wanted)
    found = ids[np.minimum(slots, ids.size - 1)] == wanted
    if not found.all():
        where = tuple(np.argwhere(~found)[0])
        message = f"{tag} references vertex {wanted[where]}, {missing} ({_id_range(ids)})"
        raise DataFormatError(path, int(line_numbers[where[0]]), message)
    return slots.astype(np.int64)


def _equivalence_map(path: Path, lines: _Lines, ids: np.ndarray) -> np.ndarray | None:
    """``(N,)`` new internal index of each vertex after merging the EQUIV classes (each class
    kept as its smallest id, survivors renumbered 0 … in ascending id order), or ``None`` when
    the file has no EQUIV lines.

    Raises:
        DataFormatError: an EQUIV line naming an id that is not a vertex of the graph.
    """
    if not lines.equivs.size:
        return None
    missing = "which is not in the graph"
    equivs = _indices(path, _EQUIV_TAG, missing, ids, lines.equivs, lines.equiv_lines)
    root = np.arange(ids.size)

    def find(v: int) -> int:
        while root[v] != v:
            root[v] = root[root[v]]
            v = int(root[v])
        return v

    for i, j in equivs:  # one step per EQUIV line, at parse time
        a, b = find(int(i)), find(int(j))
        root[max(a, b)] = min(a, b)
    while True:  # flatten every chain to its root, vectorised
        parent = root[root]
        if np.array_equal(parent, root):
            break
        root = parent
    kept = root == np.arange(ids.size)
    new_id = np.cumsum(kept) - 1
    return new_id[root]


def _kept(rows: np.ndarray, new_id: np.ndarray) -> np.ndarray:
    """The rows of the kept vertices after a merge: each merged class takes the row (pose, id)
    of its kept (smallest) id, the first vertex mapped to each new index."""
    _, first = np.unique(new_id, return_index=True)
    return rows[first]


def read_graph(path: str | Path, name: str | None = None) -> PoseGraph:
    """Read a g2o or TORO file (format from the suffix or the first tag).

    Vertex ids may be any integers ``0 … 2⁶⁴−1`` in any order, with gaps: the graph's internal
    indices ``0 … N−1`` follow the ids in ascending order and ``PoseGraph.vertex_ids`` keeps the
    ids as written (``None`` when they are ``0 … N−1``). ``FIX id…`` lines give
    ``PoseGraph.fixed``. Lines of other tags are skipped with one :class:`ReadWarning` that
    counts them per tag (docs/io.md).

    Raises:
        FileNotFoundError: no such file.
        DataFormatError: a malformed line (``file:line: reason``), a tag of the other format,
            no edges, a repeated vertex id, an edge, FIX or EQUIV line naming an id that is not a
            vertex, an information matrix that is not positive definite, or poses that no path
            of edges joins to the vertex of the smallest id (:func:`_check_connected`).
    """
    path = Path(path)
    fmt = detect_format(path)
    vertex_tag, edge_tag = _FORMATS[fmt]
    lines = _scan(path, fmt)
    if not lines.edges.size:
        raise DataFormatError(path, 0, f"no {edge_tag} lines: not a {fmt} pose graph")
    measurements = lines.edges[:, :3].copy()
    measurements[:, 2] = _wrap_out_of_range(measurements[:, 2])
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: refused just below
        information = _information(lines.edges[:, 3:], fmt, measurements[:, 2])
    _check_information(path, information, lines.edge_lines)
    _check_coordinates(path, lines)

    ids, poses = _vertex_table(path, lines)
    missing = f"which has no {vertex_tag} line"
    ends = _indices(path, edge_tag, missing, ids, lines.edge_ids, lines.edge_lines)
    tails, heads = ends[:, 0], ends[:, 1]
    missing = "which is not in the graph"
    fixed = _indices(path, _FIX_TAG, missing, ids, lines.fixes, lines.fix_lines)
    new_id = _equivalence_map(path, lines, ids)
    if new_id is not None:
        tails, heads, fixed = new_id[tails], new_id[heads], new_id[fixed]
        ids = _kept(ids, new_id)
        if poses is not None:
            poses = _kept(poses, new_id)
        loops = tails == heads
        if loops.any():
            warnings.warn(
                f"{path}: EQUIV merged {lines.equivs.shape[0]} vertex pair(s); dropped "
                f"{int(loops.sum())} edge(s) that joined equivalent vertices (self-loops)",
                ReadWarning,
                stacklevel=2,
            )
            keep = ~loops
            tails, heads = tails[keep], heads[keep]
            measurements, information = measurements[keep], information[keep]
    _check_connected(path, lines, ids, tails, heads)
    if poses is None:
        poses = odometry_composition(ids.size, tails, heads, measurements)
    _warn_skipped(path, lines.skipped, fmt)
    return make_graph(
        poses,
        tails,
        heads,
        measurements,
        information,
        name=name or path.stem,
        vertex_ids=None if int(ids[-1]) == ids.size - 1 else ids,
        fixed=np.unique(fixed) if fixed.size else None,
    )


def _warn_skipped(path: Path, skipped: dict[str, int], fmt: str) -> None:
    """One :class:`ReadWarning` naming each skipped tag with its count."""
    if not skipped:
        return
    counts = ", ".join(
        f"{tag if tag.isprintable() else repr(tag)} ×{count}" for tag, count in skipped.items()
    )
    read = " ".join([*_FORMATS[fmt], _FIX_TAG] + ([_EQUIV_TAG] if fmt == "toro" else []))
    warnings.warn(
        f"{path}: skipped {sum(skipped.values())} line(s) of kinds popbench does not model "
        f"({counts}); it reads {read} (see docs/io.md)",
        ReadWarning,
        stacklevel=3,
    )


def _check_connected(
    path: Path, lines: _Lines, ids: np.ndarray, tails: np.ndarray, heads: np.ndarray
) -> None:
    """Every pose must be joined to the vertex of the smallest id (internal index 0) by a path
    of edges (one gauge fixes the whole graph; a pose in another component is undetermined and
    makes every solver's system singular). The error names the first few unconnected poses by
    their ids in the file (``ids``, ``(N,)``, after any EQUIV merge) and the line of the first
    one's VERTEX line (or of its first edge, without VERTEX lines)."""
    unconnected = ids[unconnected_vertices(ids.size, tails, heads)]
    if not unconnected.size:
        return
    first = unconnected[0]
    if lines.vertex_ids.size:
        line = lines.vertex_lines[np.flatnonzero(lines.vertex_ids == first)[0]]
    else:
        line = lines.edge_lines[np.flatnonzero((lines.edge_ids == first).any(axis=1))[0]]
    shown = ", ".join(map(str, unconnected[:5].tolist())) + (", …" if unconnected.size > 5 else "")
    raise DataFormatError(
        path,
        int(line),
        f"{unconnected.size} of {ids.size} poses (ids {shown}) are not connected to vertex "
        f"{ids[0]} by any path of edges, so the graph has no single gauge: remove them or add "
        "edges",
    )


def read_vertices(path: str | Path) -> np.ndarray:
    """Only the VERTEX lines of a g2o/TORO file as ``(N, 3)`` poses in ascending id order, the
    order :func:`read_graph` gives the same ids (e.g. a ground-truth file); edge lines are
    skipped unparsed.

    Raises:
        DataFormatError: no VERTEX lines, a malformed one, or a repeated id.
    """
    path = Path(path)
    fmt = detect_format(path)
    lines = _scan(path, fmt, parse_edges=False)
    if not lines.vertices.size:
        raise DataFormatError(path, 0, f"no {_FORMATS[fmt][0]} lines")
    ids, poses = _vertex_table(path, lines)
    new_id = _equivalence_map(path, lines, ids)
    return poses if new_id is None else _kept(poses, new_id)


def _information(values: np.ndarray, fmt: str, theta: np.ndarray) -> np.ndarray:
    entries = _G2O_ENTRIES if fmt == "g2o" else _TORO_ENTRIES
    information = np.zeros((values.shape[0], 3, 3))
    for k, (row, col) in enumerate(entries):
        information[:, row, col] = values[:, k]
        information[:, col, row] = values[:, k]
    if fmt == "toro":
        b = np.zeros_like(information)
        b[:, :2, :2] = se2.rotation(theta)
        b[:, 2, 2] = 1.0
        information = np.swapaxes(b, 1, 2) @ information @ b
    return information


# Magnitudes the solvers are known to handle (docs/solve.md, "Refused input"): beyond them a file is
# refused at load with its line, not left to fail inside a factorisation.
COORDINATE_LIMIT = 1e9  # |x|, |y| of a VERTEX line and |dx|, |dy| of an edge [m]
INFORMATION_RANGE = (1e-100, 1e100)  # every eigenvalue of every information matrix
INFORMATION_SPREAD = 1e15  # largest / smallest eigenvalue over the whole graph


def _check_coordinates(path: Path, lines: _Lines) -> None:
    """Every translation (VERTEX x, y; edge dx, dy) within ``±COORDINATE_LIMIT`` metres."""
    for rows, columns, numbers, what in (
        (lines.vertices, [0, 1], lines.vertex_lines, "pose coordinate"),
        (lines.edges, [0, 1], lines.edge_lines, "measured translation"),
    ):
        bad = np.flatnonzero((np.abs(rows[:, columns]) > COORDINATE_LIMIT).any(axis=1))
        if bad.size:
            k = int(bad[0])
            value = rows[k, columns][np.argmax(np.abs(rows[k, columns]))]
            raise DataFormatError(
                path,
                int(numbers[k]),
                f"{what} {value:.3g} m is out of range (allowed ±{COORDINATE_LIMIT:.0e} m)",
            )


def _check_information(path: Path, information: np.ndarray, lines: np.ndarray) -> None:
    """Every information matrix positive definite with eigenvalues in
    :data:`INFORMATION_RANGE`, and their spread over the graph (largest / smallest) at most
    :data:`INFORMATION_SPREAD` (beyond it the weakest edges are below double-precision
    round-off of the strongest in the normal equations, and factorisations fail)."""
    overflow = np.flatnonzero(~np.isfinite(information).all(axis=(1, 2)))  # TORO's rotation
    if overflow.size:
        high = f"{INFORMATION_RANGE[1]:.0e}"
        message = f"information matrix overflows (allowed eigenvalues up to {high})"
        raise DataFormatError(path, lines[int(overflow[0])], message)
    eigenvalues = np.linalg.eigvalsh(information)
    smallest, largest = eigenvalues[:, 0], eigenvalues[:, -1]
    bad = np.flatnonzero(~(smallest > 0.0))  # ~(> 0): NaN fails too
    if bad.size:
        k = int(bad[0])
        raise DataFormatError(
            path,
            lines[k],
            f"information matrix is not positive definite "
            f"(smallest eigenvalue {eigenvalues[k, 0]:.3g})",
        )
    low, high = INFORMATION_RANGE
    bad = np.flatnonzero(~((smallest >= low) & (largest <= high)))
    if bad.size:
        k = int(bad[0])
        value = smallest[k] if not smallest[k] >= low else largest[k]
        raise DataFormatError(
            path,
            lines[k],
            f"information matrix eigenvalue {value:.3g} is out of range "
            f"(allowed {low:.0e} to {high:.0e})",
        )
    weakest, strongest = int(np.argmin(smallest)), int(np.argmax(largest))
    spread = largest[strongest] / smallest[weakest]
    if spread > INFORMATION_SPREAD:
        raise DataFormatError(
            path,
            lines[strongest],
            f"information spans {spread:.3g} (eigenvalue {largest[strongest]:.3g} here, "
            f"{smallest[weakest]:.3g} on line {lines[weakest]}); allowed at most "
            f"{INFORMATION_SPREAD:.0e}: the weaker edges would be below round-off",
        )


def _savetxt(handle, rows: np.ndarray, fmt: list[str] | str, delimiter: str = " ") -> None:
    """``np.savetxt`` of ``rows`` (nothing for zero rows: savetxt would write one empty line)."""
    if rows.shape[0]:
        np.savetxt(handle, rows, fmt=fmt, delimiter=delimiter)


def _rows(*columns: np.ndarray) -> np.ndarray:
    """``(R, C)`` object array of ``columns`` (each ``(R,)`` or ``(R, k)``), so that ids stay
    exact uint64 integers next to float64 numbers when :func:`_savetxt` formats them."""
    blocks = [np.asarray(column).reshape(len(column), -1) for column in columns]
    table = np.empty((len(columns[0]), sum(block.shape[1] for block in blocks)), dtype=object)
    start = 0
    for block in blocks:
        table[:, start : start + block.shape[1]] = block
        start += block.shape[1]
    return table


def file_ids(graph: PoseGraph) -> np.ndarray:
    """``(N,)`` uint64 id of each vertex as its file wrote it (``0 … N−1`` for a graph without
    ``vertex_ids``)."""
    if graph.vertex_ids is None:
        return np.arange(graph.num_poses, dtype=np.uint64)
    return np.asarray(graph.vertex_ids, dtype=np.uint64)


def _write_graph(
    graph: PoseGraph, path: str | Path, poses: np.ndarray, tags: tuple[str, str], entries
) -> None:
    """VERTEX lines (the file's ids, ``poses``), EDGE lines (the ids of their ends, the
    measurement, the six ``entries`` ``(M, 6)``), then one ``FIX id`` line per fixed pose:
    last, because GTSAM's ``readG2o`` stops reading at a tag it does not know (gtsam 4.3: the
    edges after a FIX line were lost), while g2o and popbench read FIX anywhere."""
    ids = file_ids(graph)
    vertex_tag, edge_tag = tags
    with Path(path).open("w") as handle:
        _savetxt(handle, _rows(ids, poses), [f"{vertex_tag} %d"] + ["%.17g"] * 3)
        edges = _rows(ids[graph.tails], ids[graph.heads], graph.measurements, entries)
        _savetxt(handle, edges, [f"{edge_tag} %d", "%d"] + ["%.17g"] * 9)
        if graph.fixed is not None:
            _savetxt(handle, _rows(ids[graph.fixed]), f"{_FIX_TAG} %d")


def write_g2o(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX lines, default the graph's) as g2o, with
    the file's own vertex ids (:func:`file_ids`) and its FIX lines."""
    rows, cols = zip(*_G2O_ENTRIES, strict=True)
    upper = graph.information[:, list(rows), list(cols)]
    poses = graph.poses if poses is None else poses
    _write_graph(graph, path, poses, _FORMATS["g2o"], upper)


def write_toro(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX2 lines, default the graph's) as TORO: the
    information is rotated back into TORO's frame, ``Λ_TORO = B Λ_g2o Bᵀ`` with
    ``B = blkdiag(R(θ̃), 1)`` (the inverse of the reader's conversion), so the file reads back to
    the same graph up to rounding (≈ 1e-16 relative in Λ). Ids and FIX lines as
    :func:`write_g2o` (TORO has no FIX tag; popbench reads it back)."""
    b = np.zeros_like(graph.information)
    b[:, :2, :2] = se2.rotation(graph.measurements[:, 2])
    b[:, 2, 2] = 1.0
    toro = b @ graph.information @ np.swapaxes(b, 1, 2)
    rows, cols = zip(*_TORO_ENTRIES, strict=True)
    entries = toro[:, list(rows), list(cols)]
    poses = graph.poses if poses is None else poses
    _write_graph(graph, path, poses, _FORMATS["toro"], entries)


# Suffix of an output graph file → its writer (the reader detects the same suffixes).
GRAPH_WRITERS = {".g2o": write_g2o, ".graph": write_toro}


def write_solution(graph: PoseGraph, poses: np.ndarray, path: str | Path) -> None:
    """Write ``graph`` with ``poses`` ``(N, 3)`` (a solution, rows in the graph's vertex order) as
    its VERTEX lines: g2o for a ``.g2o`` path, TORO for ``.graph``. Edges are written as the
    graph holds them (a file read by :func:`read_graph` written back reads to the same
    measurements and information, so the file's ``F`` at its own VERTEX poses is the
    solution's). Vertex ids are the file's own (:func:`file_ids`), FIX lines are written
    back. A graph read from a TORO file with EQUIV lines is written merged (one vertex per
    class, with the class's smallest id; no EQUIV lines; see docs/io.md).

    Raises:
        ValueRangeError: another suffix, or ``poses`` not ``(N, 3)``.
    """
    graph_writer(path)(graph, path, _checked_poses(graph, poses))


def graph_writer(path: str | Path, name: str = "output graph file"):
    """The writer of :data:`GRAPH_WRITERS` for ``path``'s suffix, or a ValueRangeError naming
    ``name`` (the option) and the allowed suffixes."""
    suffix = Path(path).suffix
    if suffix not in GRAPH_WRITERS:
        allowed = "a path ending in " + " or ".join(GRAPH_WRITERS) + " (g2o or TORO)"
        raise ValueRangeError(name, str(path), allowed)
    return GRAPH_WRITERS[suffix]


def _checked_poses(graph: PoseGraph, poses: np.ndarray) -> np.ndarray:
    poses = np.asarray(poses, dtype=np.float64)
    if poses.shape != (graph.num_poses, 3):
        raise ValueRangeError("poses", f"shape {poses.shape}", f"({graph.num_poses}, 3)")
    return poses


def write_tum(poses: np.ndarray, path: str | Path, ids: np.ndarray | None = None) -> None:
    """Write ``poses`` ``(N, 3)`` ``(x [m], y [m], θ [rad])`` as a TUM trajectory (what ``evo``
    reads): one line ``timestamp x y z qx qy qz qw`` per pose, the timestamp the vertex id
    (``ids`` ``(N,)``, default ``0 … N−1``) in exact decimal digits, ``z = 0`` and the unit
    quaternion of the yaw, ``(0, 0, sin θ/2, cos θ/2)``. A reader that parses the timestamp as
    a float64 (evo) reads ids up to 2⁵³ exactly and rounds larger ones (:func:`tum_rounded`)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    ids = np.arange(poses.shape[0], dtype=np.uint64) if ids is None else np.asarray(ids)
    half = poses[:, 2] / 2.0
    zeros = np.zeros((poses.shape[0], 3))
    rows = _rows(ids, poses[:, :2], zeros, np.sin(half), np.cos(half))
    with Path(path).open("w") as handle:
        handle.write("# timestamp(vertex id) x y z qx qy qz qw\n")
        _savetxt(handle, rows, ["%d"] + ["%.17g"] * 7)


def tum_rounded(ids: np.ndarray) -> int:
    """How many of the ``(N,)`` ids a float64 reader of the TUM timestamp (evo) cannot tell
    from another id: those whose float64 value another id shares (0 for ids up to 2⁵³; GTSAM
    ``Symbol`` keys, a letter in the top byte, share one float64 per 1024 consecutive
    indices)."""
    _, counts = np.unique(np.asarray(ids, dtype=np.uint64).astype(np.float64), return_counts=True)
    return int(counts[counts > 1].sum())


FLAGS_HEADER = "edge,i,j,kind,weight,flagged"


def write_flags(
    graph: PoseGraph,
    path: str | Path,
    inlier_mask: np.ndarray | None,
    weights: np.ndarray | None = None,
) -> None:
    """Write one CSV row per edge: ``edge`` (its index, the order of the file's edge lines),
    ``i``, ``j`` (the file's ids of its vertices, :func:`file_ids`), ``kind``
    (:class:`~popbench.graph.EdgeKind` name in lower case, under the problem's robot
    assignment), ``weight`` (the method's final robust weight in ``[0, 1]``) and ``flagged``
    (1: flagged as an outlier, 0: kept). ``weights`` ``(M,)`` or ``inlier_mask`` ``(M,)`` bool
    None (the method reports none): that column is left empty (pandas reads NaN)."""
    edges = np.arange(graph.num_edges)
    kind_names = np.array([kind.name.lower() for kind in EdgeKind])[graph.kinds]
    weight_text = (
        np.full(edges.size, "")
        if weights is None
        else np.char.mod("%.17g", np.asarray(weights, dtype=np.float64))
    )
    flag_text = (
        np.full(edges.size, "")
        if inlier_mask is None
        else np.where(np.asarray(inlier_mask, dtype=bool), "0", "1")
    )
    ids = file_ids(graph)
    columns = [edges.astype(str), ids[graph.tails].astype(str), ids[graph.heads].astype(str)]
    columns.append(kind_names)
    table = np.column_stack([*columns, weight_text, flag_text])
    with Path(path).open("w") as handle:
        handle.write(FLAGS_HEADER + "\n")
        _savetxt(handle, table, "%s", delimiter=",")
