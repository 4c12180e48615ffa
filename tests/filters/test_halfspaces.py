"""Safe halfspaces: closed forms, Proposition 1 against CVXPY, fallbacks and errors."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from filters.errors import InvalidArrayError, InvalidParameterError, InvalidTypeError
from filters.geometry import ConvexPolygon, Disc, collision_margin
from filters.halfspace_cvxpy import TIGHT_CLARABEL, cvxpy_halfspace
from filters.halfspaces import Halfspaces, safe_halfspaces
from filters.risk import risk_value

Y_REF = np.array([-0.9, -0.8])
P_NOMINAL = np.array([0.5, 0.0])
DISC = Disc(0.3)
ATOL = 1e-6


def one(samples: np.ndarray, y_ref: np.ndarray = Y_REF, **options) -> Halfspaces:
    """Halfspace for one obstacle at one step from samples of shape (N, d)."""
    options.setdefault("ego_shape", DISC)
    options.setdefault("obstacle_shapes", [DISC])
    return safe_halfspaces(y_ref[None], samples[None, :, None, :], **options)


def reference(samples, h, r, **options):
    """CVXPY solution, tight tolerances, warnings about accuracy silenced (status is checked)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        result = cvxpy_halfspace(samples, h, r, solver_options=TIGHT_CLARABEL, **options)
    assert result.status.startswith("optimal"), result.status
    return result


def example_one(seed: int = 0, n_samples: int = 100) -> np.ndarray:
    return np.random.default_rng(seed).normal(P_NOMINAL, 0.1, size=(n_samples, 2))


# ----------------------------------------------------------------------------- closed forms


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("risk", ["mean", "cvar", "dr_cvar"])
def test_closed_forms_equal_the_cvxpy_programs(seed, risk):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 80))
    samples = rng.normal(rng.normal(size=2), rng.uniform(0.05, 1.0), size=(n, 2))
    alpha, delta, epsilon = rng.uniform(0.05, 1.0), rng.uniform(-0.3, 0.3), rng.uniform(0, 0.3)
    y_ref = rng.normal(size=2) * 2
    ours = one(samples, y_ref, risk=risk, alpha=alpha, delta=delta, epsilon=epsilon)
    ref = reference(
        samples, ours.normals[0, 0], 0.6, risk=risk, alpha=alpha, delta=delta, epsilon=epsilon
    )
    assert ours.offsets[0, 0] == pytest.approx(ref.offset, abs=ATOL)


def test_example_one_offsets_and_the_papers_observation():
    """Example 1 / Fig. 2: b_DR = b_CVaR - eps/alpha, and y_ref is safe for all but eps=0.2."""
    samples = example_one(seed=0)  # our normal uses the sample mean, the paper's the nominal p
    b = {risk: one(samples, risk=risk, epsilon=0.05).offsets[0, 0] for risk in ("mean", "cvar")}
    x = -(samples @ one(samples).normals[0, 0])
    assert b["mean"] == pytest.approx(-(np.mean(x) - 0.1 + 0.6), abs=1e-12)
    for epsilon in (0.05, 0.1, 0.2):
        hs = one(samples, risk="dr_cvar", epsilon=epsilon)
        assert hs.offsets[0, 0] == pytest.approx(b["cvar"] - epsilon / 0.2, abs=1e-12)
        assert bool(hs.contains(Y_REF[None])[0, 0]) is (epsilon < 0.2)
    assert one(samples, risk="mean").contains(Y_REF[None])[0, 0]
    assert one(samples, risk="cvar").contains(Y_REF[None])[0, 0]


def test_normal_points_from_reference_to_sample_mean():
    samples = example_one(seed=1, n_samples=20)
    hs = one(samples)
    direction = samples.mean(axis=0) - Y_REF
    np.testing.assert_allclose(hs.normals[0, 0], direction / np.linalg.norm(direction), rtol=1e-13)
    assert not hs.degenerate.any()


def test_offsets_are_ordered_and_limits_hold():
    samples = example_one(seed=2, n_samples=57)
    b = {r: one(samples, risk=r).offsets[0, 0] for r in ("mean", "cvar", "dr_cvar")}
    assert b["mean"] > b["cvar"] > b["dr_cvar"]
    assert one(samples, risk="dr_cvar", epsilon=0.0).offsets[0, 0] == pytest.approx(
        b["cvar"], abs=1e-14
    )
    assert one(samples, risk="cvar", alpha=1.0).offsets[0, 0] == pytest.approx(b["mean"], abs=1e-14)


