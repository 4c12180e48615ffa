"""Pluggable obstacle predictors: observed history in, prediction samples out.

A *predictor* is any callable

.. code-block:: python

    predictor(history, *, dt, horizon, n_samples, rng) -> samples

with ``history`` the obstacle positions observed so far, shape
``(n_steps_so_far, n_obs, d)`` (row 0 at reset, the last row now; metres),
``dt`` the sampling time (s), ``horizon`` ``T`` and ``n_samples`` ``N_s``, and
``rng`` the environment's :class:`numpy.random.Generator` (the only allowed
source of randomness, so episodes stay reproducible). It returns samples of the
positions at steps ``t+1..t+T``, shape ``(n_obs, N_s, T, d)`` in metres
(:class:`Predictor` is the protocol).

Built in:

* the environment's own sampler (``predictor=None`` or ``"environment"``, the
  default): the nominal lane motion plus prediction noise, with access to the
  lane and the turning schedule (:meth:`safe_nav_env.obstacles.ObstacleModel.predict`);
  episodes are bit-for-bit those of an environment without the keyword;
* :class:`ConstantVelocityKalman` (``"kalman"``): a constant-velocity Kalman filter
  on the observed positions only, no access to the lane;
* :class:`StalePredictor`: any of these fed the history without its last ``k`` rows,
  i.e. predictions made ``k`` steps ago (late predictions);
* any user callable with the signature above.

Pass one to the environment with ``gym.make(id, predictor=...)``. A custom
predictor draws from the same generator as the realised noise, so the realised
noise sequence differs from the default's for the same seed.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from safe_nav_env.constants import NOISE_VARIANCE
from safe_nav_env.errors import ConfigError
from safe_nav_env.options import _finite_array, _named, _option

__all__ = ["ENVIRONMENT", "PREDICTORS", "ConstantVelocityKalman", "Predictor", "StalePredictor",
    "check_predictions", "resolve_predictor"]

ENVIRONMENT = "environment"
"""Name of the environment's own sampler (the default predictor)."""


@runtime_checkable
class Predictor(Protocol):
    """Observed obstacle positions -> prediction samples (see the module docstring)."""

    def __call__(self, history: np.ndarray, *, dt: float, horizon: int, n_samples: int,
                 rng: np.random.Generator) -> np.ndarray:
        """Samples of shape ``(n_obs, n_samples, horizon, d)``, in m."""
        ...


