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
vertex's pose; the other vertices are removed, their edges are redirected to the kept vertex, the
ids are renumbered contiguously in their original order, and an edge that ends up joining a
vertex to itself is dropped (with a :class:`UserWarning` that counts them). Edge kinds are then
labelled on the new ids (:func:`popbench.graph.single_robot_kinds`). :func:`read_vertices`
applies the same merge, so a ground-truth file with the same EQUIV lines stays aligned.

Edges written ``i > j`` are kept as written. Files without VERTEX lines get the odometry
composition of their edges (:func:`popbench.graph.odometry_composition`).
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
_IGNORED_TAGS = {"FIX", "FIX2", "PARAMS_SE2OFFSET", "VERTEX_XY", "EDGE_SE2_XY"}


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
MAX_VERTEX_ID = 2**31 - 1


def _parse_numbers(path: Path, lineno: int, tokens: list[str], count: int, tag: str) -> list[float]:
    if len(tokens) != count:
        raise DataFormatError(
            path, lineno, f"{tag} needs {count - 1} values after the tag, found {len(tokens) - 1}"
        )
    fields = _FIELDS[tag]
    values = []
    for k, token in enumerate(tokens[1:]):
        try:
            value = float(token)
        except ValueError:
            message = f"{tag} field {fields[k]} (value {k + 1} of {count - 1}) is {token!r}: "
            raise DataFormatError(path, lineno, message + "expected a number") from None
        if not math.isfinite(value):
            message = f"{tag} field {fields[k]} (value {k + 1} of {count - 1}) is non-finite"
            raise DataFormatError(path, lineno, f"{message} ({token!r})")
        values.append(value)
    ids = (0,) if tag.startswith("VERTEX") else (0, 1)
    for k in ids:
        if values[k] != int(values[k]) or values[k] < 0:
            message = f"{tag}: vertex id {tokens[k + 1]!r} is not an integer ≥ 0"
            raise DataFormatError(path, lineno, message)
        if values[k] > MAX_VERTEX_ID:
            allowed = f"0 to {MAX_VERTEX_ID}"
            message = f"{tag}: vertex id {tokens[k + 1]!r} is out of range ({allowed})"
            raise DataFormatError(path, lineno, message)
    if len(ids) == 2 and values[0] == values[1]:
        why = (
            "an EQUIV line names two different vertices"
            if tag == _EQUIV_TAG
            else ("pose-graph edges join two different poses")
        )
        message = f"{tag} joins vertex {int(values[0])} to itself ({why})"
        raise DataFormatError(path, lineno, message)
    return values


class _Lines(NamedTuple):
    """The parsed VERTEX and EDGE lines of one file, with their line numbers."""

    vertices: np.ndarray  # (V, 4) id, x, y, θ
    vertex_lines: np.ndarray  # (V,) 1-based line numbers
    edges: np.ndarray  # (E, 11) i, j, dx, dy, dθ, six information numbers
    edge_lines: np.ndarray  # (E,)
    equivs: np.ndarray  # (Q, 2) int64 i, j of the TORO EQUIV lines
    equiv_lines: np.ndarray  # (Q,)


def _scan(path: Path, fmt: str, parse_edges: bool = True) -> _Lines:
    vertex_tag, edge_tag = _FORMATS[fmt]
    vertices: list[list[float]] = []
    vertex_lines: list[int] = []
    edges: list[list[float]] = []
    edge_lines: list[int] = []
    equivs: list[list[float]] = []
    equiv_lines: list[int] = []
    lineno = 0
    try:
        with path.open(encoding="utf-8") as handle:
            for lineno, line in enumerate(handle, start=1):  # noqa: B007 - used after the loop
                tokens = line.split()
                if not tokens or tokens[0].startswith("#"):
                    continue
                tag = tokens[0]
                if tag == vertex_tag:
                    vertices.append(_parse_numbers(path, lineno, tokens, 5, tag))
                    vertex_lines.append(lineno)
                elif tag == edge_tag:
                    if parse_edges:
                        edges.append(_parse_numbers(path, lineno, tokens, 12, tag))
                    edge_lines.append(lineno)
                elif tag == _EQUIV_TAG and fmt == "toro":
                    equivs.append(_parse_numbers(path, lineno, tokens, 3, tag))
                    equiv_lines.append(lineno)
                elif tag not in _IGNORED_TAGS:
                    raise DataFormatError(
                        path, lineno, f"unknown tag {tag!r} (expected {vertex_tag} or {edge_tag})"
                    )
    except UnicodeDecodeError:
        raise DataFormatError(path, lineno + 1, "not a text file") from None
    return _Lines(
        np.asarray(vertices, dtype=np.float64).reshape(-1, 4),
        np.asarray(vertex_lines, dtype=np.int64),
        np.asarray(edges, dtype=np.float64).reshape(-1, 11),
        np.asarray(edge_lines, dtype=np.int64),
        np.asarray(equivs, dtype=np.float64).reshape(-1, 2).astype(np.int64),
        np.asarray(equiv_lines, dtype=np.int64),
    )