def test_offsets_grow_with_delta_and_shrink_with_epsilon():
    samples = example_one(seed=3, n_samples=40)
    deltas = [one(samples, delta=d).offsets[0, 0] for d in (-0.2, 0.0, 0.1, 0.3)]
    epsilons = [one(samples, epsilon=e).offsets[0, 0] for e in (0.0, 0.01, 0.1, 0.5)]
    assert np.all(np.diff(deltas) > 0) and np.all(np.diff(epsilons) < 0)


# ----------------------------------------------------------------------------- vectorisation


def test_vectorised_call_equals_loop_over_obstacles_and_steps():
    rng = np.random.default_rng(5)
    n_obstacles, n_samples, horizon = 4, 31, 6
    y_ref = rng.normal(size=(horizon, 2))
    samples = (
        rng.normal(size=(n_obstacles, n_samples, horizon, 2)) * 0.3
        + rng.normal(size=(n_obstacles, 1, horizon, 2)) * 2
    )
    ego = ConvexPolygon.box(0.6, 0.3)
    shapes = [Disc(0.3), ConvexPolygon([(0, 0), (0.5, 0), (0, 0.4)]), Disc(0.1), Disc(0.3)]
    options = dict(risk="dr_cvar", alpha=0.15, delta=0.05, epsilon=0.07)
    hs = safe_halfspaces(y_ref, samples, ego_shape=ego, obstacle_shapes=shapes, **options)
    assert hs.normals.shape == (n_obstacles, horizon, 2) and hs.offsets.shape == (4, horizon)
    for i in range(n_obstacles):
        for t in range(horizon):
            single = safe_halfspaces(
                y_ref[t : t + 1],
                samples[i : i + 1, :, t : t + 1],
                ego_shape=ego,
                obstacle_shapes=[shapes[i]],
                **options,
            )
            np.testing.assert_allclose(hs.normals[i, t], single.normals[0, 0], rtol=1e-13)
            assert hs.offsets[i, t] == pytest.approx(single.offsets[0, 0], abs=1e-12)
            # And from first principles:
            h = hs.normals[i, t]
            r = collision_margin(ego, shapes[i], h)
            g = risk_value(-(samples[i, :, t] @ h), "dr_cvar", 0.15, 0.07) - 0.05 + r
            assert hs.offsets[i, t] == pytest.approx(-g, abs=1e-12)


def test_three_dimensional_positions():
    rng = np.random.default_rng(6)
    samples = rng.normal(size=(2, 25, 3, 3))
    hs = safe_halfspaces(np.zeros((3, 3)) - 2, samples, ego_shape=DISC, obstacle_shapes=[DISC] * 2)
    assert hs.normals.shape == (2, 3, 3)
    np.testing.assert_allclose(np.linalg.norm(hs.normals, axis=-1), 1.0)


def test_zero_obstacles_give_empty_arrays():
    hs = safe_halfspaces(
        np.zeros((10, 2)), np.zeros((0, 50, 10, 2)), ego_shape=DISC, obstacle_shapes=[]
    )
    assert hs.normals.shape == (0, 10, 2) and hs.offsets.shape == (0, 10)
    assert hs.degenerate.shape == (0, 10) and hs.contains(np.zeros((10, 2))).shape == (0, 10)


def test_contains_and_violation():
    samples = example_one(seed=4, n_samples=30)
    hs = one(samples)
    h, b = hs.normals[0, 0], hs.offsets[0, 0]
    on_boundary = b * h  # h is a unit vector
    assert hs.violation((on_boundary + 0.1 * h)[None])[0, 0] == pytest.approx(0.1)
    assert hs.contains((on_boundary - 0.01 * h)[None])[0, 0]
    assert not hs.contains((on_boundary + 0.01 * h)[None])[0, 0]
    with pytest.raises(InvalidArrayError, match="positions"):
        hs.contains(np.zeros((2, 2)))


# ----------------------------------------------------------------------------- degenerate normals


def symmetric_samples_around(y: np.ndarray, horizon: int = 3) -> np.ndarray:
    """Samples (1, 4, T, 2) whose mean is exactly ``y`` at every step."""
    offsets = np.array([[0.25, 0.0], [-0.25, 0.0], [0.0, 0.5], [0.0, -0.5]])
    return np.broadcast_to((y + offsets)[None, :, None, :], (1, 4, horizon, 2)).copy()