@dataclass(frozen=True, kw_only=True)
class ConstantVelocityKalman:
    """Constant-velocity Kalman filter on observed positions, sampled from its predictive law.

    Per axis (axes and obstacles independent, same model), state
    :math:`x = (p, v)`, with white-acceleration process noise and position
    measurements:

    .. math::

        x_{t+1} = F x_t + w_t,\\ F = \\begin{pmatrix} 1 & T_s \\\\ 0 & 1 \\end{pmatrix},\\
        w_t \\sim N\\Big(0,\\
        q \\begin{pmatrix} T_s^3/3 & T_s^2/2 \\\\ T_s^2/2 & T_s \\end{pmatrix}\\Big),
        \\qquad y_t = p_t + v_t,\\ v_t \\sim N(0, r).

    Initialised at the first observation with covariance
    :math:`\\mathrm{diag}(r, \\sigma_{v,0}^2)` and zero velocity. The samples are drawn
    from the joint Gaussian predictive law of the *observations*
    :math:`y_{t+1..t+T}` given :math:`y_{0..t}` (mean :math:`H F^k \\hat x_t`, covariance
    :math:`H\\,\\mathrm{Cov}(x_{t+j}, x_{t+k}) H^\\top + r\\,\\delta_{jk}`), so a sample is a
    coherent trajectory, not independent points. It knows nothing of the lanes or
    turns: a turn shows up only through the observations.

    The covariance recursion does not depend on the data, so it is shared by all
    obstacles and axes; each call filters the whole history (the filter keeps no state).

    Parameters
    ----------
    acceleration_psd
        :math:`q`, power spectral density of the white acceleration, m²/s³ (default
        0.02: under the paper's noise, a random walk along the lane, the Gaussian fit's
        80 % one-sided quantile along random normals was exceeded 14-19 % of the time
        at look-aheads 1, 5 and 10 in 15 head-on and multi-obstacle episodes; 0.5 gave
        1-13 %, over-wide).
    measurement_variance
        :math:`r`, variance of the position jitter around the constant-velocity
        motion, m² (default 0.01, the paper's noise).
    initial_speed_std
        :math:`\\sigma_{v,0}`, prior standard deviation of each velocity component, m/s
        (default 2.0).

    Raises
    ------
    ConfigError
        For a non-finite or non-positive parameter.
    """

    acceleration_psd: float = 0.02
    measurement_variance: float = NOISE_VARIANCE
    initial_speed_std: float = 2.0

    def __post_init__(self) -> None:
        for name, strict in (("acceleration_psd", False), ("measurement_variance", True),
                             ("initial_speed_std", True)):
            object.__setattr__(self, name, _option(name, getattr(self, name), strict=strict))

    def _matrices(self, dt: float) -> tuple[np.ndarray, np.ndarray]:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        q = self.acceleration_psd
        Q = q * np.array([[dt**3 / 3.0, dt**2 / 2.0], [dt**2 / 2.0, dt]])
        return F, Q

    def filter(self, history: object, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """Filtered state after the last observation.

        Parameters
        ----------
        history
            Observed positions ``(n_steps, n_obs, d)``, ``n_steps >= 1``, m.
        dt
            Sampling time, s.

        Returns
        -------
        mean, covariance
            State means ``(n_obs, d, 2)`` (position, velocity per axis) and the shared
            ``(2, 2)`` covariance.

        Raises
        ------
        ConfigError
            If ``history`` is not a finite ``(n_steps, n_obs, d)`` array with ``n_steps >= 1``.
        """
        obs = _finite_array("history", history, "array", "(n_steps, n_obs, d) with n_steps >= 1",
                            lambda shape: len(shape) == 3 and shape[0] > 0)
        dt = _option("dt", dt, strict=True)
        F, Q = self._matrices(dt)
        r = self.measurement_variance
        mean = np.zeros((*obs.shape[1:], 2))
        mean[..., 0] = obs[0]
        P = np.diag([r, self.initial_speed_std**2])
        for row in obs[1:]:
            mean = mean @ F.T
            P = F @ P @ F.T + Q
            innovation = row - mean[..., 0]
            s = P[0, 0] + r
            gain = P[:, 0] / s  # (2,)
            mean = mean + innovation[..., None] * gain
            P = P - np.outer(gain, P[0, :])
            P = 0.5 * (P + P.T)
        return mean, P

    def predictive(
        self, history: object, *, dt: float, horizon: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Predictive mean ``(n_obs, T, d)`` and per-axis ``(T, T)`` covariance of observations."""
        mean, P = self.filter(history, dt)
        F, Q = self._matrices(float(dt))
        horizon = int(horizon)
        powers = [np.eye(2)]
        for _ in range(horizon):
            powers.append(F @ powers[-1])
        # Cov(x_{t+k}) = F Cov(x_{t+k-1}) F' + Q, Cov(x_{t+j}, x_{t+k}) = Cov(x_{t+j}) F^{k-j}'
        # for j <= k (and the (0, 0) entry is the same for the transpose, j > k).
        states = [P]
        for _ in range(horizon):
            states.append(F @ states[-1] @ F.T + Q)
        steps = range(1, horizon + 1)
        cov = np.array([[(states[min(j, k)] @ powers[abs(k - j)].T)[0, 0] for k in steps]
                        for j in steps]) + self.measurement_variance * np.eye(horizon)
        steps = np.stack([powers[k] for k in range(1, horizon + 1)])  # (T, 2, 2)
        future = np.einsum("kab,odb->okda", steps, mean)[..., 0]  # (n_obs, T, d)
        return future, cov

    def __call__(self, history: np.ndarray, *, dt: float, horizon: int, n_samples: int,
                 rng: np.random.Generator) -> np.ndarray:
        """Samples ``(n_obs, n_samples, horizon, d)`` from the predictive law, m."""
        future, cov = self.predictive(history, dt=dt, horizon=horizon)
        n_obs, _, dim = future.shape
        chol = np.linalg.cholesky(cov)
        z = rng.standard_normal((n_obs, int(n_samples), dim, int(horizon)))
        draws = z @ chol.T  # (n_obs, N_s, d, T)
        return future[:, None] + np.swapaxes(draws, -1, -2)


@dataclass(frozen=True)
class StalePredictor:
    """Late predictions: a base predictor that sees the positions only ``delay`` steps late.

    At time ``t`` the base predictor is called with the history up to ``t - k``
    (``k = delay``; at least the first row), so it returns its samples for steps
    ``t-k+1 .. t-k+T``, and these are handed out as the predictions for ``t+1 .. t+T``:
    a perception-and-prediction pipeline whose output arrives ``k`` steps
    (``k T_s`` s) after the positions it was computed from. Each predicted position
    lags the obstacle's true motion by ``k`` steps (``k T_s v`` m at speed ``v``).

    Parameters
    ----------
    base
        A predictor that uses the history (see :class:`Predictor`; default
        ``"kalman"``, a :class:`ConstantVelocityKalman`). The environment's own sampler
        (``None`` / ``"environment"``) predicts from the true current state, not from
        the history, so it cannot be made late this way.
    delay
        ``k``, in steps, an integer ``>= 0`` (0: the base predictor unchanged).

    Raises
    ------
    ConfigError
        If ``base`` is the environment's sampler or not a predictor, or ``delay`` is not
        an integer ``>= 0``.
    """

    base: Predictor | str | None = "kalman"
    delay: int = field(default=1, kw_only=True)

    def __post_init__(self) -> None:
        resolved = resolve_predictor(self.base)
        if resolved is None:
            raise ConfigError(
                "StalePredictor needs a predictor that uses the observed history (e.g. "
                f"'kalman'), not the environment's own sampler; got base={self.base!r}")
        object.__setattr__(self, "base", resolved)
        object.__setattr__(self, "delay", _option("delay (steps)", self.delay, integer=True))

    def __call__(self, history: np.ndarray, *, dt: float, horizon: int, n_samples: int,
                 rng: np.random.Generator) -> np.ndarray:
        """The base predictor's samples from ``history[: len - delay]`` (at least one row), m."""
        rows = max(1, len(history) - self.delay)
        return self.base(history[:rows], dt=dt, horizon=horizon, n_samples=n_samples, rng=rng)


PREDICTORS: dict[str, Any] = {ENVIRONMENT: None, "kalman": ConstantVelocityKalman}
"""Predictor names accepted by :func:`resolve_predictor` (``None``: the environment's sampler)."""


def resolve_predictor(value: object) -> Predictor | None:
    """Return ``value`` as a predictor, or ``None`` for the environment's own sampler.

    Parameters
    ----------
    value
        ``None`` or ``"environment"`` (the default sampler), ``"kalman"`` (a
        :class:`ConstantVelocityKalman` with default parameters), or a callable
        following :class:`Predictor`.

    Raises
    ------
    ConfigError
        For an unknown name or a non-callable value.
    """
    if value is None or value == ENVIRONMENT:
        return None
    if isinstance(value, str):
        return _named(PREDICTORS, value, "predictor", "name", ConfigError)()
    if isinstance(value, type) or not callable(value):
        raise ConfigError(
            "predictor must be None, a name in "
            f"{sorted(PREDICTORS)} or a callable (history, *, dt, horizon, n_samples, rng) -> "
            f"samples (an instance, not a class), got {value!r}"
        )
    return value  # type: ignore[return-value]


def check_predictions(
    samples: object, n_obs: int, n_samples: int, horizon: int, dim: int
) -> np.ndarray:
    """Return a predictor's output as a float64 ``(n_obs, N_s, T, d)`` array, or raise.

    Raises
    ------
    ConfigError
        If the output has another shape or holds NaN/inf.
    """
    expected = (n_obs, n_samples, horizon, dim)
    return _finite_array("the predictor's samples", samples, "array",
                         f"(n_obs, n_samples, horizon, d) = {expected}", lambda s: s == expected)
