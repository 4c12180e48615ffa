r"""The filter's fast path for the common step: a hard QP solved by DAQP, two compiled calls.

:meth:`filters.mpc.MPCSafetyFilter.solve` runs :class:`FastHardStep` when the hard QP's
back end is DAQP on the full (not lazy) whitened condensed QP and no row is soft (the
defaults for ``T m <= 40``), and the step's arrays are float64, C-contiguous and of the
right shapes. One step is then

1. :func:`filters.mpc._fast_kernels.prepare_step`: the finiteness checks, the shortcut
   (the unconstrained minimiser, when it meets every row), or the QP's data written in
   place into the DAQP back end's arrays;
2. DAQP (:meth:`filters.mpc.backends.daqp.DAQPBackend.solve_written`);
3. :func:`filters.mpc._fast_kernels.accept_step`: the acceptance check, the roll-out and
   the cost.

These are the general path's formulas (:mod:`filters.mpc.condensed`, the filter's
``_accept``) evaluated in compiled loops instead of NumPy calls: the results agree to
rounding. Everything else goes the general way: a non-finite input (which then raises
its named error), a failed or rejected hard QP (the recovery QP or the paper's
fallback, with the general path's own step data), other back ends, soft rows, lazy rows.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from filters.errors import InvalidParameterError
from filters.mpc.problem import MPCProblem

if TYPE_CHECKING:
    from filters.mpc.backends.daqp import DAQPBackend


def daqp_defaults() -> dict[str, Any]:
    """DAQP's default settings."""
    import daqp

    return daqp.Model().settings

__all__ = ["ACCEPTED", "INFEASIBLE", "NON_FINITE", "QP", "REJECT_CLIP", "REJECT_NON_FINITE",
           "REJECT_VIOLATION", "SHORTCUT", "SOLVED", "FastHardStep", "fast_path_applies"]

#: :meth:`FastHardStep.prepare`'s answers: some input is NaN or infinite (nothing was
#: written), the unconstrained minimiser is the answer, or the QP's data were written.
NON_FINITE, SHORTCUT, QP = -1, 0, 1
#: :meth:`FastHardStep.solve_hard`'s answers when its own solver's answer was accepted,
#: and when that solver found the hard QP infeasible.
SOLVED, INFEASIBLE = 2, 3
#: :meth:`FastHardStep.accept`'s answers: accepted, or why DAQP's answer was rejected.
ACCEPTED, REJECT_NON_FINITE, REJECT_CLIP, REJECT_VIOLATION = 0, 1, 2, 3


def fast_path_applies(problem: MPCProblem, backend: object, *, soft_rows: frozenset = frozenset(),
                      ) -> bool:
    """Whether :class:`FastHardStep` covers ``problem`` solved by ``backend``: a DAQP back end
    on the full whitened QP (not lazy) of ``problem`` with the rows ``soft_rows`` soft
    (none for the hard QP; the halfspace and bound rows for the recovery QP)."""
    if getattr(backend, "name", None) != "daqp" or problem.soft_rows != soft_rows:
        return False
    from filters.mpc.backends.daqp import DAQPBackend  # imported with the back end already

    return type(backend) is DAQPBackend and not backend.lazy and backend.problem is problem


