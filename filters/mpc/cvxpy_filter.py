"""The MPC safety filter with the CVXPY back end: the readable reference of the fast one.

Tests and benchmarks compare :class:`~filters.mpc.MPCSafetyFilter` with this one. Its
back end (:class:`filters.mpc.backends.cvxpy.CVXPYBackend`) imports CVXPY when the first
QP is built; ``import filters`` imports neither (``filters.CVXPYSafetyFilter`` is resolved
on first use).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from filters.mpc.filter import MPCSafetyFilter

__all__ = ["CVXPYSafetyFilter"]


class CVXPYSafetyFilter(MPCSafetyFilter):
    """:class:`~filters.mpc.MPCSafetyFilter` with the CVXPY back end (``backend="cvxpy"``).

    Same parameters, same results (to solver tolerance); for tests and benchmarks.
    ``skip_feasible_reference`` defaults to ``False`` here: the reference solves every QP.
    """

    def __init__(self, A: np.ndarray, B: np.ndarray, C: np.ndarray, **kwargs: Any) -> None:
        kwargs["backend"] = "cvxpy"
        kwargs.setdefault("skip_feasible_reference", False)
        super().__init__(A, B, C, **kwargs)
