"""Write pose graphs (g2o, TORO), solutions, TUM trajectories and per-edge flag CSVs.

Every writer writes the file's own vertex ids (:func:`file_ids`, exact uint64) and float64
numbers with 17 significant digits, so a file read by :func:`popbench.io.read.read_graph` and
written back reads to the same graph (TORO's information up to rounding, ≈ 1e-16 relative).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from popbench.errors import ValueRangeError
from popbench.graph import EdgeKind, PoseGraph
from popbench.io.format import FIX_TAG, FORMATS, G2O_ENTRIES, TORO_ENTRIES, toro_frame


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
            _savetxt(handle, _rows(ids[graph.fixed]), f"{FIX_TAG} %d")


def write_g2o(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX lines, default the graph's) as g2o, with
    the file's own vertex ids (:func:`file_ids`) and its FIX lines."""
    rows, cols = zip(*G2O_ENTRIES, strict=True)
    upper = graph.information[:, list(rows), list(cols)]
    poses = graph.poses if poses is None else poses
    _write_graph(graph, path, poses, FORMATS["g2o"], upper)


def write_toro(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX2 lines, default the graph's) as TORO: the
    information is rotated back into TORO's frame, ``Λ_TORO = B Λ_g2o Bᵀ`` with
    ``B = blkdiag(R(θ̃), 1)`` (the inverse of the reader's conversion), so the file reads back to
    the same graph up to rounding (≈ 1e-16 relative in Λ). Ids and FIX lines as
    :func:`write_g2o` (TORO has no FIX tag; popbench reads it back)."""
    b = toro_frame(graph.measurements[:, 2])
    toro = b @ graph.information @ np.swapaxes(b, 1, 2)
    rows, cols = zip(*TORO_ENTRIES, strict=True)
    entries = toro[:, list(rows), list(cols)]
    poses = graph.poses if poses is None else poses
    _write_graph(graph, path, poses, FORMATS["toro"], entries)


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
