"""Per-step halfspace rows of :class:`filters.wrapper.SafetyFilterWrapper`.

Where the normals start (the ``normals`` option), the step's safe halfspaces and the
inter-sample rows the QP is given (:func:`filters.intersample.intersample_halfspaces`,
or :func:`filters.safe_halfspaces` without the inter-sample rows).
"""

from __future__ import annotations

import numpy as np

from filters.errors import InvalidArrayError, InvalidParameterError
from filters.geometry import Disc
from filters.halfspace_checks import _Inputs
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.intersample import batched_halfspaces, intersample_halfspaces
from filters.mpc.checks import all_finite
from filters.normals import clearest_normals, nearside_normals
from filters.protocol import FilterableEnv


class HalfspaceRowsMixin:
    """The wrapper's per-step halfspace methods (mixed into
    :class:`filters.wrapper.SafetyFilterWrapper`, whose attributes they use)."""

    @property
    def _last_halfspaces(self) -> Halfspaces | None:
        """The last filtered step's :class:`~filters.halfspaces.Halfspaces` (for drawing)."""
        return self._halfspaces_made

    def _normal_origins(self, y0: np.ndarray, ref_positions: np.ndarray) -> np.ndarray:
        """Positions ``(T, d)`` the normals start from (see ``normals``); ``y0 = C x0``."""
        if self.normals == "ego":
            return np.broadcast_to(y0, ref_positions.shape)
        if self.normals == "previous_plan" and self._last_plan is not None:
            return _shifted_positions(self._last_plan @ self._unwrapped.dynamics[2].T, y0)
        return ref_positions

    def _clearest_plan(self, y0: np.ndarray) -> np.ndarray | None:
        """The last plan's positions shifted to start at ``y0`` ``(T, d)``, if that step
        was optimal, else ``None`` (the plan of ``normals="clearest"``)."""
        if self._last_plan is None or not self._plan_optimal:
            return None
        return _shifted_positions(self._last_plan @ self._unwrapped.dynamics[2].T, y0)

    def _halfspaces(
        self, base: FilterableEnv, x0: np.ndarray, ref_states: np.ndarray, radii: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The step's halfspaces ``(normals, offsets)`` and the QP's rows (with the
        inter-sample rows, if set); the halfspaces are kept for :attr:`_last_halfspaces`.

        The normals start at :meth:`_normal_origins` (``"nearside"``, ``"clearest"``: the
        rules of :mod:`filters.normals`); :func:`filters.intersample.intersample_halfspaces`
        gives the halfspaces and the inter-sample rows in one pass
        (:func:`filters.safe_halfspaces` without the inter-sample rows).
        """
        predictions = np.asarray(base.predictions, dtype=float)
        if predictions.ndim != 4 or predictions.shape[2] < self.horizon:
            raise InvalidParameterError(
                f"the filter horizon {self.horizon} exceeds the prediction horizon "
                f"of the environment (predictions of shape {predictions.shape}, expected "
                "(n_obstacles, n_samples, T, d))"
            )
        samples = predictions[:, :, :self.horizon]
        ego_shape, obstacle_shapes = self._shapes(float(base.ego_radius), radii)
        C = base.dynamics[2]
        y0 = C @ x0
        origins = self._normal_origins(y0, ref_states[1:, :] @ C.T)
        given = previous = velocity = None
        if not (len(radii) and self.normals in ("nearside", "clearest")):
            # the paper's normals; a degenerate one falls back to the last step's normals
            # (shifted by one step to line up with this horizon), then to -velocity
            previous, velocity = self._previous_normals, x0[2:]
            if previous is not None and previous.shape[0] == len(radii):
                previous = np.concatenate([previous[:, 1:], previous[:, -1:]], axis=1)
            else:
                previous = None
        else:
            if not all_finite(samples):
                raise InvalidArrayError(
                    "the prediction samples hold NaN or infinite values (at indices "
                    f"{np.argwhere(~np.isfinite(samples))[0].tolist()})")
            given = (nearside_normals(samples, origins, y0) if self.normals == "nearside"
                     else clearest_normals(samples, origins, y0, self._clearest_plan(y0)))
        if (given is not None and self.intersample and self._calibration is None
                and self.support is None and samples.shape[2] > 1
                and len(obstacle_shapes) == samples.shape[0] and all_finite(origins)):
            # the wrapper's usual step: the settings were checked by FilterConfig, and the
            # normals are unit vectors already (filters.normals divides by the norms;
            # normalising them again would move them by an ulp at most)
            data = _Inputs(self.risk, self.alpha, self.delta, origins, samples, self.epsilon, None,
                           obstacle_shapes, None, None, None, given)
            halfspaces, rows = batched_halfspaces(data, ego_shape, base.input_bounds,
                                                  float(base.dt))
            self._halfspaces_made = halfspaces
            return halfspaces.normals, halfspaces.offsets, (rows.normals, rows.offsets)
        options = dict(ego_shape=ego_shape, obstacle_shapes=obstacle_shapes, support=self.support,
                       previous_normals=previous, ego_velocity=velocity, normals=given,
                       **self._risk_options())
        if self.intersample:
            halfspaces, rows = intersample_halfspaces(
                origins, samples, input_bounds=base.input_bounds, dt=float(base.dt), **options)
        else:
            halfspaces = rows = safe_halfspaces(origins, samples, **options)
        self._halfspaces_made = halfspaces
        return halfspaces.normals, halfspaces.offsets, (rows.normals, rows.offsets)

    def _shapes(self, ego_radius: float, radii: np.ndarray) -> tuple[Disc, list[Disc]]:
        """The ego and obstacle discs, built once per set of radii (not every step)."""
        key = (ego_radius, tuple(radii.tolist()))
        if self._shape_cache is None or self._shape_cache[0] != key:
            self._shape_cache = (key, Disc(ego_radius), [Disc(r) for r in key[1]])
        return self._shape_cache[1], self._shape_cache[2]


def _shifted_positions(positions: np.ndarray, y0: np.ndarray) -> np.ndarray:
    """The last plan's positions ``(T+1, d)`` shifted one step: ``(T, d)``, starting at ``y0``.

    Row ``t`` is :math:`y^{prev}_{t+1} - y^{prev}_1 + y_0` (the last row repeated at the
    end): the plan as it continues from the current position.
    """
    shifted = np.concatenate([positions[2:], positions[-1:]], axis=0)
    return shifted - positions[1] + y0

