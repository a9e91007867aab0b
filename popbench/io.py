"""Read and write planar pose graphs: g2o (``VERTEX_SE2``/``EDGE_SE2``) and TORO
(``VERTEX2``/``EDGE2``).

g2o edge: ``EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33`` (upper triangle, (x, y, θ) order).
TORO edge: ``EDGE2 i j dx dy dθ I11 I12 I22 I33 I13 I23``; TORO's translation error is not in
the measurement frame, so the cost-preserving conversion is ``Λ_g2o = Bᵀ Λ_TORO B`` with
``B = blkdiag(R(θ̃), 1)``.

Edges written ``i > j`` are kept as written. Files without VERTEX lines get the odometry
composition of their edges (:func:`popbench.graph.odometry_composition`).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from popbench import se2
from popbench.errors import DataFormatError
from popbench.graph import PoseGraph, make_graph, odometry_composition

_FORMATS = {
    # tag: (vertex tag, edge tag, information index order into the upper triangle)
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
    with path.open() as handle:
        for line in handle:
            tag = line.split(maxsplit=1)[0] if line.strip() else ""
            if tag in ("VERTEX2", "EDGE2"):
                return "toro"
            if tag in ("VERTEX_SE2", "EDGE_SE2"):
                return "g2o"
    return "g2o"


def _parse_numbers(path: Path, lineno: int, tokens: list[str], count: int, tag: str) -> list[float]:
    if len(tokens) != count:
        raise DataFormatError(
            path, lineno, f"{tag} needs {count - 1} values after the tag, found {len(tokens) - 1}"
        )
    try:
        values = [float(token) for token in tokens[1:]]
    except ValueError as error:
        raise DataFormatError(path, lineno, f"{tag}: {error}") from None
    if not all(np.isfinite(values)):
        raise DataFormatError(path, lineno, f"{tag}: non-finite value")
    for k in (0, 1) if tag.startswith("EDGE") else (0,):
        if values[k] != int(values[k]) or values[k] < 0:
            message = f"{tag}: vertex id {tokens[k + 1]!r} is not an integer ≥ 0"
            raise DataFormatError(path, lineno, message)
    return values


def read_graph(path: str | Path, name: str | None = None) -> PoseGraph:
    """Read a g2o or TORO file (format from the suffix or the first tag).

    Raises:
        DataFormatError: a malformed line (``file:line: reason``), an unknown tag, no edges,
            non-contiguous vertex ids or an information matrix that is not positive definite.
    """
    path = Path(path)
    fmt = detect_format(path)
    vertex_tag, edge_tag = _FORMATS[fmt]
    vertices: list[list[float]] = []
    vertex_lines: list[int] = []
    edges: list[list[float]] = []
    edge_lines: list[int] = []
    with path.open() as handle:
        for lineno, line in enumerate(handle, start=1):
            tokens = line.split()
            if not tokens or tokens[0].startswith("#"):
                continue
            tag = tokens[0]
            if tag == vertex_tag:
                vertices.append(_parse_numbers(path, lineno, tokens, 5, tag))
                vertex_lines.append(lineno)
            elif tag == edge_tag:
                edges.append(_parse_numbers(path, lineno, tokens, 12, tag))
                edge_lines.append(lineno)
            elif tag not in _IGNORED_TAGS:
                raise DataFormatError(
                    path, lineno, f"unknown tag {tag!r} (expected {vertex_tag} or {edge_tag})"
                )
    if not edges:
        raise DataFormatError(path, 0, f"no {edge_tag} lines: not a {fmt} pose graph")
    edge_array = np.asarray(edges)
    tails = edge_array[:, 0].astype(np.int64)
    heads = edge_array[:, 1].astype(np.int64)
    measurements = edge_array[:, 2:5].copy()
    measurements[:, 2] = se2.wrap(measurements[:, 2])
    information = _information(edge_array[:, 5:], fmt, measurements[:, 2])
    _check_information(path, information, edge_lines)

    num_poses = int(max(tails.max(), heads.max())) + 1
    if vertices:
        vertex_array = np.asarray(vertices)
        ids = vertex_array[:, 0].astype(np.int64)
        num_poses = max(num_poses, int(ids.max()) + 1)
        if np.unique(ids).size != ids.size or ids.size != num_poses:
            missing = np.setdiff1d(np.arange(num_poses), ids)
            where = vertex_lines[-1] if missing.size == 0 else 0
            raise DataFormatError(
                path,
                where,
                f"vertex ids must be unique and contiguous from 0; "
                f"{ids.size} vertex lines for {num_poses} ids"
                + (f", missing id {int(missing[0])}" if missing.size else ""),
            )
        poses = np.zeros((num_poses, 3))
        poses[ids] = vertex_array[:, 1:4]
        poses[:, 2] = se2.wrap(poses[:, 2])
    else:
        poses = odometry_composition(num_poses, tails, heads, measurements)
    return make_graph(poses, tails, heads, measurements, information, name=name or path.stem)


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


def _check_information(path: Path, information: np.ndarray, lines: list[int]) -> None:
    eigenvalues = np.linalg.eigvalsh(information)
    bad = np.flatnonzero(eigenvalues[:, 0] <= 0.0)
    if bad.size:
        k = int(bad[0])
        raise DataFormatError(
            path,
            lines[k],
            f"information matrix is not positive definite "
            f"(smallest eigenvalue {eigenvalues[k, 0]:.3g})",
        )


def write_g2o(graph: PoseGraph, path: str | Path, poses: np.ndarray | None = None) -> None:
    """Write ``graph`` (with ``poses`` as the VERTEX lines, default the graph's) as g2o."""
    poses = graph.poses if poses is None else poses
    rows, cols = zip(*_G2O_ENTRIES, strict=True)
    upper = graph.information[:, list(rows), list(cols)]
    vertex_block = np.column_stack([np.arange(graph.num_poses), poses])
    edge_block = np.column_stack([graph.tails, graph.heads, graph.measurements, upper])
    with Path(path).open("w") as handle:
        np.savetxt(handle, vertex_block, fmt=["VERTEX_SE2 %d"] + ["%.17g"] * 3)
        np.savetxt(handle, edge_block, fmt=["EDGE_SE2 %d", "%d"] + ["%.17g"] * 9)