def degenerate_case(**options) -> Halfspaces:
    y = np.array([1.0, 2.0])
    return safe_halfspaces(
        np.tile(y, (3, 1)),
        symmetric_samples_around(y),
        ego_shape=DISC,
        obstacle_shapes=[DISC],
        **options,
    )


def test_degenerate_normal_falls_back_to_previous_normal_first():
    previous = np.zeros((1, 3, 2))
    previous[0, :, 1] = 2.0
    hs = degenerate_case(previous_normals=previous, ego_velocity=np.array([1.0, 0.0]))
    assert hs.degenerate.all() and np.isfinite(hs.offsets).all()
    np.testing.assert_allclose(hs.normals[0], np.tile([0.0, 1.0], (3, 1)))


def test_degenerate_normal_falls_back_to_minus_velocity_then_first_axis():
    previous = np.zeros((1, 3, 2))  # unusable: zero vectors
    hs = degenerate_case(previous_normals=previous, ego_velocity=np.array([0.0, -3.0]))
    np.testing.assert_allclose(hs.normals[0], np.tile([0.0, 1.0], (3, 1)))
    velocity = np.array([[0.0, 0.0], [3.0, 4.0], [0.0, 0.0]])  # per step; zero at 0 and 2
    hs = degenerate_case(ego_velocity=velocity)
    np.testing.assert_allclose(hs.normals[0], [[1.0, 0.0], [-0.6, -0.8], [1.0, 0.0]])
    hs = degenerate_case()
    np.testing.assert_allclose(hs.normals[0], np.tile([1.0, 0.0], (3, 1)))
    assert hs.degenerate.all() and np.isfinite(hs.offsets).all()


def test_only_degenerate_entries_are_flagged():
    y = np.array([1.0, 2.0])
    samples = symmetric_samples_around(y)
    samples[0, :, 1] += [1.0, 0.0]  # step 1 is well defined
    hs = safe_halfspaces(np.tile(y, (3, 1)), samples, ego_shape=DISC, obstacle_shapes=[DISC])
    np.testing.assert_array_equal(hs.degenerate, [[True, False, True]])
    np.testing.assert_allclose(hs.normals[0, 1], [1.0, 0.0])


# ----------------------------------------------------------------------------- bounded support


BOX = (np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]]),)


def box_around(samples: np.ndarray, rng: np.random.Generator, slack: float = 0.2):
    low = samples.min(axis=0) - rng.uniform(0, slack, 2)
    high = samples.max(axis=0) + rng.uniform(0, slack, 2)
    return BOX[0], np.array([high[0], -low[0], high[1], -low[1]])


@pytest.mark.parametrize("seed", range(5))
def test_polytope_support_equals_cvxpy_and_is_never_more_conservative(seed):
    rng = np.random.default_rng(seed)
    samples = example_one(seed=seed, n_samples=int(rng.integers(5, 60)))
    V, v = box_around(samples, rng)
    if seed % 2:  # add random extra (possibly redundant) faces
        extra = rng.normal(size=(2, 2))
        V, v = np.vstack([V, extra]), np.concatenate([v, (samples @ extra.T).max(0) + 0.05])
    alpha, epsilon = rng.uniform(0.05, 1.0), rng.uniform(0.0, 0.3)
    bounded = one(samples, alpha=alpha, epsilon=epsilon, support=(V, v))
    unbounded = one(samples, alpha=alpha, epsilon=epsilon)
    assert bounded.offsets[0, 0] >= unbounded.offsets[0, 0] - 1e-9
    ref = reference(
        samples, bounded.normals[0, 0], 0.6, alpha=alpha, epsilon=epsilon, support=(V, v)
    )
    assert bounded.offsets[0, 0] == pytest.approx(ref.offset, abs=ATOL)


def test_tight_support_is_strictly_less_conservative():
    samples = example_one(seed=0, n_samples=50)
    V, v = box_around(samples, np.random.default_rng(0), slack=0.0)
    bounded = one(samples, support=(V, v), epsilon=0.2)
    assert bounded.offsets[0, 0] > one(samples, epsilon=0.2).offsets[0, 0] + 0.1


