r"""Compiled (numba) kernels of the safe halfspaces: fused passes per obstacle and block of steps.

Private: :mod:`filters.kernels` prepares the arguments and picks this path or the
numpy reference of :mod:`filters.halfspaces`. Importing this module imports numba
(and loads the kernels from numba's cache, or compiles them), so nothing imports it
at ``import filters``.

The samples arrive flattened, ``flat[i, s, t d + j] = p_{i,s,t,j}``. For obstacle
:math:`i` and a block of consecutive steps (their samples stay in cache between the
passes):

1. **moments**, one pass in memory order: the sums of the deviations
   :math:`p_{i,s,t} - p_{i,0,t}` from the first sample (so the rounding error does not
   grow with the size of the positions) and of their squares and, for ``d = 2``,
   cross products; they give the sample means :math:`\bar p_{i,t}` (hence the unit
   normals, with the documented fallbacks) and the sample covariance;
2. **losses**, one pass per step and normal, only where the risk needs the samples:
   :math:`x_s = -h \cdot p_{i,s,t}` along the step's normal :math:`h_{i,t}` and, for
   the inter-sample start rows, along the next step's normal
   :math:`h' = h_{i,t+1} / \lVert h_{i,t+1} \rVert`.

Risks (see :mod:`filters.risk`), with :math:`\bar x = -h \cdot \bar p` and
:math:`s` the sample standard deviation of the :math:`x_s` (``ddof = 1``, from the
losses' own deviations :math:`x_s - \bar x`, as numpy's two-pass ``std``):

.. math::

    R_\text{mean} = \bar x, \quad R_\text{conformal} = \bar x + q_t, \quad
    R_\text{moment} = \bar x + f s, \quad
    \mathrm{CVaR}_\alpha = \tau + \frac{1}{\alpha N} \sum_s \max(x_s - \tau, 0)
    \ \ (+\, \epsilon_t / \alpha \text{ for DR-CVaR}),

with :math:`\tau = x_{(k+1)}` the :math:`(k+1)`-th largest loss and
:math:`k = \lfloor \alpha N \rfloor` (``alpha N`` snapped as
:func:`filters.risk.tail_count`; :math:`k \ge N` gives the mean). :math:`\tau` minimises
the Rockafellar-Uryasev objective :math:`\tau + \sum_s (x_s - \tau)^+ / (\alpha N)`, and
the value there equals the sorted formula
:math:`(x_{(1)} + \dots + x_{(k)} + (\alpha N - k) x_{(k+1)}) / (\alpha N)` exactly; ties
add zero. :math:`\tau` is found in O(N): while the losses are computed, the ones inside a
band around the Gaussian guess :math:`\bar x + z s_\Sigma` (:math:`s_\Sigma` from the
covariance) are copied aside and the ones below and above it counted, with the sum of
the excesses above it. When the band holds rank :math:`k + 1`, quickselect runs on the
band only; else on all the losses. The guess decides only the speed: the value is
exact either way (also for NaN guesses, which select on all the losses).

The kernels return a status: :data:`OK`; :data:`NON_FINITE_SAMPLES` (a sample mean,
hence some sample, is NaN or infinite, or their sum overflowed);
:data:`NON_FINITE_RESULT` (a normal or offset is not finite: a non-finite origin, an
overflow); :data:`ZERO_NORMAL` (a near-side normal of zero length).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

OK = 0
NON_FINITE_SAMPLES = 1
NON_FINITE_RESULT = 2
ZERO_NORMAL = 3

MODE_PAPER = 0  # normals from the origins (reference positions) to the sample means
MODE_GIVEN = 1  # normals given (unit), offsets along them
MODE_NEARSIDE = 2  # the wrapper's "nearside" normals, computed here

RISK_MEAN = 0
RISK_CVAR = 1
RISK_DR_CVAR = 2
RISK_MOMENT = 3  # gaussian_cc and moment_dr: mean + factor * std
RISK_CONFORMAL = 4

DEGENERATE_DISTANCE = 1e-9  # = filters.halfspaces.DEGENERATE_DISTANCE
_NEARSIDE_MIN = 1e-9  # the near-side normal's threshold (filters.wrapper)
_NEARSIDE_FLOOR = 1e-12

_SMALL = 16  # ranges this short are insertion-sorted by the selection
_BAND_MIN = 32  # fewer losses than this are selected from directly


# --------------------------------------------------------------------------- selection


@njit(cache=True, nogil=True)
def _rank_by_counting(a, start, count, kth):
    """Branch-free: the value of ascending rank ``kth`` among ``a[start : start + count]``.

    Element ``v`` has the ranks ``[#(< v), #(<= v))``; O(count^2), for short ranges.
    """
    result = a[start]
    for i in range(start, start + count):
        v = a[i]
        less = 0
        equal = 0
        for j in range(start, start + count):
            less += a[j] < v
            equal += a[j] == v
        hit = (less <= kth) & (kth < less + equal)
        result = v if hit else result
    return result


@njit(cache=True, nogil=True)
def select(a, n, kth, scratch):
    """The value of ascending rank ``kth`` (0-based) of ``a[:n]`` (no NaN); overwrites
    ``a[:n]`` and ``scratch[:n]``.

    Quickselect with branch-free partitions (the data decide where each value is
    written, not which instructions run, so a random order costs no mispredicted
    branches): each round copies the values below the median-of-three pivot to the
    front of the other buffer and the values above it to its back, and goes on in the
    part that holds rank ``kth`` (or returns the pivot if ``kth`` falls among its
    copies). Ranges of at most :data:`_SMALL` values are finished by counting. After
    ``2 log2(n) + 8`` rounds the rest is sorted: O(n) expected, O(n log n) at worst.
    """
    source = a
    target = scratch
    start = 0
    count = n
    rounds = 0
    limit = 2 * int(math.log2(n + 1)) + 8
    while count > _SMALL:
        rounds += 1
        if rounds > limit:
            ordered = np.sort(source[start : start + count])
            return ordered[kth]
        x = source[start]
        y = source[start + (count >> 1)]
        z = source[start + count - 1]
        pivot = max(min(x, y), min(max(x, y), z))  # median of three
        below = 0
        above = 0
        top = count - 1
        for j in range(start, start + count):
            v = source[j]
            target[below] = v
            below += v < pivot
            target[top - above] = v
            above += v > pivot
        if kth < below:
            start = 0
            count = below
        elif kth >= count - above:
            kth -= count - above
            start = count - above
            count = above
        else:
            return pivot
        source, target = target, source
    return _rank_by_counting(source, start, count, kth)


# --------------------------------------------------------------------------- reductions
# Sums whose order does not matter beyond rounding: 'reassoc' lets LLVM vectorise them
# (several partial sums). The order is fixed at compile time, so the result is the same
# bits on every call on this machine.


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _deviation_sums(rows, q, n):
    """:math:`\\sum_s (a_s - a_0)` and :math:`\\sum_s (a_s - a_0)^2`, ``a = rows[q, :n]``."""
    base = rows[q, 0]
    total = 0.0
    squares = 0.0
    for s in range(n):
        d = rows[q, s] - base
        total += d
        squares += d * d
    return total, squares


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _deviation_sum(rows, q, n):
    """:math:`\\sum_s (a_s - a_0)`, ``a = rows[q, :n]``."""
    base = rows[q, 0]
    total = 0.0
    for s in range(n):
        total += rows[q, s] - base
    return total


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _cross_sum(rows, q, n):
    """:math:`\\sum_s (a_s - a_0)(b_s - b_0)`, ``a = rows[q]``, ``b = rows[q + 1]``."""
    a0 = rows[q, 0]
    b0 = rows[q + 1, 0]
    total = 0.0
    for s in range(n):
        total += (rows[q, s] - a0) * (rows[q + 1, s] - b0)
    return total


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _centred_sums(x, n, centre):
    """:math:`\\sum_s (x_s - c)` and :math:`\\sum_s (x_s - c)^2`."""
    total = 0.0
    squares = 0.0
    for s in range(n):
        d = x[s] - centre
        total += d
        squares += d * d
    return total, squares


@njit(cache=True, nogil=True, fastmath={"reassoc"})
def _excess(x, n, tau):
    """:math:`\\sum_s \\max(x_s - \\tau, 0)`."""
    total = 0.0
    for s in range(n):
        d = x[s] - tau
        total += d if d > 0.0 else 0.0
    return total


@njit(cache=True, nogil=True)
def _count_below_band(x, n, centre, half):
    """How many of ``x[:n]`` lie below the band ``|x - centre| <= half``."""
    count = 0
    for s in range(n):
        v = x[s]
        count += (v < centre) & (abs(v - centre) > half)
    return count


@njit(cache=True, nogil=True)
def _largest(x, n):
    """:math:`\\max_s x_s`."""
    top = x[0]
    for s in range(1, n):
        top = x[s] if x[s] > top else top
    return top


# --------------------------------------------------------------------------- risks along h


@njit(cache=True, nogil=True)
def _losses_along(rows, first_row, h, dim, n, out):
    """``out[s] = -h . p_s`` from the coordinate rows ``rows[first_row + j, s]``."""
    if dim == 2:
        h0 = h[0]
        h1 = h[1]
        for s in range(n):
            out[s] = -(h0 * rows[first_row, s] + h1 * rows[first_row + 1, s])
        return
    for s in range(n):
        out[s] = 0.0
    for j in range(dim):
        hj = h[j]
        for s in range(n):
            out[s] += hj * rows[first_row + j, s]
    for s in range(n):
        out[s] = -out[s]


@njit(cache=True, nogil=True)
def _band(x, n, centre, half, band):
    """Copy the values of ``x[:n]`` with ``|v - centre| <= half`` to ``band`` without
    branches; returns ``(how many, how many lie below the band)``.

    ``|v - c|`` is monotone on each side of ``c`` (rounding included), so the band is
    an interval of values: every value below it is smaller than every value in it.
    """
    m = 0
    for s in range(n):
        v = x[s]
        band[m] = v
        m += abs(v - centre) <= half
    return m, _count_below_band(x, n, centre, half)


@njit(cache=True, nogil=True)
def _narrowed(a, m, rank, low, high, scratch):
    """The value of ascending rank ``rank`` of ``a[:m]``, whose values lie in ``[low, high]``.

    Floyd-Rivest by interpolation: inside a narrow band the values are nearly uniform,
    so rank ``r`` lies near ``low + (r + 1/2)/m (high - low)``; a band of three
    standard errors of that guess keeps about ``3 sqrt(m)`` values. Repeated while it
    holds the rank and shrinks the range, then :func:`select`. Overwrites ``a`` and
    ``scratch``.
    """
    while m > _SMALL:
        level = (rank + 0.5) / m
        centre = low + level * (high - low)
        half = 3.0 * (high - low) * math.sqrt(level * (1.0 - level) / m)
        kept, below = _band(a, m, centre, half, scratch)
        if not (0 <= rank - below < kept and kept < m):
            break
        a, scratch = scratch, a
        m = kept
        rank -= below
        low = centre - half
        high = centre + half
    return select(a, m, rank, scratch)


@njit(cache=True, nogil=True)
def kth_largest(x, n, k, low, high, band, scratch):
    """The ``(k+1)``-th largest of ``x[:n]`` (``0 <= k < n``, no NaN), exactly; keeps ``x``.

    The values in the band ``[low, high]`` are copied to ``band`` and the ones below it
    counted (:func:`_band`); if the band holds the rank sought, the selection goes on
    in the band (:func:`_narrowed`), else on a copy of all the values. Any ``low``,
    ``high`` (NaN included) give the same value; a band around the value sought makes
    it fast. ``band`` and ``scratch`` have length ``>= n``.
    """
    rank = n - 1 - k  # ascending rank of the (k+1)-th largest
    if k == 0:
        return _largest(x, n)
    if n >= _BAND_MIN:
        centre = 0.5 * (low + high)
        half = 0.5 * (high - low)
        m, below = _band(x, n, centre, half, band)
        if 0 <= rank - below < m:
            return _narrowed(band, m, rank - below, centre - half, centre + half, scratch)
    for s in range(n):
        band[s] = x[s]
    return select(band, n, rank, scratch)


@njit(cache=True, nogil=True)
def _risk_along(rows, first_row, h, dim, n, mean, spread, risk, alpha, mass, k, factor,
                z_guess, width, epsilon, margin, losses, band, scratch):
    """:math:`R(-h \\cdot p)` of the samples in ``rows[first_row : first_row + d]``.

    ``mean`` is :math:`-h \\cdot \\bar p`; ``spread`` the covariance's guess of the
    losses' standard deviation (it places the CVaR's selection band).
    """
    if risk == RISK_MEAN:
        return mean
    if risk == RISK_CONFORMAL:
        return mean + margin
    if risk == RISK_MOMENT:
        if n < 2:
            return mean
        _losses_along(rows, first_row, h, dim, n, losses)
        total, squares = _centred_sums(losses, n, mean)
        std = math.sqrt(max((squares - total * total / n) / (n - 1), 0.0))
        return mean + factor * std
    if k >= n:
        value = mean
    else:
        _losses_along(rows, first_row, h, dim, n, losses)
        low = mean + (z_guess - width) * spread
        high = mean + (z_guess + width) * spread
        tau = kth_largest(losses, n, k, low, high, band, scratch)
        value = tau + _excess(losses, n, tau) / mass
    if risk == RISK_DR_CVAR:
        value = value + epsilon / alpha
    return value


# --------------------------------------------------------------------------- normals


@njit(cache=True, nogil=True)
def _normal(i, t, mean, origins, mode, given, ego, previous, velocity, normals):
    """Unit normal of obstacle ``i`` at step ``t`` into ``normals[i, t]`` from the sample
    mean ``mean[t]``; returns ``(status, degenerate)``."""
    dim = mean.shape[1]
    if mode == MODE_GIVEN:
        for j in range(dim):
            normals[i, t, j] = given[i, t, j]
        return OK, False
    if mode == MODE_NEARSIDE:
        # from the reference while it is on the ego's side of the mean, else from the ego
        side = 0.0
        for j in range(dim):
            side += (origins[t, j] - mean[t, j]) * (ego[j] - mean[t, j])
        size2 = 0.0
        for j in range(dim):
            v = mean[t, j] - (origins[t, j] if side > 0.0 else ego[j])
            normals[i, t, j] = v
            size2 += v * v
        size = math.sqrt(size2)
        if not size > _NEARSIDE_MIN:
            size2 = 0.0
            for j in range(dim):
                v = mean[t, j] - ego[j]
                normals[i, t, j] = v
                size2 += v * v
            size = max(math.sqrt(size2), _NEARSIDE_FLOOR)
        size2 = 0.0
        for j in range(dim):
            v = normals[i, t, j] / size
            normals[i, t, j] = v
            size2 += v * v
        size = math.sqrt(size2)  # normalised again, as safe_halfspaces does to given normals
        if not size >= DEGENERATE_DISTANCE:
            return (ZERO_NORMAL if math.isfinite(size) else NON_FINITE_RESULT), False
        for j in range(dim):
            normals[i, t, j] = normals[i, t, j] / size
        return OK, False
    size2 = 0.0
    for j in range(dim):
        v = mean[t, j] - origins[t, j]
        normals[i, t, j] = v
        size2 += v * v
    size = math.sqrt(size2)
    if not size < DEGENERATE_DISTANCE:  # NaN too: a non-finite result, reported later
        for j in range(dim):
            normals[i, t, j] = normals[i, t, j] / size
        return OK, False
    # degenerate: the previous normal, else minus the ego velocity, else the first axis
    if previous.shape[0] > 0:
        size2 = 0.0
        for j in range(dim):
            size2 += previous[i, t, j] * previous[i, t, j]
        size = math.sqrt(size2)
        if size >= DEGENERATE_DISTANCE:
            for j in range(dim):
                normals[i, t, j] = previous[i, t, j] / size
            return OK, True
    if velocity.shape[0] > 0:
        row = t if velocity.shape[0] > 1 else 0
        size2 = 0.0
        for j in range(dim):
            size2 += velocity[row, j] * velocity[row, j]
        size = math.sqrt(size2)
        if size >= DEGENERATE_DISTANCE:
            for j in range(dim):
                normals[i, t, j] = -velocity[row, j] / size
            return OK, True
    for j in range(dim):
        normals[i, t, j] = 1.0 if j == 0 else 0.0
    return OK, True


# --------------------------------------------------------------------------- kernel


@njit(cache=True, nogil=True)
def _transpose(flat, i, start, width, rows):
    """``rows[q, s] = flat[i, s, start + q]`` for ``q < width``: one coordinate per row."""
    n = flat.shape[1]
    for s in range(n):
        for q in range(width):
            rows[q, s] = flat[i, s, start + q]


@njit(cache=True, nogil=True)
def _spread(h, dim, n, sums, squares, cross, b):
    """:math:`\\sqrt{h^\\top \\hat\\Sigma h}` from the shifted sums of block step ``b``."""
    if n < 2:
        return 0.0
    var = 0.0
    for j in range(dim):
        q = b * dim + j
        var += h[j] * h[j] * (squares[q] - sums[q] * sums[q] / n)
    if dim == 2:
        var += 2.0 * h[0] * h[1] * (cross[b] - sums[2 * b] * sums[2 * b + 1] / n)
    return math.sqrt(max(var / (n - 1), 0.0))


@njit(cache=True, nogil=True)
def halfspace_kernel(flat, horizon, dim, origins, mode, given, ego, previous, velocity,
                     risk, alpha, mass, k, factor, z_guess, width, delta, epsilon, conformal,
                     radii, start_rows, low, high, arc,
                     normals, degenerate, offsets, start_offsets, margins):
    """Normals, offsets and (``start_rows``) inter-sample start offsets and arc margins.

    Parameters (checked by :func:`filters.kernels.compiled_rows`): ``flat``
    ``(k, N, T' d)``; ``horizon`` ``T <= T'``; ``dim`` ``d``; ``origins`` ``(T, d)``
    (paper and near-side modes); ``mode`` one of the ``MODE_*``; ``given``
    ``(k, T, d)`` unit normals (given mode); ``ego`` ``(d,)`` (near-side mode);
    ``previous`` ``(k, T, d)`` or empty; ``velocity`` ``(1 | T, d)`` or empty; the risk
    constants of :func:`filters.kernels._risk_constants`; ``delta``; ``epsilon``
    ``(1 | T,)``; ``conformal`` ``(1 | k, 1 | T)``; ``radii`` ``(k,)`` (ego plus
    obstacle radius); ``low``, ``high`` ``(d,)`` and ``arc = dt^2 / 8`` for the arc
    margins. Outputs: ``normals`` ``(k, T, d)``, ``degenerate`` and ``offsets``
    ``(k, T)``; with ``start_rows`` also ``start_offsets`` ``(k, T - 1)`` and
    ``margins`` ``(k, T)``. Returns the first non-OK status (the outputs are then
    incomplete).

    Each obstacle's samples are read once from memory, in order, into ``rows`` (one
    row per step and coordinate, ``T d`` rows of ``N``, linear in the input); every
    later pass reads those contiguous rows from the cache.
    """
    n_obstacles, n = flat.shape[0], flat.shape[1]
    cvar = (risk == RISK_CVAR or risk == RISK_DR_CVAR) and 0 < k < n
    rows = np.empty((horizon * dim, n))
    sums = np.empty(horizon * dim)
    squares = np.zeros(horizon * dim)
    cross = np.zeros(horizon)
    mean = np.empty((horizon, dim))
    h = np.empty(dim)
    h_next = np.empty(dim)
    losses = np.empty(n)
    band = np.empty(n)
    scratch = np.empty(n)
    n_start = horizon - 1 if start_rows else 0
    for i in range(n_obstacles):
        margin_row = i if conformal.shape[0] > 1 else 0
        _transpose(flat, i, 0, horizon * dim, rows)
        for t in range(horizon):  # means, normals
            for j in range(dim):
                q = t * dim + j
                if cvar:
                    sums[q], squares[q] = _deviation_sums(rows, q, n)
                else:
                    sums[q] = _deviation_sum(rows, q, n)
                mean[t, j] = rows[q, 0] + sums[q] / n
                if not math.isfinite(mean[t, j]):
                    return NON_FINITE_SAMPLES
            if cvar and dim == 2:
                cross[t] = _cross_sum(rows, 2 * t, n)
            status, flag = _normal(i, t, mean, origins, mode, given, ego, previous,
                                   velocity, normals)
            if status != OK:
                return status
            degenerate[i, t] = flag
        for t in range(horizon):  # risks
            centre = 0.0
            for j in range(dim):
                h[j] = normals[i, t, j]
                centre -= h[j] * mean[t, j]
            eps_t = epsilon[t if epsilon.shape[0] > 1 else 0]
            margin_t = conformal[margin_row, t if conformal.shape[1] > 1 else 0]
            spread = _spread(h, dim, n, sums, squares, cross, t) if cvar else 0.0
            value = _risk_along(rows, t * dim, h, dim, n, centre, spread, risk, alpha, mass,
                                k, factor, z_guess, width, eps_t, margin_t, losses, band,
                                scratch)
            offsets[i, t] = -((value - delta) + radii[i])
            if not (math.isfinite(offsets[i, t]) and math.isfinite(h[0])):
                return NON_FINITE_RESULT
            if not start_rows:
                continue
            worst = 0.0  # arc margin (dt^2 / 8) max_u (-h . u), filters.intersample
            for j in range(dim):
                worst += max(-h[j] * low[j], -h[j] * high[j])
            margins[i, t] = arc * worst
            if t >= n_start:
                continue
            size2 = 0.0  # the next step's normal, normalised again (as offsets_along)
            for j in range(dim):
                size2 += normals[i, t + 1, j] * normals[i, t + 1, j]
            size = math.sqrt(size2)
            centre = 0.0
            for j in range(dim):
                h_next[j] = normals[i, t + 1, j] / size
                centre -= h_next[j] * mean[t, j]
            spread = _spread(h_next, dim, n, sums, squares, cross, t) if cvar else 0.0
            value = _risk_along(rows, t * dim, h_next, dim, n, centre, spread, risk, alpha,
                                mass, k, factor, z_guess, width, eps_t, margin_t, losses,
                                band, scratch)
            start_offsets[i, t] = -((value - delta) + radii[i])
            if not math.isfinite(start_offsets[i, t]):
                return NON_FINITE_RESULT
    return OK