class FastHardStep:
    """Constants and buffers of the fast step of one filter (module docstring).

    Parameters
    ----------
    problem
        The filter's (hard) problem.
    backend
        Its DAQP back end (``lazy=False``); the QP data are written into its
        :attr:`~filters.mpc.backends.daqp.DAQPBackend.row_buffers`.
    recovery
        The recovery QP's DAQP back end (``lazy=False``; its problem is ``problem`` with
        the halfspace, arena and terminal rows soft), or ``None``: the recovery then
        goes the general way.
    gain
        :attr:`MPCProblem.gain`, ``(T m, T n)``.
    disabled_offset, slack_tolerance, clip_tolerance, feasibility_tolerance
        The filter's constants (:mod:`filters.mpc.filter`).
    """

    def __init__(self, problem: MPCProblem, backend: DAQPBackend,
                 recovery: DAQPBackend | None = None, *, gain: np.ndarray,
                 disabled_offset: float, slack_tolerance: float, clip_tolerance: float,
                 feasibility_tolerance: float) -> None:
        if not disabled_offset > 0.0:  # hard_step leaves the unused rows out: never violated
            raise InvalidParameterError(
                f"disabled_offset must be > 0 (an unused row is 0 @ z <= disabled_offset), "
                f"got {disabled_offset!r}")
        from filters.mpc import _fast_kernels  # imports numba: first use only

        self._kernels = _fast_kernels
        self.backend = backend
        self.recovery = recovery
        qp = backend.qp
        T, n, m = problem.horizon, problem.n, problem.m
        self.T, self.n, self.m, self.d, self.K = T, n, m, problem.d, problem.n_obstacles
        G, g = problem.terminal_set if problem.terminal_set is not None else (
            np.zeros((0, n)), np.zeros(0))

        def dense(array: Any) -> np.ndarray:
            return np.ascontiguousarray(array, dtype=np.float64)

        self._model = (dense(problem.A), dense(problem.B), dense(problem.C))
        self._state_cost = bool(problem.has_state_cost)
        self._gain = dense(gain)
        self._cost_map, self._maps = dense(qp.cost_map), dense(qp.position_maps)
        self._u_of_z = dense(qp.u_of_z)
        self._u_box = tuple(dense(b) for b in problem.input_bounds)
        self._y_box = tuple(dense(b) for b in problem.position_bounds)
        self._terminal = (dense(G), dense(g))
        self._axes = (np.ascontiguousarray(qp.input_axes, dtype=np.int64),
                      np.ascontiguousarray(qp.arena_axes, dtype=np.int64))
        self._fixed = (dense(qp.fixed_upper), dense(qp.fixed_lower))
        self._weights = (dense(problem.input_weights), dense(problem.state_weights))
        self._tolerances = (float(disabled_offset), float(slack_tolerance),
                            float(clip_tolerance), float(feasibility_tolerance))
        # per-step buffers (the results' arrays are allocated per step: they are kept)
        self.x_ref = np.empty((T, n))
        self.f = np.empty(T * m)
        self._scratch = np.empty(n + T * n + T * m)
        self.info = np.empty(5)
        #: Solve the hard QP with the compiled solver first (``solve_hard``); DAQP decides
        #: when it finds the QP infeasible or stops. Not when DAQP has settings of the
        #: user's (``solver_settings``): those are DAQP's to apply.
        self.own_solver = backend.settings == daqp_defaults()
        #: Its stopping rule: no row violated by more than this (DAQP's ``primal_tol``;
        #: fixed at construction).
        self.primal_tolerance = float(backend.settings.get("primal_tol", 1e-6))
        qp_rows = backend.row_buffers[0].shape[0]
        # the rows transposed for the compiled solver; the fixed rows are written once
        self._AT = np.zeros((T * m, qp_rows))
        self._AT[:, : qp.n_fixed] = qp.fixed_rows.T
        self._no_AT = np.empty((0, qp_rows))
        self._n_fixed = qp.n_fixed
        self.max_iterations = 10 * (qp_rows + T * m)
        self.z = np.empty(T * m)
        A, B, C = self._model
        qp_A, upper, lower = backend.row_buffers
        disabled, slack_tolerance, clip_tolerance, feasibility_tolerance = self._tolerances
        # hard_step's arguments after the step's own (the same objects every step)
        self._hard_tail = (
            self._state_cost, A, B, C, self._gain, self._cost_map, self._maps, *self._u_box,
            *self._y_box, *self._terminal, *self._axes, *self._fixed, disabled,
            slack_tolerance, *self._weights, self._u_of_z, clip_tolerance,
            feasibility_tolerance, self.primal_tolerance, self.max_iterations, self.x_ref,
            self.f, qp_A, self._AT, upper, lower, self._scratch, self.z, self.info)
        finite = [np.isfinite(b).sum() for b in problem.position_bounds]
        self._n_bounds = T * int(sum(finite)) + G.shape[0]
        self._no_rows = (np.empty((0, T)), np.empty(0))

    def prepare(self, x0: np.ndarray, reference_states: np.ndarray, reference_inputs: np.ndarray,
                normals: np.ndarray, offsets: np.ndarray, shortcut: bool,
                inputs: np.ndarray, states: np.ndarray) -> int:
        """:func:`~filters.mpc._fast_kernels.prepare_step` on checked arrays: ``NON_FINITE``,
        ``SHORTCUT`` (``inputs`` ``(T m,)``, ``states`` and ``info[0]``, the cost, written)
        or ``QP`` (:attr:`f` and the back end's row buffers written)."""
        A, B, C = self._model
        qp_A, upper, lower = self.backend.row_buffers
        disabled, slack_tolerance, _, _ = self._tolerances
        return self._kernels.prepare_step(
            x0, reference_states, reference_inputs, normals, offsets, shortcut,
            self._state_cost, A, B, C, self._gain, self._cost_map, self._maps, *self._u_box,
            *self._y_box, *self._terminal, *self._axes, *self._fixed, disabled,
            slack_tolerance, *self._weights, self.x_ref, inputs, states, self.f, qp_A,
            self._no_AT, upper, lower, self._scratch, self.info, True)

    def solve_hard(self, x0: np.ndarray, reference_states: np.ndarray,
                   reference_inputs: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                   shortcut: bool, inputs: np.ndarray, states: np.ndarray) -> int:
        """:func:`~filters.mpc._fast_kernels.hard_step`: :meth:`prepare`, then the compiled
        solver and :meth:`accept`: ``NON_FINITE``, ``SHORTCUT``, ``SOLVED`` (``inputs``,
        ``states`` and :attr:`info` hold the accepted answer), ``INFEASIBLE`` or ``QP``
        (the solver stopped or its answer was rejected); for DAQP after the last two,
        call :meth:`write_daqp_rows` (with ``k = normals.shape[0]``) first."""
        return self._kernels.hard_step(x0, reference_states, reference_inputs, normals,
                                       offsets, shortcut, inputs, states, *self._hard_tail)

    def write_daqp_rows(self, k: int) -> None:
        """Write the step's halfspace rows into DAQP's row matrix (after :meth:`solve_hard`
        of a step with ``k`` halfspace rows per step, which writes them transposed and
        compactly only; the bounds and ``f`` are written): step ``t``'s rows into DAQP's
        rows ``n_fixed + t K + i``, ``i < k``, and zeros into its ``K - k`` unused ones."""
        qp_A = self.backend.row_buffers[0]
        n_fixed, T, K, nu = self._n_fixed, self.T, self.K, self.T * self.m
        rows = qp_A[n_fixed:].reshape(T, K, nu)  # a view: written in place
        rows[:, :k] = self._AT[:, n_fixed : n_fixed + T * k].T.reshape(T, k, nu)
        rows[:, k:] = 0.0

    def accept(self, z: np.ndarray, x0: np.ndarray, reference_inputs: np.ndarray,
               normals: np.ndarray, offsets: np.ndarray, inputs: np.ndarray,
               states: np.ndarray) -> int:
        """:func:`~filters.mpc._fast_kernels.accept_step` of the hard QP's answer ``z`` (after
        :meth:`prepare` of the same step): ``ACCEPTED`` (``inputs``, ``states`` and
        :attr:`info` written) or a rejection code."""
        A, B, C = self._model
        _, slack_tolerance, clip_tolerance, feasibility_tolerance = self._tolerances
        none = self._no_rows
        return self._kernels.accept_step(
            np.ascontiguousarray(z, dtype=np.float64), x0, self.x_ref, reference_inputs,
            normals, offsets, self._state_cost, False, False, self._u_of_z, A, B, C,
            *self._u_box, *self._y_box, *self._terminal, clip_tolerance,
            feasibility_tolerance, slack_tolerance, *self._weights, inputs, states, *none,
            *none, self.info)

    def copy_rows_to_recovery(self) -> None:
        """Hand the QP data of :meth:`prepare` to the recovery back end (the same rows and
        bounds; DAQP softens them by their sense)."""
        for source, target in zip(self.backend.row_buffers, self.recovery.row_buffers,
                                  strict=True):
            np.copyto(target, source)

    def accept_recovery(self, z: np.ndarray, x0: np.ndarray, reference_inputs: np.ndarray,
                        normals: np.ndarray, offsets: np.ndarray, inputs: np.ndarray,
                        states: np.ndarray, slack: np.ndarray) -> int:
        """:meth:`accept` for the recovery QP's answer (every halfspace, arena and terminal
        row soft); also writes the halfspace rows' excess at the accepted inputs to
        ``slack`` ``(k, T)`` (the caller keeps the violations above the slack tolerance)."""
        A, B, C = self._model
        _, slack_tolerance, clip_tolerance, feasibility_tolerance = self._tolerances
        k = normals.shape[0]
        return self._kernels.accept_step(
            np.ascontiguousarray(z, dtype=np.float64), x0, self.x_ref, reference_inputs,
            normals, offsets, self._state_cost, True, True, self._u_of_z, A, B, C,
            *self._u_box, *self._y_box, *self._terminal, clip_tolerance,
            feasibility_tolerance, slack_tolerance, *self._weights, inputs, states, slack,
            np.empty(self._n_bounds), np.empty((k, self.T)), np.empty(self._n_bounds),
            self.info)
