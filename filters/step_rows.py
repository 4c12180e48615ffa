r"""The halfspace rows of one filter step: the safe halfspaces and the inter-sample rows.

:class:`filters.SafetyFilterWrapper` calls :func:`step_rows` once per control step. It
is the composition

1. (``nearside_from`` given) :func:`nearside_normals`;
2. :func:`filters.safe_halfspaces` (Definitions 2-3);
3. (``input_bounds`` given) :func:`filters.intersample_rows`, the end rows tightened by
   the arc margin and the start rows along the next step's normal,

computed either by exactly these numpy calls (``backend="numpy"``, the reference) or,
where the compiled kernels apply (disc shapes, no polytope support; see
:mod:`filters.kernels`), by one kernel call that reads each obstacle's samples once
for both row sets. The two agree to rounding.

The compiled path checks the shapes of every array and the per-step radii and margins
(cheap); the samples and positions are checked for finiteness inside the kernel.
Whenever a shape is unexpected or the kernel reports a problem, the numpy path runs
instead and raises its named error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from filters.errors import InvalidArrayError, InvalidParameterError
from filters.geometry import Shape
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.intersample import intersample_rows
from filters.kernels import check_backend, compiled_rows, kernel_applies, use_kernel
from filters.mpc.filter import DISABLED_OFFSET
from filters.risk import check_epsilon_array, check_margins

__all__ = ["StepRows", "nearside_normals", "step_rows"]


@dataclass(frozen=True, eq=False)
class StepRows:
    """What one filter step hands to the QP.

    Attributes
    ----------
    halfspaces
        The step halfspaces (normals ``(k, T, d)``, offsets ``(k, T)``).
    normals, offsets
        The QP's rows: the halfspaces themselves, or with the inter-sample rows
        ``(2 k, T, d)`` and ``(2 k, T)`` as :class:`filters.intersample.IntersampleRows`
        lays them out. Safe side ``normals[j, t] @ y_{t+1} <= offsets[j, t]``.
    """

    halfspaces: Halfspaces
    normals: np.ndarray
    offsets: np.ndarray


def nearside_normals(samples: np.ndarray, reference: np.ndarray, ego: np.ndarray) -> np.ndarray:
    """Paper normals where the reference is on the ego's side of the obstacle, else the ego's.

    For obstacle ``i`` and step ``t`` the normal starts at the reference position
    ``y^r_t`` when ``(y^r_t - p̄_{i,t}) . (y_0 - p̄_{i,t}) > 0`` (the reference has not
    passed the obstacle's centre as seen from the ego), else at the current position
    ``y_0``: the normals then never flip inside the horizon.

    Parameters
    ----------
    samples
        ``(k, N, T, d)`` prediction samples, m.
    reference
        ``(T, d)`` reference positions, m.
    ego
        ``(d,)`` current ego position, m.

    Returns
    -------
    numpy.ndarray
        ``(k, T, d)`` unit normals.
    """
    means = samples.mean(axis=1)  # (k, T, d)
    to_reference = reference[None] - means
    to_ego = ego[None, None] - means
    near = np.einsum("ktd,ktd->kt", to_reference, to_ego) > 0.0
    origin = np.where(near[..., None], reference[None], ego[None, None])
    diff = means - origin
    size = np.sqrt(np.add.reduce(diff * diff, axis=-1, keepdims=True))  # = np.linalg.norm
    ok = size > 1e-9
    if ok.all():  # the usual case: the fallback below would not be picked anywhere
        return diff / size
    fallback = means - ego[None, None]  # the ego is never at the obstacle's mean
    fallback_size = np.sqrt(np.add.reduce(fallback * fallback, axis=-1, keepdims=True))
    return np.where(ok, diff / np.where(ok, size, 1.0),
                    fallback / np.maximum(fallback_size, 1e-12))


def step_rows(
    origins: np.ndarray,
    samples: np.ndarray,
    *,
    horizon: int,
    ego_shape: Shape,
    obstacle_shapes: Sequence[Shape],
    risk: str,
    alpha: float,
    delta: float,
    epsilon: float | np.ndarray,
    conformal_margins: np.ndarray | None = None,
    support: tuple[object, object] | None = None,
    previous_normals: np.ndarray | None = None,
    ego_velocity: np.ndarray | None = None,
    nearside_from: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    input_bounds: tuple[np.ndarray, np.ndarray] | None = None,
    dt: float = 0.0,
    backend: str = "auto",
) -> StepRows:
    """The halfspaces and (with ``input_bounds``) inter-sample rows of one filter step.

    Parameters
    ----------
    origins
        ``(T, d)``: where the normals start (the reference positions, or whatever the
        wrapper's ``normals`` setting picked), m.
    samples
        ``(k, N, T', d)`` prediction samples with ``T' >= horizon``; the first
        ``horizon`` steps are used, m.
    horizon
        ``T``.
    ego_shape, obstacle_shapes, risk, alpha, delta, epsilon, conformal_margins, support
        As for :func:`filters.safe_halfspaces` (``risk``, ``alpha`` and ``delta`` checked
        by the caller; ``epsilon`` a float or ``(T,)``).
    previous_normals, ego_velocity
        The degenerate-normal fallbacks of :func:`filters.safe_halfspaces`.
    nearside_from
        The current ego position ``(d,)``: use :func:`nearside_normals` (from
        ``origins`` while on the ego's side of the obstacle, else from here).
    normals
        Given unit normals ``(k, T, d)`` (e.g. the wrapper's ``normals="clearest"``);
        ``origins`` then only fixes the shapes. Not together with ``nearside_from``.
    input_bounds, dt
        The ego's input box ``(low, high)`` in m/s² and the sampling time in s: add
        the inter-sample rows of :func:`filters.intersample_rows`.
    backend
        ``"auto"``, ``"numba"`` or ``"numpy"`` (see :mod:`filters.kernels`).

    Raises
    ------
    InvalidArrayError
        If the samples hold NaN or infinite values (named by index), or an array has
        the wrong shape; the errors of :func:`filters.safe_halfspaces` otherwise.
    """
    backend = check_backend(backend)
    if nearside_from is not None and normals is not None:
        raise InvalidParameterError("step_rows: give nearside_from or normals, not both")
    if (type(samples) is np.ndarray and samples.ndim == 4 and samples.shape[0]
            and samples.shape[2] >= horizon and type(origins) is np.ndarray
            and origins.shape == (horizon, samples.shape[3]) and samples.shape[1]
            and len(obstacle_shapes) == samples.shape[0]
            and use_kernel(backend, support is None
                           and kernel_applies(ego_shape, obstacle_shapes, None, risk))):
        rows = _compiled(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha,
                         delta, epsilon, conformal_margins, previous_normals, ego_velocity,
                         nearside_from, normals, input_bounds, dt)
        if rows is not None:
            return rows
    return _reference(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha,
                      delta, epsilon, conformal_margins, support, previous_normals,
                      ego_velocity, nearside_from, normals, input_bounds, dt)


def _reference(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha, delta,
               epsilon, conformal_margins, support, previous_normals, ego_velocity,
               nearside_from, normals, input_bounds, dt) -> StepRows:
    """The numpy composition (see the module docstring)."""
    samples = np.asarray(samples, dtype=np.float64)
    if samples.ndim != 4 or samples.shape[2] < horizon:
        raise InvalidArrayError(
            f"samples must have shape (n_obstacles, n_samples, T', d) with T' >= {horizon}, "
            f"got {samples.shape}")
    samples = samples[:, :, :horizon]
    if not np.all(np.isfinite(samples)):
        raise InvalidArrayError(
            "the prediction samples hold NaN or infinite values (at indices "
            f"{np.argwhere(~np.isfinite(samples))[0].tolist()})")
    options = dict(risk=risk, alpha=alpha, delta=delta, epsilon=epsilon)
    if conformal_margins is not None:
        options["conformal_margins"] = conformal_margins
    given = normals
    if nearside_from is not None and samples.shape[0]:
        given = nearside_normals(samples, np.asarray(origins, dtype=np.float64),
                                 np.asarray(nearside_from, dtype=np.float64))
    halfspaces = safe_halfspaces(
        origins, samples, ego_shape=ego_shape, obstacle_shapes=obstacle_shapes,
        support=support, previous_normals=previous_normals, ego_velocity=ego_velocity,
        normals=given, backend="numpy", **options)
    if input_bounds is None:
        return StepRows(halfspaces, halfspaces.normals, halfspaces.offsets)
    rows = intersample_rows(
        halfspaces, samples, ego_shape=ego_shape, obstacle_shapes=obstacle_shapes,
        input_bounds=input_bounds, dt=dt, support=support, backend="numpy", **options)
    return StepRows(halfspaces, rows.normals, rows.offsets)


def _compiled(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha, delta,
              epsilon, conformal_margins, previous_normals, ego_velocity, nearside_from,
              normals, input_bounds, dt) -> StepRows | None:
    """The kernel path; ``None`` when an argument has an unexpected shape or the kernel
    reports a problem (the numpy path then runs and names it). The kernel does not
    check indices: every array it reads is checked here or in :func:`compiled_rows`."""
    k, _, _, dim = samples.shape
    if ((previous_normals is not None and np.shape(previous_normals) != (k, horizon, dim))
            or (ego_velocity is not None
                and np.shape(ego_velocity) not in ((dim,), (horizon, dim)))
            or (nearside_from is not None and np.shape(nearside_from) != (dim,))
            or (normals is not None and np.shape(normals) != (k, horizon, dim))
            or (input_bounds is not None
                and not all(np.shape(b) in ((), (1,), (dim,)) for b in input_bounds))
            or samples.dtype.kind not in "fiu"):
        return None
    if type(epsilon) is not float or not 0.0 <= epsilon < math.inf:
        epsilon = check_epsilon_array(epsilon, horizon)
    margins = None
    if risk == "conformal":
        margins = check_margins(conformal_margins, (k, horizon))
    radii = np.array([shape.radius for shape in obstacle_shapes], dtype=np.float64)
    radii += ego_shape.radius
    out = compiled_rows(
        samples, horizon, origins, radii=radii, risk=risk, alpha=alpha, delta=delta,
        epsilon=epsilon, conformal_margins=margins,
        normals=(normals if normals is not None
                 else "paper" if nearside_from is None else "nearside"),
        ego_position=nearside_from,
        previous_normals=previous_normals, ego_velocity=ego_velocity,
        input_bounds=input_bounds, dt=dt, disabled_offset=DISABLED_OFFSET)
    if out.status != 0:
        return None
    halfspaces = Halfspaces(out.normals, out.offsets, risk, alpha, delta, epsilon,
                            out.degenerate)
    if input_bounds is None:
        return StepRows(halfspaces, out.normals, out.offsets)
    return StepRows(halfspaces, out.rows_normals, out.rows_offsets)
