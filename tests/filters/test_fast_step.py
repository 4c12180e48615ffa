"""The wrapper's fast path (``fast_path=True``) against the general one.

* :class:`filters.kernels.WrapperRows` against :func:`filters.step_rows.step_rows` (the
  same bits) for every normal source;
* :class:`filters.SafetyFilterWrapper` episodes with ``fast_path`` on and off: the same
  statuses and actions to rounding; the fast path gives the same bits run to run.

The MPC step has one implementation; it is checked against its CVXPY formulation in
``tests/filters/test_mpc_reference.py``.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401
from benchmarks.filter_qp import double_integrator
from filters import SafetyFilterWrapper
from filters.geometry import Disc
from filters.mpc.filter import DISABLED_OFFSET
from filters.step_rows import step_rows

TS = 0.2
A, B, C = double_integrator(TS)


@pytest.mark.parametrize("normals", ["paper", "ego", "nearside", "previous_plan", "clearest"])
@pytest.mark.parametrize("intersample", [True, False])
def test_wrapper_rows_equal_step_rows(normals, intersample):
    """The prepared kernel call gives step_rows' bits, with the origins, the shifted plan and
    the previous normals formed inside it."""
    from filters.kernels import WrapperRows

    rng = np.random.default_rng([len(normals), intersample])
    k, n_samples, T = 3, 64, 10
    radii = np.array([0.3, 0.45, 0.2])
    bounds = (np.full(2, -10.0), np.full(2, 10.0))
    prepared = WrapperRows(horizon=T, n_samples=n_samples, radii=radii + 0.3,
                           risk="dr_cvar", alpha=0.2, delta=0.1, epsilon=0.05,
                           normals=normals, input_bounds=bounds if intersample else None,
                           dt=TS, disabled_offset=DISABLED_OFFSET)
    for case in range(8):
        x0 = rng.normal(size=4)
        ref_states = np.cumsum(rng.normal(scale=0.3, size=(T + 1, 4)), axis=0)
        ref_states[0] = x0
        samples = (x0[:2] + rng.uniform(-3, 3, (k, 1, 1, 2))
                   + rng.normal(scale=0.3, size=(k, n_samples, T + 2, 2)))
        plan = None if case % 3 == 0 else np.cumsum(rng.normal(scale=0.2, size=(T + 1, 4)), 0)
        previous = None if case % 2 else rng.normal(size=(k, T, 2))
        if previous is not None:
            previous /= np.linalg.norm(previous, axis=-1, keepdims=True)
        if case == 5:  # a reference on an obstacle's mean: the degenerate fallbacks
            ref_states[4, :2] = samples[0, :, 3].mean(axis=0)
        out = prepared(samples, x0, ref_states, C, plan, previous)
        assert out is not None and out[0] == 0
        _, got_normals, degenerate, offsets, rows_normals, rows_offsets = out
        y0 = C @ x0
        origins = ref_states[1:] @ C.T
        options = {}
        shifted = None
        if plan is not None:
            positions = plan @ C.T
            shifted = np.concatenate([positions[2:], positions[-1:]]) - positions[1] + y0
        if normals == "ego":
            origins = np.broadcast_to(y0, origins.shape)
        elif normals == "previous_plan" and shifted is not None:
            origins = shifted
        elif normals == "nearside":
            options["nearside_from"] = y0
        elif normals == "clearest":
            options.update(clearest_from=y0, clearest_plan=shifted)
        if previous is not None and normals in ("paper", "ego", "previous_plan"):
            options["previous_normals"] = np.concatenate([previous[:, 1:], previous[:, -1:]],
                                                         axis=1)
        expected = step_rows(
            np.ascontiguousarray(origins), samples, horizon=T, ego_shape=Disc(0.3),
            obstacle_shapes=[Disc(r) for r in radii], risk="dr_cvar", alpha=0.2, delta=0.1,
            epsilon=0.05, ego_velocity=x0[2:], input_bounds=bounds if intersample else None,
            dt=TS, **options)
        assert np.array_equal(got_normals, expected.halfspaces.normals)
        assert np.array_equal(offsets, expected.halfspaces.offsets)
        assert np.array_equal(degenerate, expected.halfspaces.degenerate)
        if intersample:
            assert np.array_equal(rows_normals, expected.normals)
            assert np.array_equal(rows_offsets, expected.offsets)
        else:
            assert rows_normals is None and rows_offsets is None
    # shapes it does not know: the general call runs instead
    assert prepared(samples[:2], x0, ref_states, C, None, None) is None
    assert prepared(samples.astype(np.float32), x0, ref_states, C, None, None) is None


def _episode(scenario: str, seed: int, fast: bool, steps: int = 40, **kwargs):
    env = SafetyFilterWrapper(gym.make(f"SafeNav/{scenario}-v0"), fast_path=fast, **kwargs)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    reports = []
    for _ in range(steps):
        action = np.clip(rng.normal(0.0, 6.0, 2), -10, 10).astype(np.float32)
        _, _, terminated, truncated, info = env.step(action)
        reports.append(info["filter"])
        if terminated or truncated:
            break
    return env, reports


@pytest.mark.parametrize(("scenario", "kwargs"), [
    ("RandomCrossing", {}),
    ("HeadOn", {"intersample": False}),
    ("MultiObstacle", {"normals": "paper", "objective": "trajectory"}),
    ("Intersection", {"fallback": "paper"}),
])
def test_wrapper_episodes_fast_and_general_agree(scenario, kwargs):
    statuses = set()
    for seed in range(3):
        fast_env, fast = _episode(scenario, seed, True, **kwargs)
        assert fast_env._fast_rows
        general_env, general = _episode(scenario, seed, False, **kwargs)
        assert not general_env._fast_rows
        assert len(fast) == len(general)
        for index, (ours, theirs) in enumerate(zip(fast, general, strict=True)):
            where = f"{scenario} seed {seed} step {index}"
            assert ours.status == theirs.status, where
            np.testing.assert_allclose(ours.applied_action, theirs.applied_action, atol=1e-6,
                                       err_msg=where)
            np.testing.assert_allclose(ours.normals, theirs.normals, atol=1e-9, err_msg=where)
            np.testing.assert_allclose(ours.offsets, theirs.offsets, atol=1e-9, err_msg=where)
            statuses.add(ours.status)
        again = _episode(scenario, seed, True, **kwargs)[1]
        assert again == fast  # the same bits run to run (timings aside)
        for ours, theirs in zip(again, fast, strict=True):
            assert np.array_equal(ours.applied_action, theirs.applied_action)
    assert len(statuses) >= 2, statuses
