"""The compiled halfspace kernels equal the numpy reference (and hence the CVXPY programs).

Every case runs both back ends on the same data: ``backend="numba"`` (the kernels of
:mod:`filters._kernels`) against ``backend="numpy"`` (the vectorised reference that the
CVXPY tests of ``test_halfspaces.py`` pin down). They evaluate the same closed forms in
another order of summation, so they agree to rounding: the tolerance below is 1e-12 of
the data's scale.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from filters import Disc, intersample_rows, safe_halfspaces
from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import ConvexPolygon
from filters.halfspaces import offsets_along
from filters.kernels import compiled_rows
from filters.risk import RISKS, empirical_cvar
from filters.step_rows import clearest_normals, step_rows

TOL = 1e-12
LOW, HIGH = np.full(2, -10.0), np.full(2, 10.0)


def close(a: np.ndarray, b: np.ndarray, scale: float = 1.0) -> bool:
    """Equal to ``TOL`` of ``scale`` (plus the arrays' own size)."""
    if a.shape != b.shape:
        return False
    bound = TOL * (scale + float(np.max(np.abs(b), initial=0.0)))
    return bool(np.all(np.abs(a - b) <= bound))


def instance(rng: np.random.Generator, n: int, n_samples: int, horizon: int, dim: int = 2,
             spread: float = 0.1, ties: bool = False):
    """Reference positions and samples around random means (metres)."""
    means = rng.uniform(-4.0, 4.0, (n, 1, horizon, dim))
    noise = spread * rng.standard_normal((n, n_samples, horizon, dim))
    if ties:  # a coarse grid: many equal losses
        noise = np.round(noise / spread * 2.0) * spread / 2.0
    reference = rng.uniform(-4.0, 4.0, (horizon, dim))
    return reference, means + noise


def both(reference, samples, **options):
    """``safe_halfspaces`` with each back end."""
    shapes = options.pop("obstacle_shapes", [Disc(0.3)] * samples.shape[0])
    ego = options.pop("ego_shape", Disc(0.3))
    fast = safe_halfspaces(reference, samples, ego_shape=ego, obstacle_shapes=shapes,
                           backend="numba", **options)
    slow = safe_halfspaces(reference, samples, ego_shape=ego, obstacle_shapes=shapes,
                           backend="numpy", **options)
    return fast, slow


def options_for(risk: str, rng: np.random.Generator, horizon: int, n: int) -> dict:
    options: dict = dict(risk=risk, alpha=0.2, delta=0.1, epsilon=0.05)
    if risk == "conformal":
        options["conformal_margins"] = rng.uniform(0.0, 0.3, (n, horizon))
    return options


# ----------------------------------------------------------------------------- selection


@pytest.mark.parametrize("n", [1, 2, 7, 8, 9, 31, 32, 33, 100, 257, 1000])
def test_kth_largest_is_the_sorted_value_for_any_band(n):
    """Exact for every rank, with ties, whatever the band (good, missed, empty, NaN)."""
    from filters import _kernels

    rng = np.random.default_rng(n)
    for trial in range(20):
        x = rng.standard_normal(n)
        if trial % 3 == 1:
            x = np.round(x * 2.0) / 2.0  # many ties
        if trial % 5 == 2:
            x[: n // 2] = x[0]  # a block of equal values
        ordered = np.sort(x)[::-1]
        for k in sorted({0, 1, n // 5, n // 2, n - 2, n - 1} & set(range(n))):
            for low, high in ((ordered[k] - 0.1, ordered[k] + 0.1), (5.0, 6.0), (-6.0, -5.0),
                              (math.nan, math.nan), (ordered[k], ordered[k]),
                              (-math.inf, math.inf)):
                work = np.empty((3, n))
                work[0] = x
                value = _kernels.kth_largest(work, n, k, low, high)
                assert value == ordered[k], (n, k, low, high)
                assert np.array_equal(work[0], x)  # the losses are kept


def test_select_handles_infinities_and_adversarial_orders():
    from filters import _kernels

    rng = np.random.default_rng(0)
    for x in (np.array([np.inf, -np.inf, 0.0, 1.0, np.inf]), np.arange(500.0),
              np.arange(500.0)[::-1], np.tile([3.0, 1.0, 2.0], 200),
              np.concatenate([np.arange(250.0), np.arange(250.0)[::-1]]),
              rng.integers(0, 3, 777).astype(float)):
        for kth in (0, len(x) // 3, len(x) - 1):
            work = np.empty((3, len(x)))
            work[1] = x
            assert _kernels.select(work, 1, len(x), kth) == np.sort(x)[kth]


def test_heapsort_guard_sorts():
    from filters import _kernels

    rng = np.random.default_rng(1)
    for n in (1, 2, 5, 64, 333):
        work = np.empty((3, n))
        work[2] = rng.integers(0, 10, n)
        expected = np.sort(work[2])
        _kernels._heapsort(work, 2, 0, n)
        assert np.array_equal(work[2], expected)


# ----------------------------------------------------------------------------- safe_halfspaces


@pytest.mark.parametrize("risk", RISKS)
@pytest.mark.parametrize("size", [(1, 1, 1), (3, 100, 10), (2, 57, 20), (4, 20, 3),
                                  (2, 1000, 17), (1, 5, 80)])
def test_kernel_equals_numpy_for_every_risk(risk, size):
    n, n_samples, horizon = size
    rng = np.random.default_rng(hash((risk, size)) % 2**32)
    reference, samples = instance(rng, n, n_samples, horizon)
    fast, slow = both(reference, samples, **options_for(risk, rng, horizon, n))
    assert close(fast.offsets, slow.offsets, 4.0)
    assert close(fast.normals, slow.normals)
    assert np.array_equal(fast.degenerate, slow.degenerate)
    assert fast.risk == slow.risk and fast.alpha == slow.alpha and fast.epsilon == slow.epsilon


@pytest.mark.parametrize("alpha", [1e-3, 0.01, 0.2, 0.25, 0.7, 1 / 3, 0.999, 1.0])
@pytest.mark.parametrize("n_samples", [1, 2, 3, 10, 50, 100, 333])
def test_cvar_tail_mass_fractional_integer_below_one_and_one(alpha, n_samples):
    """alpha N fractional, integral (0.2 * 50, snapped), below 1 (the maximum), N = 1."""
    rng = np.random.default_rng(n_samples)
    reference, samples = instance(rng, 2, n_samples, 3)
    for risk in ("cvar", "dr_cvar"):
        fast, slow = both(reference, samples, risk=risk, alpha=alpha, epsilon=0.03)
        assert close(fast.offsets, slow.offsets, 4.0), (risk, alpha, n_samples)
    # and the kernel's CVaR is the exact one of filters.risk
    fast = safe_halfspaces(reference, samples, ego_shape=Disc(0.0),
                           obstacle_shapes=[Disc(0.0)] * 2, risk="cvar", alpha=alpha,
                           delta=0.0, backend="numba")
    losses = -np.einsum("istd,itd->its", samples, fast.normals)
    assert close(-fast.offsets, empirical_cvar(losses, alpha), 4.0)


@pytest.mark.parametrize("risk", ["cvar", "dr_cvar", "mean", "gaussian_cc", "moment_dr"])
def test_ties_and_identical_samples(risk):
    rng = np.random.default_rng(3)
    reference, samples = instance(rng, 3, 64, 5, ties=True)
    samples[1] = samples[1, :1]  # every sample of obstacle 1 the same: zero spread
    fast, slow = both(reference, samples, risk=risk)
    assert close(fast.offsets, slow.offsets, 4.0)


def test_per_step_epsilon_and_conformal_margin_shapes():
    rng = np.random.default_rng(4)
    reference, samples = instance(rng, 3, 40, 6)
    fast, slow = both(reference, samples, risk="dr_cvar", epsilon=np.linspace(0.0, 0.2, 6))
    assert close(fast.offsets, slow.offsets, 4.0)
    assert np.array_equal(fast.epsilon, slow.epsilon)
    for margins in (0.2, np.linspace(0.0, 0.3, 6), rng.uniform(0.0, 0.3, (3, 6))):
        fast, slow = both(reference, samples, risk="conformal", conformal_margins=margins)
        assert close(fast.offsets, slow.offsets, 4.0)


def test_degenerate_normals_take_the_same_fallbacks():
    y = np.array([1.0, 2.0])
    spokes = np.array([[0.25, 0.0], [-0.25, 0.0], [0.0, 0.5], [0.0, -0.5]])
    samples = np.broadcast_to((y + spokes)[None, :, None, :], (2, 4, 3, 2)).copy()
    samples[1, :, 1] += [1.0, 0.0]  # obstacle 1, step 1: well defined
    reference = np.tile(y, (3, 1))
    previous = np.zeros((2, 3, 2))
    previous[0, :, 1] = 2.0  # obstacle 0: a usable previous normal; obstacle 1: zero
    for extra in (dict(previous_normals=previous, ego_velocity=np.array([0.0, -3.0])),
                  dict(ego_velocity=np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 0.0]])),
                  dict(previous_normals=previous), dict()):
        fast, slow = both(reference, samples, **extra)
        assert np.array_equal(fast.degenerate, slow.degenerate)
        assert fast.degenerate.sum() == 5
        assert np.array_equal(fast.normals, slow.normals)  # the fallbacks are exact
        assert close(fast.offsets, slow.offsets, 4.0)


def test_given_normals_and_higher_dimensions():
    rng = np.random.default_rng(5)
    reference, samples = instance(rng, 3, 30, 4, dim=3)
    fast, slow = both(reference, samples)
    assert close(fast.offsets, slow.offsets, 4.0) and close(fast.normals, slow.normals)
    normals = rng.standard_normal((3, 4, 3))
    fast, slow = both(reference, samples, normals=normals, risk="moment_dr")
    assert close(fast.offsets, slow.offsets, 4.0)
    assert np.array_equal(fast.normals, slow.normals)


def test_large_positions_keep_their_accuracy():
    """Kilometre coordinates, centimetre spread: both agree to 1e-12 of the offsets' scale,
    and the kernel (shifted sums) is at least as close to a long-double reference."""
    rng = np.random.default_rng(6)
    reference, samples = instance(rng, 2, 200, 4, spread=0.01)
    reference, samples = reference + 3e3, samples + 3e3
    fast, slow = both(reference, samples, risk="cvar", delta=0.0, ego_shape=Disc(0.0),
                      obstacle_shapes=[Disc(0.0)] * 2)
    assert close(fast.offsets, slow.offsets)
    points, origin = samples.astype(np.longdouble), reference.astype(np.longdouble)
    h = points.mean(axis=1) - origin
    h /= np.sqrt((h * h).sum(axis=-1))[..., None]
    losses = -np.sort(np.einsum("istd,itd->its", points, h), axis=-1)  # descending -h.p
    exact = (losses[..., :40].sum(axis=-1) / 40).astype(float)  # alpha N = 40 exactly
    assert np.max(np.abs(fast.offsets + exact)) <= np.max(np.abs(slow.offsets + exact))
    assert np.max(np.abs(fast.normals - h.astype(float))) <= 1e-13


def test_auto_uses_the_kernel_only_where_it_applies(monkeypatch):
    import filters.halfspaces as halfspaces

    calls = []
    real = halfspaces.compiled_rows

    def counted(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(halfspaces, "compiled_rows", counted)
    rng = np.random.default_rng(7)
    reference, samples = instance(rng, 2, 20, 3)
    safe_halfspaces(reference, samples, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2)
    assert len(calls) == 1
    box = (np.vstack([np.eye(2), -np.eye(2)]), np.full(4, 10.0))
    safe_halfspaces(reference, samples, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2,
                    support=box)  # Proposition 1 with a polytope: numpy
    safe_halfspaces(reference, samples, ego_shape=ConvexPolygon.box(0.6, 0.3),
                    obstacle_shapes=[Disc(0.3)] * 2)  # a polygon: numpy
    assert len(calls) == 1
    fast = safe_halfspaces(reference, samples, ego_shape=Disc(0.3),
                           obstacle_shapes=[Disc(0.3)] * 2, support=box, risk="cvar")
    assert len(calls) == 2  # the support only matters for dr_cvar
    slow = safe_halfspaces(reference, samples, ego_shape=Disc(0.3),
                           obstacle_shapes=[Disc(0.3)] * 2, support=box, risk="cvar",
                           backend="numpy")
    assert close(fast.offsets, slow.offsets, 4.0)


def test_zero_obstacles_and_results_are_deterministic():
    """The same data give the same bits, wherever the arrays and the scratch space lie."""
    empty = safe_halfspaces(np.zeros((4, 2)), np.zeros((0, 10, 4, 2)), ego_shape=Disc(0.3),
                            obstacle_shapes=[], backend="numba")
    assert empty.offsets.shape == (0, 4) and empty.normals.shape == (0, 4, 2)
    rng = np.random.default_rng(8)
    reference, samples = instance(rng, 3, 503, 12)
    kwargs = dict(horizon=12, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 3,
                  risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05,
                  input_bounds=(LOW, HIGH), dt=0.2, backend="numba")
    first = step_rows(reference, samples, **kwargs)
    keep = []
    for size in rng.integers(1, 5000, 20):
        keep.append(np.ones(size))  # shift where the next allocations land
        copy = np.empty(samples.size + size)[size:].reshape(samples.shape)  # other alignment
        copy[...] = samples
        again = step_rows(reference, copy, **kwargs)
        assert np.array_equal(first.offsets, again.offsets)
        assert np.array_equal(first.normals, again.normals)


# ----------------------------------------------------------------------------- start rows


@pytest.mark.parametrize("risk", RISKS)
def test_offsets_along_and_intersample_rows_equal_numpy(risk):
    rng = np.random.default_rng(9)
    n, horizon = 3, 10
    reference, samples = instance(rng, n, 100, horizon + 2)
    normals = rng.standard_normal((n, horizon, 2))
    shapes = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.2), Disc(0.3), Disc(0.4)])
    options = options_for(risk, rng, horizon, n)
    fast = offsets_along(normals, samples, backend="numba", **shapes, **options)
    slow = offsets_along(normals, samples, backend="numpy", **shapes, **options)
    assert close(fast, slow, 4.0)
    samples = samples[:, :, :horizon]
    hs = safe_halfspaces(reference[:horizon], samples, **shapes, **options)
    kwargs = dict(input_bounds=(LOW, HIGH), dt=0.2, **shapes, **options)
    fast_rows = intersample_rows(hs, samples, backend="numba", **kwargs)
    slow_rows = intersample_rows(hs, samples, backend="numpy", **kwargs)
    assert np.array_equal(fast_rows.normals, slow_rows.normals)
    assert close(fast_rows.offsets, slow_rows.offsets, 4.0)


