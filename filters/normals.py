r"""Where the wrapper's halfspace normals start: the near-side and the clearest rules.

Definitions 2-3 hold for any unit normal :math:`h`; the paper takes
:math:`h_{i,t} = (\bar p_{i,t} - y^r_t) / \lVert \bar p_{i,t} - y^r_t \rVert` (see
:func:`filters.safe_halfspaces`). :class:`filters.SafetyFilterWrapper` offers two
other choices of origin (``normals="nearside"`` and ``normals="clearest"``), computed
here and handed to :func:`filters.safe_halfspaces` as given ``normals``.
"""

from __future__ import annotations

import numpy as np

from filters.halfspaces import _sample_means

__all__ = ["clearest_normals", "nearside_normals"]


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
    means = _sample_means(np.asarray(samples, dtype=np.float64))
    return _unit(_nearside_directions(means, reference, ego), means, ego)


def _nearside_directions(means: np.ndarray, reference: np.ndarray,
                         ego: np.ndarray) -> np.ndarray:
    """Un-normalised near-side directions ``means - origin``, ``(k, T, d)`` (a new array)."""
    to_reference = reference[None] - means
    near = np.add.reduce(to_reference * (ego[None, None] - means), axis=-1) > 0.0
    return means - np.where(near[..., None], reference[None], ego[None, None])


def _unit(diff: np.ndarray, means: np.ndarray, ego: np.ndarray) -> np.ndarray:
    """``diff`` normalised along the last axis; a direction of length at most 1e-9 (an
    origin on the mean) falls back to the one from the ego, ``means - ego``, and where the
    ego is on the mean too, to the first axis."""
    size = np.sqrt(np.add.reduce(diff * diff, axis=-1, keepdims=True))
    usable = size > 1e-9
    if np.count_nonzero(usable) == usable.size:  # the usual case (NaN is not usable)
        return diff / size
    from_ego = means - ego[None, None]  # (k, T, d)
    ego_size = np.sqrt(np.add.reduce(from_ego * from_ego, axis=-1, keepdims=True))
    axis = np.eye(means.shape[-1])[0]
    fallback = np.where(ego_size > 1e-9, from_ego / np.maximum(ego_size, 1e-12), axis)
    return np.where(usable, diff / np.maximum(size, 1e-12), fallback)


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
    means = _sample_means(np.asarray(samples, dtype=np.float64))
    if plan is None:
        diff = _nearside_directions(means, reference, ego)
    else:  # the farther origin (squared distances)
        to_reference, to_plan = means - reference[None], means - plan[None]
        use_reference = np.add.reduce(to_reference * to_reference, axis=-1) >= np.add.reduce(
            to_plan * to_plan, axis=-1)
        diff = np.where(use_reference[..., None], to_reference, to_plan)
    diff[:, 0] = means[:, 0] - ego  # the first step's normal starts at the ego
    return _unit(diff, means, ego)
