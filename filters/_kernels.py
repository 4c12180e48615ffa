r"""Compiled (numba) kernels of the safe halfspaces and the inter-sample start rows.

Private: :mod:`filters.kernels` prepares the arguments and picks this path or the
numpy reference of :mod:`filters.halfspaces`. Importing this module imports numba
(and loads the kernels from numba's cache, or compiles them), so nothing imports it
at ``import filters``.

The samples arrive flattened, ``flat[i, s, t d + j] = p_{i,s,t,j}``. Per obstacle
:math:`i`:

1. its samples are read once from memory, in order, into ``rows[t d + j, s]`` (one
   contiguous row per step and coordinate; every later pass reads these rows from
   the cache);
2. **moments**: per row, the sums of the deviations from the first sample,
   :math:`\sum_s (p_{i,s,t,j} - p_{i,0,t,j})` (so the rounding error does not grow
   with the size of the positions), which give the sample means
   :math:`\bar p_{i,t}`;
3. **normals** from the origins (or given, or the near-side or clearest ones of
   :mod:`filters.step_rows`) to the means, with the fallbacks of
   :func:`filters.safe_halfspaces` for a degenerate normal;
4. **risks** of the losses :math:`x_s = -h \cdot p_{i,s,t}` along the step's normal
   and, for the inter-sample start rows, along the next step's normal
   :math:`h' = h_{i,t+1} / \lVert h_{i,t+1} \rVert`; the losses are formed only where
   the risk needs the samples.

Risks (see :mod:`filters.risk`), with :math:`\bar x = -h \cdot \bar p` and :math:`s` the
sample standard deviation of the losses (``ddof = 1``; 0 for one sample), from their
deviations :math:`x_s - \bar x`:

.. math::

    R_\text{mean} = \bar x, \quad R_\text{conformal} = \bar x + q_t, \quad
    R_\text{moment} = \bar x + f s, \quad
    \mathrm{CVaR}_\alpha = \tau + \frac{1}{\alpha N} \sum_s \max(x_s - \tau, 0)
    \ \ (+\, \epsilon_t / \alpha \text{ for DR-CVaR}),

with :math:`\tau = x_{(k+1)}` the :math:`(k+1)`-th largest loss and
:math:`k = \lfloor \alpha N \rfloor` (``alpha N`` snapped as
:func:`filters.risk.tail_count`; :math:`k \ge N` gives the mean). :math:`\tau` minimises
the Rockafellar-Uryasev objective :math:`\tau + \sum_s (x_s - \tau)^+ / (\alpha N)`, and
the value there is the sorted formula
:math:`(x_{(1)} + \dots + x_{(k)} + (\alpha N - k) x_{(k+1)}) / (\alpha N)` exactly (ties
add zero). :math:`\tau` is found in O(N) without data-dependent branches (a random
order would mispredict every other one): the losses inside a band around the
Gaussian guess :math:`\bar x + z s` (:math:`z` the normal quantile of the rank sought,
a band of two standard errors of that quantile) are copied aside and the ones below
it counted; if the band holds rank :math:`k + 1`, the search narrows inside it
(Floyd-Rivest by interpolation) and ends with a quickselect; else the quickselect
runs on all the losses. The band decides only the speed: the value is exact for any
band (NaN included).

The kernel returns a status: :data:`OK`; :data:`NON_FINITE_SAMPLES` (a sample mean,
hence some sample, is NaN or infinite, or their sum overflowed);
:data:`NON_FINITE_RESULT` (a normal or offset is not finite: a non-finite origin, an
overflow); :data:`ZERO_NORMAL` (a near-side normal of zero length).

Compiled with ``error_model="numpy"``: a division by zero gives ``inf``/``NaN``
(caught by the status checks) instead of raising. The per-step helpers are inlined
(a call costs two atomic reference-count updates per array argument) and the
selection works by row index in one scratch array for the same reason. The sums (of
the deviations, squares and excesses) are vectorised with partial sums per vector lane
(``fastmath={"reassoc"}`` on those functions only): a machine gives the same bits on
every call; another CPU may differ in the last bit, as numpy's BLAS products do.
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
MODE_CLEAREST = 3  # the wrapper's "clearest" normals, computed here

RISK_MEAN = 0
RISK_CVAR = 1
RISK_DR_CVAR = 2
RISK_MOMENT = 3  # gaussian_cc and moment_dr: mean + factor * std
RISK_CONFORMAL = 4

DEGENERATE_DISTANCE = 1e-9  # = filters.halfspaces.DEGENERATE_DISTANCE
_NEARSIDE_MIN = 1e-9  # the near-side normal's thresholds (filters.step_rows.nearside_normals)
_NEARSIDE_FLOOR = 1e-12
_CLEAREST_SHORT = 0.5  # filters.step_rows.clearest_normals: shorter directions fall back

_SMALL = 8  # ranges this short are finished by counting
_BAND_MIN = 32  # fewer losses than this are selected from directly
_NARROW_ERRORS = 2.0  # half-width of the narrowing bands, in standard errors
_NARROW_MIN = 24  # smaller bands go straight to the quickselect (measured: faster)

_FLAGS = dict(cache=True, nogil=True, error_model="numpy")
# Inlined where called: each call costs two atomic reference-count updates per array
# argument, more than a short function's work.
_INLINE = dict(_FLAGS, inline="always")
# Sums whose order only changes the rounding: 'reassoc' lets LLVM vectorise them (partial
# sums per vector lane). The order is fixed when the kernel is compiled for this CPU, so
# a machine gives the same bits on every call; another CPU may differ in the last bit.
_SUMS = dict(_FLAGS, fastmath={"reassoc"})


# --------------------------------------------------------------------------- selection
# The selection works in the rows 1 and 2 of a ``(3, N)`` scratch array, by index (a
# function call or a rebinding per array costs two atomic reference-count updates).


@njit(**_INLINE)
def _rank_by_counting(work, row, start, count, kth):
    """The value of ascending rank ``kth`` among ``work[row, start : start + count]``,
    branch-free: value ``v`` holds the ranks ``[#(< v), #(<= v))``; O(count^2)."""
    result = work[row, start]
    for i in range(start, start + count):
        v = work[row, i]
        less = 0
        equal = 0
        for j in range(start, start + count):
            less += work[row, j] < v
            equal += work[row, j] == v
        hit = (less <= kth) & (kth < less + equal)
        result = v if hit else result
    return result


@njit(**_FLAGS)
def _heapsort(work, row, start, count):
    """Sort ``work[row, start : start + count]`` in place (the worst-case guard)."""
    for first in range(count // 2 - 1, -1, -1):
        _sift(work, row, start, first, count)
    for end in range(count - 1, 0, -1):
        top = work[row, start]
        work[row, start] = work[row, start + end]
        work[row, start + end] = top
        _sift(work, row, start, 0, end)


@njit(**_FLAGS)
def _sift(work, row, start, node, count):
    """Move ``node`` down the max-heap ``work[row, start : start + count]``."""
    while True:
        child = 2 * node + 1
        if child >= count:
            return
        if child + 1 < count and work[row, start + child + 1] > work[row, start + child]:
            child += 1
        if work[row, start + node] >= work[row, start + child]:
            return
        v = work[row, start + node]
        work[row, start + node] = work[row, start + child]
        work[row, start + child] = v
        node = child


@njit(**_INLINE)
def select(work, source, count, kth):
    """The value of ascending rank ``kth`` (0-based) of ``work[source, :count]`` (no NaN);
    ``source`` is 1 or 2, and rows 1 and 2 are overwritten.

    Quickselect with branch-free partitions (the data decide where each value is
    written, not which instructions run, so a random order costs no mispredicted
    branches): each round copies the values below the median-of-three pivot to the
    front of the other row and those above it to its back, and goes on in the part
    that holds rank ``kth`` (or returns the pivot, if ``kth`` falls among its copies).
    At most :data:`_SMALL` values are finished by :func:`_rank_by_counting`. After
    ``2 log2(n) + 8`` rounds the rest is heap-sorted: O(n) expected, O(n log n) at worst.
    """
    start = 0
    rounds = 0
    limit = 2 * int(math.log2(count + 1)) + 8
    while count > _SMALL:
        rounds += 1
        if rounds > limit:
            _heapsort(work, source, start, count)
            return work[source, start + kth]
        target = 3 - source
        x = work[source, start]
        y = work[source, start + (count >> 1)]
        z = work[source, start + count - 1]
        pivot = max(min(x, y), min(max(x, y), z))  # median of three
        below = 0
        above = 0
        top = count - 1
        for j in range(start, start + count):
            v = work[source, j]
            work[target, below] = v
            below += v < pivot
            work[target, top - above] = v
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
        source = target
    return _rank_by_counting(work, source, start, count, kth)


@njit(**_INLINE)
def _narrowed(work, count, rank, low, high):
    """The value of ascending rank ``rank`` of ``work[1, :count]``, all of whose values lie
    in ``[low, high]``; rows 1 and 2 are overwritten.

    Floyd-Rivest by interpolation: in a narrow band the values are nearly uniform, so
    rank ``r`` lies near ``low + (r + 1/2)/m (high - low)``; a band of
    :data:`_NARROW_ERRORS` standard errors around that guess keeps about
    ``4 sqrt(r (m - r) / m)`` values (copied without branches, and the values below
    it counted). Repeated while more than :data:`_NARROW_MIN` values are left, the band
    holds the rank and shrinks the range; then :func:`select`.
    """
    source = 1
    while count > _NARROW_MIN:
        level = (rank + 0.5) / count
        centre = low + level * (high - low)
        half = _NARROW_ERRORS * (high - low) * math.sqrt(level * (1.0 - level) / count)
        target = 3 - source
        kept = 0
        for s in range(count):
            v = work[source, s]
            work[target, kept] = v
            kept += abs(v - centre) <= half
        below = 0
        for s in range(count):
            v = work[source, s]
            below += (v < centre) & (abs(v - centre) > half)
        if not (0 <= rank - below < kept and kept < count):
            break
        source = target
        count = kept
        rank -= below
        low = centre - half
        high = centre + half
    return select(work, source, count, rank)


@njit(**_INLINE)
def kth_largest(work, n, k, low, high):
    """The ``(k+1)``-th largest of ``work[0, :n]`` (``0 <= k < n``, no NaN), exactly.

    Row 0 is kept; rows 1 and 2 are scratch. The values in ``[low, high]`` (as
    ``|v - c| <= w``, ``c`` and ``w`` its centre and half-width) are copied to row 1
    without branches, and the ones below counted: ``|v - c|`` is monotone on each side
    of ``c`` (rounding included), so the band is an interval of values. If it holds the
    rank sought the search narrows inside it (:func:`_narrowed`), else :func:`select`
    runs on a copy of all the values. Any ``low``, ``high`` (NaN included) give the
    same value; a band around the value sought makes it fast.
    """
    rank = n - 1 - k  # ascending rank of the (k+1)-th largest
    if k == 0:
        top = work[0, 0]
        for s in range(1, n):
            top = max(top, work[0, s])
        return top
    if n >= _BAND_MIN:
        centre = 0.5 * (low + high)
        half = 0.5 * (high - low)
        m = 0
        for s in range(n):
            v = work[0, s]
            work[1, m] = v
            m += abs(v - centre) <= half
        below = 0
        for s in range(n):
            v = work[0, s]
            below += (v < centre) & (abs(v - centre) > half)
        if 0 <= rank - below < m:
            return _narrowed(work, m, rank - below, centre - half, centre + half)
    for s in range(n):
        work[1, s] = work[0, s]
    return select(work, 1, n, rank)


# --------------------------------------------------------------------------- sums


@njit(**_SUMS)
def _row_sums(rows, n_rows, n, sums):
    """:math:`\\sum_s (a_s - a_0)` of every row ``a = rows[q, :n]``, ``q < n_rows``."""
    for q in range(n_rows):
        base = rows[q, 0]
        total = 0.0
        for s in range(n):
            total += rows[q, s] - base
        sums[q] = total


@njit(**_INLINE)
def _losses_std(rows, first, h, dim, n, centre, work):
    """Write the losses :math:`x_s = -h \\cdot p_s` to ``work[0, :n]`` (the coordinates of
    :math:`p_s` in ``rows[first + j, s]``) and return their sample standard deviation
    (``ddof = 1``; 0 for one sample)."""
    if dim == 2:
        h0 = h[0]
        h1 = h[1]
        for s in range(n):
            work[0, s] = -(h0 * rows[first, s] + h1 * rows[first + 1, s])
    else:
        for s in range(n):
            work[0, s] = 0.0
        for j in range(dim):
            for s in range(n):
                work[0, s] += h[j] * rows[first + j, s]
        for s in range(n):
            work[0, s] = -work[0, s]
    if n < 2:
        return 0.0
    return _centred_std(work, n, centre)


@njit(**_SUMS)
def _centred_std(work, n, centre):
    """Sample standard deviation (``ddof = 1``, ``n >= 2``) of ``work[0, :n]``, from the
    deviations from ``centre`` (near the mean, :math:`-h \\cdot \\bar p`), corrected by
    their mean."""
    total = 0.0
    squares = 0.0
    for s in range(n):
        d = work[0, s] - centre
        total += d
        squares += d * d
    return math.sqrt(max((squares - total * total / n) / (n - 1), 0.0))


@njit(**_SUMS)
def _excess(work, n, tau):
    """:math:`\\sum_s \\max(x_s - \\tau, 0)` of ``x = work[0, :n]``."""
    total = 0.0
    for s in range(n):
        d = work[0, s] - tau
        total += d if d > 0.0 else 0.0
    return total


# --------------------------------------------------------------------------- normals


@njit(**_INLINE)
def _clearest_normal(normals, i, t, mean, origins, plan, ego, dim):
    """Write the clearest unit normal of obstacle ``i`` at step ``t`` to ``normals[i, t]``.

    The operations of :func:`filters.step_rows.clearest_normals`, in its order: at the
    first step no candidate; later, from the farther of the reference ``origins[t]``
    and the plan ``plan[t]`` (zero within 1e-9 of the mean), or without a plan (``plan``
    empty) the near-side normal; a candidate shorter than 1/2 falls back to the
    direction from ``ego`` (within 1e-9 of the mean: the first axis). Then normalised
    again, as :func:`filters.safe_halfspaces` does to given normals. Returns
    :data:`NON_FINITE_RESULT` if a distance from the mean is not finite (a non-finite
    position, an overflow), else :data:`OK`.
    """
    has_plan = plan.shape[0] > 0
    ego2 = 0.0
    reference2 = 0.0
    plan2 = 0.0
    for j in range(dim):
        v = mean[t, j] - ego[j]
        ego2 += v * v
        v = mean[t, j] - origins[t, j]
        reference2 += v * v
        if has_plan:
            v = mean[t, j] - plan[t, j]
            plan2 += v * v
    from_ego = math.sqrt(ego2)
    from_reference = math.sqrt(reference2)
    from_plan = math.sqrt(plan2)
    if not (math.isfinite(from_ego) and math.isfinite(from_reference)
            and math.isfinite(from_plan)):
        return NON_FINITE_RESULT
    size2 = 0.0  # the candidate's squared length
    if t > 0 and has_plan:  # from the clearer origin
        use_reference = from_reference >= from_plan
        size = from_reference if use_reference else from_plan
        if size > _NEARSIDE_MIN:
            for j in range(dim):
                v = (mean[t, j] - (origins[t, j] if use_reference else plan[t, j])) / size
                normals[i, t, j] = v
                size2 += v * v
    elif t > 0:  # the near-side normal
        side = 0.0
        for j in range(dim):
            side += (origins[t, j] - mean[t, j]) * (ego[j] - mean[t, j])
        for j in range(dim):
            v = mean[t, j] - (origins[t, j] if side > 0.0 else ego[j])
            normals[i, t, j] = v
            size2 += v * v
        size = math.sqrt(size2)
        if not size > _NEARSIDE_MIN:
            size = max(from_ego, _NEARSIDE_FLOOR)
            for j in range(dim):
                normals[i, t, j] = mean[t, j] - ego[j]
        size2 = 0.0
        for j in range(dim):
            v = normals[i, t, j] / size
            normals[i, t, j] = v
            size2 += v * v
    if math.sqrt(size2) < _CLEAREST_SHORT:  # the direction from the ego, else an axis
        size2 = 0.0
        for j in range(dim):
            v = 1.0 if j == 0 else 0.0
            if from_ego > _NEARSIDE_MIN:
                v = (mean[t, j] - ego[j]) / from_ego
            normals[i, t, j] = v
            size2 += v * v
    size = math.sqrt(size2)
    for j in range(dim):
        normals[i, t, j] = normals[i, t, j] / size
    return OK


# --------------------------------------------------------------------------- per obstacle


@njit(**_FLAGS)
def _transpose(flat, i, width, rows):
    """``rows[q, s] = flat[i, s, q]`` for ``q < width``: read obstacle ``i`` once, in order."""
    n = flat.shape[1]
    for s in range(n):
        for q in range(width):
            rows[q, s] = flat[i, s, q]


@njit(**_FLAGS)
def halfspace_kernel(flat, horizon, dim, origins, mode, given, ego, plan, previous, velocity,
                     risk, alpha, mass, k, factor, z_guess, band_width, delta, epsilon,
                     conformal, radii, start_rows, low, high, arc, disabled,
                     normals, degenerate, offsets, rows_normals, rows_offsets):
    """Normals, offsets and (``start_rows``) the inter-sample rows of every obstacle.

    Per obstacle ``i``: its samples into ``rows`` (:func:`_transpose`), the shifted sums
    and the sample means; the unit normals of :func:`filters.safe_halfspaces` (paper
    mode: origin to mean, and for a degenerate one the previous normal, minus the ego
    velocity, the first axis), given ones, or the near-side ones of
    :func:`filters.step_rows.nearside_normals` or the clearest ones of
    :func:`filters.step_rows.clearest_normals` (:func:`_clearest_normal`) normalised
    again (as ``safe_halfspaces`` does to given normals); then along each normal
    :math:`h` the offset :math:`b = -((R - \\delta) + r)`. With ``start_rows``, row
    ``i`` of ``rows_*`` is the end row (the halfspace tightened by the arc margin
    :math:`m(h_{i,t})` of :func:`filters.intersample.arc_margin`) and row ``k + i`` the
    start row: the step-``t`` samples along the next step's normal normalised again (as
    :func:`filters.halfspaces.offsets_along`), tightened by :math:`m(h_{i,t+1})`, and
    ``0 @ y <= disabled`` at the last step (:func:`filters.intersample_rows`' layout).
    The losses go to ``work[0]``; rows 1 and 2 are the selection's scratch. (One
    function: a call with this many array arguments costs more than an obstacle's
    bookkeeping.)

    Parameters (checked by :func:`filters.kernels.compiled_rows`): ``flat``
    ``(k, N, T' d)``; ``horizon`` ``T <= T'``; ``dim`` ``d``; ``origins`` ``(T, d)``
    (paper, near-side and clearest modes); ``mode`` one of the ``MODE_*``; ``given``
    ``(k, T, d)`` unit normals (given mode); ``ego`` ``(d,)`` (near-side and clearest
    modes); ``plan`` ``(T, d)`` or empty (clearest mode); ``previous``
    ``(k, T, d)`` or empty; ``velocity`` ``(1 | T, d)`` or empty; the risk constants of
    :func:`filters.kernels._risk_constants`; ``delta``; ``epsilon`` ``(1 | T,)``;
    ``conformal`` ``(1 | k, 1 | T)``; ``radii`` ``(k,)`` (ego plus obstacle radius);
    ``low``, ``high`` ``(d,)``, ``arc = dt^2 / 8`` and ``disabled`` (the offset of an
    unused row) for the inter-sample rows. Outputs: ``normals`` ``(k, T, d)``,
    ``degenerate`` and ``offsets`` ``(k, T)``; with ``start_rows`` also the QP's rows
    ``rows_normals`` ``(2 k, T, d)`` and ``rows_offsets`` ``(2 k, T)``.
    Returns the first non-OK status (the outputs are then incomplete). Scratch space
    is linear in the input: one obstacle's samples, and a few ``(N,)`` buffers.
    """
    n_obstacles, n = flat.shape[0], flat.shape[1]
    n_rows = horizon * dim
    rows = np.empty((n_rows, n))
    sums = np.empty(n_rows)
    mean = np.empty((horizon, dim))
    h = np.empty(dim)
    work = np.empty((3, n))
    for i in range(n_obstacles):
        _transpose(flat, i, n_rows, rows)
        _row_sums(rows, n_rows, n, sums)
        # the sample means and the unit normals of obstacle i
        for t in range(horizon):
            for j in range(dim):
                q = t * dim + j
                mean[t, j] = rows[q, 0] + sums[q] / n
                if not math.isfinite(mean[t, j]):
                    return NON_FINITE_SAMPLES
            degenerate[i, t] = False
            if mode == MODE_GIVEN:
                for j in range(dim):
                    normals[i, t, j] = given[i, t, j]
                continue
            if mode == MODE_CLEAREST:
                status = _clearest_normal(normals, i, t, mean, origins, plan, ego, dim)
                if status != OK:
                    return status
                continue
            if mode == MODE_NEARSIDE:  # from the reference while on the ego's side, else ego
                side = 0.0
                for j in range(dim):
                    side += (origins[t, j] - mean[t, j]) * (ego[j] - mean[t, j])
                if not math.isfinite(side):  # a non-finite reference or ego, or an overflow
                    return NON_FINITE_RESULT
                size2 = 0.0
                for j in range(dim):
                    v = mean[t, j] - (origins[t, j] if side > 0.0 else ego[j])
                    normals[i, t, j] = v
                    size2 += v * v
                size = math.sqrt(size2)
                if not math.isfinite(size):
                    return NON_FINITE_RESULT
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
                size = math.sqrt(size2)
                if not size >= DEGENERATE_DISTANCE:
                    return ZERO_NORMAL if math.isfinite(size) else NON_FINITE_RESULT
                for j in range(dim):
                    normals[i, t, j] = normals[i, t, j] / size
                continue
            size2 = 0.0
            for j in range(dim):
                v = mean[t, j] - origins[t, j]
                normals[i, t, j] = v
                size2 += v * v
            size = math.sqrt(size2)
            if not math.isfinite(size):  # a non-finite origin, or an overflow
                return NON_FINITE_RESULT
            if size >= DEGENERATE_DISTANCE:
                for j in range(dim):
                    normals[i, t, j] = normals[i, t, j] / size
                continue
            degenerate[i, t] = True
            size = 0.0
            if previous.shape[0] > 0:
                size2 = 0.0
                for j in range(dim):
                    size2 += previous[i, t, j] * previous[i, t, j]
                size = math.sqrt(size2)
            if size >= DEGENERATE_DISTANCE:
                for j in range(dim):
                    normals[i, t, j] = previous[i, t, j] / size
                continue
            row = t if velocity.shape[0] > 1 else 0
            size = 0.0
            if velocity.shape[0] > 0:
                size2 = 0.0
                for j in range(dim):
                    size2 += velocity[row, j] * velocity[row, j]
                size = math.sqrt(size2)
            if size >= DEGENERATE_DISTANCE:
                for j in range(dim):
                    normals[i, t, j] = -velocity[row, j] / size
                continue
            for j in range(dim):
                normals[i, t, j] = 1.0 if j == 0 else 0.0
        # its offsets and, with start_rows, its rows of the QP
        sampled = risk == RISK_MOMENT or ((risk == RISK_CVAR or risk == RISK_DR_CVAR) and k < n)
        margin_row = i if conformal.shape[0] > 1 else 0
        for t in range(horizon):
            eps_t = epsilon[t if epsilon.shape[0] > 1 else 0]
            margin_t = conformal[margin_row, t if conformal.shape[1] > 1 else 0]
            # the arc margins (dt^2 / 8) max_u (-h . u) of this step's normal and the next
            # one's (filters.intersample.arc_margin): arc * arc_here, arc * arc_next
            arc_here = 0.0
            arc_next = 0.0
            if start_rows:
                for j in range(dim):
                    arc_here += max(-normals[i, t, j] * low[j], -normals[i, t, j] * high[j])
                    if t < horizon - 1:
                        arc_next += max(-normals[i, t + 1, j] * low[j],
                                        -normals[i, t + 1, j] * high[j])
            for row in range(2 if start_rows and t < horizon - 1 else 1):
                # row 0: the step's normal; row 1: the next step's, normalised again
                size = 1.0
                if row == 1:
                    size2 = 0.0
                    for j in range(dim):
                        size2 += normals[i, t + 1, j] * normals[i, t + 1, j]
                    size = math.sqrt(size2)
                centre = 0.0
                for j in range(dim):
                    h[j] = normals[i, t, j] if row == 0 else normals[i, t + 1, j] / size
                    centre -= h[j] * mean[t, j]
                value = centre  # mean, conformal, and CVaR with alpha N >= N
                if sampled:
                    std = _losses_std(rows, t * dim, h, dim, n, centre, work)
                    if risk == RISK_MOMENT:
                        value = centre + factor * std
                    else:  # the band: the Gaussian guess of the threshold, +- a few errors
                        tau = kth_largest(work, n, k, centre + (z_guess - band_width) * std,
                                          centre + (z_guess + band_width) * std)
                        value = tau + _excess(work, n, tau) / mass
                if risk == RISK_CONFORMAL:
                    value = value + margin_t
                elif risk == RISK_DR_CVAR:
                    value = value + eps_t / alpha
                offset = -((value - delta) + radii[i])
                if not (math.isfinite(offset) and math.isfinite(h[0])):
                    return NON_FINITE_RESULT
                if row == 0:
                    offsets[i, t] = offset
                    if start_rows:
                        for j in range(dim):
                            rows_normals[i, t, j] = normals[i, t, j]
                        rows_offsets[i, t] = offset - arc * arc_here
                else:
                    for j in range(dim):
                        rows_normals[n_obstacles + i, t, j] = normals[i, t + 1, j]
                    rows_offsets[n_obstacles + i, t] = offset - arc * arc_next
            if start_rows and t == horizon - 1:  # no next step: the row is off
                for j in range(dim):
                    rows_normals[n_obstacles + i, t, j] = 0.0
                rows_offsets[n_obstacles + i, t] = disabled
    return OK


# --------------------------------------------------------------------------- the wrapper's step

ORIGIN_REFERENCE = 0  # normals start at the reference positions C x^r_t
ORIGIN_EGO = 1  # ... at the current position C x_0, every step
ORIGIN_PLAN = 2  # ... at the last plan shifted by one step (the reference without a plan)


@njit(**_INLINE)
def _shifted_plan(plan_states, C, y0, out):
    """``out[t] = (C x^p_{t+2} - C x^p_1) + y0`` (the last row repeats ``C x^p_T``): the last
    plan ``(T + 1, n)`` shifted by one step and re-anchored at ``y0``, in the operation
    order of :func:`filters.wrapper._shifted_positions`."""
    horizon, dim = out.shape
    n = plan_states.shape[1]
    for t in range(horizon):
        row = min(t + 2, horizon)
        for a in range(dim):
            here = 0.0
            first = 0.0
            for j in range(n):
                here += C[a, j] * plan_states[row, j]
                first += C[a, j] * plan_states[1, j]
            out[t, a] = (here - first) + y0[a]


@njit(**_FLAGS)
def wrapper_step_kernel(flat, horizon, dim, x0, ref_states, C, origin_mode, mode, plan_states,
                        previous_raw, risk, alpha, mass, k, factor, z_guess, band_width, delta,
                        epsilon, conformal, radii, start_rows, low, high, arc, disabled,
                        normals, degenerate, offsets, rows_normals, rows_offsets):
    """:func:`halfspace_kernel` with its inputs formed from the wrapper's raw state.

    From the state ``x0`` ``(n,)`` (its velocity ``x0[dim : 2 dim]`` is the degenerate
    normals' fallback), the reference ``ref_states`` ``(T + 1, n)``, the output map ``C``
    ``(d, n)``, the last plan ``plan_states`` ``(T + 1, n)`` (or empty) and the last normals
    ``previous_raw`` ``(k, T, d)`` (or empty): the origins (``origin_mode``: the reference
    positions, the ego position, or the shifted plan when there is one), the ego position
    and the shifted plan of the near-side and clearest modes, and the previous normals
    shifted by one step (the last step repeated). Then :func:`halfspace_kernel` with the
    remaining arguments; returns its status.
    """
    n = x0.shape[0]
    y0 = np.empty(dim)
    for a in range(dim):
        value = 0.0
        for j in range(n):
            value += C[a, j] * x0[j]
        y0[a] = value
    has_plan = plan_states.shape[0] > 0
    origins = np.empty((horizon, dim))
    if origin_mode == ORIGIN_EGO:
        for t in range(horizon):
            for a in range(dim):
                origins[t, a] = y0[a]
    elif origin_mode == ORIGIN_PLAN and has_plan:
        _shifted_plan(plan_states, C, y0, origins)
    else:
        for t in range(horizon):
            for a in range(dim):
                value = 0.0
                for j in range(n):
                    value += ref_states[t + 1, j] * C[a, j]
                origins[t, a] = value
    plan = np.empty((horizon if mode == MODE_CLEAREST and has_plan else 0, dim))
    if plan.shape[0]:
        _shifted_plan(plan_states, C, y0, plan)
    ego = y0 if mode == MODE_NEARSIDE or mode == MODE_CLEAREST else np.empty(0)
    n_previous = previous_raw.shape[0]
    previous = np.empty((n_previous, horizon if n_previous else 0, dim))
    for i in range(n_previous):
        for t in range(horizon):
            for a in range(dim):
                previous[i, t, a] = previous_raw[i, min(t + 1, horizon - 1), a]
    velocity = np.empty((1, dim))
    for a in range(dim):
        velocity[0, a] = x0[dim + a]
    return halfspace_kernel(flat, horizon, dim, origins, mode, np.empty((0, 0, 0)), ego, plan,
                            previous, velocity, risk, alpha, mass, k, factor, z_guess,
                            band_width, delta, epsilon, conformal, radii, start_rows, low, high,
                            arc, disabled, normals, degenerate, offsets, rows_normals,
                            rows_offsets)