def _step_rows_both_backends(reference, samples, rng, risk, intersample, **normals):
    """``step_rows`` on three discs with the numba kernel and the numpy composition
    (``normals``: the normal rule's keywords), checked equal in normals and offsets."""
    n, horizon = samples.shape[0], reference.shape[0]
    kwargs = dict(horizon=horizon, ego_shape=Disc(0.3),
                  obstacle_shapes=[Disc(0.3), Disc(0.5), Disc(0.1)],
                  previous_normals=rng.standard_normal((n, horizon, 2)),
                  ego_velocity=np.array([1.5, 0.2]),
                  input_bounds=(LOW, HIGH) if intersample else None, dt=0.2,
                  **normals, **options_for(risk, rng, horizon, n))
    if risk == "dr_cvar":
        kwargs["epsilon"] = np.linspace(0.01, 0.1, horizon)
    fast = step_rows(reference, samples, backend="numba", **kwargs)
    slow = step_rows(reference, samples, backend="numpy", **kwargs)
    assert close(fast.normals, slow.normals) and close(fast.offsets, slow.offsets, 4.0)
    assert close(fast.halfspaces.offsets, slow.halfspaces.offsets, 4.0)
    return fast, slow


@pytest.mark.parametrize("risk", RISKS)
@pytest.mark.parametrize("nearside", [False, True])
@pytest.mark.parametrize("intersample", [False, True])
def test_step_rows_kernel_equals_the_numpy_composition(risk, nearside, intersample):
    """The wrapper's step: one kernel call against near-side normals, safe_halfspaces and
    intersample_rows in numpy, including degenerate steps and the previous normals."""
    rng = np.random.default_rng(10)
    n, horizon = 3, 10
    reference, samples = instance(rng, n, 100, horizon + 3, spread=0.3)
    reference = reference[:horizon]
    samples[0, :, 2] += reference[2] - samples[0, :, 2].mean(axis=0)  # mean at the reference
    ego = rng.uniform(-4.0, 4.0, 2)
    fast, slow = _step_rows_both_backends(
        reference, samples, rng, risk, intersample, nearside_from=ego if nearside else None)
    assert np.array_equal(fast.halfspaces.degenerate, slow.halfspaces.degenerate)
    assert fast.normals.shape == (2 * n if intersample else n, horizon, 2)
    if not nearside:
        assert fast.halfspaces.degenerate[0, 2]


