"""Readable CVXPY reference for one risk-based safe halfspace (Definition 2, Proposition 1).

This module is the specification the fast closed forms of
:mod:`filters.halfspaces` are tested against, and the baseline of the paper's
Table I benchmark. It solves, for ONE obstacle at ONE prediction step with
samples :math:`p^1, \\dots, p^N`, unit normal :math:`h` and collision margin
:math:`r`, the problem of Definition 2 (eq. (4))

.. math::

    g^* = \\min_g \\; g \\quad \\text{s.t.} \\quad R(\\ell(p)) \\le \\delta, \\qquad
    \\ell(p) = -(h \\cdot p + g - r),

and returns the ego halfspace :math:`h \\cdot y \\le b`, :math:`b = -g^*` (the
safe side is ``h @ y <= b``; ``h`` points from the ego towards the obstacle).

* ``risk="mean"``: :math:`\\frac1N\\sum_i \\ell_i \\le \\delta` (an LP).
* ``risk="cvar"``: an LP, the paper's CVaR halfspace,
  :math:`\\tau + \\frac{1}{\\alpha N}\\sum_i \\max(\\ell_i - \\tau, 0) \\le \\delta`.
* ``risk="dr_cvar"``: Proposition 1 (eq. (6)) with :math:`K = 2` pieces
  :math:`a_1 = -h/\\alpha,\\ b_1 = -1/\\alpha,\\ c_1 = 1 - 1/\\alpha` and
  :math:`a_2 = 0,\\ b_2 = 0,\\ c_2 = 1`:

  .. math::

      \\lambda\\epsilon + \\frac1N \\sum_i \\eta_i \\le \\delta, \\quad
      a_k \\cdot p^i + b_k \\tilde g + c_k \\tau + \\gamma_{ik} \\cdot (v - V p^i)
      \\le \\eta_i, \\quad
      \\lVert V^\\top \\gamma_{ik} - a_k \\rVert_2 \\le \\lambda, \\quad \\gamma_{ik} \\ge 0,

  with :math:`\\tilde g = g - r`. With ``support=None`` (:math:`\\Xi = \\mathbb{R}^d`)
  there are no :math:`\\gamma` and the norm constraints read
  :math:`\\lambda \\ge \\lVert a_k \\rVert_2` (an LP, as in the authors' code);
  with a polytope :math:`\\Xi = \\{p : V p \\le v\\}` they are second-order cones.

Two formulations give the same optimum: ``"vectorized"`` (default; one
vector constraint per piece, fast to compile) and ``"paper"``, which writes
eq. (6) sample by sample (one constraint per sample and piece, with its own
:math:`\\gamma`), as the authors' code does; its compilation time grows quickly with
:math:`N` (this is what the paper's Table I "Call" column measures).

All problems are solved with Clarabel. ``cvxpy`` is imported by this module
only; ``import filters`` does not import it.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass

import cvxpy as cp
import numpy as np

from filters._validation import finite_array
from filters.constants import ALPHA, DELTA, EPSILON
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.risk import PAPER_RISKS, check_alpha, check_epsilon, check_risk

__all__ = ["FORMULATIONS", "TIGHT_CLARABEL", "CvxpyHalfspace", "build_halfspace_problem",
           "cvxpy_halfspace", "time_cvxpy_halfspace"]

#: Names of the two CVXPY formulations of Proposition 1.
FORMULATIONS: tuple[str, ...] = ("vectorized", "paper")

#: Clarabel settings used by the tests: tight enough to compare with the closed forms at 1e-6.
TIGHT_CLARABEL = {"tol_gap_abs": 1e-9, "tol_gap_rel": 1e-9, "tol_feas": 1e-9}


@dataclass(frozen=True)
class CvxpyHalfspace:
    """Result of :func:`cvxpy_halfspace`.

    Attributes
    ----------
    g
        Optimal value :math:`g^*` (metres); NaN unless ``status`` starts with ``"optimal"``.
    offset
        Ego halfspace offset :math:`b = -g^*`: the safe side is ``h @ y <= offset``.
    status
        CVXPY status string.
    setup_time
        CVXPY compilation time ``problem.compilation_time``, in seconds.
    solve_time
        Solver-reported time ``problem.solver_stats.solve_time``, in seconds.
    call_time
        Wall-clock time of ``problem.solve(...)``, in seconds.
    """

    g: float
    offset: float
    status: str
    setup_time: float
    solve_time: float
    call_time: float


def build_halfspace_problem(
    samples: object, h: object, r: float, *, risk: str = "dr_cvar", alpha: float = ALPHA,
    delta: float = DELTA, epsilon: float = EPSILON, support: tuple[object, object] | None = None,
    formulation: str = "vectorized",
) -> tuple[cp.Problem, cp.Variable]:
    """Build (but do not solve) the CVXPY problem of Definition 2 for one halfspace.

    Parameters
    ----------
    samples
        Obstacle position samples, shape ``(N, d)``, metres.
    h
        Halfspace normal, shape ``(d,)`` (unit for the paper's setting).
    r
        Collision margin :math:`S_{\\mathcal{O}}(h) + S_{-\\mathcal{A}}(h)`, metres.
    risk
        ``"mean"``, ``"cvar"`` or ``"dr_cvar"``.
    alpha
        CVaR tail mass in :math:`(0, 1]`.
    delta
        Risk bound :math:`\\delta` (metres of intrusion depth).
    epsilon
        Wasserstein radius :math:`\\ge 0` (metres), ``"dr_cvar"`` only.
    support
        ``None`` for :math:`\\Xi = \\mathbb{R}^d`, or ``(V, v)`` with ``V`` of shape
        ``(m, d)``: :math:`\\Xi = \\{p : V p \\le v\\}` (``"dr_cvar"`` only).
    formulation
        ``"vectorized"`` or ``"paper"`` (eq. (6) written per sample, ``"dr_cvar"`` only).

    Returns
    -------
    problem, g
        The problem (minimise ``g``) and the variable ``g``.

    Raises
    ------
    InvalidParameterError
        For an unknown ``risk``, ``alpha`` outside :math:`(0, 1]`, ``epsilon < 0``
        or a non-finite ``delta``, or an unknown ``formulation``.
    InvalidArrayError
        For malformed or non-finite arrays.
    """
    if formulation not in FORMULATIONS:
        raise InvalidParameterError(
            f"formulation must be one of {FORMULATIONS}, got {formulation!r}")
    risk = check_risk(risk, PAPER_RISKS)  # the CVXPY reference covers the paper's metrics
    alpha, epsilon = check_alpha(alpha), check_epsilon(epsilon)
    delta = float(finite_array("delta", delta, ndim=0))
    points = finite_array("samples", samples, ndim=2)
    if points.shape[0] == 0:
        raise InvalidArrayError("samples must hold at least one sample, got shape (0, d)")
    normal = finite_array("h", h, shape=(points.shape[1],))
    poly = None
    if support is not None:
        V = finite_array("support V", support[0], shape=(None, points.shape[1]))
        poly = (V, finite_array("support v", support[1], shape=(V.shape[0],)))
    hp = points @ normal  # h . p^i
    g = cp.Variable(name="g")
    g_tilde = g - float(finite_array("r", r, ndim=0))
    n, tau = points.shape[0], cp.Variable(name="tau")
    if risk == "mean":
        return cp.Problem(cp.Minimize(g), [cp.sum(-(hp + g_tilde)) / n <= delta]), g
    if risk == "cvar":
        cvar = tau + cp.sum(cp.pos(-(hp + g_tilde) - tau)) / (alpha * n)
        return cp.Problem(cp.Minimize(g), [cvar <= delta]), g
    # Proposition 1 (eq. (6)): pieces k = 1 (a_1 = -h/alpha, b_1 = -1/alpha,
    # c_1 = 1 - 1/alpha) and k = 2 (a_2 = 0, b_2 = 0, c_2 = 1).
    pieces = [(-normal / alpha, -1.0 / alpha, 1.0 - 1.0 / alpha), (np.zeros_like(normal), 0.0, 1.0)]
    lam, eta = cp.Variable(name="lambda"), cp.Variable(n, name="eta")
    constraints = [lam * epsilon + cp.sum(eta) / n <= delta]
    # "vectorized": one block of all N samples; "paper": N blocks of one sample each
    blocks = [slice(i, i + 1) for i in range(n)] if formulation == "paper" else [slice(None)]
    for (a_k, b_k, c_k), rows in itertools.product(pieces, blocks):
        block = points[rows]
        lhs = block @ a_k + b_k * g_tilde + c_k * tau
        if poly is None:
            constraints += [lhs <= eta[rows], lam >= np.linalg.norm(a_k)]  # ||a_2|| = 0: lam >= 0
            continue
        V, v = poly
        gamma = cp.Variable((len(block), V.shape[0]), nonneg=True)
        slack = v[None, :] - block @ V.T  # (rows, m): v - V p^i
        constraints += [lhs + cp.sum(cp.multiply(gamma, slack), axis=1) <= eta[rows],
                        cp.norm(gamma @ V - a_k[None, :], 2, axis=1) <= lam]
    return cp.Problem(cp.Minimize(g), constraints), g


def cvxpy_halfspace(
    samples: object, h: object, r: float, *, risk: str = "dr_cvar", alpha: float = ALPHA,
    delta: float = DELTA, epsilon: float = EPSILON, support: tuple[object, object] | None = None,
    formulation: str = "vectorized", solver_options: dict[str, float] | None = None,
) -> CvxpyHalfspace:
    """Solve Definition 2 / Proposition 1 for one halfspace with CVXPY and Clarabel.

    A fresh problem is built on every call (as the paper's benchmark did), so
    ``call_time`` includes CVXPY's compilation. Parameters are those of
    :func:`build_halfspace_problem`; ``solver_options`` are passed to Clarabel
    (e.g. :data:`TIGHT_CLARABEL`).

    Returns
    -------
    CvxpyHalfspace
        :math:`g^*`, the offset :math:`b = -g^*` of the safe side ``h @ y <= b``,
        the status and the three timings in seconds.

    Raises
    ------
    InvalidParameterError, InvalidArrayError
        As :func:`build_halfspace_problem`.
    """
    problem, g = build_halfspace_problem(samples, h, r, risk=risk, alpha=alpha, delta=delta,
                                         epsilon=epsilon, support=support, formulation=formulation)
    start = time.perf_counter()
    problem.solve(solver=cp.CLARABEL, **(solver_options or {}))
    call_time = time.perf_counter() - start
    status = str(problem.status)
    value = float(g.value) if status.startswith("optimal") and g.value is not None else np.nan
    return CvxpyHalfspace(g=value, offset=-value, status=status,
                          setup_time=float(problem.compilation_time or 0.0),
                          solve_time=float(problem.solver_stats.solve_time or 0.0),
                          call_time=call_time)


def time_cvxpy_halfspace(
    samples: object, h: object, r: float, risk: str = "dr_cvar", *, alpha: float = ALPHA,
    delta: float = DELTA, epsilon: float = EPSILON, support: tuple[object, object] | None = None,
    formulation: str = "vectorized",
) -> tuple[float, float, float]:
    """Time one fresh CVXPY halfspace solve, as in the paper's Table I.

    Returns
    -------
    setup_time, solve_time, call_time
        In seconds: CVXPY's ``compilation_time``, Clarabel's reported solve time,
        and the wall-clock time of ``problem.solve``.

    Raises
    ------
    InvalidParameterError, InvalidArrayError
        As :func:`build_halfspace_problem`.
    """
    result = cvxpy_halfspace(samples, h, r, risk=risk, alpha=alpha, delta=delta, epsilon=epsilon,
                             support=support, formulation=formulation)
    return result.setup_time, result.solve_time, result.call_time
