"""Compiled kernel of :func:`filters.references.hold_action_reference` (numba).

Imported on first use only, so that ``import filters`` does not import numba.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["hold"]


@njit(cache=True)
def hold(x0: np.ndarray, action: np.ndarray, low: np.ndarray, high: np.ndarray,
          A: np.ndarray, B: np.ndarray, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`hold_action_reference`'s arrays: ``u = clip(a)`` held, ``x_{k+1} = A x_k + B u``.

    Each product sums in index order, then ``A x_k`` and ``B u`` are added: for the
    double integrator (entries 0, 1, ``T_s``, ``T_s²/2``) the bits of numpy's
    ``A @ x + B @ u``.
    """
    n, m = B.shape
    states = np.empty((horizon + 1, n))
    inputs = np.empty((horizon, m))
    u = np.empty(m)
    for j in range(m):
        v = action[j]
        if v < low[j]:  # np.clip's result, a NaN stays NaN
            v = low[j]
        if v > high[j]:
            v = high[j]
        u[j] = v
    bu = np.empty(n)
    for i in range(n):
        total = 0.0
        for j in range(m):
            total += B[i, j] * u[j]
        bu[i] = total
    for i in range(n):
        states[0, i] = x0[i]
    for k in range(horizon):
        for j in range(m):
            inputs[k, j] = u[j]
        for i in range(n):
            total = 0.0
            for j in range(n):
                total += A[i, j] * states[k, j]
            states[k + 1, i] = total + bu[i]
    return states, inputs