def _equivalence_map(path: Path, lines: _Lines, num_poses: int) -> np.ndarray | None:
    """``(num_poses,)`` new id of each original vertex after merging the EQUIV classes (each
    class kept as its smallest id, survivors renumbered 0 … in their original order), or
    ``None`` when the file has no EQUIV lines.

    Raises:
        DataFormatError: an EQUIV line naming a vertex id ≥ ``num_poses``.
    """
    if not lines.equivs.size:
        return None
    bad = np.flatnonzero(lines.equivs.max(axis=1) >= num_poses)
    if bad.size:
        k = int(bad[0])
        vertex = int(lines.equivs[k].max())
        raise DataFormatError(
            path,
            int(lines.equiv_lines[k]),
            f"EQUIV references vertex {vertex}, which is not in the graph (ids 0–{num_poses - 1})",
        )
    root = np.arange(num_poses)

    def find(v: int) -> int:
        while root[v] != v:
            root[v] = root[root[v]]
            v = int(root[v])
        return v

    for i, j in lines.equivs:  # one step per EQUIV line, at parse time
        a, b = find(int(i)), find(int(j))
        root[max(a, b)] = min(a, b)
    while True:  # flatten every chain to its root, vectorised
        parent = root[root]
        if np.array_equal(parent, root):
            break
        root = parent
    kept = root == np.arange(num_poses)
    new_id = np.cumsum(kept) - 1
    return new_id[root]


def _vertex_poses(path: Path, lines: _Lines) -> np.ndarray:
    """``(V, 3)`` poses from the ``V`` VERTEX lines, whose ids must be exactly 0 … V − 1."""
    ids = lines.vertices[:, 0].astype(np.int64)
    order = np.argsort(ids, kind="stable")
    repeated = np.flatnonzero(np.diff(ids[order]) == 0)
    if repeated.size:
        k = order[repeated[0] + 1]
        raise DataFormatError(path, int(lines.vertex_lines[k]), f"vertex id {ids[k]} repeated")
    num_poses = ids.size
    beyond = np.flatnonzero(ids >= num_poses)  # unique ids: some id below V is then missing
    if beyond.size:
        k = int(beyond[0])
        missing = np.setdiff1d(np.arange(num_poses), ids)
        raise DataFormatError(
            path,
            int(lines.vertex_lines[k]),
            f"vertex ids must be contiguous from 0: no VERTEX line for id {int(missing[0])} "
            f"({missing.size} of 0–{num_poses - 1} missing) but one for id {ids[k]}",
        )
    poses = np.zeros((num_poses, 3))
    poses[ids] = lines.vertices[:, 1:4]
    poses[:, 2] = _wrap_out_of_range(poses[:, 2])
    return poses


def _check_edge_ids(
    path: Path, tag: str, lines: _Lines, tails: np.ndarray, heads: np.ndarray
) -> None:
    """Every edge endpoint must have a VERTEX line (ids 0 … V − 1); in a file without VERTEX
    lines every id from 0 to the largest must be an endpoint of some edge (else that pose would
    be undefined)."""
    if lines.vertices.size:
        num_poses = lines.vertices.shape[0]
        reason = f"which has no VERTEX line (ids 0–{num_poses - 1})"
    else:
        used = np.unique(np.concatenate([tails, heads]))
        num_poses = used.size  # ids 0 … max all used ⟺ max < number of distinct ids
        if int(used[-1]) < num_poses:
            return
        gap = int(np.setdiff1d(np.arange(num_poses), used)[0])
        reason = (
            f"but no edge references vertex {gap} and the file has no VERTEX lines, "
            "so that pose would be undefined"
        )
    bad = np.flatnonzero((tails >= num_poses) | (heads >= num_poses))
    if bad.size:
        k = int(bad[0])
        vertex = int(tails[k] if tails[k] >= num_poses else heads[k])
        raise DataFormatError(
            path, int(lines.edge_lines[k]), f"{tag} references vertex {vertex}, {reason}"
        )


