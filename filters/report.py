"""What the safety filter did in one step: :class:`FilterReport` (``info["filter"]``).

Also the filter statuses the report carries (:data:`NOMINAL_STATUSES`,
:data:`FALLBACK_STATUSES`) and the fast builders the wrapper uses every step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

PASSTHROUGH = "passthrough"
"""Filter status reported when ``risk="none"``."""

NOMINAL_STATUSES = ("optimal", PASSTHROUGH)
"""Statuses of a step where the filter's constraints all held (or no filter ran)."""

FALLBACK_STATUSES = ("soft", "recovery", "shifted", "brake", "error")
"""Statuses of a step where some constraint could not be met: slack, a fallback, bad data."""


_TIMING_FIELDS = ("solve_time", "halfspace_time", "filter_time", "reference_time")


@dataclass(frozen=True, eq=False)
class FilterReport:
    """What the filter did in one step: ``info["filter"]``.

    Reads like a dict too (``report["status"]``), so ``info`` stays easy to log.

    Attributes
    ----------
    status
        ``"optimal"``, ``"soft"`` (solved with halfspace slack), ``"recovery"`` (arena or
        terminal slack: being brought back), ``"shifted"`` (the paper's fallback: the
        last optimal plan, shifted), ``"brake"`` (last resort), ``"error"`` (bad data:
        braking, see ``error``) or ``"passthrough"`` (``risk="none"``).
    proposed_action, applied_action
        The reference planner's action (clipped to the input box) and the filtered one,
        in m/s².
    intervention
        :math:`\\|u_{applied} - u_{proposed}\\|_2`, in m/s².
    solve_time, halfspace_time, filter_time, reference_time
        Wall times in s: the QP solver call; the halfspaces; halfspaces + QP (the
        filter step); making the reference trajectory. They vary from run to run and
        are left out of equality, so that two runs with the same seed compare equal.
    slack
        Halfspace violations (n_obstacles, T) in m when the QP had slack rows (soft
        mode or recovery; the larger of the two inter-sample rows), else ``None``.
    normals, offsets
        The halfspaces ``normals @ y <= offsets``, shapes (n_obstacles, T, d) and
        (n_obstacles, T); ``None`` when no filter ran.
    planned_states
        The filtered plan's states (T+1, n), or ``None``.
    error
        Why the filter braked on bad numbers (a NaN action, ...), else ``""``.

    Notes
    -----
    A report is immutable: its arrays are read-only and belong to it alone (the wrapper
    copies what the halfspaces and the QP hand it), so a report kept from one step is
    not changed by the next, and ``copy.deepcopy`` returns the report itself.
    """

    status: str
    proposed_action: np.ndarray
    applied_action: np.ndarray
    intervention: float = 0.0
    solve_time: float = 0.0
    halfspace_time: float = 0.0
    filter_time: float = 0.0
    reference_time: float = 0.0
    slack: np.ndarray | None = None
    normals: np.ndarray | None = None
    offsets: np.ndarray | None = None
    planned_states: np.ndarray | None = None
    error: str = ""

    def __post_init__(self) -> None:
        # Built by hand (the wrapper builds its own with read-only copies already): keep
        # the report immutable, whatever the caller does with the arrays it passed.
        for key in ("proposed_action", "applied_action", "slack", "normals", "offsets",
                    "planned_states"):
            object.__setattr__(self, key, _owned(getattr(self, key)))

    def __getitem__(self, key: str) -> Any:
        if key not in _REPORT_KEYS:
            raise KeyError(key)
        return getattr(self, key)

    def keys(self) -> tuple[str, ...]:
        return _REPORT_KEYS

    def as_dict(self) -> dict[str, Any]:
        """The report as a plain dict."""
        return {key: getattr(self, key) for key in self.keys()}

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, FilterReport):
            return NotImplemented
        for key in _COMPARED_KEYS:
            a, b = getattr(self, key), getattr(other, key)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b and not (a != a and b != b):  # NaN == NaN, as for the arrays
                return False
        return True

    __hash__ = None  # type: ignore[assignment]

    def __copy__(self) -> FilterReport:
        return self

    def __deepcopy__(self, memo: dict[int, Any]) -> FilterReport:
        """The report itself: it is immutable (frozen fields, read-only arrays that no one
        else holds), so a copy could not differ from it (SB3's ``DummyVecEnv``
        deep-copies every step's infos)."""
        return self


_REPORT_KEYS: tuple[str, ...] = tuple(f.name for f in fields(FilterReport))
"""The field names of :class:`FilterReport`, computed once (``keys`` runs every step)."""
_COMPARED_KEYS = tuple(key for key in _REPORT_KEYS if key not in _TIMING_FIELDS)


def _report(status: str, proposed: np.ndarray, applied: np.ndarray, intervention: float,
            solve_time: float = 0.0, halfspace_time: float = 0.0, filter_time: float = 0.0,
            reference_time: float = 0.0, slack: np.ndarray | None = None,
            normals: np.ndarray | None = None, offsets: np.ndarray | None = None,
            planned_states: np.ndarray | None = None, error: str = "") -> FilterReport:
    """A :class:`FilterReport` built without the frozen ``__init__``'s per-field
    ``object.__setattr__`` and array copies (the same object; the arrays given must be
    read-only and the report's own). The parameters are the fields, in their order."""
    fields = dict(zip(_REPORT_KEYS, locals().values(), strict=True))
    report = object.__new__(FilterReport)
    report.__dict__.update(fields)
    return report


def _owned(array: np.ndarray | None) -> np.ndarray | None:
    """A read-only float64 copy of ``array`` that only the report holds (``None`` stays)."""
    if array is None:
        return None
    copy = np.array(array, dtype=np.float64)  # always a copy
    copy.setflags(write=False)
    return copy


def _distance(a: np.ndarray, b: np.ndarray) -> float:
    """Euclidean distance between two actions (the intervention size, m/s²).

    :math:`\\sqrt{\\sum_i (a_i - b_i)^2}` by :func:`math.dist`: the value of
    ``numpy.linalg.norm(a - b)`` within rounding, without its per-call overhead.
    """
    return math.dist(np.asarray(a, dtype=float).tolist(), np.asarray(b, dtype=float).tolist())
