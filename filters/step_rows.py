r"""The halfspace rows of one filter step: the safe halfspaces and the inter-sample rows.

:class:`filters.SafetyFilterWrapper` calls :func:`step_rows` once per control step. It
is the composition

1. (``nearside_from`` given) :func:`nearside_normals`; (``clearest_from`` given)
   :func:`clearest_normals`;
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

from filters._validation import finite_array
from filters.errors import InvalidArrayError, InvalidParameterError
from filters.geometry import Shape
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.intersample import intersample_rows
from filters.kernels import check_backend, compiled_rows, kernel_applies, use_kernel
from filters.mpc.filter import DISABLED_OFFSET
from filters.risk import check_epsilon_array, check_margins

__all__ = ["StepRows", "clearest_normals", "nearside_normals", "step_rows"]


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


def clearest_normals(samples: np.ndarray, reference: np.ndarray, ego: np.ndarray,
                     plan: np.ndarray | None = None) -> np.ndarray:
    r"""Normals from the clearer of the reference and the last plan: ``normals="clearest"``.

    Any unit normal :math:`h` gives a valid safe halfspace
    :math:`h \cdot y \le b(h)` (Definitions 2-3 hold for every direction); the
    choice decides which plans the filter can find. With :math:`\bar p_{i,t}` the
    sample mean of obstacle :math:`i` at step :math:`t`, the normal is
    :math:`h_{i,t} = (\bar p_{i,t} - o_{i,t}) / \|\bar p_{i,t} - o_{i,t}\|`, with the
    origin

    * :math:`o_{i,1} = y_0`, the current position, at the first step: the direction in
      which the next position gets clear of the obstacle fastest (a plan's first
      position lies within :math:`T_s \|v\| + T_s^2 u_{max}/2` of :math:`y_0`);
    * for :math:`t \ge 2`, with :math:`\hat y_t` the last optimal plan shifted by one
      step: :math:`o_{i,t} = y^r_t` (the reference, the paper's choice) if
      :math:`\|\bar p_{i,t} - y^r_t\| \ge \|\bar p_{i,t} - \hat y_t\|`, else
      :math:`\hat y_t`: the clearer of the two. A point :math:`z` as far from
      :math:`\bar p` as the halfspace's margin satisfies the halfspace whose normal
      starts at :math:`z` (:math:`h \cdot (\bar p - z) = \|\bar p - z\|`). Where the
      plan's normal is taken, the shifted plan (which met last step's rows) meets it
      again up to the change of the predictions, and the normal cannot flip where the
      reference runs through the obstacle, since the plan does not; where the
      reference's normal is taken, the reference meets its own row whenever the plan
      met its. This makes infeasible steps rarer; it is no guarantee of recursive
      feasibility (the first-step normal, the inter-sample rows and the reference's
      normals may still cut the shifted plan off);
    * without a plan (``plan=None``: the first step of an episode, or after a step
      that was not optimal, whose plan may pass through an obstacle), the
      ``"nearside"`` rule for :math:`t \ge 2`.

    A direction of length at most 1e-9 (an origin on the mean) falls back to the one
    from :math:`y_0`, and where :math:`y_0` is on the mean too, to the first axis.
    This is the numpy reference of ``step_rows(..., clearest_from=ego,
    clearest_plan=plan)``, whose compiled kernel computes the same normals.

    Parameters
    ----------
    samples
        Prediction samples ``(k, N_s, T, d)``, in m.
    reference
        Reference positions :math:`y^r_1..y^r_T`, ``(T, d)``.
    ego
        Current position :math:`y_0`, ``(d,)``.
    plan
        The last optimal plan's positions shifted by one step and re-anchored at
        :math:`y_0` (:math:`\hat y_1..\hat y_T`, ``(T, d)``), or ``None``.

    Returns
    -------
    numpy.ndarray
        ``(k, T, d)`` unit normals.
    """
    means = samples.mean(axis=1)  # (k, T, d)
    if plan is None:
        normals = nearside_normals(samples, reference, ego)
    else:
        to_reference = means - reference[None]
        to_plan = means - plan[None]
        d_reference = np.sqrt(np.add.reduce(to_reference * to_reference, axis=-1))
        d_plan = np.sqrt(np.add.reduce(to_plan * to_plan, axis=-1))
        use_reference = (d_reference >= d_plan)[..., None]
        diff = np.where(use_reference, to_reference, to_plan)
        size = np.where(use_reference, d_reference[..., None], d_plan[..., None])
        normals = diff / np.maximum(size, 1e-12)
        normals = np.where(size > 1e-9, normals, 0.0)
    from_ego = means - ego[None, None]  # (k, T, d)
    ego_size = np.sqrt(np.add.reduce(from_ego * from_ego, axis=-1, keepdims=True))
    ego_normals = np.where(ego_size > 1e-9, from_ego / np.maximum(ego_size, 1e-12), 0.0)
    normals[:, 0] = ego_normals[:, 0]
    degenerate = np.sqrt(np.add.reduce(normals * normals, axis=-1, keepdims=True)) < 0.5
    if degenerate.any():  # an origin on the mean: the direction from the ego, else an axis
        axis = np.zeros(means.shape[-1])
        axis[0] = 1.0
        fallback = np.where(ego_size > 1e-9, ego_normals, axis)
        normals = np.where(degenerate, fallback, normals)
    return normals


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
    clearest_from: np.ndarray | None = None,
    clearest_plan: np.ndarray | None = None,
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
    clearest_from, clearest_plan
        The current ego position ``(d,)`` and the last optimal plan's positions shifted
        by one step ``(T, d)`` (or ``None``: no plan): use :func:`clearest_normals`
        (``origins`` are the reference positions), the wrapper's ``normals="clearest"``.
    normals
        Given unit normals ``(k, T, d)``; ``origins`` then only fix the shapes. At most
        one of ``nearside_from``, ``clearest_from`` and ``normals``.
    input_bounds, dt
        The ego's input box ``(low, high)`` in m/s² and the sampling time in s: add
        the inter-sample rows of :func:`filters.intersample_rows`.
    backend
        ``"auto"``, ``"numba"`` or ``"numpy"`` (see :mod:`filters.kernels`).

    Raises
    ------
    InvalidArrayError
        If the samples, ``clearest_from`` or ``clearest_plan`` hold NaN or infinite
        values (named by index), or an array has the wrong shape; the errors of
        :func:`filters.safe_halfspaces` otherwise.
    InvalidParameterError
        If more than one of ``nearside_from``, ``clearest_from`` and ``normals`` is
        given, or ``clearest_plan`` without ``clearest_from``.
    """
    backend = check_backend(backend)
    if (nearside_from is not None) + (clearest_from is not None) + (normals is not None) > 1:
        raise InvalidParameterError(
            "step_rows: give at most one of nearside_from, clearest_from and normals")
    if clearest_plan is not None and clearest_from is None:
        raise InvalidParameterError("step_rows: clearest_plan needs clearest_from (the ego "
                                    "position)")
    if (type(samples) is np.ndarray and samples.ndim == 4 and samples.shape[0]
            and samples.shape[2] >= horizon and type(origins) is np.ndarray
            and origins.shape == (horizon, samples.shape[3]) and samples.shape[1]
            and len(obstacle_shapes) == samples.shape[0]
            and use_kernel(backend, support is None
                           and kernel_applies(ego_shape, obstacle_shapes, None, risk))):
        rows = _compiled(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha,
                         delta, epsilon, conformal_margins, previous_normals, ego_velocity,
                         nearside_from, clearest_from, clearest_plan, normals, input_bounds,
                         dt)
        if rows is not None:
            return rows
    return _reference(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha,
                      delta, epsilon, conformal_margins, support, previous_normals,
                      ego_velocity, nearside_from, clearest_from, clearest_plan, normals,
                      input_bounds, dt)


