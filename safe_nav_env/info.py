"""Per-obstacle ``info`` entries padded to a fixed number of rows (``pad_info``).

Gymnasium's vector environments stack info arrays, so they need one shape even when
the obstacle count changes between episodes; see :class:`safe_nav_env.env.SafeNavEnv`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

_PADDED = (("predictions", np.inf), ("obstacle_positions", np.inf),
           ("obstacle_velocities", 0.0), ("distance_to_collision", np.inf),
           ("swept_distance_to_collision", np.inf))
"""The padded keys and the value of their absent rows (infinitely far, at rest)."""


def _padded(info: dict[str, Any], n: int, rows: int) -> dict[str, Any]:
    """The entries of :data:`_PADDED` with ``rows`` rows (the first ``n`` real, read-only)
    and ``obstacle_present`` ``(rows,)``."""
    padded: dict[str, Any] = {}
    for key, fill in _PADDED:
        value = info[key]
        array = np.empty((rows, *value.shape[1:]))
        array[:n] = value
        array[n:] = fill  # only the padding rows: no second pass over the data
        array.flags.writeable = False
        padded[key] = array
    padded["obstacle_present"] = np.arange(rows) < n
    return padded
