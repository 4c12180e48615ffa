r"""The condensed filter QP in whitened coordinates: an identity Hessian and one row bank.

The states are eliminated with the prediction matrices of the problem
(:attr:`~filters.mpc.MPCProblem.rollout`), :math:`X = \Phi x_0 + \Gamma u`, so the
variables are the inputs :math:`u \in \mathbb{R}^{T m}`, and the cost (8) is, up to a
constant,

.. math::

    \tfrac12 u^\top H u + f^\top u, \qquad
    H = 2 (\bar R + \Gamma^\top \bar Q \Gamma), \quad
    f = -2 \bar R u^r + 2 \Gamma^\top \bar Q (\Phi x_0 - X^r).

**Whitening.** With :math:`H = U U^\top`, :math:`U` *upper* triangular (a Cholesky
factor of :math:`H` with the variable order reversed), the variables
:math:`z = U^\top u` turn the cost into :math:`\tfrac12 \|z\|^2 + f_z^\top z` with
:math:`f_z = U^{-1} f`, and every row :math:`a^\top u` into :math:`a^\top U^{-\top} z`.
:math:`U^{-\top}` is lower triangular, so :math:`u_t` depends on :math:`z_0..z_t` only and
a row of step :math:`t` still reads only the first :math:`t` blocks (the roll-out stays
causal). An identity Hessian is what makes a dual active-set solver cheap here: DAQP
then uses the rows as they are instead of transforming each one by the Hessian's
factor (:math:`O(\text{rows}\,T m)` instead of :math:`O(\text{rows}\,(T m)^2)` per step).

**The row bank**, in original units (m/s² for inputs, m for positions), in this order:

* ``fixed`` rows, the same every step (only their bounds move with :math:`x_0`):
  the input box :math:`u_\text{low} \le u_t \le u_\text{high}` (axes with a finite side),
  the arena :math:`y_\text{low} \le C x_t \le y_\text{high}` (one two-sided row per step
  and finite axis, step-major), the terminal rows :math:`G x_T \le g`, the speed
  polygon :math:`S x_t \le s` (step-major; :attr:`~filters.mpc.MPCProblem.speed_rows`);
* ``halfspace`` rows :math:`a_{i,t}^\top C x_t \le b_{i,t}`, step-major (row
  ``(t - 1) K + i``), written per step from the normals: :math:`a_{i,t}^\top W_t z` with
  :math:`W_t = C \Gamma_t U^{-\top}` precomputed, shape ``(T, d, T m)``.

:meth:`CondensedQP.excess` evaluates *every* row at a point with one matrix-vector
product (inputs, positions and terminal values together) and a few vectorised
operations: the check that makes lazy (screened) rows exact, see
:mod:`filters.mpc.backends.daqp`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from filters.mpc._linalg import matvec_operator
from filters.mpc.problem import MPCProblem

__all__ = ["CondensedQP", "StepRows"]

#: dot products over the last axis, broadcast (np.vecdot on NumPy >= 2).
vecdot = getattr(np, "vecdot", None) or (lambda a, b: np.einsum("...d,...d->...", a, b))


@dataclass
class StepRows:
    """One step's numbers of the whitened QP (see :meth:`CondensedQP.step_rows`).

    Attributes
    ----------
    f
        :math:`f_z`, shape ``(T m,)``.
    upper, lower
        Bounds of the fixed rows, shifted by the current state, ``(n_fixed,)``.
    normals
        Halfspace normals, step-major, ``(T, K, d)``.
    hs_upper
        Upper bounds of the halfspace rows, shifted by the current state, ``(T, K)``.
    positions0
        :math:`C \\Phi_t x_0`, ``(T, d)``: the positions if every input were zero.
    """

    f: np.ndarray
    upper: np.ndarray
    lower: np.ndarray
    normals: np.ndarray
    hs_upper: np.ndarray
    positions0: np.ndarray


class CondensedQP:
    """The whitened condensed QP of one :class:`~filters.mpc.MPCProblem` (module docstring).

    Parameters
    ----------
    problem
        The problem to condense.

    Attributes
    ----------
    hessian
        :math:`H`, ``(T m, T m)``.
    u_of_z
        :math:`U^{-\\top}`, ``(T m, T m)``, lower triangular: ``u = u_of_z @ z``.
    z_of_u
        :math:`U^\\top`, ``(T m, T m)``: ``z = z_of_u @ u``.
    fixed_rows
        The fixed rows in :math:`z`, ``(n_fixed, T m)``.
    n_fixed
        Number of fixed rows.
    row_slices
        ``(inputs, arena, terminal, speed)``: where each kind of fixed row sits (the input
        rows step-major over the axes with a finite side, the arena rows step-major over
        the arena's finite axes, each two-sided; the speed rows step-major, never soft).
    fixed_soft
        Which fixed rows are soft in this problem (the arena and terminal rows when
        ``"bounds"`` is in its ``soft_rows``).
    position_maps
        :math:`W_t`, ``(T, d, T m)``.
    cost_map
        :math:`F` with :math:`f_z = F [x_0; X^r; u^r]`, ``(T m, n + T n + T m)``, dense.
    fixed_upper, fixed_lower
        The fixed rows' bounds before the shift by the current state, ``(n_fixed,)``.
    input_axes, arena_axes
        The input and position axes with a finite side: those of the input and arena
        rows.
    """

    def __init__(self, problem: MPCProblem) -> None:
        self.problem = p = problem
        T, n, m, d, K = p.horizon, p.n, p.m, p.d, p.n_obstacles
        nu = T * m
        phi, gamma = p.rollout
        R_bar, Q_bar, half_hessian = p.condensed_weights
        hessian = 2.0 * half_hessian
        reverse = np.arange(nu)[::-1]
        lower = np.linalg.cholesky(hessian[np.ix_(reverse, reverse)])
        upper = np.ascontiguousarray(lower[np.ix_(reverse, reverse)])  # H = U U'
        # exact zeros above the diagonal
        u_of_z = np.tril(scipy.linalg.solve_triangular(upper, np.eye(nu), lower=False).T)
        self.hessian = hessian
        self.z_of_u = np.ascontiguousarray(upper.T)
        self.u_of_z = np.ascontiguousarray(u_of_z)
        # f = F [x0; X^r; u^r]; f_z = U^{-1} f = u_of_z' f.
        linear = np.hstack([2.0 * gamma.T @ Q_bar @ phi, -2.0 * gamma.T @ Q_bar, -2.0 * R_bar])
        self.cost_map = np.ascontiguousarray(u_of_z.T @ linear)
        self._F = matvec_operator(self.cost_map)

        C_phi = np.einsum("dn,tnk->tdk", p.C, phi.reshape(T, n, n))  # (T, d, n)
        C_gamma = np.einsum("dn,tnk->tdk", p.C, gamma.reshape(T, n, nu))  # (T, d, nu)
        self.position_maps = W = np.ascontiguousarray(C_gamma @ u_of_z)  # (T, d, nu)

        u_low, u_high = p.input_bounds
        y_low, y_high = p.position_bounds
        input_axes = np.flatnonzero(np.isfinite(u_low) | np.isfinite(u_high))
        arena_axes = np.flatnonzero(np.isfinite(y_low) | np.isfinite(y_high))
        G, g = p.terminal_rows
        S, s = p.speed_rows
        speed_map = np.einsum("jn,tnk->tjk", S, gamma.reshape(T, n, nu)).reshape(-1, nu)
        input_index = (np.arange(T)[:, None] * m + input_axes[None]).reshape(-1)
        rows = [u_of_z[input_index], W[:, arena_axes].reshape(-1, nu),
                G @ gamma[(T - 1) * n :] @ u_of_z, speed_map @ u_of_z]
        self.fixed_rows = np.ascontiguousarray(np.vstack(rows))
        self.fixed_upper = np.concatenate(
            [np.tile(u_high[input_axes], T), np.tile(y_high[arena_axes], T), g, np.tile(s, T)])
        self.fixed_lower = np.concatenate(
            [np.tile(u_low[input_axes], T), np.tile(y_low[arena_axes], T),
             np.full(len(g) + T * len(s), -np.inf)])
        self.input_axes, self.arena_axes = input_axes, arena_axes
        self._input_index = input_index
        n_inputs, n_arena = len(input_index), T * len(arena_axes)
        n_bounds = n_inputs + n_arena + len(g)  # the rows "bounds" softens end here
        self.n_fixed = n_bounds + T * len(s)
        self.fixed_soft = np.zeros(self.n_fixed, dtype=bool)
        if p.soft_bounds:
            self.fixed_soft[n_inputs:n_bounds] = True
        self.row_slices = (slice(0, n_inputs), slice(n_inputs, n_inputs + n_arena),
                           slice(n_inputs + n_arena, n_bounds), slice(n_bounds, self.n_fixed))
        # Shift of the fixed bounds by x0: inputs none, arena C Phi_t x0, terminal G Phi_T x0,
        # speed S Phi_t x0.
        speed_shift = np.einsum("jn,tnk->tjk", S, phi.reshape(T, n, n)).reshape(-1, n)
        shift = np.vstack([np.zeros((n_inputs, n)), C_phi[:, arena_axes].reshape(-1, n),
                           G @ phi[(T - 1) * n :], speed_shift])
        # One product S x0: the shift of the fixed rows, then the positions C Phi_t x0.
        self._S = matvec_operator(np.vstack([shift, C_phi.reshape(T * d, n)]))
        # One product E z: u, the positions C Gamma u, the terminal and the speed values.
        self._E = matvec_operator(np.vstack([u_of_z, W.reshape(T * d, nu), rows[2], rows[3]]))
        self._hi, self._lo = np.isfinite(y_high[arena_axes]), np.isfinite(y_low[arena_axes])
        self.T, self.n, self.m, self.d, self.K, self.nu = T, n, m, d, K, nu
        self._v = np.empty(n + T * n + nu)

    # ------------------------------------------------------------------ per step
    def step_rows(self, x0: np.ndarray, ref_states: np.ndarray, ref_inputs: np.ndarray,
                  normals: np.ndarray, offsets: np.ndarray) -> StepRows:
        """The step's linear cost and bounds; ``normals`` ``(K, T, d)``, ``offsets`` ``(K, T)``."""
        v = np.concatenate((x0, ref_states.reshape(-1), ref_inputs.reshape(-1)), out=self._v)
        shift, n_fixed = self._S @ x0, self.n_fixed
        positions0 = shift[n_fixed:].reshape(self.T, self.d)
        fixed_shift = shift[:n_fixed]
        return StepRows(self._F @ v, self.fixed_upper - fixed_shift,
                        self.fixed_lower - fixed_shift, normals.transpose(1, 0, 2),
                        (offsets - vecdot(normals, positions0)).T, positions0)

    def halfspace_rows(self, rows: StepRows, steps: np.ndarray, obstacles: np.ndarray,
                       out: np.ndarray | None = None) -> np.ndarray:
        """Rows :math:`a_{i,t}^\\top W_t` of the given (step, obstacle) pairs, ``(r, T m)``."""
        a = rows.normals[steps, obstacles]  # (r, d)
        W = self.position_maps[steps]  # (r, d, nu)
        return np.matmul(a[:, None, :], W, out=None if out is None else out[:, None, :])[:, 0]

    def excess(self, z: np.ndarray, rows: StepRows) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Excess ``lhs - rhs`` (<= 0: the row holds) of every row at ``z``.

        Returns ``(fixed, halfspace, fixed_values)``: ``fixed`` ``(n_fixed,)`` (a two-sided
        row's excess is the larger of its two sides'), ``halfspace`` ``(T, K)``, and the
        fixed rows' values (for :meth:`bound_slack`).
        """
        # One product: the inputs, C Gamma_t u, then the terminal and speed rows' values.
        product, nu, T, d = self._E @ z, self.nu, self.T, self.d
        positions = product[nu : nu + T * d].reshape(T, d)
        values = np.concatenate((product[:nu][self._input_index],
                                 positions[:, self.arena_axes].reshape(-1), product[nu + T * d :]))
        fixed = np.maximum(values - rows.upper, rows.lower - values)
        halfspace = vecdot(rows.normals, positions[:, None, :]) - rows.hs_upper
        return fixed, halfspace, values

    def bound_slack(self, values: np.ndarray, rows: StepRows) -> np.ndarray:
        """Violations ``max(0, excess)`` of the upper arena faces (by step, then axis), the
        lower faces, then the terminal rows: the filter's order of the bound rows."""
        _, arena, terminal, _ = self.row_slices
        T = self.T
        up = (values[arena] - rows.upper[arena]).reshape(T, -1)[:, self._hi]
        low = (rows.lower[arena] - values[arena]).reshape(T, -1)[:, self._lo]
        term = values[terminal] - rows.upper[terminal]
        return np.maximum(np.concatenate((up.reshape(-1), low.reshape(-1), term)), 0.0)
