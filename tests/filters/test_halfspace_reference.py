"""The one implementation of the halfspaces against the CVXPY formulation, by tolerance.

:func:`filters.safe_halfspaces` (and the wrapper's rows built on it: given normals,
the inter-sample start rows) is checked against the readable reference on seeded random
instances: each normal against :math:`(\\bar p - y^r) / \\lVert \\bar p - y^r \\rVert`
written out per obstacle and step, each offset against :math:`b = -g^*` of
:func:`filters.halfspace_cvxpy.cvxpy_halfspace` (Definition 2 and Proposition 1, solved
by Clarabel at tight tolerances). The paper's facts are then checked on whole
``(n_obstacles, T)`` arrays: :math:`b_{mean} \\ge b_{CVaR} \\ge b_{DR-CVaR}`,
DR-CVaR :math:`\\to` CVaR as :math:`\\epsilon \\to 0`, :math:`b` grows with
:math:`\\delta`, and CVaR at :math:`\\alpha = 1` is the mean.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from filters import Disc, intersample_rows, safe_halfspaces
from filters.halfspace_cvxpy import TIGHT_CLARABEL, cvxpy_halfspace
from filters.halfspaces import _losses
from filters.intersample import intersample_halfspaces

#: Relative tolerance of offsets against CVXPY, ``|b - b_ref| <= RTOL (1 + |b_ref|)``
#: (Clarabel at ``TIGHT_CLARABEL`` reaches about 1e-11 on these instances).
RTOL = 1e-9
#: Proposition 1 with a polytope support: a golden-section search over the multiplier
#: (bracket 1e-10 of ``1/alpha``) against a conic program, which Clarabel often reports
#: as "optimal_inaccurate" at these tolerances.
RTOL_SUPPORT = 1e-7
#: Normals against the formula written out: rounding only.
RTOL_NORMALS = 1e-12


def random_instance(rng: np.random.Generator) -> dict:
    """A few obstacles, steps and samples, with the risk settings drawn too."""
    n, n_samples, horizon = int(rng.integers(1, 4)), int(rng.integers(5, 120)), int(
        rng.integers(1, 4))
    centres = rng.uniform(-4.0, 4.0, (n, 1, horizon, 2))
    samples = centres + rng.uniform(0.05, 0.8) * rng.standard_normal((n, n_samples, horizon, 2))
    return dict(
        reference=rng.uniform(-4.0, 4.0, (horizon, 2)), samples=samples,
        ego=Disc(float(rng.uniform(0.1, 0.5))),
        obstacles=[Disc(float(r)) for r in rng.uniform(0.1, 0.5, n)],
        alpha=float(rng.uniform(0.05, 1.0)), delta=float(rng.uniform(-0.3, 0.3)),
        epsilon=float(rng.uniform(0.0, 0.3)))


def cvxpy_offset(samples: np.ndarray, normal: np.ndarray, margin: float, *,
                 accept: tuple[str, ...] = ("optimal",), **options) -> float:
    """:math:`b = -g^*` of one obstacle and step, by CVXPY (status one of ``accept``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # accuracy notes; the status is checked
        result = cvxpy_halfspace(samples, normal, margin, solver_options=TIGHT_CLARABEL,
                                 **options)
    assert result.status in accept, result.status
    return result.offset


def halfspaces_of(case: dict, risk: str, **change):
    options = dict(risk=risk, alpha=case["alpha"], delta=case["delta"],
                   epsilon=case["epsilon"])
    options.update(change)
    return safe_halfspaces(case["reference"], case["samples"], ego_shape=case["ego"],
                           obstacle_shapes=case["obstacles"], **options)


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar"])
def test_halfspaces_equal_the_cvxpy_formulation(seed, risk):
    case = random_instance(np.random.default_rng([seed, len(risk)]))
    ours = halfspaces_of(case, risk)
    samples, reference = case["samples"], case["reference"]
    n, _, horizon, _ = samples.shape
    for i in range(n):
        margin = case["ego"].radius + case["obstacles"][i].radius
        for t in range(horizon):
            towards = samples[i, :, t].mean(axis=0) - reference[t]
            normal = towards / np.linalg.norm(towards)
            np.testing.assert_allclose(ours.normals[i, t], normal, rtol=0,
                                       atol=RTOL_NORMALS)
            expected = cvxpy_offset(samples[i, :, t], normal, margin, risk=risk,
                                    alpha=case["alpha"], delta=case["delta"],
                                    epsilon=case["epsilon"])
            assert abs(ours.offsets[i, t] - expected) <= RTOL * (1 + abs(expected))
    assert not ours.degenerate.any()


@pytest.mark.parametrize("seed", range(4))
def test_given_normals_offsets_equal_the_cvxpy_formulation(seed):
    """The wrapper's rows: offsets along given normals (the near-side and clearest rules,
    the inter-sample start rows), per-step radii ``epsilon``."""
    rng = np.random.default_rng([seed, 99])
    case = random_instance(rng)
    samples = case["samples"]
    n, _, horizon, _ = samples.shape
    normals = rng.standard_normal((n, horizon, 2))
    epsilon = rng.uniform(0.0, 0.3, horizon)
    ours = safe_halfspaces(np.zeros((horizon, 2)), samples, ego_shape=case["ego"],
                           obstacle_shapes=case["obstacles"], risk="dr_cvar", normals=normals,
                           alpha=case["alpha"], delta=case["delta"], epsilon=epsilon).offsets
    for i in range(n):
        margin = case["ego"].radius + case["obstacles"][i].radius
        for t in range(horizon):
            unit = normals[i, t] / np.linalg.norm(normals[i, t])
            expected = cvxpy_offset(samples[i, :, t], unit, margin, risk="dr_cvar",
                                    alpha=case["alpha"], delta=case["delta"],
                                    epsilon=float(epsilon[t]))
            assert abs(ours[i, t] - expected) <= RTOL * (1 + abs(expected))


@pytest.mark.parametrize("seed", range(3))
def test_intersample_start_rows_equal_the_cvxpy_formulation(seed):
    """Start row ``t``: the samples of step ``t`` along the normal of step ``t + 1``,
    less the arc margin."""
    rng = np.random.default_rng([seed, 7])
    case = random_instance(rng)
    case["reference"] = rng.uniform(-4.0, 4.0, (3, 2))
    case["samples"] = case["samples"][:, :, :1] + 0.3 * rng.standard_normal(
        (len(case["obstacles"]), case["samples"].shape[1], 3, 2))
    hs = halfspaces_of(case, "dr_cvar")
    bounds = (np.array([-10.0, -8.0]), np.array([9.0, 10.0]))
    rows = intersample_rows(hs, case["samples"], ego_shape=case["ego"],
                            obstacle_shapes=case["obstacles"], input_bounds=bounds, dt=0.2)
    n = hs.n_obstacles
    for i in range(n):
        margin = case["ego"].radius + case["obstacles"][i].radius
        for t in range(2):
            normal = hs.normals[i, t + 1]
            arc = 0.2**2 / 8 * np.maximum(-normal * bounds[0], -normal * bounds[1]).sum()
            expected = cvxpy_offset(case["samples"][i, :, t], normal, margin, risk="dr_cvar",
                                    alpha=case["alpha"], delta=case["delta"],
                                    epsilon=case["epsilon"]) - arc
            np.testing.assert_allclose(rows.normals[n + i, t], normal, rtol=0, atol=0)
            assert abs(rows.offsets[n + i, t] - expected) <= RTOL * (1 + abs(expected))


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("given", [False, True])
def test_one_pass_rows_equal_the_cvxpy_formulation(seed, given):
    """The wrapper's one pass (:func:`filters.intersample.intersample_halfspaces`): end
    row ``t`` along ``h_t``, start row ``t`` along ``h_{t+1}``, both from the samples of
    step ``t``, less the arc margin; per-step radii; paper or given normals."""
    rng = np.random.default_rng([seed, 11, int(given)])
    case = random_instance(rng)
    horizon = int(rng.integers(2, 5))
    n = len(case["obstacles"])
    case["reference"] = rng.uniform(-4.0, 4.0, (horizon, 2))
    case["samples"] = case["samples"][:, :, :1] + 0.3 * rng.standard_normal(
        (n, case["samples"].shape[1], horizon, 2))
    epsilon = rng.uniform(0.0, 0.3, horizon)
    normals = rng.standard_normal((n, horizon, 2)) if given else None
    bounds = (np.array([-10.0, -8.0]), np.array([9.0, 10.0]))
    hs, rows = intersample_halfspaces(
        case["reference"], case["samples"], ego_shape=case["ego"],
        obstacle_shapes=case["obstacles"], input_bounds=bounds, dt=0.2, risk="dr_cvar",
        alpha=case["alpha"], delta=case["delta"], epsilon=epsilon, normals=normals)
    for i in range(n):
        margin = case["ego"].radius + case["obstacles"][i].radius
        for t in range(horizon):
            if given:
                normal = normals[i, t] / np.linalg.norm(normals[i, t])
            else:
                towards = case["samples"][i, :, t].mean(axis=0) - case["reference"][t]
                normal = towards / np.linalg.norm(towards)
            np.testing.assert_allclose(hs.normals[i, t], normal, rtol=RTOL_NORMALS, atol=0)
            for row, h in ((i, hs.normals[i, t]), (n + i, hs.normals[i, min(t + 1, horizon - 1)])):
                if row >= n and t == horizon - 1:
                    assert rows.offsets[row, t] == 1.0 and not rows.normals[row, t].any()
                    continue  # the last start row is off
                arc = 0.2**2 / 8 * np.maximum(-h * bounds[0], -h * bounds[1]).sum()
                expected = cvxpy_offset(case["samples"][i, :, t], h, margin, risk="dr_cvar",
                                        alpha=case["alpha"], delta=case["delta"],
                                        epsilon=float(epsilon[t])) - arc
                np.testing.assert_allclose(rows.normals[row, t], h, rtol=0, atol=0)
                assert abs(rows.offsets[row, t] - expected) <= RTOL * (1 + abs(expected))
            assert abs(hs.offsets[i, t] - rows.offsets[i, t]
                       - 0.2**2 / 8 * np.maximum(-hs.normals[i, t] * bounds[0],
                                                 -hs.normals[i, t] * bounds[1]).sum()) <= 1e-12


@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar", "gaussian_cc", "moment_dr",
                                  "conformal"])