@pytest.mark.parametrize("intersample", [False, True])
def test_step_rows_with_given_normals_kernel_equals_numpy(intersample):
    """Given normals (the wrapper's normals="clearest"): the kernel and the numpy
    composition agree, and the normals are the given ones."""
    rng = np.random.default_rng(13)
    n, horizon = 3, 10
    reference, samples = instance(rng, n, 100, horizon, spread=0.3)
    given = rng.standard_normal((n, horizon, 2))
    given /= np.linalg.norm(given, axis=-1, keepdims=True)
    kwargs = dict(horizon=horizon, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * n,
                  risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05, normals=given,
                  input_bounds=(LOW, HIGH) if intersample else None, dt=0.2)
    fast = step_rows(reference[:horizon], samples, backend="numba", **kwargs)
    slow = step_rows(reference[:horizon], samples, backend="numpy", **kwargs)
    assert close(fast.normals, slow.normals) and close(fast.offsets, slow.offsets, 4.0)
    assert close(fast.halfspaces.normals, given)
    with pytest.raises(InvalidParameterError, match="at most one"):
        step_rows(reference[:horizon], samples, nearside_from=np.zeros(2), **kwargs)


def _clearest_instance(rng: np.random.Generator, plan: bool, horizon: int = 10):
    """Three obstacles, and the clearest rule's degenerate cases placed on purpose:

    * obstacle 0, step 2: the reference (and the plan) on the sample mean, so the
      direction falls back to the one from the ego;
    * obstacle 1, step 3 and obstacle 2, step 0: the ego exactly on the mean (dyadic
      samples, whose means both paths compute exactly), so the direction from the ego
      is degenerate too and the first axis is taken (at step 3 only without a plan: the
      near-side rule from the ego; with a plan the reference or the plan is the origin).
    """
    n = 3
    reference, samples = instance(rng, n, 100, horizon + 3, spread=0.3)
    reference = reference[:horizon]
    shift = rng.uniform(-4.0, 4.0, (horizon, 2))
    path = reference + shift if plan else None
    samples[0, :, 2] += reference[2] - samples[0, :, 2].mean(axis=0)
    if plan:
        path[2] = reference[2]
    ego = np.array([0.75, -1.25])
    around = np.stack([np.resize([0.125, -0.125], 100), np.resize([0.25, 0.25, -0.25, -0.25],
                                                                   100)], axis=-1)
    samples[1, :, 3] = ego + around
    samples[2, :, 0] = ego - around
    return reference, samples, ego, path


