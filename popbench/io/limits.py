"""Value ranges of a pose-graph file that the solvers are known to handle, checked at load.

Beyond them a file is refused with its line (``file:line: reason``), not left to fail inside a
factorisation; docs/solve.md ("Refused input") has the measurements behind each limit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from popbench.errors import DataFormatError
from popbench.io.format import ScannedLines

# Magnitudes the solvers are known to handle (docs/solve.md, "Refused input"): beyond them a file is
# refused at load with its line, not left to fail inside a factorisation.
COORDINATE_LIMIT = 1e9  # |x|, |y| of a VERTEX line and |dx|, |dy| of an edge [m]
INFORMATION_RANGE = (1e-100, 1e100)  # every eigenvalue of every information matrix
INFORMATION_SPREAD = 1e15  # largest / smallest eigenvalue over the whole graph


def check_coordinates(path: Path, lines: ScannedLines) -> None:
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


def check_information(path: Path, information: np.ndarray, lines: np.ndarray) -> None:
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
