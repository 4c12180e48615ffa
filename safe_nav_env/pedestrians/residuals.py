"""Prediction residual banks, measured on other scenes (leave one scene out).

For every pedestrian of a scene and every step ``t`` with ``T`` recorded steps
after it, the forecaster (:mod:`safe_nav_env.pedestrians.forecast`) sees the window of
positions up to ``t`` and predicts the nominal trajectory; the *residual trajectory*
is what really happened minus that prediction,

.. math::

    e_k = R_t^\\top\\,(p_{t+k} - \\bar p_{t+k}), \\qquad k = 1, \\dots, T,

expressed in the forecast's heading frame ``R_t`` (along and across the estimated
velocity for a moving pedestrian, world axes otherwise) and filed under the
forecast's stratum (new, standing, moving). The bank of a scene ``s`` holds the
residual trajectories of the *other* packaged scenes only; a scene given by a file
path uses all six. Prediction samples are then

.. math::

    \\hat p^{(j)}_{t+k} = \\bar p_{t+k} + R_t\\, e^{(m_j)}_k, \\qquad m_j \\sim U\\{1..M\\},

one whole residual trajectory per sample, drawn from the stratum of the current
forecast: the marginal at look-ahead ``k`` is the empirical law of the ``k``-step
residuals of the other scenes, and the look-aheads keep their correlation.

Banks are computed from the packaged files on first use and cached per process
(all six scenes, one forecaster: about 2 s measured on a heavily loaded 2-core host);
nothing is shipped precomputed, so the banks always match the code and the data.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from functools import cache

import numpy as np

from safe_nav_env.errors import ConfigError
from safe_nav_env.pedestrians.forecast import STRATA, Forecaster, headings, strata_of
from safe_nav_env.pedestrians.recording import SCENES, Recording, load_recording

__all__ = ["ResidualBank", "residual_bank", "scene_residuals"]


def scene_residuals(recording: Recording, forecaster: Forecaster, horizon: int) -> list[np.ndarray]:
    """Residual trajectories of one scene, per stratum: a list of ``(M_s, T, 2)`` arrays, m.

    Uses, for each pedestrian and step ``t``, the window of its positions at steps
    ``max(first, t - H + 1) .. t`` only, and the positions ``t+1 .. t+T`` as truth.
    """
    h = forecaster.history_steps
    parts: list[list[np.ndarray]] = [[] for _ in STRATA]
    for i in range(recording.n_pedestrians):
        track = recording.track(i)
        n = track.shape[0] - horizon  # steps t = 0 .. n-1 of the track have a full future
        if n <= 0:
            continue
        futures = np.lib.stride_tricks.sliding_window_view(track[1:], horizon, axis=0)
        futures = np.swapaxes(futures[:n], 1, 2)  # (n, T, 2)
        positions = np.empty((n, 2))
        velocities = np.empty((n, 2))
        lengths = np.minimum(np.arange(n) + 1, h)
        for t in range(min(n, h - 1)):  # short windows at the start of the track
            positions[t], velocities[t] = forecaster.estimate(track[: t + 1])
        if n >= h:
            windows = np.swapaxes(np.lib.stride_tricks.sliding_window_view(track, h, axis=0),
                                  1, 2)[: n - h + 1]
            positions[h - 1 :], velocities[h - 1 :] = forecaster.estimate_windows(windows)
        nominal = forecaster.nominal(positions, velocities, horizon)
        strata = strata_of(velocities, lengths)
        diff = futures - nominal
        local = np.conj(headings(velocities, strata))[:, None] * (diff[..., 0] + 1j * diff[..., 1])
        local = np.stack((local.real, local.imag), axis=-1)  # (along, across) = R^T r
        for code in range(len(STRATA)):
            rows = strata == code
            if rows.any():
                parts[code].append(local[rows])
    return [np.concatenate(p) if p else np.zeros((0, horizon, 2)) for p in parts]


@dataclass(frozen=True, eq=False)
class ResidualBank:
    """Residual trajectories per stratum and the scene each came from.

    Attributes
    ----------
    scenes
        The scenes the residuals were measured on.
    residuals
        Per stratum (``STRATA`` order) an ``(M, T, 2)`` read-only array, m, in the
        heading frame.
    sources
        Per stratum the index in :attr:`scenes` of each row's scene, ``(M,)``.
    """

    scenes: tuple[str, ...]
    residuals: tuple[np.ndarray, ...]
    sources: tuple[np.ndarray, ...]

    @property
    def horizon(self) -> int:
        """Look-ahead steps ``T`` of the residual trajectories."""
        return int(self.residuals[0].shape[1])

    def __post_init__(self) -> None:
        # All strata in one complex table (along + i across), (M_total, T) contiguous: one
        # gather per step, and the rotation is one complex product.
        table = np.concatenate([r[..., 0] + 1j * r[..., 1] for r in self.residuals])
        sizes = np.array([r.shape[0] for r in self.residuals], dtype=np.int64)
        offsets = np.concatenate(([0], np.cumsum(sizes)[:-1]))
        for name, value in (("_table", table), ("_sizes", sizes), ("_offsets", offsets)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    def sample(self, rng: np.random.Generator, nominal: np.ndarray, strata: np.ndarray,
               heading: np.ndarray, n_samples: int) -> np.ndarray:
        """Prediction samples ``nominal + R e``, shape ``(n, N_s, T, 2)``, m.

        Parameters
        ----------
        rng
            The only source of randomness: one ``rng.random((n, N_s))`` call; sample
            ``j`` of forecast ``i`` takes residual row ``floor(u_ij M)`` of its stratum
            (``M`` rows).
        nominal
            Nominal trajectories ``(n, T', 2)`` with ``T' <= T``, m.
        strata, heading
            Stratum code ``(n,)`` and heading frame ``(n,)`` (unit complex numbers, see
            :func:`~safe_nav_env.pedestrians.forecast.headings`) of each forecast.
        n_samples
            ``N_s``.
        """
        n, horizon = nominal.shape[0], nominal.shape[1]
        if horizon > self.horizon:
            raise ConfigError(
                f"the residual bank has {self.horizon} look-ahead steps, {horizon} requested"
            )
        uniform = rng.random((n, n_samples))
        rows = (uniform * self._sizes[strata][:, None]).astype(np.int64)
        rows += self._offsets[strata][:, None]
        picked = np.take(self._table, rows.ravel(), axis=0)
        if horizon < self.horizon:
            picked = picked[:, :horizon]
        out = picked.reshape(n, n_samples, horizon)
        out *= heading[:, None, None]  # R e
        out += (nominal[..., 0] + 1j * nominal[..., 1])[:, None, :]
        return out.view(np.float64).reshape(n, n_samples, horizon, 2)


def _merge(scenes: tuple[str, ...], per_scene: list[list[np.ndarray]]) -> ResidualBank:
    residuals, sources = [], []
    for code, stratum in enumerate(STRATA):
        arrays = [parts[code] for parts in per_scene]
        merged = np.concatenate(arrays)
        origin = np.concatenate([np.full(a.shape[0], s) for s, a in enumerate(arrays)])
        if merged.shape[0] == 0:
            raise ConfigError(
                f"no residual of stratum {stratum!r} in scenes {list(scenes)}: "
                "too few pedestrians or too short tracks for the horizon"
            )
        merged.flags.writeable = False
        origin.flags.writeable = False
        residuals.append(merged)
        sources.append(origin)
    return ResidualBank(scenes, tuple(residuals), tuple(sources))


def residual_bank(scene: str, forecaster: Forecaster, horizon: int,
                  recordings: Mapping[str, Recording] | None = None) -> ResidualBank:
    """The residual bank for predictions in ``scene``: every scene but ``scene``.

    Parameters
    ----------
    scene
        The test scene's name; if it is one of the scenes used (a packaged name by
        default), it is left out.
    forecaster
        The nominal forecaster whose errors are measured.
    horizon
        Look-ahead steps ``T``.
    recordings
        Scenes to measure on, by name; default the six packaged scenes at the
        forecaster's ``dt`` (then the result is cached per process).
    """
    if recordings is None:
        return _packaged_bank(scene if scene in SCENES else "", forecaster, int(horizon))
    names = tuple(name for name in recordings if name != scene)
    if not names:
        raise ConfigError(f"no scene left to measure residuals on after leaving out {scene!r}")
    parts = [scene_residuals(recordings[name], forecaster, int(horizon)) for name in names]
    return _merge(names, parts)


@cache
def _packaged_residuals(name: str, forecaster: Forecaster, horizon: int) -> list[np.ndarray]:
    return scene_residuals(load_recording(name, dt=forecaster.dt), forecaster, horizon)


@cache
def _packaged_bank(left_out: str, forecaster: Forecaster, horizon: int) -> ResidualBank:
    names = tuple(name for name in SCENES if name != left_out)
    return _merge(names, [_packaged_residuals(name, forecaster, horizon) for name in names])