@pytest.mark.parametrize("risk", RISKS)
@pytest.mark.parametrize("plan", [False, True])
@pytest.mark.parametrize("intersample", [False, True])
def test_step_rows_clearest_kernel_equals_the_numpy_composition(risk, plan, intersample):
    """normals="clearest" computed in the kernel against clearest_normals, safe_halfspaces
    and intersample_rows in numpy, with and without a plan, degenerate steps included (the
    paper's fallbacks, previous normals and ego velocity, are not used by this rule)."""
    rng = np.random.default_rng(20)
    n, horizon = 3, 10
    reference, samples, ego, path = _clearest_instance(rng, plan, horizon)
    fast, slow = _step_rows_both_backends(reference, samples, rng, risk, intersample,
                                          clearest_from=ego, clearest_plan=path)
    assert not fast.halfspaces.degenerate.any() and not slow.halfspaces.degenerate.any()
    expected = clearest_normals(samples[:, :, :horizon], reference, ego, path)
    assert close(fast.halfspaces.normals, expected)
    assert fast.normals.shape == (2 * n if intersample else n, horizon, 2)
    # the degenerate cases were reached: the ego's direction, and the first axis
    from_ego = samples[0, :, 2].mean(axis=0) - ego
    assert close(fast.halfspaces.normals[0, 2], from_ego / np.linalg.norm(from_ego))
    assert np.array_equal(fast.halfspaces.normals[2, 0], [1.0, 0.0])
    if not plan:
        assert np.array_equal(fast.halfspaces.normals[1, 3], [1.0, 0.0])


