"""Noise laws of the obstacle motion and of its predictions.

A law is a frozen dataclass with a mean (the *bias*) and a covariance, and
:meth:`~Gaussian.sample` draws from it with a :class:`numpy.random.Generator`.
Every law is an affine image of a standardised vector ``z`` with independent,
zero-mean, unit-variance components,

.. math::

    w = \\mu + L z, \\qquad L L^\\top = \\Sigma,

so ``E[w] = μ`` and ``Cov[w] = Σ`` exactly, whatever the law of the components:

* :class:`Gaussian`: ``z_j ~ N(0, 1)``.
* :class:`Laplace`: ``z_j ~ Laplace(0, 1/√2)``, so with a diagonal ``Σ`` axis ``j``
  is Laplace with scale ``b_j = sqrt(Σ_jj / 2)`` (excess kurtosis 3).
* :class:`StudentT`: ``z_j = t_ν · sqrt((ν - 2)/ν)`` with ``ν > 2`` degrees of
  freedom (excess kurtosis ``6/(ν - 4)`` for ``ν > 4``, infinite below).

The covariance is given as a scalar ``σ²`` (meaning ``σ² I``), a sequence of
per-axis variances (a diagonal ``Σ``) or a full symmetric positive semidefinite
matrix; positions are in m, so covariances are in m². A zero covariance gives a
deterministic law (useful in tests).

:class:`NoiseModel` pairs the law used to *predict* the obstacles (the samples the
safety filter sees) with the law of *reality* (the realised obstacle motion), and
the number of prediction samples. Named presets are in :data:`NOISE_PRESETS`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from safe_nav_env.constants import N_SAMPLES, NOISE_VARIANCE
from safe_nav_env.errors import ScenarioError
from safe_nav_env.options import _finite_array, _from_fields, _named, _option

# A covariance as given by the user: σ², (σ²_1, ..., σ²_d) or a d × d matrix.
Covariance = float | tuple[float, ...] | tuple[tuple[float, ...], ...]
Mean = float | tuple[float, ...]


def _as_float_tuple(value: Any, path: str) -> float | tuple[float, ...] | tuple[tuple, ...]:
    array = _finite_array(path, value, "scalar, vector or matrix", "(), (d,) or (d, e)",
                          lambda shape: len(shape) <= 2, ScenarioError)
    values = array.tolist()  # Python floats
    return values if array.ndim == 0 else tuple(map(tuple, values) if array.ndim == 2 else values)


@dataclass(frozen=True)
class _Law:
    """Common part of the noise laws (see the module docstring)."""

    covariance: Covariance = NOISE_VARIANCE
    mean: Mean = 0.0

    # Filled in by __post_init__: how to scale the standardised draws.
    _kind: str = field(init=False, repr=False, compare=False, default="iso")
    _scale: Any = field(init=False, repr=False, compare=False, default=1.0)
    _mean_array: Any = field(init=False, repr=False, compare=False, default=None)

    law: ClassVar[str] = ""

    def __post_init__(self) -> None:
        name = type(self).__name__
        cov = _as_float_tuple(self.covariance, f"{name}.covariance")
        mean = _as_float_tuple(self.mean, f"{name}.mean")
        object.__setattr__(self, "covariance", cov)
        object.__setattr__(self, "mean", mean)
        cov_array = np.asarray(cov, dtype=np.float64)
        if cov_array.ndim < 2:  # σ² or per-axis variances
            if np.any(cov_array < 0):
                raise ScenarioError(f"{name}.covariance must be >= 0 (variances in m²), got {cov}")
            kind = "iso" if cov_array.ndim == 0 else "diag"
            scale = math.sqrt(float(cov_array)) if kind == "iso" else np.sqrt(cov_array)
        else:
            if cov_array.shape[0] != cov_array.shape[1]:
                raise ScenarioError(f"{name}.covariance must be a square matrix, got shape "
                                    f"{cov_array.shape}")
            if not np.allclose(cov_array, cov_array.T, rtol=0.0, atol=1e-12):
                raise ScenarioError(f"{name}.covariance must be symmetric, got {cov}")
            eigenvalues, eigenvectors = np.linalg.eigh(cov_array)
            if eigenvalues.min() < -1e-12 * max(1.0, float(np.abs(eigenvalues).max())):
                raise ScenarioError(f"{name}.covariance must be positive semidefinite, got "
                                    f"eigenvalues {eigenvalues.tolist()}")
            kind = "full"
            scale = eigenvectors * np.sqrt(np.clip(eigenvalues, 0.0, None))  # L with L L' = Σ
        mean_array = np.asarray(mean, dtype=np.float64)
        if mean_array.ndim > 1:
            raise ScenarioError(f"{name}.mean must be a scalar or a vector, got {mean}")
        if kind != "iso" and mean_array.ndim == 1 and mean_array.shape[0] != cov_array.shape[0]:
            raise ScenarioError(f"{name}.mean has {mean_array.shape[0]} entries but "
                                f"{name}.covariance is for {cov_array.shape[0]} axes")
        object.__setattr__(self, "_kind", kind)
        object.__setattr__(self, "_scale", scale)
        object.__setattr__(self, "_mean_array", None if not np.any(mean_array) else mean_array)
        self._check_extra()

    def _check_extra(self) -> None:
        """Validate law-specific parameters (overridden by :class:`StudentT`)."""

    @property
    def dim(self) -> int | None:
        """Number of axes fixed by the parameters, or ``None`` if any number fits."""
        if self._kind != "iso":
            return int(np.shape(self.covariance)[0])
        return int(np.shape(self.mean)[0]) if np.ndim(self.mean) == 1 else None

    def mean_vector(self, dim: int) -> np.ndarray:
        """Mean ``μ`` as a vector of length ``dim``, in m."""
        return np.broadcast_to(np.asarray(self.mean, dtype=np.float64), (dim,)).copy()

    def covariance_matrix(self, dim: int) -> np.ndarray:
        """Covariance ``Σ`` as a ``(dim, dim)`` matrix, in m²."""
        cov = np.asarray(self.covariance, dtype=np.float64)
        if cov.ndim == 0:
            return float(cov) * np.eye(dim)
        return np.diag(cov) if cov.ndim == 1 else cov.copy()

    def _standard(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        raise NotImplementedError

    def sample(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Draw independent vectors ``w = μ + L z``.

        Parameters
        ----------
        rng
            Source of randomness.
        shape
            Shape of the result; its last entry is the number of axes ``d`` and
            every other index is an independent draw.

        Returns
        -------
        numpy.ndarray
            Float64 array of ``shape``, in m.
        """
        z = self._standard(rng, shape)
        if self._kind == "full":
            z = z @ self._scale.T
        elif self._kind == "diag" or self._scale != 1.0:
            z *= self._scale
        if self._mean_array is not None:
            z += self._mean_array
        return z


