"""Continuous-time collisions: the exact swept clearance against a dense sub-sampling."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env.collision import real_cubic_roots, swept_clearance


def dense_clearance(state, u, dt, before, after, radii_sum, n=20001):
    """The clearance on a fine grid of the step: the obviously correct, slow reference."""
    s = np.linspace(0.0, dt, n)[:, None]
    p, v = np.asarray(state[:2]), np.asarray(state[2:])
    ego = p + s * v + 0.5 * s**2 * np.asarray(u)
    before, after = np.asarray(before), np.asarray(after)
    obstacles = before[None] + (s / dt)[..., None] * (after - before)[None]
    return np.linalg.norm(ego[:, None] - obstacles, axis=2).min(axis=0) - np.asarray(radii_sum)


@pytest.mark.parametrize("seed", range(6))
def test_swept_clearance_equals_dense_reference(seed):
    rng = np.random.default_rng(seed)
    for trial in range(300):
        n = int(rng.integers(1, 6))
        state = np.concatenate([rng.normal(0, 2, 2), rng.normal(0, 4, 2)])
        u = rng.uniform(-10, 10, 2)
        if trial % 5 == 0:
            u[:] = 0.0  # no cubic term: the quadratic / linear branch
        if trial % 7 == 0:
            state[2:] = 0.0
        before = rng.normal(0, 2, (n, 2))
        after = before + rng.normal(0, 0.5, (n, 2))
        if trial % 11 == 0:  # an obstacle that moves exactly with the ego's chord
            after = before + 0.2 * state[2:] + 0.02 * u
        radii = rng.uniform(0.3, 0.8, n)
        exact = np.array(swept_clearance(state.tolist(), u.tolist(), 0.2, before.tolist(),
                                         after.tolist(), radii.tolist()))
        dense = dense_clearance(state, u, 0.2, before, after, radii)
        # never above the dense minimum (it is the minimum), and at most the grid's error
        assert np.all(exact <= dense + 1e-12)
        assert np.all(dense - exact <= 1e-5)


def test_swept_clearance_catches_a_pass_through_between_samples():
    # 6 m/s through a standing obstacle: both samples clear, the middle of the step not.
    state, u = [-0.6, 0.0, 6.0, 0.0], [0.0, 0.0]
    before = after = [[0.0, 0.0]]
    ends = [np.hypot(-0.6, 0) - 0.6, np.hypot(0.6, 0) - 0.6]
    assert min(ends) >= 0.0
    (clearance,) = swept_clearance(state, u, 0.2, before, after, [0.6])
    assert clearance == pytest.approx(-0.6)


@pytest.mark.parametrize("coefficients", [
    (1.0, -6.0, 11.0, -6.0),  # roots 1, 2, 3
    (2.0, 0.0, 0.0, -16.0),  # one real root 2
    (0.0, 1.0, -3.0, 2.0),  # quadratic: 1, 2
    (0.0, 0.0, 2.0, -1.0),  # linear: 0.5
    (1.0, -3.0, 3.0, -1.0),  # triple root 1
])
def test_real_cubic_roots(coefficients):
    expected = np.roots(np.trim_zeros(np.array(coefficients), "f"))
    expected = np.sort(expected[np.abs(expected.imag) < 1e-6].real)
    roots = np.sort(np.array(real_cubic_roots(*coefficients)))
    for root in expected:
        assert np.min(np.abs(roots - root)) < 1e-4


@pytest.mark.parametrize("env_id", ["SafeNav/HeadOn-v0", "SafeNav/MultiObstacle-v0",
                                    "SafeNav/RandomCrossing-v0"])
def test_env_collision_is_continuous_time(env_id):
    """info["collision"] is the swept clearance of each step, checked densely."""
    env = gym.make(env_id)
    base = env.unwrapped
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=5)
    assert info["collision"] == info["sampled_collision"]
    for _ in range(40):
        state = np.array(base.ego_state)
        before = np.array(base.obstacle_positions)
        n = base.n_obstacles
        action = rng.uniform(-10, 10, 2)
        obs, reward, terminated, truncated, info = env.step(action)
        after = np.array(base.obstacle_positions)[:n]
        radii = np.asarray(base.obstacle_radii) + base.ego_radius
        dense = dense_clearance(state, info["acceleration"], base.dt, before[:n],
                                after, radii)
        swept = np.asarray(info["swept_distance_to_collision"])[:n]
        assert np.all(swept <= dense + 1e-12) and np.all(dense - swept <= 1e-5)
        assert np.all(swept <= np.asarray(info["distance_to_collision"])[:n])
        assert info["collision"] == bool(swept.min() <= 0.0)
        assert info["cost"] == (1.0 if info["collision"] else 0.0)
        assert not info["sampled_collision"] or info["collision"]
        if terminated or truncated:
            obs, info = env.reset(seed=int(rng.integers(1000)))
    env.close()


def test_terminate_on_collision_uses_the_swept_clearance():
    # The ego crosses a standing obstacle within one step; the samples never overlap.
    from safe_nav_env import Scenario
    from safe_nav_env.noise import Gaussian, NoiseModel

    scenario = Scenario(name="pass", ego_start=(-0.65, 0.0, 6.5, 0.0), goal=(4.0, 0.0),
                        obstacles=[{"start": (0.0, 0.0), "velocity": (0.0, 0.0)}])
    still = NoiseModel(Gaussian(0.0), Gaussian(0.0), n_samples=10)
    env = gym.make("SafeNav/Custom-v0", scenario=scenario, terminate_on_collision=True,
                   max_speed=np.inf, noise=still)
    env.reset(seed=0)
    _, reward, terminated, _, info = env.step(np.zeros(2))
    assert info["min_distance_to_collision"] > 0.0
    assert not info["sampled_collision"]
    assert info["collision"] and terminated and info["cost"] == 1.0