def test_clearest_ties_go_to_the_reference_and_to_the_ego_as_in_numpy():
    """Exact ties, with sample means that both paths compute exactly: the reference as far
    from the mean as the plan (taken: ``>=``), and the reference orthogonal to the ego's
    side of the mean (near-side rule: not ``> 0``, so from the ego). Where the means are
    not exact, a tie is decided by their last bits (see the property tests)."""
    pattern = np.array([[0.25, 0.0], [-0.25, 0.0], [0.0, 0.125], [0.0, -0.125]])
    means = np.array([[-1.0, 0.5], [1.0, 0.5], [1.0, 0.0]])  # steps 0, 1, 2
    samples = (means[None, :, :] + pattern[:, None, :])[None]  # (1, 4, 3, 2)
    reference = np.array([[0.0, 2.0], [1.75, 1.0], [1.0, 0.75]])
    plan = np.array([[2.0, 2.0], [0.25, 1.0], [3.0, 3.0]])
    ego = np.zeros(2)
    for path, step, origin in ((plan, 1, reference[1]), (None, 2, ego)):
        out = compiled_rows(samples, 3, reference, radii=np.full(1, 0.6), risk="mean",
                            alpha=0.2, delta=0.1, epsilon=0.05, normals="clearest",
                            ego_position=ego, plan=path)
        expected = clearest_normals(samples, reference, ego, path)
        direction = means[step] - origin
        assert np.allclose(expected[0, step], direction / np.linalg.norm(direction),
                           rtol=0.0, atol=1e-15)
        assert out.status == 0 and close(out.normals, expected)


