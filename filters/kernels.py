r"""The compiled path of the safe halfspaces: when it applies, its settings, and the call.

:func:`filters.safe_halfspaces`, :func:`filters.halfspaces.offsets_along`,
:func:`filters.intersample_rows` and the wrapper's step (:func:`filters.step_rows.step_rows`)
take ``backend=``:

* ``"numpy"``: the vectorised numpy implementation of :mod:`filters.halfspaces`, the
  reference every test compares against;
* ``"numba"``: the compiled kernel of :mod:`filters._kernels`: per obstacle, one read
  of its samples from memory, the sample means and normals, then per step and normal
  one pass for the losses (and their standard deviation) and an O(N) branch-free
  selection for the CVaR; the wrapper's step computes both row sets of the
  inter-sample constraints in the same call;
* ``"auto"`` (the default): ``"numba"`` wherever it applies, else ``"numpy"``.

The kernel covers every risk of :data:`filters.risk.RISKS`, scalar and per-step
:math:`\epsilon`, conformal margins, given normals, the near-side and clearest normals
of :mod:`filters.step_rows` and the degenerate-normal fallbacks, for disc-shaped ego and
obstacles in any dimension, with the unbounded support :math:`\Xi = \mathbb{R}^d` (a
polytope support changes only DR-CVaR, Proposition 1: that case, and polygon shapes,
stay on the numpy path). Its results equal the numpy path's to rounding (about 1e-15 of
the positions' scale; the tests hold them to 1e-12 of it): both evaluate the same closed
forms in another order of summation. The near-side and clearest rules choose between two
origins; at an exact tie (two origins equally far from a mean, or the near-side product
zero) the choice follows the last bits of the sample means, so there the two paths may
take different, equally valid, normals. Both are deterministic: on a machine, the same
data give the same bits.

numba is imported, and the kernel loaded from numba's on-disk cache, only when a
compiled path first runs (``import filters`` stays light). The very first run on a
machine compiles it (about 20 s here) and caches it next to the module.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from types import ModuleType

import numpy as np
from scipy.special import ndtri

from filters.errors import InvalidParameterError, InvalidTypeError
from filters.geometry import Disc
from filters.risk import CHANCE_RISKS, cantelli_factor, gaussian_factor, tail_count

__all__ = [
    "BACKENDS",
    "KernelRows",
    "WrapperRows",
    "check_backend",
    "compiled_rows",
    "kernel_applies",
    "kernels_available",
    "use_kernel",
]

BACKENDS: tuple[str, ...] = ("auto", "numba", "numpy")
"""Implementations of the halfspaces: ``"auto"`` picks ``"numba"`` where it applies."""

_RISK_CODES = {"mean": 0, "cvar": 1, "dr_cvar": 2, "gaussian_cc": 3, "moment_dr": 3,
               "conformal": 4}
_MODES = {"paper": 0, "given": 1, "nearside": 2, "clearest": 3}
#: Half-width of the selection band around the Gaussian guess of the CVaR's threshold,
#: in standard errors of the sample quantile (plus a floor, in standard deviations).
_BAND_ERRORS = 2.0
_BAND_FLOOR = 0.01

_EMPTY_3 = np.empty((0, 0, 0))
_EMPTY_2 = np.empty((0, 0))
_EMPTY_1 = np.empty(0)
_ZERO = np.zeros(1)
_ZERO_2 = np.zeros((1, 1))
_module: ModuleType | None = None
_missing: str | None = None


def check_backend(backend: object) -> str:
    """Return ``backend`` if it is one of :data:`BACKENDS`, else raise a named error."""
    if isinstance(backend, str) and backend in BACKENDS:
        return backend
    if not isinstance(backend, str):
        raise InvalidTypeError(f"backend must be a string, one of {BACKENDS}, got {backend!r}")
    raise InvalidParameterError(f"backend must be one of {BACKENDS}, got {backend!r}")


def kernels_available() -> bool:
    """Whether the compiled kernels can run (numba imports; imports it on first call)."""
    return _load() is not None


def kernel_applies(
    ego_shape: object, obstacle_shapes: Sequence[object], support: object | None, risk: str
) -> bool:
    """Whether the compiled kernels cover this case: disc shapes, and no polytope support
    for ``"dr_cvar"`` (the only risk a support changes)."""
    return ((support is None or risk != "dr_cvar") and type(ego_shape) is Disc
            and all(type(shape) is Disc for shape in obstacle_shapes))


def use_kernel(backend: str, applies: bool) -> bool:
    """Whether to run the compiled path for a checked ``backend``.

    Raises
    ------
    InvalidParameterError
        If ``backend="numba"`` is asked for a case the kernels do not cover, or numba
        cannot be imported.
    """
    if backend == "numpy":
        return False
    if backend == "auto":
        return applies and _load() is not None
    if not applies:
        raise InvalidParameterError(
            "backend='numba' covers disc shapes, and DR-CVaR with the unbounded support "
            "only (no polytope support, no ConvexPolygon); use backend='auto' or 'numpy'"
        )
    if _load() is None:
        raise InvalidParameterError(f"backend='numba' needs numba: {_missing}")
    return True


def _load() -> ModuleType | None:
    """The kernel module (imports numba on first use); ``None`` if numba is missing."""
    global _module, _missing
    if _module is None and _missing is None:
        try:
            from filters import _kernels
        except ImportError as exc:  # numba is a dependency; be explicit if it is broken
            _missing = f"{type(exc).__name__}: {exc}"
            return None
        _module = _kernels
    return _module


@functools.lru_cache(maxsize=128)
def _risk_constants(risk: str, alpha: float, n_samples: int) -> tuple[int, float, int, float,
                                                                        float, float]:
    """``(code, mass, k, factor, z_guess, width)`` of a checked risk at ``N`` samples.

    ``mass`` is :func:`filters.risk.tail_count` (:math:`\\alpha N`, snapped), ``k`` its
    floor; ``factor`` the chance constraints' :math:`z_{1-\\alpha}` or Cantelli factor;
    ``z_guess`` and ``width`` place the CVaR's selection band (in standard deviations
    of the losses): the normal quantile of the rank sought, and its half-width.
    """
    mass = tail_count(alpha, n_samples)
    k = min(int(math.floor(mass)), n_samples)
    factor = 0.0
    if risk in CHANCE_RISKS:
        factor = gaussian_factor(alpha) if risk == "gaussian_cc" else cantelli_factor(alpha)
    z_guess = width = 0.0
    if k < n_samples:
        level = 1.0 - (k + 0.5) / n_samples
        z_guess = float(ndtri(level))
        density = math.exp(-0.5 * z_guess * z_guess) / math.sqrt(2.0 * math.pi)
        spread = math.sqrt(level * (1.0 - level) / n_samples) / density
        width = _BAND_ERRORS * spread + _BAND_FLOOR
    return _RISK_CODES[risk], mass, k, factor, z_guess, width


@dataclass(frozen=True, eq=False)
class KernelRows:
    """Raw output of :func:`compiled_rows` (``k`` obstacles, ``T`` steps).

    Attributes
    ----------
    normals, degenerate, offsets
        ``(k, T, d)`` unit normals, ``(k, T)`` fallback flags, ``(k, T)`` offsets in m.
    rows_normals, rows_offsets
        With the inter-sample rows: the QP's ``(2 k, T, d)`` and ``(2 k, T)`` rows as
        :func:`filters.intersample_rows` lays them out (end rows, then start rows; the
        last start row ``0 @ y <= 1``), else ``None``.
    status
        One of :mod:`filters._kernels`' codes: 0 (OK), 1 (a non-finite sample), 2 (a
        non-finite normal or offset), 3 (a zero near-side normal). The arrays are only
        meaningful with status 0.
    """

    normals: np.ndarray
    degenerate: np.ndarray
    offsets: np.ndarray
    rows_normals: np.ndarray | None
    rows_offsets: np.ndarray | None
    status: int


def _floats(value: object, ndim: int) -> np.ndarray:
    """A C-contiguous float64 array of ``ndim`` dimensions (leading axes of length 1)."""
    array = np.ascontiguousarray(value, dtype=np.float64)
    while array.ndim < ndim:
        array = array[None]
    return array


_FLOAT64 = np.dtype(np.float64)


def _plain(array: np.ndarray) -> bool:
    """Whether an ndarray holds C-contiguous native float64 (what the kernels take as is)."""
    return (array.dtype is _FLOAT64 or array.dtype == _FLOAT64) and array.flags.c_contiguous


def _bound(value: object, dim: int) -> np.ndarray:
    """An input bound as a ``(d,)`` float array (a scalar applies to every axis)."""
    array = np.ascontiguousarray(value, dtype=np.float64)
    if array.shape == (dim,):
        return array
    return np.full(dim, float(array.reshape(-1)[0])) if array.size == 1 else array.reshape(dim)


def compiled_rows(
    samples: np.ndarray,
    horizon: int,
    origins: np.ndarray | None,
    *,
    radii: np.ndarray,
    risk: str,
    alpha: float,
    delta: float,
    epsilon: float | np.ndarray,
    conformal_margins: np.ndarray | float | None = None,
    normals: str | np.ndarray = "paper",
    ego_position: np.ndarray | None = None,
    plan: np.ndarray | None = None,
    previous_normals: np.ndarray | None = None,
    ego_velocity: np.ndarray | None = None,
    input_bounds: tuple[np.ndarray, np.ndarray] | None = None,
    dt: float = 0.0,
    disabled_offset: float = 1.0,
) -> KernelRows:
    """Normals, offsets and (with ``input_bounds``) the inter-sample rows, compiled.

    The arguments must already be checked (shapes, finiteness of everything but the
    samples and positions, the risk settings); the kernel itself reports non-finite
    samples and results through :attr:`KernelRows.status`.

    Parameters
    ----------
    samples
        ``(k, N, T', d)`` with ``T' >= horizon``; the first ``horizon`` steps are used.
    horizon
        ``T``.
    origins
        ``(T, d)``: where the normals start (``"paper"``: the reference positions;
        ``"nearside"``: the reference, while it is on the ego's side of the mean;
        ``"clearest"``: the reference or the plan, whichever is farther from the mean);
        ``None`` with given normals.
    radii
        ``(k,)``: ego radius plus obstacle radius, in m (the collision margin of discs).
    risk, alpha, delta, epsilon, conformal_margins
        As for :func:`filters.safe_halfspaces` (``epsilon`` a float or ``(T,)``;
        margins a scalar, ``(T,)`` or ``(k, T)``).
    normals
        ``"paper"``, ``"nearside"`` (:func:`filters.step_rows.nearside_normals`; needs
        ``ego_position``), ``"clearest"`` (:func:`filters.step_rows.clearest_normals`;
        needs ``ego_position``, uses ``plan``) or given unit normals ``(k, T, d)``.
    plan
        ``"clearest"``: the last optimal plan's positions shifted by one step ``(T, d)``,
        or ``None`` (no plan: the near-side rule after the first step).
    previous_normals, ego_velocity
        The degenerate-normal fallbacks (``"paper"`` only): ``(k, T, d)``, and ``(d,)``
        or ``(T, d)``.
    input_bounds, dt
        With ``input_bounds`` (``(low, high)``, m/s², scalars or ``(d,)``) and the
        sampling time in s, also the inter-sample rows of :func:`filters.intersample_rows`
        (end and start rows, arc margins), in the same pass over the samples.
    disabled_offset
        The offset of the unused last start rows (``0 @ y <= disabled_offset``).
    """
    kernels = _load()
    n_obstacles, n_samples, _, dim = samples.shape
    flat = np.ascontiguousarray(samples, dtype=np.float64).reshape(n_obstacles, n_samples, -1)
    code, mass, k, factor, z_guess, width = _risk_constants(risk, alpha, n_samples)
    if isinstance(normals, str):
        mode, given = _MODES[normals], _EMPTY_3
    else:
        mode, given = _MODES["given"], _floats(normals, 3)
    ego = _EMPTY_1 if ego_position is None else _floats(ego_position, 1)
    shifted_plan = _EMPTY_2 if plan is None else _floats(plan, 2)
    previous = _EMPTY_3 if previous_normals is None else _floats(previous_normals, 3)
    velocity = _EMPTY_2 if ego_velocity is None else _floats(ego_velocity, 2)
    eps = _floats(epsilon, 1) if code == 2 else _ZERO
    margins = _floats(conformal_margins, 2) if code == 4 else _ZERO_2
    out_normals = np.empty((n_obstacles, horizon, dim))
    out_degenerate = np.empty((n_obstacles, horizon), dtype=np.bool_)
    out_offsets = np.empty((n_obstacles, horizon))
    start = input_bounds is not None
    if start:
        low, high = _bound(input_bounds[0], dim), _bound(input_bounds[1], dim)
        arc = dt * dt / 8.0
        rows_normals = np.empty((2 * n_obstacles, horizon, dim))
        rows_offsets = np.empty((2 * n_obstacles, horizon))
    else:
        low = high = _EMPTY_1
        arc = 0.0
        rows_normals, rows_offsets = _EMPTY_3, _EMPTY_2
    origins = _EMPTY_2 if origins is None else _floats(origins, 2)
    status = kernels.halfspace_kernel(
        flat, horizon, dim, origins, mode, given, ego, shifted_plan, previous, velocity, code,
        alpha, mass, k, factor, z_guess, width, delta, eps, margins, _floats(radii, 1), start,
        low, high, arc, disabled_offset, out_normals, out_degenerate, out_offsets, rows_normals,
        rows_offsets)
    return KernelRows(out_normals, out_degenerate, out_offsets,
                      rows_normals if start else None, rows_offsets if start else None,
                      int(status))


_ORIGINS = {"paper": 0, "ego": 1, "previous_plan": 2, "nearside": 0, "clearest": 0}
_NORMAL_MODES = {"paper": "paper", "ego": "paper", "previous_plan": "paper",
                 "nearside": "nearside", "clearest": "clearest"}


class WrapperRows:
    """The wrapper's halfspace rows, one kernel call per step with the constants prepared.

    What :func:`filters.step_rows.step_rows` computes for
    :class:`filters.SafetyFilterWrapper` on the compiled path, for one set of obstacles
    (disc radii), one sample count and a risk with fixed settings (every risk but
    ``"conformal"``, a float ``epsilon``): the risk constants, radii, input bounds and
    arc margin are formed once, and the kernel forms the origins, the ego position, the
    shifted plan and the shifted previous normals from the raw state itself (the
    operations of the wrapper, in their order). The same kernel as the general call, on
    the same numbers: the same bits.

    Parameters
    ----------
    horizon, n_samples
        ``T`` and ``N_s``.
    radii
        Ego plus obstacle radius per obstacle ``(k,)``, m.
    risk, alpha, delta, epsilon
        Checked risk settings (``risk`` not ``"conformal"``, ``epsilon`` a float).
    normals
        The wrapper's ``normals`` setting (:data:`filters.wrapper.NORMAL_SOURCES`).
    input_bounds, dt
        With ``input_bounds``, the inter-sample rows (as :func:`compiled_rows`).
    disabled_offset
        Offset of the unused last start rows.
    """

    def __init__(self, *, horizon: int, n_samples: int, radii: np.ndarray, risk: str,
                 alpha: float, delta: float, epsilon: float, normals: str,
                 input_bounds: tuple[np.ndarray, np.ndarray] | None, dt: float,
                 disabled_offset: float, dim: int = 2) -> None:
        if risk == "conformal" or type(epsilon) is not float:
            raise InvalidParameterError("WrapperRows takes fixed risk settings (not conformal, "
                                        f"a float epsilon), got {risk!r}, {epsilon!r}")
        self._kernels = _load()
        if self._kernels is None:
            raise InvalidParameterError(f"WrapperRows needs numba: {_missing}")
        self.horizon, self.n_samples, self.dim = int(horizon), int(n_samples), int(dim)
        self.radii = np.ascontiguousarray(radii, dtype=np.float64)
        self.n_obstacles = self.radii.shape[0]
        self.normals = normals
        self._origin_mode = _ORIGINS[normals]
        self._mode = _MODES[_NORMAL_MODES[normals]]
        self._constants = _risk_constants(risk, alpha, self.n_samples)
        self._alpha, self._delta = float(alpha), float(delta)
        self._epsilon = _floats(epsilon, 1)
        self._start = input_bounds is not None
        if self._start:
            self._low, self._high = _bound(input_bounds[0], dim), _bound(input_bounds[1], dim)
            self._arc = dt * dt / 8.0
        else:
            self._low = self._high = _EMPTY_1
            self._arc = 0.0
        self._disabled = float(disabled_offset)
        self._C_given: object = None
        self._C = _EMPTY_2

    def __call__(self, samples: np.ndarray, x0: np.ndarray, ref_states: np.ndarray,
                 C: np.ndarray, plan_states: np.ndarray | None,
                 previous_normals: np.ndarray | None) -> tuple | None:
        """``(status, normals, degenerate, offsets, rows_normals, rows_offsets)`` as in
        :class:`KernelRows` (a plain tuple: this runs every step), or ``None`` if an array
        does not fit (the general path then runs). ``status`` non-zero: the kernel found a
        non-finite number.

        ``samples`` ``(k, N_s, T', d)`` float64 C-contiguous, ``T' >= T``; ``x0`` ``(2 d,)``
        (position, velocity); ``ref_states`` and ``plan_states`` ``(T + 1, 2 d)``
        (``plan_states``: the last plan for ``"previous_plan"``, the last optimal plan for
        ``"clearest"``, else ignored); ``C`` ``(d, 2 d)``; ``previous_normals``
        ``(k, T, d)`` (``"paper"``-style modes) or ``None``.
        """
        T, dim, k = self.horizon, self.dim, self.n_obstacles
        n = 2 * dim
        shape = samples.shape
        if not (type(samples) is np.ndarray and _plain(samples) and len(shape) == 4
                and shape[0] == k and shape[1] == self.n_samples and shape[2] >= T
                and shape[3] == dim and type(x0) is np.ndarray and _plain(x0)
                and x0.shape == (n,) and type(ref_states) is np.ndarray and _plain(ref_states)
                and ref_states.shape == (T + 1, n) and np.shape(C) == (dim, n)):
            return None
        if plan_states is None or self._origin_mode != 2 and self._mode != _MODES["clearest"]:
            plan_states = _EMPTY_2
        elif not (type(plan_states) is np.ndarray and _plain(plan_states)
                  and plan_states.shape == (T + 1, n)):
            return None
        if previous_normals is None or self._mode != _MODES["paper"]:
            previous_normals = _EMPTY_3
        elif not (type(previous_normals) is np.ndarray and _plain(previous_normals)
                  and previous_normals.shape == (k, T, dim)):
            return None
        if C is not self._C_given:  # the environment's output map, converted once
            self._C_given, self._C = C, _floats(C, 2)
        code, mass, kk, factor, z_guess, width = self._constants
        normals = np.empty((k, T, dim))
        degenerate = np.empty((k, T), dtype=np.bool_)
        offsets = np.empty((k, T))
        if self._start:
            rows_normals, rows_offsets = np.empty((2 * k, T, dim)), np.empty((2 * k, T))
        else:
            rows_normals, rows_offsets = _EMPTY_3, _EMPTY_2
        status = self._kernels.wrapper_step_kernel(
            samples.reshape(k, self.n_samples, -1), T, dim, x0, ref_states, self._C,
            self._origin_mode, self._mode, plan_states, previous_normals, code, self._alpha, mass,
            kk, factor, z_guess, width, self._delta, self._epsilon, _ZERO_2, self.radii,
            self._start, self._low, self._high, self._arc, self._disabled, normals,
            degenerate, offsets, rows_normals, rows_offsets)
        if not self._start:
            return status, normals, degenerate, offsets, None, None
        return status, normals, degenerate, offsets, rows_normals, rows_offsets
