r"""The guarantee audit: did each risk formulation's promise hold on what really happened?

Every risk formulation of :mod:`filters.risk` makes a promise about the *loss* of
docs/design.md, the intrusion depth

.. math::

    \ell(p) = h \cdot y_\text{boundary} + r - h \cdot p = b + r - h \cdot p,

of an obstacle at position :math:`p` past the safe halfspace :math:`h \cdot y \le b`
(:math:`r = r_A + r_O` for two discs; :math:`\ell > 0` means that an ego on the
halfspace's boundary would overlap the obstacle by :math:`\ell`). The offset
:math:`b` is chosen from the *predicted* samples so that

* ``mean``: :math:`\mathbb E\,\ell \le \delta`;
* ``cvar``, ``dr_cvar``: :math:`\mathrm{CVaR}_\alpha(\ell) \le \delta` (DR-CVaR: for
  every law in the Wasserstein ball around the samples);
* ``gaussian_cc``, ``moment_dr``, ``conformal``: :math:`P(\ell > \delta) \le \alpha`
  (under a Gaussian fit; for every law with the samples' mean and covariance; with
  conformal marginal coverage).

The audit replaces the predicted law by the *realised* one: for the first-step
halfspace (look-ahead ``k = 1``) of each obstacle it evaluates :math:`\ell` at the
obstacle's realised position one step later, and pools those losses over the steps
where the halfspace was **active**:

.. math::

    b - h \cdot y_1 \le m(h) + \text{tol},

with :math:`y_1 = C x_1` the applied plan's position at ``k = 1``, :math:`m(h)` the
inter-sample bow margin of :func:`filters.intersample.arc_margin` when the filter adds
the inter-sample rows (its step-1 end row is :math:`h \cdot y_1 \le b - m(h)`; 0
without them) and ``tol`` = :data:`AUDIT_TOLERANCE` (1 mm, far above the QP solver's
tolerance). A step where the plan violates the halfspace (soft mode) counts as active
too. The promise matters only where it binds: an inactive halfspace is far from the
ego, whatever its loss.

Steps are pooled over episodes. The losses of successive steps of one episode are
correlated, so the Wilson interval of the violation frequency (which assumes
independent trials) is optimistic; the mean and the CVaR get a *cluster* bootstrap
interval instead (:func:`cluster_bootstrap`: episodes, not steps, are resampled), which
respects that correlation.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from agents.errors import RecordsFileError
from agents.evaluation.statistics import wilson_interval
from filters._validation import finite_array, scalar_in_range
from filters.risk import CHANCE_RISKS, check_alpha, empirical_cvar

__all__ = ["AUDIT_TOLERANCE", "PROMISES", "AuditResult", "audit_losses", "cluster_bootstrap",
           "decode_losses", "encode_losses", "first_step_losses"]

AUDIT_TOLERANCE = 1e-3
"""How close (m) the plan's step-1 position must come to a halfspace's tightest row
for that halfspace to count as active (see the module docstring)."""

PROMISES: dict[str, str] = {"mean": "mean", "cvar": "cvar", "dr_cvar": "cvar",
                            **dict.fromkeys((*CHANCE_RISKS, "conformal"), "chance")}
"""What each risk promises about the loss: ``"mean"`` (E ℓ <= δ), ``"cvar"``
(CVaR_α ℓ <= δ) or ``"chance"`` (P(ℓ > δ) <= α)."""

_DECIMALS = 4
"""Decimals (m) of a loss in the records' ``audit_losses`` columns: 0.1 mm."""