def test_one_pass_rows_equal_the_two_calls(risk):
    """Every risk: the one pass gives what ``safe_halfspaces`` then ``intersample_rows``
    give (the reference above covers the paper's risks), to rounding."""
    rng = np.random.default_rng(len(risk))
    n, horizon = 3, 6
    samples = rng.uniform(-3, 3, (n, 1, 1, 2)) + 0.2 * rng.standard_normal((n, 40, horizon, 2))
    reference = rng.uniform(-3, 3, (horizon, 2))
    options = dict(ego_shape=Disc(0.3), obstacle_shapes=[Disc(0.2), Disc(0.3), Disc(0.4)],
                   risk=risk, alpha=0.2, delta=0.1, epsilon=rng.uniform(0, 0.2, horizon),
                   conformal_margins=rng.uniform(0, 0.5, (n, horizon)))
    bounds = (np.array([-10.0, -10.0]), np.array([10.0, 10.0]))
    hs, rows = intersample_halfspaces(reference, samples, input_bounds=bounds, dt=0.2,
                                      **options)
    hs2 = safe_halfspaces(reference, samples, **options)
    rows2 = intersample_rows(hs2, samples, input_bounds=bounds, dt=0.2, **options)
    np.testing.assert_allclose(hs.normals, hs2.normals, rtol=1e-12, atol=0)
    np.testing.assert_allclose(hs.offsets, hs2.offsets, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(rows.normals, rows2.normals, rtol=1e-12, atol=0)
    np.testing.assert_allclose(rows.offsets, rows2.offsets, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("seed", range(3))
def test_polytope_support_equals_the_cvxpy_conic_program(seed):
    rng = np.random.default_rng([seed, 5])
    case = random_instance(rng)
    samples = case["samples"]
    low, high = samples.min(axis=(0, 1, 2)) - 0.2, samples.max(axis=(0, 1, 2)) + 0.2
    V = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
    v = np.array([high[0], -low[0], high[1], -low[1]])
    ours = halfspaces_of(case, "dr_cvar", support=(V, v))
    for i in range(samples.shape[0]):
        margin = case["ego"].radius + case["obstacles"][i].radius
        for t in range(samples.shape[2]):
            expected = cvxpy_offset(samples[i, :, t], ours.normals[i, t], margin,
                                    risk="dr_cvar", alpha=case["alpha"], delta=case["delta"],
                                    epsilon=case["epsilon"], support=(V, v),
                                    accept=("optimal", "optimal_inaccurate"))
            assert abs(ours.offsets[i, t] - expected) <= RTOL_SUPPORT * (1 + abs(expected))


def test_losses_are_minus_h_dot_p_for_long_horizons():
    """Each step's losses use that step's normal and samples only (T = 80, d = 3)."""
    rng = np.random.default_rng(3)
    points = rng.standard_normal((4, 31, 80, 3))
    normals = rng.standard_normal((4, 80, 3))
    expected = -np.einsum("isTd,iTd->iTs", points, normals)
    np.testing.assert_allclose(_losses(points, normals), expected, rtol=0, atol=1e-14)


# --------------------------------------------------------------------------- the paper's facts


@pytest.mark.parametrize("seed", range(8))
def test_the_papers_facts_hold_on_random_instances(seed):
    case = random_instance(np.random.default_rng([seed, 11]))
    mean, cvar, dr_cvar = (halfspaces_of(case, risk).offsets
                           for risk in ("mean", "cvar", "dr_cvar"))
    slack = 1e-12 * (1 + np.abs(mean))
    assert np.all(mean >= cvar - slack) and np.all(cvar >= dr_cvar - slack)
    # DR-CVaR -> CVaR as epsilon -> 0 (the gap is epsilon / alpha)
    for epsilon in (1e-2, 1e-4, 1e-8, 0.0):
        gap = cvar - halfspaces_of(case, "dr_cvar", epsilon=epsilon).offsets
        np.testing.assert_allclose(gap, epsilon / case["alpha"], rtol=0, atol=1e-12)
    # monotone in delta (each offset grows by exactly the increase of delta)
    for risk in ("mean", "cvar", "dr_cvar"):
        low = halfspaces_of(case, risk, delta=case["delta"] - 0.05).offsets
        high = halfspaces_of(case, risk, delta=case["delta"] + 0.05).offsets
        np.testing.assert_allclose(high - low, 0.1, rtol=0, atol=1e-12)
    # CVaR at alpha = 1 is the mean
    np.testing.assert_allclose(halfspaces_of(case, "cvar", alpha=1.0).offsets, mean,
                               rtol=0, atol=1e-12)


def test_backend_is_a_deprecated_no_op():
    case = random_instance(np.random.default_rng(0))
    plain = halfspaces_of(case, "dr_cvar")
    for backend in ("auto", "numba", "numpy"):
        with pytest.warns(DeprecationWarning, match="backend"):
            again = halfspaces_of(case, "dr_cvar", backend=backend)
        np.testing.assert_array_equal(again.offsets, plain.offsets)
    with pytest.raises(ValueError, match="backend"):
        halfspaces_of(case, "dr_cvar", backend="gpu")
