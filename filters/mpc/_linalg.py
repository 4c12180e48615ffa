"""Matrix-vector products of the per-step hot path that stay single-threaded.

OpenBLAS runs a matrix-vector product on several threads once the matrix has more than
about 9,000 entries (2304 x its GEMM_MULTITHREAD_THRESHOLD of 4). On a machine whose
cores are busy the threads wait for each other: measured here, a 1130 x 485 product of
the T = 80 filter took milliseconds per call in the control loop while its arithmetic
takes tens of µs. Those maps are mostly zeros anyway (block-banded: the dynamics, the
block-diagonal weights, the causal roll-out), so a CSR product, which never calls BLAS,
is both safe and cheaper there.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["DENSE_LIMIT", "matvec_operator"]

#: Largest matrix (entries) kept dense: below OpenBLAS's multithreading threshold.
DENSE_LIMIT = 8192


def matvec_operator(matrix: np.ndarray) -> np.ndarray | sp.csr_matrix:
    """``matrix`` itself when small, else as CSR (zeros dropped); both support ``@ v``.

    ``M @ v`` with a 1-D ``v`` returns a 1-D ``ndarray`` either way.
    """
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.size <= DENSE_LIMIT:
        return np.ascontiguousarray(matrix)
    csr = sp.csr_matrix(matrix)
    csr.eliminate_zeros()
    return csr
