"""The wrapper's fast path (``fast_path=True``) against the general one.

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
from filters import SafetyFilterWrapper


# --------------------------------------------------------------------------- the wrapper
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
        general_env, general = _episode(scenario, seed, False, **kwargs)
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