def test_clearest_kernel_equals_clearest_normals_on_random_instances():
    """Many random instances (dimension 2 and 3, plans near the reference so that either
    origin is chosen, origins near the means): the kernel's normals are clearest_normals'."""
    rng = np.random.default_rng(21)
    chosen = {True: 0, False: 0}
    for trial in range(200):
        dim = 2 if trial % 4 else 3
        n, horizon = int(rng.integers(1, 5)), int(rng.integers(1, 12))
        reference, samples = instance(rng, n, int(rng.integers(1, 60)), horizon, dim=dim,
                                      spread=float(rng.uniform(0.01, 1.0)))
        ego = rng.uniform(-4.0, 4.0, dim)
        plan = None
        if trial % 3:
            plan = reference + rng.normal(0.0, 1.0, (horizon, dim))
            means = samples.mean(axis=1)
            chosen[True] += int(np.sum(np.linalg.norm(means - reference, axis=-1)
                                       >= np.linalg.norm(means - plan, axis=-1)))
            chosen[False] += int(np.sum(np.linalg.norm(means - reference, axis=-1)
                                        < np.linalg.norm(means - plan, axis=-1)))
        out = compiled_rows(samples, horizon, reference, radii=np.full(n, 0.6), risk="cvar",
                            alpha=0.2, delta=0.1, epsilon=0.05, normals="clearest",
                            ego_position=ego, plan=plan)
        assert out.status == 0
        assert close(out.normals, clearest_normals(samples, reference, ego, plan))
        assert close(np.linalg.norm(out.normals, axis=-1), np.ones((n, horizon)))
    assert chosen[True] > 100 and chosen[False] > 100