def read_graph(path: str | Path, name: str | None = None) -> PoseGraph:
    """Read a g2o or TORO file (format from the suffix or the first tag).

    Raises:
        FileNotFoundError: no such file.
        DataFormatError: a malformed line (``file:line: reason``), an unknown tag, no edges,
            non-contiguous vertex ids, an information matrix that is not positive definite, or
            poses that no path of edges joins to vertex 0 (:func:`_check_connected`).
    """
    path = Path(path)
    fmt = detect_format(path)
    lines = _scan(path, fmt)
    if not lines.edges.size:
        raise DataFormatError(path, 0, f"no {_FORMATS[fmt][1]} lines: not a {fmt} pose graph")
    tails = lines.edges[:, 0].astype(np.int64)
    heads = lines.edges[:, 1].astype(np.int64)
    measurements = lines.edges[:, 2:5].copy()
    measurements[:, 2] = _wrap_out_of_range(measurements[:, 2])
    with np.errstate(over="ignore", invalid="ignore"):  # overflow: refused just below
        information = _information(lines.edges[:, 5:], fmt, measurements[:, 2])
    _check_information(path, information, lines.edge_lines)
    _check_coordinates(path, lines)

    _check_edge_ids(path, _FORMATS[fmt][1], lines, tails, heads)
    poses = _vertex_poses(path, lines) if lines.vertices.size else None
    num_poses = len(poses) if poses is not None else int(max(tails.max(), heads.max())) + 1
    new_id = _equivalence_map(path, lines, num_poses)
    if new_id is not None:
        tails, heads = new_id[tails], new_id[heads]
        if poses is not None:
            poses = _merged_poses(poses, new_id)
        num_poses = int(new_id.max()) + 1
        loops = tails == heads
        if loops.any():
            warnings.warn(
                f"{path}: EQUIV merged {lines.equivs.shape[0]} vertex pair(s); dropped "
                f"{int(loops.sum())} edge(s) that joined equivalent vertices (self-loops)",
                stacklevel=2,
            )
            keep = ~loops
            tails, heads = tails[keep], heads[keep]
            measurements, information = measurements[keep], information[keep]
    _check_connected(path, lines, num_poses, tails, heads, new_id)
    if poses is None:
        poses = odometry_composition(num_poses, tails, heads, measurements)
    return make_graph(poses, tails, heads, measurements, information, name=name or path.stem)


def _check_connected(
    path: Path,
    lines: _Lines,
    num_poses: int,
    tails: np.ndarray,
    heads: np.ndarray,
    new_id: np.ndarray | None,
) -> None:
    """Every pose must be joined to vertex 0 by a path of edges (one gauge fixes the whole
    graph; a pose in another component is undetermined and makes every solver's system
    singular). The error names the first few unconnected poses by their ids in the file and the
    line of the first one's VERTEX line (or of its first edge, without VERTEX lines)."""
    unconnected = unconnected_vertices(num_poses, tails, heads)
    if not unconnected.size:
        return
    if new_id is not None:  # back to the file's ids: each merged class's kept (smallest) id
        unconnected = np.unique(new_id, return_index=True)[1][unconnected]
    first = int(unconnected[0])
    if lines.vertices.size:
        line = lines.vertex_lines[np.flatnonzero(lines.vertices[:, 0] == first)[0]]
    else:
        line = lines.edge_lines[np.flatnonzero((lines.edges[:, :2] == first).any(axis=1))[0]]
    shown = ", ".join(map(str, unconnected[:5].tolist())) + (", …" if unconnected.size > 5 else "")
    raise DataFormatError(
        path,
        int(line),
        f"{unconnected.size} of {num_poses} poses (ids {shown}) are not connected to vertex 0 "
        "by any path of edges, so the graph has no single gauge: remove them or add edges",
    )


def read_vertices(path: str | Path) -> np.ndarray:
    """Only the VERTEX lines of a g2o/TORO file as ``(N, 3)`` poses (e.g. a ground-truth file);
    edge lines are skipped unparsed.

    Raises:
        DataFormatError: no VERTEX lines, a malformed one, or ids not contiguous from 0.
    """
    path = Path(path)
    fmt = detect_format(path)
    lines = _scan(path, fmt, parse_edges=False)
    if not lines.vertices.size:
        raise DataFormatError(path, 0, f"no {_FORMATS[fmt][0]} lines")
    poses = _vertex_poses(path, lines)
    new_id = _equivalence_map(path, lines, len(poses))
    return poses if new_id is None else _merged_poses(poses, new_id)


def _merged_poses(poses: np.ndarray, new_id: np.ndarray) -> np.ndarray:
    """The ``(N', 3)`` poses of the kept vertices: each merged class takes the pose of its kept
    (smallest) id, which is the first original vertex mapped to each new id."""
    _, first = np.unique(new_id, return_index=True)
    return poses[first]


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
        (lines.vertices, [1, 2], lines.vertex_lines, "pose coordinate"),
        (lines.edges, [2, 3], lines.edge_lines, "measured translation"),
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


