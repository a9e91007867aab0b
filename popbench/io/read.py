"""Read planar pose graphs: g2o (``VERTEX_SE2``/``EDGE_SE2``) and TORO (``VERTEX2``/``EDGE2``).

The line layouts and TORO's information conversion are :mod:`popbench.io.format`, the value
ranges refused at load :mod:`popbench.io.limits`, the writers :mod:`popbench.io.write`; the
package, :mod:`popbench.io`, gathers their public names (``from popbench.io import write_g2o``).

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

import numpy as np

from popbench import se2
from popbench.errors import DataFormatError
from popbench.graph import (
    PoseGraph,
    make_graph,
    odometry_composition,
    unconnected_vertices,
)
from popbench.io.format import (
    EQUIV_TAG,
    FIELDS,
    FIX_TAG,
    FORMAT_OF_TAG,
    FORMATS,
    MAX_VERTEX_ID,
    ScannedLines,
    information_matrices,
)
from popbench.io.limits import check_coordinates, check_information


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
    fields = FIELDS[tag]
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
            if tag == EQUIV_TAG
            else ("pose-graph edges join two different poses")
        )
        message = f"{tag} joins vertex {ids[0]} to itself ({why})"
        raise DataFormatError(path, lineno, message)
    return ids, values


def _refuse_numbers(path: Path, lineno: int, tokens: list[str], tag: str, id_count: int) -> None:
    """Raise the DataFormatError for the first number of the line that is not a finite float."""
    fields, count = FIELDS[tag], len(tokens) - 1
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


def _scan(path: Path, fmt: str, parse_edges: bool = True) -> ScannedLines:
    vertex_tag, edge_tag = FORMATS[fmt]
    # tag → (kind, tokens per line); EQUIV is a TORO tag only.
    kinds = {vertex_tag: ("vertex", 5), edge_tag: ("edge", 12)}
    if fmt == "toro":
        kinds[EQUIV_TAG] = ("equiv", 3)
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
                elif tag == FIX_TAG:
                    if len(tokens) < 2:
                        raise DataFormatError(path, lineno, "FIX needs at least one vertex id")
                    ids["fix"].extend([_parse_id(path, lineno, tag, "id", t)] for t in tokens[1:])
                    line_numbers["fix"].extend([lineno] * (len(tokens) - 1))
                elif tag in FORMAT_OF_TAG or tag == EQUIV_TAG:
                    other = FORMAT_OF_TAG.get(tag, "toro")
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

    return ScannedLines(
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


def _vertex_table(path: Path, lines: ScannedLines) -> tuple[np.ndarray, np.ndarray | None]:
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


def _equivalence_map(path: Path, lines: ScannedLines, ids: np.ndarray) -> np.ndarray | None:
    """``(N,)`` new internal index of each vertex after merging the EQUIV classes (each class
    kept as its smallest id, survivors renumbered 0 … in ascending id order), or ``None`` when
    the file has no EQUIV lines.

    Raises:
        DataFormatError: an EQUIV line naming an id that is not a vertex of the graph.
    """
    if not lines.equivs.size:
        return None
    missing = "which is not in the graph"
    equivs = _indices(path, EQUIV_TAG, missing, ids, lines.equivs, lines.equiv_lines)
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
    vertex_tag, edge_tag = FORMATS[fmt]
    lines = _scan(path, fmt)
    if not lines.edges.size:
        raise DataFormatError(path, 0, f"no {edge_tag} lines: not a {fmt} pose graph")
    measurements = lines.edges[:, :3].copy()
    measurements[:, 2] = _wrap_out_of_range(measurements[:, 2])
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: refused just below
        information = information_matrices(lines.edges[:, 3:], fmt, measurements[:, 2])
    check_information(path, information, lines.edge_lines)
    check_coordinates(path, lines)

    ids, poses = _vertex_table(path, lines)
    missing = f"which has no {vertex_tag} line"
    ends = _indices(path, edge_tag, missing, ids, lines.edge_ids, lines.edge_lines)
    tails, heads = ends[:, 0], ends[:, 1]
    missing = "which is not in the graph"
    fixed = _indices(path, FIX_TAG, missing, ids, lines.fixes, lines.fix_lines)
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
    read = " ".join([*FORMATS[fmt], FIX_TAG] + ([EQUIV_TAG] if fmt == "toro" else []))
    warnings.warn(
        f"{path}: skipped {sum(skipped.values())} line(s) of kinds popbench does not model "
        f"({counts}); it reads {read} (see docs/io.md)",
        ReadWarning,
        stacklevel=3,
    )


def _check_connected(
    path: Path, lines: ScannedLines, ids: np.ndarray, tails: np.ndarray, heads: np.ndarray
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
        raise DataFormatError(path, 0, f"no {FORMATS[fmt][0]} lines")
    ids, poses = _vertex_table(path, lines)
    new_id = _equivalence_map(path, lines, ids)
    return poses if new_id is None else _kept(poses, new_id)
