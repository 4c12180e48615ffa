"""Recorded pedestrian scenes: parse ``frame pedestrian_id x y`` files, resample to ``dt``.

A raw file has one observation per line, whitespace (tab) separated,
``frame  pedestrian_id  x  y``, positions in m; frame numbers count
:data:`SECONDS_PER_FRAME` s each (ETH/UCY: frames every 10 = 0.4 s). A
:class:`Recording` holds every pedestrian's track on the environment's time grid
``t_j = j · dt`` (``j = 0, 1, ...``, time 0 at the file's first frame):

.. math::

    p_i(t_j) = p_i(\\tau_a)
        + \\frac{t_j - \\tau_a}{\\tau_b - \\tau_a}\\,(p_i(\\tau_b) - p_i(\\tau_a)),
    \\qquad \\tau_a \\le t_j \\le \\tau_b,

with ``τ_a, τ_b`` consecutive observed times of pedestrian ``i``. Pedestrian ``i``
exists from its first to its last observed time: a gap between two observations
inside that span is interpolated, and outside it the pedestrian is absent (NaN). No
extrapolation, ever.

Note that a grid point between two frames is interpolated from the frame after it
(at most one frame period, 0.4 s, later): that is the definition of the realised
positions, which the predictors then only read up to the current step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np

from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.options import _option

__all__ = ["SCENES", "SECONDS_PER_FRAME", "Recording", "RecordingError", "load_recording",
    "parse_tracks", "resample", "scene_path"]

SECONDS_PER_FRAME = 0.04
"""Duration of one frame number in the ETH/UCY files, s (10 frames = 0.4 s)."""

SCENES: dict[str, str] = {
    "eth": "biwi_eth.txt",
    "hotel": "biwi_hotel.txt",
    "zara1": "crowds_zara01.txt",
    "zara2": "crowds_zara02.txt",
    "students001": "students001.txt",
    "students003": "students003.txt",
}
"""Packaged scene names and their files in ``safe_nav_env/pedestrians/data``."""


class RecordingError(ScenarioError):
    """A pedestrian file is empty or malformed; the message names the file, line and text."""


@dataclass(frozen=True, eq=False)
class Recording:
    """Pedestrian tracks of one scene on the time grid ``t_j = j · dt``.

    Attributes
    ----------
    name
        Scene name (a key of :data:`SCENES`) or the file's path.
    dt
        Grid spacing, s.
    positions
        Shape ``(n_steps, n_pedestrians, 2)``, m; NaN where the pedestrian does not
        exist. Read-only.
    ids
        The file's pedestrian ids, shape ``(n_pedestrians,)``.
    first, last
        First and last grid step at which each pedestrian exists, shape
        ``(n_pedestrians,)`` (``first <= last``).
    """

    name: str
    dt: float
    positions: np.ndarray
    ids: np.ndarray
    first: np.ndarray
    last: np.ndarray

    @property
    def n_steps(self) -> int:
        """Number of grid steps."""
        return int(self.positions.shape[0])

    @property
    def n_pedestrians(self) -> int:
        """Number of pedestrians."""
        return int(self.positions.shape[1])

    def track(self, index: int) -> np.ndarray:
        """Positions of pedestrian ``index`` from its first to its last step, ``(n, 2)``, m."""
        return self.positions[self.first[index] : self.last[index] + 1, index]

    def walkable_box(
        self, quantile: float = 0.02
    ) -> tuple[tuple[float, float], tuple[float, float]]:
        """Box where people walk: per axis, the ``quantile`` and ``1 - quantile`` quantiles.

        The bounding box of all positions shrunk to drop the few far-out stretches of
        track (default: 2 % of the positions on each side, per axis), in m, as
        ``((x_min, y_min), (x_max, y_max))``.
        """
        points = self.positions.reshape(-1, 2)
        points = points[~np.isnan(points[:, 0])]
        low = np.quantile(points, quantile, axis=0)
        high = np.quantile(points, 1.0 - quantile, axis=0)
        return (float(low[0]), float(low[1])), (float(high[0]), float(high[1]))

    def with_positions(self, positions: np.ndarray) -> Recording:
        """A copy with other positions (same NaN pattern expected), e.g. to alter the future."""
        array = np.array(positions, dtype=np.float64)
        if array.shape != self.positions.shape:
            raise ConfigError(
                f"positions must have shape {self.positions.shape}, got {array.shape}"
            )
        array.flags.writeable = False
        return Recording(self.name, self.dt, array, self.ids, self.first, self.last)


def scene_path(name: str) -> Path:
    """Path of a packaged scene's file.

    Raises
    ------
    ConfigError
        If ``name`` is not a key of :data:`SCENES`.
    """
    if name not in SCENES:
        raise ConfigError(f"unknown scene {name!r}; choose one of {list(SCENES)} or pass a path")
    return Path(str(resources.files("safe_nav_env.pedestrians") / "data" / SCENES[name]))


def parse_tracks(text: str, source: str = "<text>") -> np.ndarray:
    """Parse ``frame pedestrian_id x y`` lines into an ``(n, 4)`` float array.

    Blank lines are skipped; every other line must hold exactly four finite numbers,
    and each ``(frame, pedestrian_id)`` pair may appear once.

    Raises
    ------
    RecordingError
        For an empty file (no data line) or a malformed line; the message names
        ``source``, the 1-based line number and the line's text.
    """
    rows: list[tuple[float, float, float, float]] = []
    seen: dict[tuple[float, float], int] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        try:
            if len(fields) != 4:
                raise ValueError
            row = tuple(float(f) for f in fields)
        except ValueError:
            raise RecordingError(
                f"{source}, line {number}: expected 4 tab-separated numbers "
                f"'frame pedestrian_id x y', got {line!r}"
            ) from None
        if not all(math.isfinite(v) for v in row):
            raise RecordingError(
                f"{source}, line {number}: values must be finite, got {line!r}"
            )
        key = (row[0], row[1])
        if key in seen:
            raise RecordingError(
                f"{source}, line {number}: pedestrian {fields[1]} already observed at frame "
                f"{fields[0]} on line {seen[key]}, got {line!r}"
            )
        seen[key] = number
        rows.append(row)  # type: ignore[arg-type]
    if not rows:
        raise RecordingError(
            f"{source}: the file is empty (no line 'frame pedestrian_id x y'; "
            f"{len(text.splitlines())} blank lines)"
        )
    return np.array(rows, dtype=np.float64)


def resample(
    table: np.ndarray, *, dt: float, name: str, seconds_per_frame: float = SECONDS_PER_FRAME
) -> Recording:
    """Interpolate each pedestrian's track linearly onto ``t_j = j · dt`` inside its span.

    Parameters
    ----------
    table
        ``(n, 4)`` rows ``frame, pedestrian_id, x, y`` (see :func:`parse_tracks`).
    dt
        Grid spacing, s, ``> 0``.
    name
        Scene name stored in the result.
    seconds_per_frame
        Duration of one frame number, s.

    Returns
    -------
    Recording
        Time 0 is the table's first frame.
    """
    dt = _option("dt (s)", dt, strict=True)
    times = (table[:, 0] - table[:, 0].min()) * seconds_per_frame
    n_steps = int(math.floor(times.max() / dt + 1e-9)) + 1
    ids, inverse = np.unique(table[:, 1], return_inverse=True)
    positions = np.full((n_steps, ids.shape[0], 2), np.nan)
    first = np.empty(ids.shape[0], dtype=np.int64)
    last = np.empty(ids.shape[0], dtype=np.int64)
    order = np.lexsort((times, inverse))
    starts = np.searchsorted(inverse[order], np.arange(ids.shape[0] + 1))
    for i in range(ids.shape[0]):
        rows = order[starts[i] : starts[i + 1]]
        t, xy = times[rows], table[rows, 2:]
        j0 = int(math.ceil(t[0] / dt - 1e-9))
        j1 = int(math.floor(t[-1] / dt + 1e-9))
        if j1 < j0:  # observed only between two grid points: keep its nearest grid point
            j0 = j1 = int(round(t[0] / dt))
        grid = np.clip(np.arange(j0, j1 + 1) * dt, t[0], t[-1])
        positions[j0 : j1 + 1, i, 0] = np.interp(grid, t, xy[:, 0])
        positions[j0 : j1 + 1, i, 1] = np.interp(grid, t, xy[:, 1])
        first[i], last[i] = j0, j1
    for array in (positions, ids, first, last):
        array.flags.writeable = False
    return Recording(name, float(dt), positions, ids, first, last)


def load_recording(scene: str | Path, *, dt: float = 0.2) -> Recording:
    """Load a packaged scene by name, or a file in the same format by path.

    Packaged scenes are parsed once per process and ``dt`` (cached).

    Parameters
    ----------
    scene
        A key of :data:`SCENES` or a path to a ``frame pedestrian_id x y`` file.
    dt
        Grid spacing, s.

    Raises
    ------
    ConfigError
        If ``scene`` is neither a packaged name nor an existing file.
    RecordingError
        If the file is empty or malformed (the message names the line).
    """
    if isinstance(scene, str) and scene in SCENES:
        return _packaged(scene, float(dt))
    if not isinstance(scene, str | Path):
        raise ConfigError(f"scene must be a scene name in {list(SCENES)} or a path, got {scene!r}")
    path = Path(scene)
    if not path.is_file():
        raise ConfigError(
            f"scene {str(scene)!r} is neither a packaged scene ({list(SCENES)}) nor a file"
        )
    return resample(parse_tracks(path.read_text(), str(path)), dt=float(dt), name=str(path))


@cache
def _packaged(name: str, dt: float) -> Recording:
    path = scene_path(name)
    return resample(parse_tracks(path.read_text(), str(path)), dt=dt, name=name)
