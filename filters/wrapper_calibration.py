"""Calibration glue of :class:`filters.wrapper.SafetyFilterWrapper`.

The held-out calibration run at construction (``risk="conformal"``,
``epsilon="auto"``, ``adaptive_epsilon=True``: split conformal, calibrate on held-out
braking episodes, then run), its per-process snapshots, and the per-step feed of the
online calibration (:class:`filters.calibration.OnlineCalibration`) and the calibrated
risk options.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any

import numpy as np

from filters.calibration import OnlineCalibration
from filters.config import FIELDS, FilterConfig
from filters.constants import EPSILON

_MAX_CALIBRATION_STEPS = 10_000
"""Safety cap on the steps of one held-out episode (the environment truncates earlier)."""

_SNAPSHOTS: dict[tuple, OnlineCalibration] = {}
"""Calibrated states of this process, by environment and settings (see ``_snapshot_key``)."""

_MAX_SNAPSHOTS = 32


def calibration_settings(risk: str, epsilon: float | str = EPSILON,
                         **settings: Any) -> dict[str, Any] | None:
    """The held-out calibration a :class:`filters.wrapper.SafetyFilterWrapper` with these
    keywords runs: :meth:`filters.config.FilterConfig.calibration` of their config.

    Keywords that are not settings (``policy``, ``reference``, the deprecated ones) are
    ignored, so ``calibration_settings(**kwargs)`` works on a wrapper's keyword dict.
    """
    return FilterConfig.from_dict({name: value for name, value in settings.items()
                                   if name in FIELDS}, FilterConfig(risk, epsilon=epsilon)
                                  ).calibration()


def _plain_settings(value: object) -> tuple | None:
    """A hashable canonical form of plain settings, or ``None`` if ``value`` holds others.

    Plain: ``None``, bools, numbers, strings, and tuples, lists, string-keyed dicts and
    frozen dataclasses of plain values (types included, so ``1`` and ``1.0`` differ). A
    dataclass is read through the fields that define its equality (``compare=True``):
    derived caches such as the noise laws' scaled mean array are left out.
    """
    cls = type(value)
    if value is None or isinstance(value, bool | int | float | str):
        return (cls.__qualname__, value)
    if isinstance(value, tuple | list):
        tag, named = cls.__qualname__, enumerate(value)
    elif isinstance(value, dict) and all(isinstance(name, str) for name in value):
        tag, named = "dict", ((name, value[name]) for name in sorted(value))
    elif (dataclasses.is_dataclass(value) and not isinstance(value, type)
          and value.__dataclass_params__.frozen):
        tag = f"{cls.__module__}.{cls.__qualname__}"
        named = ((f.name, getattr(value, f.name)) for f in dataclasses.fields(value) if f.compare)
    else:
        return None
    items = tuple((name, _plain_settings(item)) for name, item in named)
    return None if any(item is None for _, item in items) else (tag, items)


class CalibrationMixin:
    """The wrapper's calibration methods (mixed into
    :class:`filters.wrapper.SafetyFilterWrapper`, whose attributes they use)."""

    def _calibrate(self) -> None:
        """Score the realised obstacle positions against the predictions issued for now.

        An environment whose obstacle rows change hands names the obstacle in each row
        (``obstacle_ids``, negative for an empty row): each prediction is then scored
        against its own obstacle's position only.
        """
        base = self._unwrapped
        predictions = np.asarray(base.predictions, dtype=float)[:, :, : self.horizon]
        if np.isfinite(predictions).all():
            self._calibration.update(predictions, np.asarray(base.obstacle_positions),
                                     ids=getattr(base, "obstacle_ids", None))

    def _warm_up_calibration(self) -> None:
        """Feed ``calibration_episodes`` held-out braking episodes to the calibration.

        Sets the state every episode starts from (``calibration_memory="episode"``) and
        :attr:`calibration_time`. The base environment is driven directly (the wrappers
        in between keep no record of these episodes); its seed state and render mode
        are restored afterwards.
        """
        begin = time.perf_counter()
        key = self._snapshot_key() if self.calibration_episodes else None
        if key is not None and key in _SNAPSHOTS:
            self._calibration, self._calibrated = _SNAPSHOTS[key].copy(), _SNAPSHOTS[key].copy()
            self.calibration_time = time.perf_counter() - begin
            return
        base = self._unwrapped
        saved = {name: getattr(base, name) for name in ("_np_random", "_np_random_seed",
                                                         "render_mode") if hasattr(base, name)}
        try:
            if "render_mode" in saved:
                base.render_mode = None  # no window or trail for held-out episodes
            for episode in range(self.calibration_episodes):
                base.reset(seed=self.calibration_seed + episode)
                self._calibration.reset()
                self._calibrate()
                for _ in range(_MAX_CALIBRATION_STEPS):
                    brake = self._mpc.braking_input(np.asarray(base.ego_state, dtype=float))
                    _, _, terminated, truncated, _ = base.step(brake.astype(np.float32))
                    self._calibrate()
                    if terminated or truncated:
                        break
        finally:
            for name, value in saved.items():
                setattr(base, name, value)
        self._calibration.reset()
        if self.epsilon == "auto" and self.calibration_episodes:
            self._calibration.radii()  # the bootstrap runs once here, not in every episode
        self._calibrated = self._calibration.copy()
        if key is not None:
            if len(_SNAPSHOTS) >= _MAX_SNAPSHOTS:
                del _SNAPSHOTS[next(iter(_SNAPSHOTS))]
            _SNAPSHOTS[key] = self._calibration.copy()
        self.calibration_time = time.perf_counter() - begin

    def _snapshot_key(self) -> tuple | None:
        """What determines the held-out calibration, or ``None`` if it cannot be told.

        The held-out episodes depend only on the environment's construction (its
        ``gym.make`` id and keywords: the scenario, noise, predictor, samples ...; the
        ego's braking follows from its dynamics and bounds), the seeds, the horizon and
        the calibration's settings. When the keywords are plain values (numbers, strings,
        frozen dataclasses of them, as the scenarios, noise models and stress cases are),
        the calibrated state is computed once per process and copied to every wrapper
        of the same environment and settings (the evaluation builds one wrapper per
        episode). Anything else (a callable predictor, an environment not made by
        ``gym.make``) gives ``None``: no sharing.
        """
        base = self._unwrapped
        spec = getattr(base, "spec", None)
        kwargs = _plain_settings(dict(spec.kwargs)) if spec is not None else None
        if kwargs is None:
            return None
        return (type(base).__module__, type(base).__qualname__, spec.id, kwargs,
                _plain_settings(spec.max_episode_steps), self.horizon,
                self._calibration.conformal.alpha, self.epsilon == "auto",
                (self.alpha, self.epsilon) if self.adaptive_epsilon else None,
                self.calibration_episodes, self.calibration_seed)

    def _risk_options(self) -> dict[str, Any]:
        """Risk settings of this step (the calibrated ones per look-ahead step)."""
        epsilon = self.epsilon
        if epsilon == "auto":
            epsilon = self._calibration.radii()
        elif self.adaptive_epsilon:
            epsilon = self._calibration.adaptive_radii()
        options = dict(risk=self.risk, alpha=self.alpha, delta=self.delta, epsilon=epsilon)
        if self.risk == "conformal":
            options["conformal_margins"] = self._calibration.margins()
        return options
