"""The g2o and TORO line formats: tags, field names and information layout.

g2o edge: ``EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33`` (upper triangle, (x, y, θ) order).
TORO edge: ``EDGE2 i j dx dy dθ I11 I12 I22 I33 I13 I23``; TORO's translation error is not in
the measurement frame, so the cost-preserving conversion is ``Λ_g2o = Bᵀ Λ_TORO B`` with
``B = blkdiag(R(θ̃), 1)`` (:func:`toro_frame`). Reading is :mod:`popbench.io.read`, writing
:mod:`popbench.io.write`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from popbench import se2

FORMATS = {
    # format: (vertex tag, edge tag)
    "g2o": ("VERTEX_SE2", "EDGE_SE2"),
    "toro": ("VERTEX2", "EDGE2"),
}
# Upper-triangle (row, col) of each of the six information numbers, per format.
G2O_ENTRIES = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
TORO_ENTRIES = [(0, 0), (0, 1), (1, 1), (2, 2), (0, 2), (1, 2)]
# The pose-graph tags of each format: one of them in a file of the other format is refused
# (a mixed file), never skipped.
FORMAT_OF_TAG = {"VERTEX_SE2": "g2o", "EDGE_SE2": "g2o", "VERTEX2": "toro", "EDGE2": "toro"}
FIELDS = {
    "VERTEX_SE2": ("id", "x", "y", "theta"),
    "VERTEX2": ("id", "x", "y", "theta"),
    "EDGE_SE2": ("i", "j", "dx", "dy", "dtheta", "I11", "I12", "I13", "I22", "I23", "I33"),
    "EDGE2": ("i", "j", "dx", "dy", "dtheta", "I11", "I12", "I22", "I33", "I13", "I23"),
    "EQUIV": ("i", "j"),
}
# TORO: ``EQUIV i j`` declares vertices i and j the same pose (merged on reading).
EQUIV_TAG = "EQUIV"
# g2o: ``FIX id…`` holds those poses fixed (also read in TORO files, where popbench writes it).
FIX_TAG = "FIX"
# Vertex ids are unsigned 64-bit integers written in decimal digits (GTSAM keys, ``Symbol``s).
MAX_VERTEX_ID = 2**64 - 1


def toro_frame(theta: np.ndarray) -> np.ndarray:
    """``(M, 3, 3)`` ``B = blkdiag(R(θ), 1)`` of each measured rotation ``theta`` ``(M,)`` [rad]:
    ``Λ_g2o = Bᵀ Λ_TORO B``."""
    b = np.zeros((theta.shape[0], 3, 3))
    b[:, :2, :2] = se2.rotation(theta)
    b[:, 2, 2] = 1.0
    return b


def information_matrices(values: np.ndarray, fmt: str, theta: np.ndarray) -> np.ndarray:
    """``(M, 3, 3)`` g2o-frame information matrices from the six numbers ``values`` ``(M, 6)``
    of each edge line of format ``fmt``, ``theta`` ``(M,)`` the measured rotations [rad]."""
    entries = G2O_ENTRIES if fmt == "g2o" else TORO_ENTRIES
    information = np.zeros((values.shape[0], 3, 3))
    for k, (row, col) in enumerate(entries):
        information[:, row, col] = values[:, k]
        information[:, col, row] = values[:, k]
    if fmt == "toro":
        b = toro_frame(theta)
        information = np.swapaxes(b, 1, 2) @ information @ b
    return information


class ScannedLines(NamedTuple):
    """The parsed lines of one file (what :mod:`popbench.io.read` scans and
    :mod:`popbench.io.limits` checks), with their 1-based line numbers; ids exact, as written."""

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
