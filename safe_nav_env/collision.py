r"""Collisions in continuous time: the exact minimum clearance over one sampling period.

Between two samples (:math:`s \in [0, T_s]`) the ego double integrator with the
constant input :math:`u` follows the arc

.. math::  y(s) = p + s\,v + \tfrac{s^2}{2} u,

and obstacle :math:`i` is taken to move on the chord between its realised positions,
:math:`o_i(s) = o_i + \tfrac{s}{T_s}(o_i' - o_i)` (docs/design.md). Their relative
position is a quadratic in the normalised time :math:`\tau = s / T_s \in [0, 1]`,

.. math::  r(\tau) = d_0 + \tau\,w + \tau^2 c, \qquad
           d_0 = p - o_i,\quad w = T_s v - (o_i' - o_i),\quad c = \tfrac{T_s^2}{2} u,

so the squared distance :math:`f(\tau) = \lVert r(\tau) \rVert^2` is a quartic whose
minimum over :math:`[0, 1]` lies at an end point or at a real root of

.. math::  \tfrac12 f'(\tau) = 2 c\!\cdot\!c\,\tau^3 + 3 w\!\cdot\!c\,\tau^2
           + (w\!\cdot\!w + 2 d_0\!\cdot\!c)\,\tau + d_0\!\cdot\!w .

The real roots come from the closed-form (Cardano / trigonometric) solution of the
cubic; when the cubic term is negligible on :math:`[0, 1]` the quadratic (or linear)
formula is used. Scalar Python arithmetic: for the few obstacles of a scenario it is
several times faster than batched NumPy calls, and the environment step stays cheap.
The clearance is then
:math:`\min_\tau \lVert r(\tau) \rVert - r_A - r_{O,i}`, in m, and a collision is a
clearance :math:`\le 0` (touching counts), as for the sampled clearance.

An inexact root costs only second order in the distance (the minimum is flat), and
every candidate is evaluated exactly, so the result is never below the true minimum by
more than rounding: the tests compare it with a dense sub-sampling of the step.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

#: Relative size below which a leading coefficient counts as zero on [0, 1].
_NEGLIGIBLE = 1e-9


def real_cubic_roots(a3: float, a2: float, a1: float, a0: float) -> tuple[float, ...]:
    """Real roots of :math:`a_3 t^3 + a_2 t^2 + a_1 t + a_0` (degenerate cases included).

    A leading coefficient below ``1e-9`` times the largest one is treated as zero (the
    quadratic, then the linear formula). A quadratic without real roots returns its
    vertex and a cubic with one real root returns it, so the caller always gets the
    stationary candidates. The roots are accurate to rounding except near multiple
    roots, where they are accurate to about the square root of the rounding error, which
    costs nothing for a minimum (see the module docstring).
    """
    scale = max(abs(a3), abs(a2), abs(a1), abs(a0))
    if scale == 0.0:
        return ()
    if abs(a3) <= _NEGLIGIBLE * scale:
        if abs(a2) <= _NEGLIGIBLE * scale:
            return (-a0 / a1,) if a1 != 0.0 else ()
        disc = a1 * a1 - 4.0 * a2 * a0
        if disc < 0.0:
            return (-a1 / (2.0 * a2),)
        q = -0.5 * (a1 + math.copysign(math.sqrt(disc), a1))  # no cancellation
        return (q / a2, a0 / q) if q != 0.0 else (0.0,)
    b, c, d = a2 / a3, a1 / a3, a0 / a3
    shift = b / 3.0  # t = s - b/3: s^3 + p s + q = 0
    p = c - b * shift
    q = (2.0 * shift * shift - c) * shift + d
    half_q, third_p = 0.5 * q, p / 3.0
    disc = half_q * half_q + third_p * third_p * third_p
    if disc >= 0.0:  # one real root (Cardano, the larger cube root first: no cancellation)
        root = math.sqrt(disc)
        u = -half_q - root if half_q > 0.0 else -half_q + root
        u = math.copysign(abs(u) ** (1.0 / 3.0), u)
        s = u - third_p / u if u != 0.0 else 0.0
        return (s - shift,)
    m = 2.0 * math.sqrt(-third_p)  # three real roots (trigonometric form)
    theta = math.acos(max(-1.0, min(1.0, 3.0 * q / (p * m)))) / 3.0
    return tuple(m * math.cos(theta - 2.0 * math.pi * k / 3.0) - shift for k in range(3))


def swept_clearance(ego_state: Sequence[float], ego_input: Sequence[float], dt: float,
                    obstacles_before: Sequence[Sequence[float]],
                    obstacles_after: Sequence[Sequence[float]],
                    radii_sum: Sequence[float]) -> list[float]:
    r"""Minimum clearance between the ego arc and each obstacle chord over one step.

    Parameters
    ----------
    ego_state
        ``[p_x, p_y, v_x, v_y]`` at the start of the step, in m and m/s.
    ego_input
        The acceleration :math:`u = (u_x, u_y)` held over the step, in m/s².
    dt
        The sampling time :math:`T_s`, in s.
    obstacles_before, obstacles_after
        Obstacle positions ``(x, y)`` at the start and at the end of the step, in m
        (``n`` pairs each; lists are fastest).
    radii_sum
        :math:`r_A + r_{O,i}` per obstacle, in m.

    Returns
    -------
    list of float
        :math:`\min_{s \in [0, T_s]} \lVert y(s) - o_i(s) \rVert - r_A - r_{O,i}` per
        obstacle, in m; ``<= 0`` is a collision somewhere in the step. Never larger
        than the clearance at either end of the step.
    """
    px, py, vx, vy = ego_state
    half_dt2 = 0.5 * dt * dt
    cx, cy = half_dt2 * ego_input[0], half_dt2 * ego_input[1]
    a3 = 2.0 * (cx * cx + cy * cy)
    out = []
    for (ox, oy), (qx, qy), radius in zip(obstacles_before, obstacles_after, radii_sum,
                                          strict=True):
        dx, dy = px - ox, py - oy
        wx, wy = dt * vx - (qx - ox), dt * vy - (qy - oy)
        ex, ey = dx + wx + cx, dy + wy + cy
        best = min(dx * dx + dy * dy, ex * ex + ey * ey)  # the two ends
        roots = real_cubic_roots(
            a3, 3.0 * (wx * cx + wy * cy), wx * wx + wy * wy + 2.0 * (dx * cx + dy * cy),
            dx * wx + dy * wy,
        )
        for t in roots:
            if 0.0 < t < 1.0:
                tt = t * t
                ex, ey = dx + t * wx + tt * cx, dy + t * wy + tt * cy
                best = min(best, ex * ex + ey * ey)
        out.append(math.sqrt(best) - radius)
    return out
