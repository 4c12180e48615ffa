r"""The MPC safety-filter problem: model, horizon, objective, bounds, terminal set, soft rows.

:class:`MPCProblem` is a frozen, validated value; the back ends
(:mod:`filters.mpc.backends`) build their QP from it once, and
:class:`filters.mpc.MPCSafetyFilter` uses its precomputed roll-out and
unconstrained-optimum gain. Every QP it describes has the form

.. math::

    \min_{u, x} \quad & \sum_{t=0}^{T-1} (u_t - u^r_t)^\top R_t (u_t - u^r_t)
        + \sum_{t=1}^{T} (x_t - x^r_t)^\top Q_t (x_t - x^r_t)
        \ [+ \rho \textstyle\sum s] \\
    \text{s.t.} \quad & x_{t+1} = A x_t + B u_t, \quad
        u_\text{low} \le u_t \le u_\text{high}, \\
        & y_\text{low} \le C x_t \ [+ \sigma] ,\quad C x_t \ [- \sigma] \le y_\text{high},
          \quad t = 1..T \quad\text{(the arena)}, \\
        & G x_T \ [- \tau] \le g \quad\text{(terminal set)}, \qquad
          a_{i,t}^\top C x_t \ [- s_{i,t}] \le b_{i,t}  \quad\text{(halfspaces)}, \\
        & h_j^\top v_t \le v_\max \cos(\pi / M), \quad j = 1..M,\ t = 1..T
          \quad\text{(speed limit, always hard)},

with the bracketed nonnegative slacks present for the rows named in ``soft_rows``
(an exact L1 penalty: with :math:`\rho` above the largest multiplier the soft QP has
the hard one's solution whenever that is feasible). The objectives:

* ``"trajectory"`` (the paper's Problem 2, objective (8)): :math:`R_t = R`,
  :math:`Q_t = Q` for :math:`t < T`, :math:`Q_T` = ``Q_terminal``;
* ``"first_input"`` (the predictive safety filter of Wabersich & Zeilinger):
  :math:`R_0 = R`, :math:`R_t = w R` for :math:`t \ge 1` with ``w =
  later_input_weight > 0`` (the QP stays strictly convex), :math:`Q_t = 0`.

**Speed limit** (``max_speed`` finite; the state is :math:`x = [p; v]`, ``n = 2 d``):
the disc :math:`\|v_t\|_2 \le v_\max` is replaced by the regular ``M``-gon
(``speed_sides``) inscribed in it, with vertices on the axes: unit normals
:math:`h_j = (\cos\theta_j, \sin\theta_j)`, :math:`\theta_j = (2j - 1)\pi / M`, at
distance :math:`v_\max \cos(\pi/M)` from the origin (for ``d = 1``: :math:`|v_t| \le
v_\max`). Inside the disc, so a plan that keeps the rows keeps the speed limit; it
gives up at most a share :math:`1 - \cos(\pi/M)` of the speed (7.6 % at ``M = 8``)
between two vertices.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg

from filters._validation import finite_array, finite_scalar, scalar_in_range
from filters.constants import SPEED_SIDES
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.mpc.checks import box, integer, weight

__all__ = ["OBJECTIVES", "SOFT_ROWS", "MPCProblem", "speed_polygon"]

#: The objectives :class:`MPCProblem` accepts.
OBJECTIVES = ("trajectory", "first_input")
#: Row groups that can be softened: ``"halfspaces"``, and ``"bounds"`` (arena + terminal).
SOFT_ROWS = frozenset({"halfspaces", "bounds"})


def speed_polygon(max_speed: float, sides: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
    r"""Rows ``(H, h)``, :math:`H v \le h`, of the ``sides``-gon inscribed in the speed disc.

    Parameters
    ----------
    max_speed
        :math:`v_\max > 0`, in m/s (finite).
    sides
        :math:`M \ge 3` for ``dim = 2`` (ignored for ``dim = 1``: the rows are ``±v <= v_max``).
    dim
        Velocity dimension ``d``, 1 or 2.

    Returns
    -------
    H, h
        Shapes ``(M, d)`` and ``(M,)``: unit normals at angles :math:`(2j - 1)\pi/M` and
        offsets :math:`v_\max \cos(\pi/M)` (vertices at radius :math:`v_\max`, on the axes).

    Raises
    ------
    InvalidParameterError
        If ``dim`` is not 1 or 2.
    """
    if dim == 1:
        return np.array([[1.0], [-1.0]]), np.full(2, float(max_speed))
    if dim != 2:
        raise InvalidParameterError(f"max_speed: a speed polygon needs 1 or 2 velocity axes, "
                                    f"got {dim}")
    angles = (2.0 * np.arange(1, sides + 1) - 1.0) * np.pi / sides
    H = np.column_stack([np.cos(angles), np.sin(angles)])
    return H, np.full(sides, max_speed * np.cos(np.pi / sides))


@dataclass(frozen=True, eq=False)
class MPCProblem:
    r"""One safety-filter QP structure, validated on construction.

    Parameters
    ----------
    A, B, C
        Dynamics :math:`x_{t+1} = A x_t + B u_t` and position :math:`y = C x`, shapes
        ``(n, n)``, ``(n, m)``, ``(d, n)``.
    horizon
        Number of steps ``T >= 1``.
    R
        Symmetric positive definite input weight ``(m, m)``.
    Q, Q_terminal
        Symmetric PSD state weights ``(n, n)`` for steps ``1..T-1`` and ``T``; required
        by ``objective="trajectory"``, ignored (may be ``None``) by ``"first_input"``.
    objective
        ``"trajectory"`` or ``"first_input"`` (see the module docstring).
    later_input_weight
        ``w > 0``: weight of :math:`u_1..u_{T-1}` relative to ``R`` in ``"first_input"``.
    input_bounds, position_bounds
        ``(low, high)`` boxes (numbers or arrays of shape ``(m,)`` / ``(d,)``, ±inf
        for a free side), or ``None`` (unbounded). Units: m/s² and m.
    terminal_set
        ``(G, g)``, shapes ``(r, n)`` and ``(r,)``: the plan ends in
        :math:`G x_T \le g`; ``None`` for none (see :mod:`filters.mpc.terminal`).
    n_obstacles
        Halfspace rows per step the QP holds (calls may pass fewer).
    soft_rows
        Which rows carry slacks: a subset of ``{"halfspaces", "bounds"}``.
    slack_penalty
        :math:`\rho > 0`, cost per m of violation of a soft row.
    max_speed
        :math:`v_\max > 0` in m/s, kept on every step ``t = 1..T`` as the inscribed
        polygon's rows (module docstring), hard in every QP; ``inf`` (default): none.
        Needs a state ``[position; velocity]`` (``n = 2 d``, ``d`` 1 or 2).
    speed_sides
        :math:`M \ge 3`, sides of the polygon (default 8).

    Raises
    ------
    InvalidArrayError, InvalidParameterError, InvalidTypeError
        On a wrong shape or non-finite entry, a weight that is not symmetric/(semi)definite,
        crossed bounds, an unknown objective or soft row, a non-positive penalty, a
        non-positive ``max_speed`` or one without a ``[position; velocity]`` state.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    horizon: int
    R: np.ndarray
    Q: np.ndarray | None = None
    Q_terminal: np.ndarray | None = None
    objective: str = "trajectory"
    later_input_weight: float = 1e-2
    input_bounds: tuple[np.ndarray, np.ndarray] | None = None
    position_bounds: tuple[np.ndarray, np.ndarray] | None = None
    terminal_set: tuple[np.ndarray, np.ndarray] | None = None
    n_obstacles: int = 0
    soft_rows: frozenset[str] = frozenset()
    slack_penalty: float = 1e6
    max_speed: float = np.inf
    speed_sides: int = SPEED_SIDES

    def __post_init__(self) -> None:
        put = object.__setattr__  # frozen: normalise the fields once, here
        A = finite_array("A", self.A, ndim=2)
        n = A.shape[0]
        A = finite_array("A", A, (n, n))
        B = finite_array("B", self.B, (n, None))
        C = finite_array("C", self.C, (None, n))
        m, d = B.shape[1], C.shape[0]
        if n == 0 or m == 0 or d == 0:
            raise InvalidArrayError(
                f"A, B and C must be non-empty, got shapes {A.shape}, {B.shape}, {C.shape}")
        if self.objective not in OBJECTIVES:
            raise InvalidParameterError(
                f"objective must be one of {OBJECTIVES}, got {self.objective!r}")
        trajectory = self.objective == "trajectory"
        for name in ("Q", "Q_terminal") if trajectory else ():
            if getattr(self, name) is None:
                raise InvalidParameterError(
                    f'{name} is required by objective="trajectory" (or pass '
                    'objective="first_input", which has no state terms)')
        terminal = self.terminal_set
        if terminal is not None:
            if isinstance(terminal, (str, bytes)) or not hasattr(terminal, "__len__") or len(
                    terminal) != 2:
                raise InvalidTypeError(f"terminal_set must be None or a pair (G, g), got "
                                       f"{terminal!r}")
            G = finite_array("terminal_set G", terminal[0], (None, n))
            terminal = (G, finite_array("terminal_set g", terminal[1], (G.shape[0],)))
        if not isinstance(self.soft_rows, (set, frozenset, tuple, list)) or not set(
                self.soft_rows) <= SOFT_ROWS:
            raise InvalidParameterError(
                f"soft_rows must be a subset of {sorted(SOFT_ROWS)}, got {self.soft_rows!r}")
        for name, value in (
            ("A", A), ("B", B), ("C", C), ("terminal_set", terminal),
            ("horizon", integer("horizon", self.horizon, low=1)),
            ("n_obstacles", integer("n_obstacles", self.n_obstacles, low=0)),
            ("R", weight("R", self.R, m, definite=True)),
            ("Q", weight("Q", self.Q, n, definite=False) if trajectory else None),
            ("Q_terminal", weight("Q_terminal", self.Q_terminal, n, definite=False)
             if trajectory else None),
            ("later_input_weight", finite_scalar("later_input_weight", self.later_input_weight,
                                                 low=0.0, strict=True)),
            ("input_bounds", box("input_bounds", self.input_bounds, m)),
            ("position_bounds", box("position_bounds", self.position_bounds, d)),
            ("soft_rows", frozenset(self.soft_rows)),
            ("slack_penalty", finite_scalar("slack_penalty", self.slack_penalty, low=0.0,
                                            strict=True)),
            ("max_speed", scalar_in_range("max_speed", self.max_speed, low=0.0,
                                          low_inclusive=False, high=np.inf)),
            ("speed_sides", integer("speed_sides", self.speed_sides, low=3)),
        ):
            put(self, name, value)
        if np.isfinite(self.max_speed) and (n != 2 * d or d > 2):
            raise InvalidParameterError(
                f"max_speed needs a state [position; velocity] with 1 or 2 axes (n = 2 d), "
                f"got n = {n}, d = {d}; pass max_speed=inf")
        for array in (self.A, self.B, self.C, self.R, self.Q, self.Q_terminal,
                      *self.input_bounds, *self.position_bounds, *(self.terminal_set or ())):
            if array is not None:
                array.setflags(write=False)

    def with_soft_rows(self, soft_rows: frozenset[str] | set[str]) -> MPCProblem:
        """The same problem with other rows softened."""
        return dataclasses.replace(self, soft_rows=frozenset(soft_rows))

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """State dimension."""
        return self.A.shape[0]

    @property
    def m(self) -> int:
        """Input dimension."""
        return self.B.shape[1]

    @property
    def d(self) -> int:
        """Position dimension."""
        return self.C.shape[0]

    @property
    def soft_halfspaces(self) -> bool:
        """Whether the halfspace rows carry slacks."""
        return "halfspaces" in self.soft_rows

    @property
    def soft_bounds(self) -> bool:
        """Whether the arena and terminal rows carry slacks."""
        return "bounds" in self.soft_rows

    @property
    def terminal_rows(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G, g)`` of the terminal set, or empty ``(0, n)`` and ``(0,)`` rows without one."""
        return self.terminal_set or (np.zeros((0, self.n)), np.zeros(0))

    @cached_property
    def speed_rows(self) -> tuple[np.ndarray, np.ndarray]:
        r"""``(S, s)``: the speed rows :math:`S x_t \le s` of every step, shapes ``(M, n)``
        and ``(M,)``, :math:`S = [0\ H]` (:func:`speed_polygon`); ``M = 0`` without a limit."""
        n, d = self.n, self.d
        if not np.isfinite(self.max_speed):
            return np.zeros((0, n)), np.zeros(0)
        H, h = speed_polygon(self.max_speed, self.speed_sides, d)
        S = np.zeros((H.shape[0], n))
        S[:, d:] = H
        return S, h

    # ------------------------------------------------------------------ weights
    @cached_property
    def input_weights(self) -> np.ndarray:
        """:math:`R_t`, ``t = 0..T-1``, shape ``(T, m, m)``."""
        T = self.horizon
        weights = np.broadcast_to(self.R, (T, self.m, self.m)).copy()
        if self.objective == "first_input":
            weights[1:] *= self.later_input_weight
        return weights

    @cached_property
    def state_weights(self) -> np.ndarray:
        """:math:`Q_t`, ``t = 1..T``, shape ``(T, n, n)`` (zeros for ``"first_input"``)."""
        T, n = self.horizon, self.n
        if self.objective == "first_input":
            return np.zeros((T, n, n))
        return np.concatenate([np.broadcast_to(self.Q, (T - 1, n, n)), self.Q_terminal[None]])

    @cached_property
    def has_state_cost(self) -> bool:
        """Whether some :math:`Q_t` is nonzero."""
        return bool(np.any(self.state_weights))

    # ------------------------------------------------------------------ condensed maps
    @cached_property
    def rollout(self) -> tuple[np.ndarray, np.ndarray]:
        r"""``(Phi, Gamma)`` with :math:`[x_1; \dots; x_T] = \Phi x_0 + \Gamma u`.

        Shapes ``(T n, n)`` and ``(T n, T m)``.
        """
        T, n, m = self.horizon, self.n, self.m
        powers = [np.eye(n)]
        for _ in range(T):
            powers.append(self.A @ powers[-1])
        phi = np.concatenate(powers[1:])
        gamma = np.zeros((T * n, T * m))
        for t in range(1, T + 1):
            for j in range(t):
                gamma[(t - 1) * n : t * n, j * m : (j + 1) * m] = powers[t - 1 - j] @ self.B
        return phi, gamma

    @cached_property
    def gain(self) -> np.ndarray:
        r"""Gain of the unconstrained minimiser, shape ``(T m, T n)``.

        With the states eliminated the cost is :math:`\|u - u^r\|^2_{\bar R} +
        \|\Phi x_0 + \Gamma u - x^r\|^2_{\bar Q}`, strictly convex (every :math:`R_t` is
        positive definite), minimised by

        .. math:: u^\circ = u^r + K (x^r - \Phi x_0 - \Gamma u^r), \qquad
            K = (\bar R + \Gamma^\top \bar Q \Gamma)^{-1} \Gamma^\top \bar Q.

        For ``"first_input"`` :math:`\bar Q = 0`, so :math:`K = 0` and :math:`u^\circ = u^r`.
        """
        if not self.has_state_cost:
            return np.zeros((self.horizon * self.m, self.horizon * self.n))
        _, q_block, hessian = self.condensed_weights
        gamma = self.rollout[1]
        return scipy.linalg.solve(hessian, gamma.T @ q_block, assume_a="pos")

    @cached_property
    def condensed_weights(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        r"""``(R_bar, Q_bar, H)``: the block-diagonal :math:`\bar R` ``(T m, T m)`` and
        :math:`\bar Q` ``(T n, T n)``, and :math:`H = \bar R + \Gamma^\top \bar Q \Gamma`
        (symmetrised), the cost's Hessian in the inputs up to the factor 2."""
        gamma = self.rollout[1]
        R_bar = scipy.linalg.block_diag(*self.input_weights)
        Q_bar = scipy.linalg.block_diag(*self.state_weights)
        hessian = R_bar + gamma.T @ Q_bar @ gamma
        return R_bar, Q_bar, 0.5 * (hessian + hessian.T)

    @cached_property
    def check_map(self) -> tuple[np.ndarray, np.ndarray]:
        r"""``(M, r)``: ``M @ [x0; u] - r`` is :math:`[x_0..x_T; C x_1..C x_T]` followed by
        the excess (``lhs - rhs``, <= 0: the row holds) of every bound row, in the back
        ends' order: upper arena faces (by step, then axis), lower faces, terminal rows;
        then the speed rows (by step, then side), which are never soft.
        One product checks a whole plan (small NumPy calls cost microseconds each)."""
        T, n, d = self.horizon, self.n, self.d
        phi, gamma = self.rollout  # [x_0..x_T] = rollout @ [x0; u], then C x_1..C x_T
        rollout = np.block([[np.eye(n), np.zeros((n, T * self.m))], [phi, gamma]])
        evaluation = np.vstack([rollout, np.kron(np.eye(T), self.C) @ rollout[n:]])
        split = (T + 1) * n
        positions = evaluation[split:].reshape(T, d, -1)
        y_low, y_high = self.position_bounds
        hi, lo = np.flatnonzero(np.isfinite(y_high)), np.flatnonzero(np.isfinite(y_low))
        G, g = self.terminal_rows
        columns = evaluation.shape[1]
        S, s = self.speed_rows
        states = evaluation[n:split].reshape(T, n, columns)
        rows = [evaluation, positions[:, hi].reshape(-1, columns),
                -positions[:, lo].reshape(-1, columns), G @ evaluation[T * n : split],
                np.einsum("jn,tnc->tjc", S, states).reshape(-1, columns)]
        offsets = [np.zeros(split + T * d), np.tile(y_high[hi], T), -np.tile(y_low[lo], T), g,
                   np.tile(s, T)]
        return np.vstack(rows), np.concatenate(offsets)

    # ------------------------------------------------------------------ cost
    def cost(self, inputs: np.ndarray, states: np.ndarray, ref_states: np.ndarray,
             ref_inputs: np.ndarray) -> float:
        """The cost (8) of a trajectory (penalties not included).

        ``inputs`` ``(T, m)``, ``states`` ``(T + 1, n)``, ``ref_states`` ``(T, n)`` (steps
        1..T), ``ref_inputs`` ``(T, m)``.
        """
        du = inputs - ref_inputs
        total = float(np.einsum("ti,tij,tj->", du, self.input_weights, du))
        if self.has_state_cost:
            dx = states[1:] - ref_states
            total += float(np.einsum("ti,tij,tj->", dx, self.state_weights, dx))
        return total
