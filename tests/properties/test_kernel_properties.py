"""Hypothesis: the compiled kernels equal the numpy reference on arbitrary small instances."""

from __future__ import annotations

import hypothesis.extra.numpy as hnp
import numpy as np
from hypothesis import assume, given
from hypothesis import strategies as st

from filters.geometry import Disc
from filters.halfspaces import safe_halfspaces
from filters.risk import RISKS
from filters.step_rows import step_rows

DISC = Disc(0.3)
# A coarse grid makes ties (equal losses, equal means) common.
grid = st.integers(-8, 8).map(lambda v: v / 4.0)
fine = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)


@st.composite
def instances(draw):
    n = draw(st.integers(1, 3))
    n_samples = draw(st.integers(1, 40))
    horizon = draw(st.integers(1, 4))
    elements = draw(st.sampled_from([grid, fine]))
    samples = draw(hnp.arrays(np.float64, (n, n_samples, horizon, 2), elements=elements))
    reference = draw(hnp.arrays(np.float64, (horizon, 2), elements=grid))
    return reference, samples


def choice_is_a_tie(samples, reference, ego, plan, first: int) -> bool:
    """Whether the near-side or clearest rule meets a tie (to 1e-10) at a step ``>= first``:
    the reference and the ego on orthogonal sides of a mean, or the reference and the plan
    equally far from it. There the choice follows the last bits of the sample means,
    which the two paths sum in another order; both choices are the rule's."""
    means = samples.mean(axis=1)[:, first:]
    reference = reference[first:]
    if plan is not None:
        gap = (np.linalg.norm(means - reference, axis=-1)
               - np.linalg.norm(means - plan[first:], axis=-1))
    else:
        gap = np.einsum("ktd,ktd->kt", reference - means, ego - means)
    return bool(np.any(np.abs(gap) < 1e-10))


def agree(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(np.all(np.abs(a - b) <= 1e-12 * (4.0 + np.max(np.abs(b), initial=0.0))))


@given(instance=instances(), risk=st.sampled_from(RISKS), alpha=st.floats(0.01, 0.99),
       delta=st.floats(-0.5, 0.5), epsilon=st.floats(0.0, 0.5), integral=st.booleans())
def test_kernel_equals_numpy(instance, risk, alpha, delta, epsilon, integral):
    reference, samples = instance
    n, n_samples, horizon, _ = samples.shape
    if integral:  # alpha N an integer (snapped by tail_count), alpha = 1 included
        alpha = min(max(round(alpha * n_samples), 1), n_samples) / n_samples
        if risk in ("gaussian_cc", "moment_dr", "conformal"):
            alpha = min(alpha, 0.99)  # a probability: below 1
    options = dict(risk=risk, alpha=alpha, delta=delta, epsilon=epsilon,
                   ego_shape=DISC, obstacle_shapes=[DISC] * n, ego_velocity=np.array([1.0, 0.0]))
    if risk == "conformal":
        options["conformal_margins"] = np.full(horizon, 0.2)
    fast = safe_halfspaces(reference, samples, backend="numba", **options)
    slow = safe_halfspaces(reference, samples, backend="numpy", **options)
    assert np.array_equal(fast.degenerate, slow.degenerate)
    assert agree(fast.normals, slow.normals) and agree(fast.offsets, slow.offsets)


@given(instance=instances(), risk=st.sampled_from(["cvar", "dr_cvar", "mean", "moment_dr"]),
       normals=st.sampled_from(["paper", "nearside", "clearest", "clearest_plan"]),
       data=st.data())
def test_step_rows_kernel_equals_numpy(instance, risk, normals, data):
    reference, samples = instance
    n, _, horizon, _ = samples.shape
    ego = np.array([-3.5, 0.25])
    mode: dict = {}
    if normals == "nearside":
        mode = dict(nearside_from=ego)
        assume(not choice_is_a_tie(samples, reference, ego, None, 0))
    elif normals.startswith("clearest"):  # on the grid too: the ego or the plan on a mean
        ego = data.draw(hnp.arrays(np.float64, (2,), elements=grid))
        mode = dict(clearest_from=ego)
        if normals == "clearest_plan":
            mode["clearest_plan"] = data.draw(hnp.arrays(np.float64, (horizon, 2),
                                                         elements=grid))
        assume(not choice_is_a_tie(samples, reference, ego, mode.get("clearest_plan"), 1))
    kwargs = dict(horizon=horizon, ego_shape=DISC, obstacle_shapes=[DISC] * n, risk=risk,
                  alpha=0.2, delta=0.1, epsilon=0.05, ego_velocity=np.array([1.5, 0.0]),
                  input_bounds=(np.full(2, -10.0), np.full(2, 10.0)), dt=0.2, **mode)
    try:
        slow = step_rows(reference, samples, backend="numpy", **kwargs)
    except ValueError as error:  # e.g. a zero near-side normal: both raise the same
        try:
            step_rows(reference, samples, backend="numba", **kwargs)
        except ValueError as same:
            assert type(same) is type(error) and str(same) == str(error)
            return
        raise AssertionError("the kernel path did not raise") from error
    fast = step_rows(reference, samples, backend="numba", **kwargs)
    assert agree(fast.normals, slow.normals) and agree(fast.offsets, slow.offsets)