def write_g2o(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX lines, default the graph's) as g2o."""
    poses = graph.poses if poses is None else poses
    rows, cols = zip(*_G2O_ENTRIES, strict=True)
    upper = graph.information[:, list(rows), list(cols)]
    vertex_block = np.column_stack([np.arange(graph.num_poses), poses])
    edge_block = np.column_stack([graph.tails, graph.heads, graph.measurements, upper])
    with Path(path).open("w") as handle:
        _savetxt(handle, vertex_block, ["VERTEX_SE2 %d"] + ["%.17g"] * 3)
        _savetxt(handle, edge_block, ["EDGE_SE2 %d", "%d"] + ["%.17g"] * 9)


def write_toro(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX2 lines, default the graph's) as TORO: the
    information is rotated back into TORO's frame, ``Λ_TORO = B Λ_g2o Bᵀ`` with
    ``B = blkdiag(R(θ̃), 1)`` (the inverse of the reader's conversion), so the file reads back to
    the same graph up to rounding (≈ 1e-16 relative in Λ)."""
    poses = graph.poses if poses is None else poses
    b = np.zeros_like(graph.information)
    b[:, :2, :2] = se2.rotation(graph.measurements[:, 2])
    b[:, 2, 2] = 1.0
    toro = b @ graph.information @ np.swapaxes(b, 1, 2)
    rows, cols = zip(*_TORO_ENTRIES, strict=True)
    entries = toro[:, list(rows), list(cols)]
    vertex_block = np.column_stack([np.arange(graph.num_poses), poses])
    edge_block = np.column_stack([graph.tails, graph.heads, graph.measurements, entries])
    with Path(path).open("w") as handle:
        _savetxt(handle, vertex_block, ["VERTEX2 %d"] + ["%.17g"] * 3)
        _savetxt(handle, edge_block, ["EDGE2 %d", "%d"] + ["%.17g"] * 9)


# Suffix of an output graph file → its writer (the reader detects the same suffixes).
GRAPH_WRITERS = {".g2o": write_g2o, ".graph": write_toro}


def write_solution(graph: PoseGraph, poses: np.ndarray, path: str | Path) -> None:
    """Write ``graph`` with ``poses`` ``(N, 3)`` (a solution, rows in the graph's vertex order) as
    its VERTEX lines: g2o for a ``.g2o`` path, TORO for ``.graph``. Edges are written as the
    graph holds them (a file read by :func:`read_graph` written back reads to the same
    measurements and information, so the file's ``F`` at its own VERTEX poses is the
    solution's). A graph read from a TORO file with EQUIV lines is written merged (its
    renumbered ids, no EQUIV lines; see docs/io.md).

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
    (``ids``, default ``0 … N−1``), ``z = 0`` and the unit quaternion of the yaw,
    ``(0, 0, sin θ/2, cos θ/2)``."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    ids = np.arange(poses.shape[0]) if ids is None else np.asarray(ids)
    half = poses[:, 2] / 2.0
    zeros = np.zeros(poses.shape[0])
    rows = np.column_stack([ids, poses[:, :2], zeros, zeros, zeros, np.sin(half), np.cos(half)])
    with Path(path).open("w") as handle:
        handle.write("# timestamp(vertex id) x y z qx qy qz qw\n")
        _savetxt(handle, rows, ["%d"] + ["%.17g"] * 7)


FLAGS_HEADER = "edge,i,j,kind,weight,flagged"


def write_flags(
    graph: PoseGraph,
    path: str | Path,
    inlier_mask: np.ndarray | None,
    weights: np.ndarray | None = None,
) -> None:
    """Write one CSV row per edge: ``edge`` (its index, the order of the file's edge lines),
    ``i``, ``j`` (its vertex ids), ``kind`` (:class:`~popbench.graph.EdgeKind` name in lower
    case, under the problem's robot assignment), ``weight`` (the method's final robust weight
    in ``[0, 1]``) and ``flagged`` (1: flagged as an outlier, 0: kept). ``weights`` ``(M,)`` or
    ``inlier_mask`` ``(M,)`` bool None (the method reports none): that column is left empty
    (pandas reads NaN)."""
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
    columns = [edges.astype(str), graph.tails.astype(str), graph.heads.astype(str), kind_names]
    table = np.column_stack([*columns, weight_text, flag_text])
    with Path(path).open("w") as handle:
        handle.write(FLAGS_HEADER + "\n")
        _savetxt(handle, table, "%s", delimiter=",")