def _reference(origins, samples, horizon, ego_shape, obstacle_shapes, risk, alpha, delta,
               epsilon, conformal_margins, support, previous_normals, ego_velocity,
               nearside_from, clearest_from, clearest_plan, normals, input_bounds,
               dt) -> StepRows:
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
    if clearest_from is not None and samples.shape[0]:
        dim = samples.shape[3]
        ego = finite_array("clearest_from", clearest_from, shape=(dim,))
        plan = (None if clearest_plan is None
                else finite_array("clearest_plan", clearest_plan, shape=(horizon, dim)))
        given = clearest_normals(samples, np.asarray(origins, dtype=np.float64), ego, plan)
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
              clearest_from, clearest_plan, normals, input_bounds, dt) -> StepRows | None:
    """The kernel path; ``None`` when an argument has an unexpected shape or the kernel
    reports a problem (the numpy path then runs and names it). The kernel does not
    check indices: every array it reads is checked here or in :func:`compiled_rows`."""
    k, _, _, dim = samples.shape
    if ((previous_normals is not None and np.shape(previous_normals) != (k, horizon, dim))
            or (ego_velocity is not None
                and np.shape(ego_velocity) not in ((dim,), (horizon, dim)))
            or (nearside_from is not None and np.shape(nearside_from) != (dim,))
            or (clearest_from is not None and np.shape(clearest_from) != (dim,))
            or (clearest_plan is not None and np.shape(clearest_plan) != (horizon, dim))
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
    if nearside_from is not None:
        mode, ego = "nearside", nearside_from
    elif clearest_from is not None:
        mode, ego = "clearest", clearest_from
    else:
        mode, ego = ("paper" if normals is None else normals), None
    out = compiled_rows(
        samples, horizon, origins, radii=radii, risk=risk, alpha=alpha, delta=delta,
        epsilon=epsilon, conformal_margins=margins, normals=mode, ego_position=ego,
        plan=clearest_plan,
        previous_normals=previous_normals, ego_velocity=ego_velocity,
        input_bounds=input_bounds, dt=dt, disabled_offset=DISABLED_OFFSET)
    if out.status != 0:
        return None
    halfspaces = Halfspaces(out.normals, out.offsets, risk, alpha, delta, epsilon,
                            out.degenerate)
    if input_bounds is None:
        return StepRows(halfspaces, out.normals, out.offsets)
    return StepRows(halfspaces, out.rows_normals, out.rows_offsets)