def test_unbounded_polyhedral_support_equals_cvxpy():
    samples = example_one(seed=9, n_samples=30)
    # A halfplane facing the ego, and a wedge open away from it.
    for V in (np.array([[-0.6, -0.8]]), np.array([[-1.0, 0.0], [0.2, -1.0]])):
        v = (samples @ V.T).max(axis=0) + 0.01
        bounded = one(samples, support=(V, v), epsilon=0.1)
        ref = reference(samples, bounded.normals[0, 0], 0.6, epsilon=0.1, support=(V, v))
        assert bounded.offsets[0, 0] > one(samples, epsilon=0.1).offsets[0, 0] + 1e-3
        assert bounded.offsets[0, 0] == pytest.approx(ref.offset, abs=ATOL)
    # Open towards the ego: mass can travel along -h for ever, nothing is gained.
    V = np.array([[0.6, 0.8], [0.8, -0.6]])
    v = (samples @ V.T).max(axis=0) + 0.01
    bounded = one(samples, support=(V, v), epsilon=0.1)
    unbounded = one(samples, epsilon=0.1)
    assert bounded.offsets[0, 0] == pytest.approx(unbounded.offsets[0, 0], abs=1e-12)


def test_support_per_obstacle_and_support_only_changes_dr_cvar():
    rng = np.random.default_rng(11)
    samples = rng.normal(P_NOMINAL, 0.1, size=(2, 40, 3, 2))
    samples[1] += 1.0
    y_ref = np.tile(Y_REF, (3, 1))
    v = np.array([[0.9, -0.1, 0.4, 0.4], [1.9, -1.1, 1.4, -0.6]])
    support = (np.broadcast_to(BOX[0], (2, 4, 2)), v)
    shared = (BOX[0], np.array([2.0, 0.0, 2.0, 2.0]))
    options = dict(ego_shape=DISC, obstacle_shapes=[DISC, DISC])
    per = safe_halfspaces(y_ref, samples, support=support, **options)
    for i in range(2):
        single = safe_halfspaces(
            y_ref,
            samples[i : i + 1],
            support=(BOX[0], v[i]),
            ego_shape=DISC,
            obstacle_shapes=[DISC],
        )
        np.testing.assert_allclose(per.offsets[i], single.offsets[0], atol=1e-12)
    for risk in ("mean", "cvar"):
        a = safe_halfspaces(y_ref, samples, risk=risk, support=shared, **options)
        b = safe_halfspaces(y_ref, samples, risk=risk, **options)
        np.testing.assert_array_equal(a.offsets, b.offsets)


def test_three_dimensional_support_uses_the_cvxpy_path():
    rng = np.random.default_rng(12)
    samples = rng.normal(size=(12, 3)) * 0.2
    V, v = np.vstack([np.eye(3), -np.eye(3)]), np.full(6, 0.5)
    y_ref = np.array([-1.0, -1.0, 0.0])
    bounded = one(samples, y_ref, support=(V, v), epsilon=0.2)
    ref = reference(samples, bounded.normals[0, 0], 0.6, epsilon=0.2, support=(V, v))
    assert bounded.offsets[0, 0] == pytest.approx(ref.offset, abs=ATOL)
    assert bounded.offsets[0, 0] >= one(samples, y_ref, epsilon=0.2).offsets[0, 0] - 1e-12


def test_samples_outside_the_support_are_rejected():
    samples = example_one(seed=0, n_samples=10)
    V, v = BOX[0], np.array([0.5, 0.0, 1.0, 1.0])  # x <= 0.5 cuts samples off
    with pytest.raises(InvalidArrayError, match="support"):
        one(samples, support=(V, v))


# ----------------------------------------------------------------------------- CVXPY reference


def test_paper_formulation_equals_vectorised_formulation():
    samples = example_one(seed=13, n_samples=15)
    h = np.array([0.6, 0.8])
    V, v = box_around(samples, np.random.default_rng(13))
    for support in (None, (V, v)):
        a = reference(samples, h, 0.6, support=support)
        b = reference(samples, h, 0.6, support=support, formulation="paper")
        assert a.g == pytest.approx(b.g, abs=ATOL)
        assert a.setup_time >= 0 and a.solve_time >= 0 and a.call_time > 0


def test_cvxpy_reference_rejects_bad_input():
    samples = example_one(n_samples=5)
    with pytest.raises(InvalidParameterError, match="formulation"):
        cvxpy_halfspace(samples, np.ones(2), 0.6, formulation="loop")
    with pytest.raises(InvalidParameterError, match="risk"):
        cvxpy_halfspace(samples, np.ones(2), 0.6, risk="var")
    with pytest.raises(InvalidArrayError, match="h"):
        cvxpy_halfspace(samples, np.ones(3), 0.6)


