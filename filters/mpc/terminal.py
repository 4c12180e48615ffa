r"""A terminal set for the double integrator: the plan ends able to stop inside the arena.

:func:`stopping_terminal_set` returns ``(G, g)`` for the keyword ``terminal_set`` of
:class:`filters.mpc.MPCSafetyFilter`; with it (and the arena as position rows) a
plan that was feasible stays feasible after a shift (extended by the stopping input
below): recursive feasibility against the static bounds.
"""

from __future__ import annotations

import numpy as np

from filters._validation import finite_scalar
from filters.errors import InvalidParameterError
from filters.mpc.checks import box

__all__ = ["stopping_terminal_set", "stopping_input"]


def stopping_terminal_set(
    dt: float,
    input_bounds: tuple[object, object] | None,
    position_bounds: tuple[object, object] | None,
    stop_time: float = 0.5,
    *,
    dim: int = 2,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Terminal rows :math:`G x_T \le g` of a control-invariant set of the double integrator.

    The state is :math:`x = [p; v]` with :math:`p, v \in \mathbb{R}^d`, sampled with
    period ``dt`` under a constant input per step: :math:`p' = p + \Delta v +
    \tfrac{\Delta^2}{2} u`, :math:`v' = v + \Delta u`. Per axis :math:`j`, with
    :math:`a_j = \min(|u_{\text{low},j}|, u_{\text{high},j})` and :math:`c` = ``stop_time``:

    .. math::

        \text{low}_j \le p_j + c\, v_j \le \text{high}_j, \qquad
        |v_j| \le a_j (\Delta/2 + c),

    and :math:`p_T` lies in the box already (the arena's position rows).

    **Why it is control invariant** (needs :math:`c \ge \Delta/2`). Take
    :math:`u_j = -v_j / (\Delta/2 + c)`, feasible since :math:`|v_j| \le a_j(\Delta/2 + c)`.
    One step gives

    .. math::

        p'_j + c v'_j = p_j + c v_j + \Delta\,(v_j + (\Delta/2 + c) u_j) = p_j + c v_j,
        \qquad v'_j = \frac{c - \Delta/2}{c + \Delta/2}\, v_j,
        \qquad p'_j = p_j + \frac{2c\Delta}{2c + \Delta}\, v_j .

    So :math:`p' + c v'` is unchanged (still in the box), :math:`|v'| \le |v|` (the
    velocity rows hold), and :math:`0 \le 2c\Delta/(2c + \Delta) \le c` puts
    :math:`p'_j` between :math:`p_j` and :math:`p_j + c v_j`, both in the box. Hence a plan
    ending in the set, shifted by one step and extended by this input, is again a plan
    ending in the set: the QP stays feasible against the arena (not against moving
    obstacles, which the set does not know about).

    Parameters
    ----------
    dt
        Sampling period :math:`\Delta > 0`, in s.
    input_bounds
        ``(low, high)`` of the acceleration box (m/s², numbers or shape ``(d,)``), with
        ``low <= 0 <= high``; ``None``: unbounded (no velocity rows).
    position_bounds
        ``(low, high)`` of the arena (m); ``None`` or infinite sides: no position rows.
    stop_time
        :math:`c \ge \Delta/2`, in s: how far ahead (:math:`p + c v`) must stay inside.
    dim
        Position dimension ``d``; the state has ``2 d`` entries.

    Returns
    -------
    G, g
        Shapes ``(r, 2 d)`` and ``(r,)``; rows with an infinite right-hand side are left out.

    Raises
    ------
    InvalidParameterError
        If ``dt <= 0``, ``stop_time < dt / 2``, or the input box does not contain 0.
    """
    dt = finite_scalar("dt", dt, low=0.0, strict=True)
    c = finite_scalar("stop_time", stop_time, low=dt / 2)
    u_low, u_high = box("input_bounds", input_bounds, dim)
    y_low, y_high = box("position_bounds", position_bounds, dim)
    if np.any(u_low > 0.0) or np.any(u_high < 0.0):
        raise InvalidParameterError(f"input_bounds must contain 0 (braking must be possible), "
                                    f"got low={u_low}, high={u_high}")
    accel = np.minimum(np.abs(u_low), u_high)
    eye, rows = np.eye(dim), []
    for j in range(dim):
        reach = np.concatenate([eye[j], c * eye[j]])  # p_j + c v_j
        speed = np.concatenate([np.zeros(dim), eye[j]])  # v_j
        rows += [(row, bound) for row, bound in (
            (reach, y_high[j]), (-reach, -y_low[j]), (speed, accel[j] * (dt / 2 + c)),
            (-speed, accel[j] * (dt / 2 + c))) if np.isfinite(bound)]
    return (np.array([row for row, _ in rows]).reshape(-1, 2 * dim),
            np.array([bound for _, bound in rows], dtype=float))


def stopping_input(x: np.ndarray, dt: float, stop_time: float = 0.5) -> np.ndarray:
    r"""The input :math:`u = -v / (\Delta/2 + c)` under which the stopping set is invariant.

    ``x`` is ``[p, v]`` (or a batch, last axis); returns ``v``'s shape (m/s²).
    """
    x = np.asarray(x, dtype=float)
    return -x[..., x.shape[-1] // 2 :] / (dt / 2 + stop_time)