def first_step_losses(
    normals: np.ndarray,
    offsets: np.ndarray,
    planned_position: np.ndarray,
    realised_positions: np.ndarray,
    radii: np.ndarray,
    *,
    margins: np.ndarray | float = 0.0,
    tolerance: float = AUDIT_TOLERANCE,
) -> tuple[np.ndarray, np.ndarray]:
    r"""Which first-step halfspaces were active, and the realised loss of each obstacle.

    Parameters
    ----------
    normals
        Unit normals of the step-1 halfspaces, ``(k, d)``.
    offsets
        Their offsets :math:`b`, ``(k,)``, in m; safe side ``normals @ y <= offsets``.
    planned_position
        :math:`y_1`, the applied plan's ego position at step 1, ``(d,)``, in m.
    realised_positions
        The obstacles' realised positions at that step, ``(k, d)``, in m.
    radii
        :math:`r = S_O(h) + S_{-A}(h)` per obstacle (``r_A + r_O`` for discs), ``(k,)``.
    margins
        The inter-sample bow margin :math:`m(h)` per obstacle (``(k,)`` or a scalar), m.
    tolerance
        ``tol`` of the activity test, in m (>= 0).

    Returns
    -------
    active : numpy.ndarray of bool, shape (k,)
        :math:`b - h \cdot y_1 \le m + \text{tol}`.
    losses : numpy.ndarray, shape (k,)
        :math:`\ell = b + r - h \cdot p_\text{realised}`, in m (for every obstacle).

    Raises
    ------
    InvalidArrayError
        On inconsistent shapes or non-finite values.
    InvalidParameterError
        If ``tolerance`` is negative or not finite.
    """
    h = finite_array("normals", normals, ndim=2)
    k, d = h.shape
    b = finite_array("offsets", offsets, shape=(k,))
    y = finite_array("planned_position", planned_position, shape=(d,))
    p = finite_array("realised_positions", realised_positions, shape=(k, d))
    r = finite_array("radii", radii, shape=(k,))
    m = finite_array("margins", np.broadcast_to(np.asarray(margins, dtype=float), (k,)))
    tolerance = scalar_in_range("tolerance", tolerance, low=0.0, high=np.inf,
                                high_inclusive=False)
    active = b - h @ y <= m + tolerance
    losses = b + r - np.einsum("kd,kd->k", h, p)
    return active, losses


@dataclass(frozen=True)
class AuditResult:
    """The realised losses of one (case, method), against the method's promise.

    Attributes
    ----------
    n
        Active obstacle-steps pooled.
    alpha, delta
        The method's tail mass / violation probability and risk bound (m).
    mean_loss, cvar_loss
        Empirical mean and :math:`\\mathrm{CVaR}_\\alpha` of the realised loss, in m
        (NaN when ``n = 0``).
    violations
        Active steps with :math:`\\ell > \\delta`.
    violation_rate, violation_low, violation_high
        ``violations / n`` and its Wilson 95 % interval.
    mean_low, mean_high, cvar_low, cvar_high
        95 % cluster-bootstrap intervals of the mean and the CVaR (episodes resampled;
        NaN when the losses were not given per episode).
    """

    n: int
    alpha: float
    delta: float
    mean_loss: float
    cvar_loss: float
    violations: int
    violation_rate: float
    violation_low: float
    violation_high: float
    mean_low: float = math.nan
    mean_high: float = math.nan
    cvar_low: float = math.nan
    cvar_high: float = math.nan

    def verdict(self, promise: str) -> str:
        """Whether the promise (see :data:`PROMISES`) held on the realised losses.

        ``"held"`` if the point estimate meets the bound; ``"violated"`` if even the
        95 % interval lies beyond it (Wilson for P(ℓ > δ), the cluster bootstrap for the
        mean and the CVaR; without a bootstrap interval, the point estimate decides);
        ``"within noise"`` if only the point estimate does; ``"-"`` for no data.
        """
        if self.n == 0:
            return "-"
        value, bound, low = {"chance": (self.violation_rate, self.alpha, self.violation_low),
                             "mean": (self.mean_loss, self.delta, self.mean_low)}.get(
            promise, (self.cvar_loss, self.delta, self.cvar_low))
        if value <= bound:
            return "held"
        return "within noise" if not math.isnan(low) and low <= bound else "violated"