def test_step_rows_with_one_step_and_one_sample():
    rng = np.random.default_rng(11)
    reference, samples = instance(rng, 2, 1, 1)
    kwargs = dict(horizon=1, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2,
                  risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05,
                  input_bounds=(LOW, HIGH), dt=0.2)
    fast = step_rows(reference, samples, backend="numba", **kwargs)
    slow = step_rows(reference, samples, backend="numpy", **kwargs)
    assert np.array_equal(fast.normals, slow.normals)
    assert close(fast.offsets, slow.offsets, 4.0)
    assert np.array_equal(fast.offsets[2:], np.ones((2, 1)))  # no next step: rows off


# ----------------------------------------------------------------------------- errors


def test_bad_samples_raise_the_same_named_errors():
    rng = np.random.default_rng(12)
    reference, samples = instance(rng, 2, 10, 4)
    for value in (np.nan, np.inf, -np.inf):
        bad = samples.copy()
        bad[1, 3, 2, 0] = value
        messages = []
        for backend in ("numba", "numpy"):
            with pytest.raises(InvalidArrayError, match=r"samples.*\(1, 3, 2, 0\)") as info:
                safe_halfspaces(reference, bad, ego_shape=Disc(0.3),
                                obstacle_shapes=[Disc(0.3)] * 2, backend=backend)
            messages.append(str(info.value))
        assert messages[0] == messages[1]
        for backend in ("numba", "numpy"):
            with pytest.raises(InvalidArrayError, match=r"\[1, 3, 2, 0\]"):
                step_rows(reference, bad, horizon=4, ego_shape=Disc(0.3),
                          obstacle_shapes=[Disc(0.3)] * 2, risk="cvar", alpha=0.2, delta=0.1,
                          epsilon=0.05, backend=backend)
    huge = samples * 1e306
    for backend in ("numba", "numpy"):
        with pytest.raises(InvalidArrayError, match="too large"):
            safe_halfspaces(reference, huge, ego_shape=Disc(0.3),
                            obstacle_shapes=[Disc(0.3)] * 2, backend=backend)


@pytest.mark.parametrize("normals", [{}, {"nearside_from": np.array([0.5, 0.2])},
                                     {"clearest_from": np.array([0.5, 0.2])},
                                     {"clearest_from": np.array([0.5, 0.2]),
                                      "clearest_plan": np.zeros((4, 2))}])
def test_non_finite_reference_in_the_lean_path_is_named(normals):
    rng = np.random.default_rng(13)
    reference, samples = instance(rng, 2, 10, 4)
    reference[2, 1] = np.nan
    for backend in ("numba", "numpy"):
        with pytest.raises(InvalidArrayError, match="reference_positions"):
            step_rows(reference, samples, horizon=4, ego_shape=Disc(0.3),
                      obstacle_shapes=[Disc(0.3)] * 2, risk="cvar", alpha=0.2, delta=0.1,
                      epsilon=0.05, backend=backend, **normals)


