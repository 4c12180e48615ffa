r"""Inter-sample safety: halfspace rows that keep the ego safe *between* the samples.

The halfspaces of Definitions 2-3 constrain the predicted ego positions :math:`y_t`
at the sample instants only. At 5-6 m/s the ego covers more than a disc diameter in
one 0.2 s step, so a plan whose samples are all safe can pass through an obstacle in
between. This module adds the rows that cover every intermediate time.

Derivation
----------
Take the interval :math:`[t, t+1]` of one obstacle, a unit normal :math:`h` common to
both ends, and write :math:`\lambda = s / T_s \in [0, 1]`. Between the samples

* the obstacle moves on the chord between its positions,
  :math:`o(\lambda) = (1-\lambda) o_t + \lambda o_{t+1}` (the environment's own
  continuous-time model, docs/design.md);
* the ego, under the constant input :math:`u_t`, follows
  :math:`y(\lambda) = (1-\lambda) y_t + \lambda y_{t+1} - \tfrac{T_s^2}{2}
  \lambda(1-\lambda) u_t`, its chord plus a bow whose size along :math:`h` is at most
  :math:`m(h) = \tfrac{T_s^2}{8} \max_{u \in \mathcal U} (-h \cdot u)` (the maximum of
  :math:`\lambda(1-\lambda)` is 1/4). For the box :math:`[u_\text{low}, u_\text{high}]`,
  :math:`m(h) = \tfrac{T_s^2}{8} \sum_j \max(-h_j u_{\text{low},j}, -h_j
  u_{\text{high},j})`; at ±10 m/s² and :math:`T_s = 0.2` s it is at most 0.071 m.

The loss (intrusion depth) at :math:`\lambda` is
:math:`\ell(\lambda) = h \cdot y(\lambda) + r - h \cdot o(\lambda)
\le (1-\lambda)\,\ell_t + \lambda\,\ell_{t+1} + m(h)`, with :math:`\ell_t = h \cdot y_t
+ r - h \cdot o_t`. The mean, CVaR and DR-CVaR are monotone, translation equivariant,
convex and positively homogeneous (coherent), and so subadditive for any joint law of
:math:`(o_t, o_{t+1})`:

.. math::

    R(\ell(\lambda)) \le (1-\lambda)\, R(\ell_t) + \lambda\, R(\ell_{t+1}) + m(h)
    \le \max\big(R(\ell_t), R(\ell_{t+1})\big) + m(h).

So if **both** ends satisfy :math:`h \cdot y \le b(h) - m(h)`, each with the offset
:math:`b(h)` of Definition 2 computed from *its own* samples along the common normal
:math:`h`, then :math:`R(\ell(\lambda)) \le \delta` at every intermediate time. (Imposing
the tighter of the two offsets on both ends, as the issue suggests, is also sufficient,
but more conservative than needed.)

The rows
--------
For obstacle :math:`i` and the interval :math:`[t-1, t]` we use the normal
:math:`h_{i,t}` of the step-:math:`t` halfspace (paper's Definition 3), so

* **end rows** (one per step :math:`t = 1..T`): :math:`h_{i,t} \cdot y_t \le b_{i,t}
  - m(h_{i,t})`: the ordinary halfspace, tightened by the bow;
* **start rows** (:math:`t = 1..T-1`): :math:`h_{i,t+1} \cdot y_t \le b_t(h_{i,t+1})
  - m(h_{i,t+1})`, the offset from the step-:math:`t` samples along the next normal.

The first interval starts at the current position :math:`y_0`, which the filter cannot
move: its start row is a check only (:attr:`IntersampleRows.start_violation`), reported
so that a user sees when continuous-time safety of the first step is out of reach.
The chance-constraint and conformal risks of :mod:`filters.risk` are not coherent in
general (a quantile is not subadditive); for them the rows are a heuristic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from filters.constants import ALPHA, DELTA, DISABLED_OFFSET, EPSILON
from filters.geometry import Shape
from filters.halfspace_checks import _check_finite_result, _checked_inputs, _Inputs
from filters.halfspaces import (
    Halfspaces,
    _offsets,
    _step_normals,
    safe_halfspaces,
    warn_deprecated_backend,
)

__all__ = ["IntersampleRows", "arc_margin", "intersample_halfspaces", "intersample_rows"]


def arc_margin(
    normals: np.ndarray, input_bounds: tuple[np.ndarray, np.ndarray], dt: float
) -> np.ndarray:
    r"""Largest excursion of the ego arc beyond its chord along each normal, in m.

    .. math:: m(h) = \frac{T_s^2}{8} \max_{u_\text{low} \le u \le u_\text{high}} (-h\cdot u)
              = \frac{T_s^2}{8} \sum_j \max(-h_j u_{\text{low},j}, -h_j u_{\text{high},j})

    Parameters
    ----------
    normals
        Unit normals, shape ``(..., d)``.
    input_bounds
        ``(low, high)`` accelerations, each shape ``(d,)``, in m/s² (finite).
    dt
        Sampling time :math:`T_s`, in s.

    Returns
    -------
    numpy.ndarray
        Shape ``normals.shape[:-1]``, ``>= 0`` when the box contains 0.
    """
    low, high = input_bounds  # max(-h u_low, -h u_high) = -min(h u_low, h u_high)
    best = np.add.reduce(np.minimum(normals * low, normals * high), axis=-1)
    return (dt * dt / -8.0) * best


@dataclass(frozen=True, eq=False)
class IntersampleRows:
    """The halfspace rows that make a plan safe in continuous time.

    Attributes
    ----------
    normals, offsets
        Shapes ``(2 k, T, d)`` and ``(2 k, T)``: rows ``0..k-1`` are the end rows (the
        step-``t`` halfspaces tightened by the bow), rows ``k..2k-1`` the start rows
        (step-``t`` position, next step's normal); the start rows at ``t = T`` are
        disabled (``0 @ y <= 1``). Safe side ``normals[j, t-1] @ y_t <= offsets[j, t-1]``.
    margins
        The bow :math:`m(h_{i,t})` of the end rows, ``(k, T)``, in m.
    start_violation
        ``h_{i,1} @ y_0 - (b_0(h_{i,1}) - m)``, shape ``(k,)``, in m: the start row of the
        first interval at the current position, which no plan can change (``<= 0``:
        satisfied). ``None`` when the current obstacle positions were not given.
    """

    normals: np.ndarray
    offsets: np.ndarray
    margins: np.ndarray
    start_violation: np.ndarray | None


def intersample_rows(
    halfspaces: Halfspaces,
    samples: np.ndarray,
    *,
    ego_shape: Shape,
    obstacle_shapes: Sequence[Shape],
    input_bounds: tuple[np.ndarray, np.ndarray],
    dt: float,
    support: tuple[object, object] | None = None,
    current_position: np.ndarray | None = None,
    current_obstacles: np.ndarray | None = None,
    backend: str | None = None,
    **risk_options: object,
) -> IntersampleRows:
    r"""End and start rows for every obstacle and interval (see the module docstring).

    Parameters
    ----------
    halfspaces
        The step halfspaces from :func:`filters.safe_halfspaces` (their normals are
        reused; their risk, alpha, delta and epsilon are used for the start rows unless
        ``risk_options`` overrides them, e.g. per-step arrays).
    samples
        The same prediction samples, ``(k, N_s, T, d)``, in m.
    ego_shape, obstacle_shapes, support
        As for :func:`filters.safe_halfspaces`.
    input_bounds
        The ego's input box ``(low, high)``, in m/s², finite.
    dt
        Sampling time :math:`T_s`, in s.
    current_position, current_obstacles
        Optional ego position ``(d,)`` and obstacle positions ``(k, d)`` now, to report
        the start row of the first interval.
    backend
        Deprecated and ignored, as for :func:`filters.safe_halfspaces`.
    **risk_options
        Passed on to :func:`filters.safe_halfspaces` for the start rows.
    """
    warn_deprecated_backend(backend, "intersample_rows")
    normals, offsets = halfspaces.normals, halfspaces.offsets
    k, horizon, dim = normals.shape
    options = dict(risk=halfspaces.risk, alpha=halfspaces.alpha, delta=halfspaces.delta,
                   epsilon=halfspaces.epsilon)
    options.update(risk_options)
    start = None
    if k and horizon > 1:
        start = safe_halfspaces(  # step t's samples along the normals of step t + 1
            np.zeros((horizon - 1, dim)), np.asarray(samples)[:, :, :horizon - 1],
            ego_shape=ego_shape, obstacle_shapes=obstacle_shapes, support=support,
            normals=normals[:, 1:], **_steps(options, slice(0, horizon - 1))).offsets
    both = np.zeros((2, k, horizon))  # the end offsets, then the start offsets
    both[0] = offsets
    if start is not None:
        both[1, :, :-1] = start
    rows = _rows(_row_normals(normals, start is not None), both, start is not None,
                 input_bounds, dt)
    if k and current_position is not None and current_obstacles is not None:
        now = safe_halfspaces(
            np.zeros((1, dim)), np.asarray(current_obstacles, dtype=np.float64)[:, None, None],
            ego_shape=ego_shape, obstacle_shapes=obstacle_shapes, support=support,
            normals=normals[:, :1], **_steps(options, slice(0, 1)),
        )
        violation = normals[:, 0] @ np.asarray(current_position, dtype=np.float64)
        return replace(rows, start_violation=violation - (now.offsets[:, 0] - rows.margins[:, 0]))
    return rows


def intersample_halfspaces(
    reference_positions: object,
    samples: object,
    *,
    ego_shape: Shape,
    obstacle_shapes: Sequence[Shape],
    input_bounds: tuple[np.ndarray, np.ndarray],
    dt: float,
    risk: str = "dr_cvar",
    alpha: float = ALPHA,
    delta: float = DELTA,
    epsilon: float | object = EPSILON,
    support: tuple[object, object] | None = None,
    previous_normals: object | None = None,
    ego_velocity: object | None = None,
    normals: object | None = None,
    conformal_margins: object | None = None,
) -> tuple[Halfspaces, IntersampleRows]:
    r"""The step halfspaces and their inter-sample rows in one pass.

    ``safe_halfspaces(reference_positions, samples, ...)`` and
    ``intersample_rows(that, samples, ...)`` (without the start-row check at the current
    position) to rounding: the same checks (once) and the same closed forms
    (:func:`filters.halfspaces.safe_halfspaces`), with the two offsets of each step
    and obstacle, :math:`b_t(h_{i,t})` (end row) and :math:`b_t(h_{i,t+1})` (start row),
    computed along the step's samples in one batched product and one CVaR pass over
    ``(n, T, 2, N)`` losses. The wrapper's per-step path.

    Parameters are those of :func:`filters.safe_halfspaces` (``input_bounds`` in m/s² and
    ``dt`` in s as for :func:`intersample_rows`).

    Returns
    -------
    (Halfspaces, IntersampleRows)
        The step halfspaces (as :func:`filters.safe_halfspaces`) and the rows
        (``start_violation`` is ``None``).

    Raises
    ------
    InvalidArrayError, InvalidParameterError, InvalidTypeError
        As :func:`filters.safe_halfspaces`.
    """
    data = _checked_inputs(reference_positions, samples, ego_shape, obstacle_shapes,
                           risk, alpha, delta, epsilon, support, previous_normals,
                           ego_velocity, normals, conformal_margins)
    k, _, horizon, _ = data.points.shape
    if k and horizon > 1 and data.polytope is None:
        return batched_halfspaces(data, ego_shape, input_bounds, dt)
    shapes = dict(ego_shape=ego_shape, obstacle_shapes=obstacle_shapes, support=support,
                  conformal_margins=conformal_margins)  # nothing to batch: the two calls
    halfspaces = safe_halfspaces(
        reference_positions, samples, risk=risk, alpha=alpha, delta=delta, epsilon=epsilon,
        previous_normals=previous_normals, ego_velocity=ego_velocity, normals=normals, **shapes)
    return halfspaces, intersample_rows(halfspaces, samples, input_bounds=input_bounds, dt=dt,
                                        **shapes)


def batched_halfspaces(data: _Inputs, ego_shape: Shape,
                       input_bounds: tuple[np.ndarray, np.ndarray],
                       dt: float) -> tuple[Halfspaces, IntersampleRows]:
    """:func:`intersample_halfspaces` on checked inputs (the closed forms, no checks).

    ``data`` is what :func:`filters.halfspace_checks._checked_inputs` returns, with at
    least one obstacle, ``T >= 2`` and no polytope support; the wrapper, which checks
    its risk settings once and holds unit normals of its own, builds it directly.
    Non-finite samples are reported (:class:`~filters.errors.InvalidArrayError`).
    """
    with np.errstate(all="ignore"):  # non-finite samples are reported below, by name
        unit, degenerate = _step_normals(data)
        rows_n = _row_normals(unit, True)  # step t: h_{i,t} (end), h_{i,t+1} (start)
        offsets = _offsets(data.points, rows_n, ego_shape, data.shapes, data.risk, data.alpha,
                           data.delta, data.epsilon, data.margins, None)  # (2, k, T)
    _check_finite_result(data.points, unit, offsets)
    halfspaces = Halfspaces(unit, offsets[0], data.risk, data.alpha, data.delta, data.epsilon,
                            degenerate)
    return halfspaces, _rows(rows_n, offsets, True, input_bounds, dt)


def _row_normals(normals: np.ndarray, start: bool) -> np.ndarray:
    """The rows' normals ``(2, k, T, d)`` from the step normals ``(k, T, d)``: the end rows
    :math:`h_{i,t}`, then the start rows :math:`h_{i,t+1}` (zero, so off, at ``t = T``, and
    everywhere without ``start``)."""
    rows_n = np.zeros((2, *normals.shape))
    rows_n[0] = normals
    if start:
        rows_n[1, :, :-1] = normals[:, 1:]
    return rows_n


def _rows(rows_n: np.ndarray, offsets: np.ndarray, start: bool,
          input_bounds: tuple[np.ndarray, np.ndarray], dt: float) -> IntersampleRows:
    """The rows of :class:`IntersampleRows` from their normals (:func:`_row_normals`) and
    offsets ``(2, k, T)``, the step offsets then the start offsets ``b_t(h_{i,t+1})``
    (ignored at ``t = T``, and everywhere without ``start``), each tightened by the bow of
    its own normal."""
    _, k, horizon, dim = rows_n.shape
    margins = arc_margin(rows_n, input_bounds, dt)  # (2, k, T)
    rows_b = offsets - margins
    rows_b[1, :, -1 if start else slice(None)] = DISABLED_OFFSET  # 0 @ y <= 1: off
    return IntersampleRows(rows_n.reshape(2 * k, horizon, dim), rows_b.reshape(2 * k, horizon),
                           margins[0], None)


def _steps(options: dict[str, object], steps: slice) -> dict[str, object]:
    """The options of the given steps: per-step arrays (last axis ``T``) are sliced."""
    return {
        key: value[..., steps] if isinstance(value, np.ndarray) and value.ndim else value
        for key, value in options.items()
    }