def cluster_bootstrap(
    groups: Sequence[np.ndarray],
    statistic: Callable[[np.ndarray], float],
    *,
    n_boot: int = 1000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile interval of ``statistic`` over the pooled values, resampling whole groups.

    Each replicate draws ``len(groups)`` groups (episodes) with replacement from a
    seeded ``numpy.random.Generator``, pools their values and evaluates
    ``statistic(pool)`` (e.g. ``np.mean``, or :func:`filters.risk.empirical_cvar` with
    its ``alpha`` bound); the interval is the ``(1 - level)/2`` and ``(1 + level)/2``
    quantiles of the replicates (replicates with no values are skipped). Correlation
    *within* a group is kept, which an interval over independent steps would ignore.

    Returns
    -------
    (low, high)
        NaN, NaN if no group has a value.
    """
    groups = [np.asarray(g, dtype=float).reshape(-1) for g in groups]
    if sum(g.size for g in groups) == 0:
        return (math.nan, math.nan)
    draws = np.random.default_rng(seed).integers(0, len(groups), (n_boot, len(groups)))
    pools = (np.concatenate([groups[i] for i in row]) for row in draws)
    replicates = [float(statistic(pool)) for pool in pools if pool.size]
    low, high = np.quantile(replicates, [(1 - level) / 2, (1 + level) / 2])
    return (float(low), float(high))


def audit_losses(losses: Sequence[float] | np.ndarray, *, alpha: float,
                 delta: float, groups: Sequence[np.ndarray] | None = None,
                 n_boot: int = 1000, seed: int = 0) -> AuditResult:
    """Empirical mean, CVaR_α and violation frequency P(ℓ > δ) of realised losses.

    Parameters
    ----------
    losses
        Realised losses :math:`\\ell` of the active steps, in m (ignored when ``groups``
        is given).
    alpha
        Tail mass of the CVaR and the allowed violation probability, in (0, 1].
    delta
        Risk bound, in m.
    groups
        The losses per episode; then they are pooled, and the mean and the CVaR get
        cluster-bootstrap intervals (:func:`cluster_bootstrap`, ``n_boot`` replicates,
        ``seed``).

    Raises
    ------
    InvalidArrayError
        If a loss is not finite.
    InvalidParameterError
        If ``alpha`` is outside (0, 1] or ``delta`` is not finite.
    """
    if groups is not None:
        groups = [np.asarray(g, dtype=float).reshape(-1) for g in groups]
        losses = np.concatenate(groups) if groups else np.zeros(0)
    x = finite_array("losses", losses).reshape(-1)
    alpha = check_alpha(alpha)
    delta = scalar_in_range("delta", delta)  # in m, finite
    n = int(x.size)
    violations = int(np.count_nonzero(x > delta))
    low, high = wilson_interval(violations, n)
    intervals: dict[str, float] = {}
    if groups is not None and n:
        for name, statistic in (("mean", np.mean),
                                ("cvar", functools.partial(empirical_cvar, alpha=alpha))):
            intervals[f"{name}_low"], intervals[f"{name}_high"] = cluster_bootstrap(
                groups, statistic, n_boot=n_boot, seed=seed)
    return AuditResult(
        n=n, alpha=alpha, delta=delta, mean_loss=float(x.mean()) if n else math.nan,
        cvar_loss=float(empirical_cvar(x, alpha)) if n else math.nan,
        violations=violations,
        violation_rate=violations / n if n else math.nan,
        violation_low=low, violation_high=high, **intervals,
    )


def encode_losses(losses: Iterable[float]) -> str:
    """Losses as the records' ``audit_losses`` text: ``";"``-separated, rounded to 0.1 mm.

    Trailing zeros are dropped and ``-0`` is written ``0``: ``0.1000`` -> ``0.1``.
    """
    texts = (f"{float(v):.{_DECIMALS}f}".rstrip("0").rstrip(".") for v in losses)
    return ";".join("0" if text == "-0" else text for text in texts)


def decode_losses(text: str) -> np.ndarray:
    """The losses of an ``audit_losses`` text (empty: none).

    Raises
    ------
    RecordsFileError
        If a field is not a finite number.
    """
    if not text:
        return np.zeros(0)
    try:
        values = np.array([float(v) for v in text.split(";")])
    except ValueError:
        raise RecordsFileError(f"audit_losses must be ';'-separated numbers, got "
                             f"{text[:80]!r}") from None
    if not np.all(np.isfinite(values)):
        raise RecordsFileError(f"audit_losses must be finite, got {text[:80]!r}")
    return values