def test_clearest_arguments_are_checked():
    """Bad ego positions and plans: named errors on both paths, never a silent normal."""
    rng = np.random.default_rng(17)
    reference, samples = instance(rng, 2, 10, 4)
    kwargs = dict(horizon=4, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2,
                  risk="cvar", alpha=0.2, delta=0.1, epsilon=0.05)
    ego, plan = np.array([0.5, 0.2]), np.zeros((4, 2))
    bad_ego, bad_plan = ego.copy(), plan.copy()
    bad_ego[1] = np.nan
    bad_plan[3, 0] = np.inf
    for backend in ("numba", "numpy"):
        for bad, match in (
                (dict(clearest_from=np.ones(3)), r"clearest_from must have shape \(2,\)"),
                (dict(clearest_from=ego, clearest_plan=np.ones((3, 2))),
                 r"clearest_plan must have shape \(4, 2\)"),
                (dict(clearest_from=bad_ego), r"clearest_from must be finite.*\(1,\)"),
                (dict(clearest_from=bad_ego, clearest_plan=plan), "clearest_from"),
                (dict(clearest_from=ego, clearest_plan=bad_plan),
                 r"clearest_plan must be finite.*\(3, 0\)")):
            with pytest.raises(InvalidArrayError, match=match):
                step_rows(reference, samples, backend=backend, **bad, **kwargs)
        for bad in (dict(clearest_plan=plan), dict(clearest_from=ego, nearside_from=ego),
                    dict(clearest_from=ego, normals=np.ones((2, 4, 2)))):
            with pytest.raises(InvalidParameterError):
                step_rows(reference, samples, backend=backend, **bad, **kwargs)


def test_step_rows_checks_every_shape_before_the_kernel():
    """The kernel does not check indices: a wrong shape goes to the numpy path's errors."""
    rng = np.random.default_rng(16)
    reference, samples = instance(rng, 2, 10, 4)
    kwargs = dict(horizon=4, ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)] * 2,
                  risk="cvar", alpha=0.2, delta=0.1, epsilon=0.05, backend="numba")
    with pytest.raises(InvalidArrayError, match="previous_normals"):
        step_rows(reference, samples, previous_normals=np.ones((2, 3, 2)), **kwargs)
    with pytest.raises(InvalidArrayError, match="ego_velocity"):
        step_rows(reference, samples, ego_velocity=np.ones(3), **kwargs)
    with pytest.raises(InvalidArrayError, match="epsilon"):
        step_rows(reference, samples, **dict(kwargs, risk="dr_cvar", epsilon=np.ones(3)))
    with pytest.raises(InvalidArrayError, match="conformal_margins"):
        step_rows(reference, samples,
                  **dict(kwargs, risk="conformal", conformal_margins=np.ones((3, 4))))
    with pytest.raises(InvalidArrayError, match="samples"):
        step_rows(reference, samples[:, :, :3], **kwargs)
    for bad in (dict(input_bounds=(np.ones(3), np.ones(3)), dt=0.2),
                dict(nearside_from=np.ones(3))):
        with pytest.raises(ValueError):
            step_rows(reference, samples, **bad, **kwargs)


def test_backend_is_checked():
    rng = np.random.default_rng(14)
    reference, samples = instance(rng, 1, 10, 2)
    kwargs = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.3)])
    with pytest.raises(InvalidParameterError, match="backend"):
        safe_halfspaces(reference, samples, backend="fortran", **kwargs)
    with pytest.raises(InvalidTypeError, match="backend"):
        safe_halfspaces(reference, samples, backend=None, **kwargs)
    with pytest.raises(InvalidParameterError, match="numba"):
        safe_halfspaces(reference, samples, backend="numba", ego_shape=ConvexPolygon.box(1, 1),
                        obstacle_shapes=[Disc(0.3)])
    box = (np.vstack([np.eye(2), -np.eye(2)]), np.full(4, 10.0))
    with pytest.raises(InvalidParameterError, match="numba"):
        safe_halfspaces(reference, samples, backend="numba", support=box, **kwargs)


def test_compiled_rows_reports_a_status_instead_of_raising():
    rng = np.random.default_rng(15)
    reference, samples = instance(rng, 2, 10, 4)
    radii = np.full(2, 0.6)
    options = dict(radii=radii, risk="cvar", alpha=0.2, delta=0.1, epsilon=0.05)
    assert compiled_rows(samples, 4, reference, **options).status == 0
    bad = samples.copy()
    bad[0, 0, 0, 0] = np.nan
    assert compiled_rows(bad, 4, reference, **options).status == 1
    reference = reference.copy()
    reference[1] = np.inf
    assert compiled_rows(samples, 4, reference, **options).status == 2


def test_import_filters_does_not_import_numba():
    code = "import sys, filters; print('numba' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.strip() == "False"
