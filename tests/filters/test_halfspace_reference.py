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
from filters.halfspaces import _losses, offsets_along

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
def test_offsets_along_given_normals_equal_the_cvxpy_formulation(seed):
    """The wrapper's rows: offsets along given normals (the near-side and clearest rules,
    the inter-sample start rows), per-step radii ``epsilon``."""
    rng = np.random.default_rng([seed, 99])
    case = random_instance(rng)
    samples = case["samples"]
    n, _, horizon, _ = samples.shape
    normals = rng.standard_normal((n, horizon, 2))
    epsilon = rng.uniform(0.0, 0.3, horizon)
    ours = offsets_along(normals, samples, ego_shape=case["ego"],
                         obstacle_shapes=case["obstacles"], risk="dr_cvar",
                         alpha=case["alpha"], delta=case["delta"], epsilon=epsilon)
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
