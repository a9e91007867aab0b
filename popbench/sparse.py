"""Sparse linear algebra shared by the solvers: one place for how a symmetric positive-definite
system is ordered and factorised.

* :func:`nested_dissection` — a fill-reducing METIS nested-dissection order of a graph (pymetis).
* :func:`spd_lu` — SuperLU on an SPD matrix already in a fill-reducing order: the natural column
  order, diagonal pivots and symmetric mode (:data:`SPD_LU_OPTIONS`).
* :class:`CholeskyFactor` — a cached sparse Cholesky factor (cholespy, CHOLMOD-style supernodal,
  AMD-ordered) of a CSC or CSR matrix, for many solves with one matrix.

Which solver uses which, and the measurements behind the choices: ``docs/sparse.md``.

Example:
    >>> import numpy as np, scipy.sparse as sp
    >>> from popbench.sparse import CholeskyFactor, spd_lu
    >>> matrix = sp.csc_matrix(np.array([[4.0, 1.0], [1.0, 3.0]]))
    >>> rhs = np.array([1.0, 2.0])
    >>> bool(np.allclose(CholeskyFactor(matrix).solve(rhs), spd_lu(matrix).solve(rhs)))
    True
"""

from __future__ import annotations

import numpy as np
import pymetis
import scipy.sparse as sp
from cholespy import CholeskySolverD, MatrixType
from scipy.sparse.linalg import SuperLU, splu

# SuperLU settings for symmetric positive-definite matrices: diagonal pivots, symmetric mode.
SPD_LU_OPTIONS = {"diag_pivot_thresh": 0.0, "options": {"SymmetricMode": True}}


def nested_dissection(starts: np.ndarray, neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """METIS nested dissection of the graph in CSR adjacency form (``starts`` ``(n + 1,)``,
    ``neighbours`` ``(nnz,)``, no self loops).

    Returns:
        ``(order, position)``, both ``(n,)`` int64: ``order[k]`` is the vertex placed k-th and
        ``position[v]`` the place of vertex ``v`` (``position[order] = arange(n)``).
    """
    order, position = pymetis.nested_dissection(
        adjacency=pymetis.CSRAdjacency(adj_starts=starts, adjacent=neighbours)
    )
    return np.asarray(order, dtype=np.int64), np.asarray(position, dtype=np.int64)


def spd_lu(matrix: sp.csc_matrix) -> SuperLU:
    """SuperLU factor of a symmetric positive-definite CSC ``matrix`` whose unknowns are already
    in a fill-reducing order (natural column order, diagonal pivots)."""
    return splu(matrix, permc_spec="NATURAL", **SPD_LU_OPTIONS)


class CholeskyFactor:
    """Sparse Cholesky factor of a symmetric positive-definite CSC or CSR matrix (cholespy: an
    AMD-ordered supernodal factorisation), for repeated solves."""

    def __init__(self, matrix: sp.csc_matrix | sp.csr_matrix) -> None:
        kind = MatrixType.CSR if matrix.format == "csr" else MatrixType.CSC
        self._solver = CholeskySolverD(
            matrix.shape[0],
            matrix.indptr.astype(np.int32),
            matrix.indices.astype(np.int32),
            np.ascontiguousarray(matrix.data),
            kind,
        )

    def solve(self, rhs: np.ndarray) -> np.ndarray:
        """``A⁻¹ rhs`` for ``rhs`` ``(n,)`` or ``(n, k)``."""
        rhs = np.ascontiguousarray(rhs, dtype=np.float64)
        solution = np.empty_like(rhs)
        self._solver.solve(rhs, solution)
        return solution