def test_benchmark_table_one_smoke():
    from agents.experiments.table_one import benchmark_table_one, format_table_one

    result = benchmark_table_one(sample_counts=(50,), repeats=1, seed=1)
    assert [row.risk for row in result.cvxpy] == ["cvar", "dr_cvar"]
    assert result.cvxpy[1].paper_call == 9.10 and result.cvxpy[0].call_mean > 0
    assert all(row.grid_us > 0 and row.speedup > 0 for row in result.ours)
    text = format_table_one(result)
    assert "Table I" in text and "dr_cvar" in text


# ----------------------------------------------------------------------------- errors


def call(**changes):
    arguments = dict(
        reference_positions=np.zeros((4, 2)),
        samples=np.ones((2, 5, 4, 2)),
        ego_shape=DISC,
        obstacle_shapes=[DISC, DISC],
    )
    arguments.update(changes)
    return safe_halfspaces(**arguments)


def with_value(index, value):
    samples = np.ones((2, 5, 4, 2))
    samples[index] = value
    return samples


@pytest.mark.parametrize(
    "changes, error, name",
    [
        (dict(samples=with_value((1, 3, 2, 0), np.nan)), InvalidArrayError, "samples"),
        (dict(samples=with_value((0, 0, 0, 1), np.inf)), InvalidArrayError, "samples"),
        (dict(samples=with_value((0, 0, 0, 1), -np.inf)), InvalidArrayError, "samples"),
        (
            dict(reference_positions=np.full((4, 2), np.nan)),
            InvalidArrayError,
            "reference_positions",
        ),
        (dict(reference_positions=np.zeros((4, 3))), InvalidArrayError, "samples"),
        (dict(reference_positions=np.zeros(4)), InvalidArrayError, "reference_positions"),
        (dict(samples=np.ones((2, 5, 3, 2))), InvalidArrayError, "samples"),
        (dict(samples=np.ones((5, 4, 2))), InvalidArrayError, "samples"),
        (dict(samples=np.ones((2, 0, 4, 2))), InvalidArrayError, "samples"),
        (dict(obstacle_shapes=[DISC]), InvalidParameterError, "obstacle_shapes"),
        (dict(obstacle_shapes=[DISC, 0.3]), InvalidTypeError, "obstacle_shapes"),
        (dict(obstacle_shapes=DISC), InvalidTypeError, "obstacle_shapes"),
        (dict(ego_shape=None), InvalidTypeError, "ego_shape"),
        (dict(alpha=0.0), InvalidParameterError, "alpha"),
        (dict(alpha=1.2), InvalidParameterError, "alpha"),
        (dict(alpha=math.nan), InvalidParameterError, "alpha"),
        (dict(epsilon=-0.1), InvalidParameterError, "epsilon"),
        (dict(delta=math.nan), InvalidParameterError, "delta"),
        (dict(delta=math.inf), InvalidParameterError, "delta"),
        (dict(risk="var"), InvalidParameterError, "risk"),
        (dict(previous_normals=np.ones((2, 4))), InvalidArrayError, "previous_normals"),
        (dict(previous_normals=np.full((2, 4, 2), np.nan)), InvalidArrayError, "previous_normals"),
        (dict(ego_velocity=np.ones(3)), InvalidArrayError, "ego_velocity"),
        (dict(ego_velocity=np.array([np.nan, 1.0])), InvalidArrayError, "ego_velocity"),
        (dict(ego_velocity="fast"), InvalidArrayError, "ego_velocity"),
        (dict(support=(np.ones((4, 3)), np.ones(4))), InvalidArrayError, "support"),
        (dict(support=(np.ones((4, 2)), np.ones(3))), InvalidArrayError, "support"),
        (dict(support=(np.zeros((1, 2)), np.ones(1))), InvalidArrayError, "support"),
        (dict(support=np.ones((4, 2))), InvalidTypeError, "support"),
    ],
)
def test_bad_input_raises_a_named_error(changes, error, name):
    with pytest.raises(error, match=name):
        call(**changes)


def test_non_finite_sample_error_names_the_index():
    with pytest.raises(InvalidArrayError, match=r"\(1, 3, 2, 0\)"):
        call(samples=with_value((1, 3, 2, 0), np.nan))


def test_polygon_shapes_need_planar_positions():
    with pytest.raises(InvalidArrayError, match="ConvexPolygon"):
        safe_halfspaces(
            np.zeros((1, 3)),
            np.ones((1, 2, 1, 3)),
            ego_shape=DISC,
            obstacle_shapes=[ConvexPolygon.box(1, 1)],
        )