@dataclass(frozen=True)
class Gaussian(_Law):
    """Gaussian law ``N(μ, Σ)``.

    Parameters
    ----------
    covariance
        ``σ²`` (for ``σ² I``), per-axis variances, or a full matrix, in m².
    mean
        Mean ``μ`` (bias), scalar (same on every axis) or per axis, in m.
    """

    law: ClassVar[str] = "gaussian"

    def _standard(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return rng.standard_normal(shape)


_INV_SQRT2 = 1.0 / math.sqrt(2.0)


@dataclass(frozen=True)
class Laplace(_Law):
    """Laplace law with mean ``μ`` and covariance ``Σ`` (independent axes when ``Σ`` is diagonal).

    Axis ``j`` has density ``exp(-|w_j - μ_j| / b_j) / (2 b_j)`` with scale
    ``b_j = sqrt(Σ_jj / 2)``, so its variance is ``2 b_j² = Σ_jj``: the paper's
    realised motion, "a Laplace distribution with the same mean and covariance as
    the Gaussian".

    Parameters
    ----------
    covariance
        ``σ²`` (for ``σ² I``), per-axis variances, or a full matrix, in m².
    mean
        Mean ``μ`` (bias), in m.
    """

    law: ClassVar[str] = "laplace"

    @classmethod
    def from_scale(cls, scale: float | tuple[float, ...], mean: Mean = 0.0) -> Laplace:
        """Laplace law given its per-axis scale ``b`` (in m) instead of its covariance ``2 b²``."""
        b = np.asarray(scale, dtype=np.float64)
        if b.ndim > 1 or not np.all(np.isfinite(b)) or np.any(b < 0):
            raise ScenarioError(f"Laplace scale must be >= 0 (in m), got {scale!r}")
        return cls(covariance=(2.0 * b**2).tolist(), mean=mean)

    @property
    def scale(self) -> float | np.ndarray:
        """Per-axis scale ``b = sqrt(Σ_jj / 2)``, in m."""
        cov = np.asarray(self.covariance, dtype=np.float64)
        diagonal = cov if cov.ndim < 2 else np.diag(cov)
        b = np.sqrt(diagonal / 2.0)
        return float(b) if b.ndim == 0 else b

    def _standard(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        return rng.laplace(0.0, _INV_SQRT2, shape)


@dataclass(frozen=True)
class StudentT(_Law):
    """Student-t law with ``dof`` degrees of freedom, scaled to mean ``μ`` and covariance ``Σ``.

    Each standardised component is ``t_ν sqrt((ν - 2)/ν)``; the tails are heavier
    than the Laplace law's when ``ν <= 7`` (excess kurtosis ``6/(ν - 4)``, infinite
    for ``ν <= 4``).

    Parameters
    ----------
    covariance
        ``σ²`` (for ``σ² I``), per-axis variances, or a full matrix, in m².
    mean
        Mean ``μ`` (bias), in m.
    dof
        Degrees of freedom ``ν > 2`` (the variance is infinite otherwise).
    """

    dof: float = 3.0
    law: ClassVar[str] = "student_t"

    def _check_extra(self) -> None:
        object.__setattr__(self, "dof", _option("StudentT.dof", self.dof, low=2.0, strict=True,
                                                error=ScenarioError))

    def _standard(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        z = rng.standard_t(self.dof, shape)
        z *= math.sqrt((self.dof - 2.0) / self.dof)
        return z


NoiseLaw = Gaussian | Laplace | StudentT
"""Any of the noise laws."""

LAWS: dict[str, type[_Law]] = {cls.law: cls for cls in (Gaussian, Laplace, StudentT)}
"""Noise laws by name, as used in mappings: ``{"law": "laplace", "covariance": 0.01}``."""


def noise_law(value: Any, path: str = "law") -> _Law:
    """Return ``value`` as a noise law.

    Parameters
    ----------
    value
        A law object, a law name (``"gaussian"``, ``"laplace"``, ``"student_t"``,
        with default parameters), or a mapping ``{"law": name, **parameters}``.
    path
        Field path used in error messages.

    Raises
    ------
    ScenarioError
        If the name is unknown or a parameter is invalid; the message starts with ``path``.
    """
    if isinstance(value, _Law):
        return value
    if isinstance(value, str):
        value = {"law": value}
    if not isinstance(value, Mapping):
        raise ScenarioError(f"{path} must be a noise law (Gaussian, Laplace, StudentT), a law "
                            f"name in {sorted(LAWS)} or a mapping with a 'law' key, got {value!r}")
    params = dict(value)
    name = params.pop("law", None)
    if name not in LAWS:
        raise ScenarioError(f"{path}.law must be one of {sorted(LAWS)}, got {name!r}")
    return _from_fields(LAWS[name], params, path)


@dataclass(frozen=True)
class NoiseModel:
    """How the obstacles' predictions are sampled and how they really move.

    Laws may also be given by name or as mappings (see :func:`noise_law`), so a
    noise model can be written as plain data.

    Parameters
    ----------
    prediction
        Law of the noise added to the nominal trajectory at each predicted step
        (independently per step and per sample). Default ``N(0, 0.01 I)``, the paper's.
    reality
        Law of the noise added to the obstacle's nominal one-step motion. Default
        Laplace with the same mean and covariance as the prediction law, the paper's.
    n_samples
        Number of prediction samples per obstacle, ``N_s`` (default 100).

    Raises
    ------
    ScenarioError
        If a law is invalid or ``n_samples < 1``; the message names the field.
    """

    prediction: NoiseLaw = field(default_factory=lambda: Gaussian(NOISE_VARIANCE))
    reality: NoiseLaw = field(default_factory=lambda: Laplace(NOISE_VARIANCE))
    n_samples: int = N_SAMPLES

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_samples", _option("noise.n_samples", self.n_samples, low=1,
                                                      integer=True, error=ScenarioError))
        for name in ("prediction", "reality"):
            object.__setattr__(self, name, noise_law(getattr(self, name), f"noise.{name}"))
            dim = getattr(self, name).dim
            if dim is not None and dim != 2:
                raise ScenarioError(f"noise.{name} is for {dim} axes, the arena has 2")


NOISE_PRESETS: dict[str, NoiseModel] = {
    "paper": NoiseModel(n_samples=N_SAMPLES),
    "authors_code": NoiseModel(Gaussian(0.1), Laplace.from_scale(0.1), n_samples=20),
    "gaussian_reality": NoiseModel(reality=Gaussian(NOISE_VARIANCE), n_samples=N_SAMPLES),
    "student_t": NoiseModel(reality=StudentT(NOISE_VARIANCE, dof=3.0), n_samples=N_SAMPLES),
}
"""Named noise models.

``"paper"``
    Section IV-B: 100 samples of ``N(0, 0.01 I)``; reality Laplace with the same
    mean and covariance (scale ``sqrt(0.005) ≈ 0.071`` m per axis).
``"authors_code"``
    What the authors' simulation code does: 20 samples with covariance ``0.1 I``
    (std 0.316 m per axis), reality Laplace with scale 0.1 m (covariance ``0.02 I``).
``"gaussian_reality"``
    As ``"paper"`` but reality Gaussian too: the predictions are exact in law.
``"student_t"``
    As ``"paper"`` but reality Student-t with 3 degrees of freedom and covariance
    ``0.01 I``: a heavier tail than the Laplace law.
"""


def resolve_noise(value: Any, path: str = "noise") -> NoiseModel:
    """Return ``value`` as a :class:`NoiseModel`.

    Parameters
    ----------
    value
        A :class:`NoiseModel`, a preset name from :data:`NOISE_PRESETS`, or a mapping
        of :class:`NoiseModel` fields.
    path
        Field path used in error messages.

    Raises
    ------
    ScenarioError
        If the preset name is unknown or the data invalid.
    """
    if isinstance(value, str):
        return _named(NOISE_PRESETS, value, path, "noise preset")
    return _from_fields(NoiseModel, value, path, names=NOISE_PRESETS)
