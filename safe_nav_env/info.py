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


def _padded(info: dict[str, Any], present: np.ndarray | None, rows: int) -> dict[str, Any]:
    """The entries of :data:`_PADDED` with ``rows`` rows, read-only, and ``obstacle_present``.

    The first ``n`` rows are the obstacle model's (``present``: its mask of real rows, or
    ``None``: all real); the rows not present and the padding rows get the fill value.
    """
    n = info["obstacle_positions"].shape[0]
    mask = np.zeros(rows, dtype=bool)
    mask[:n] = True if present is None else present
    mask.flags.writeable = False
    padded: dict[str, Any] = {"obstacle_present": mask}
    if mask.all():
        return padded
    absent = ~mask
    for key, fill in _PADDED:
        value = info[key]
        array = np.empty((rows, *value.shape[1:]))
        array[:n] = value
        array[absent] = fill
        array.flags.writeable = False
        padded[key] = array
    return padded
