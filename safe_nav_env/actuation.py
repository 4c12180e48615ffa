"""Ego actuation the safety filter does not model: a first-order actuator lag and linear drag.

The filter plans with the double integrator ``x_{t+1} = A x_t + B u_t``
(:func:`safe_nav_env.dynamics.double_integrator`): the commanded acceleration ``u_t``
acts at once and nothing else pushes the ego. A real vehicle's actuators respond with
a delay and it loses speed to friction. :class:`Actuation` maps the (clipped) command
``u_t`` to the acceleration the ego really gets over step ``t``:

.. math::

    \\bar a_t = \\bar a_{t-1} + \\beta\\,(u_t - \\bar a_{t-1}), \\qquad
    \\beta = 1 - e^{-T_s/\\tau}, \\qquad \\bar a_{-1} = 0,

    a_t = \\bar a_t - c\\,v_t,

with ``τ`` the actuator time constant in s (``τ = 0``: ``β = 1``, no lag), ``c`` the
linear drag coefficient in 1/s and ``v_t`` the ego velocity at the start of the step
(m/s). ``a_t`` (m/s²) is held over the step, so the ego still moves on the
constant-acceleration arc ``p + s v + s²/2 a_t`` that the environment's continuous-time
collision check (:func:`safe_nav_env.collision.swept_clearance`) assumes; it may exceed
the input bound by the drag term (drag is not an actuator). The lag is the exact
discretisation of ``τ ȧ = u - a`` sampled once per step (the filtered command is held
over the step, like the command itself).

The reward's control cost then charges ``a_t``. Both default to 0 (off): the environment
is then the paper's double integrator, bit for bit. Set them with
``gym.make(id, actuator_lag=τ, drag=c)``.
"""

from __future__ import annotations

import math

from safe_nav_env.options import _option

__all__ = ["Actuation", "resolve_actuation"]


class Actuation:
    """First-order actuator lag and linear drag acting on the ego's commanded acceleration.

    Parameters
    ----------
    actuator_lag
        Time constant ``τ`` of the actuators, in s, ``>= 0`` (0: none).
    drag
        Linear drag coefficient ``c``, in 1/s, ``>= 0`` (0: none).
    dt
        Sampling time ``T_s``, in s, ``> 0``.

    Raises
    ------
    ConfigError
        If a value is not a finite number in its range.
    """

    def __init__(self, actuator_lag: float, drag: float, dt: float) -> None:
        self.actuator_lag = _option("actuator_lag", actuator_lag)
        self.drag = _option("drag", drag)
        self.dt = _option("dt", dt, strict=True)
        self.gain = 1.0 - math.exp(-self.dt / self.actuator_lag) if self.actuator_lag else 1.0
        self.reset()

    def __repr__(self) -> str:
        return f"Actuation(actuator_lag={self.actuator_lag!r}, drag={self.drag!r}, dt={self.dt!r})"

    def reset(self) -> None:
        """Forget the lagged acceleration (an episode starts with ``ā_{-1} = 0``)."""
        self.lagged = (0.0, 0.0)

    def apply(
        self, ux: float, uy: float, vx: float, vy: float, *, first: bool = False
    ) -> tuple[float, float]:
        """The acceleration ``a_t`` (m/s²) held over the step, given the command and velocity.

        Parameters
        ----------
        ux, uy
            The commanded acceleration ``u_t`` (clipped to the input bounds), m/s².
        vx, vy
            The ego velocity at the start of the step, m/s.
        first
            The episode's first step: :meth:`reset` first (``ā_{-1} = 0``).
        """
        if first:
            self.reset()
        beta = self.gain
        ax = self.lagged[0] + beta * (ux - self.lagged[0])
        ay = self.lagged[1] + beta * (uy - self.lagged[1])
        self.lagged = (ax, ay)
        return ax - self.drag * vx, ay - self.drag * vy


def resolve_actuation(actuator_lag: float, drag: float, dt: float) -> Actuation | None:
    """An :class:`Actuation`, or ``None`` when both effects are off (validated either way)."""
    actuation = Actuation(actuator_lag, drag, dt)
    return actuation if actuation.actuator_lag or actuation.drag else None
