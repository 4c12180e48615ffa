"""The failure classes of the stress suite do what their names say.

A stopping obstacle halts (and the predictions keep its lane speed), stale predictions
lag the true ones by k steps, actuator lag and drag change the ego's motion (and are off
by default), understated noise is wider than predicted, and bad settings are refused.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env.actuation import Actuation
from safe_nav_env.errors import ConfigError, ScenarioError
from safe_nav_env.noise import Gaussian, NoiseModel
from safe_nav_env.predictors import StalePredictor
from safe_nav_env.scenarios import ObstacleSpec, Scenario
from safe_nav_env.stress import (
    DENSE8,
    STOPPING,
    STRESS_SUITE,
    FasterObstacles,
    crossing_scenario,
    understated_noise,
)

QUIET = NoiseModel(Gaussian(0.0), Gaussian(0.0), n_samples=4)  # no noise at all
DT = 0.2


def _one_obstacle(**spec) -> Scenario:
    return Scenario(name="one", ego_start=(-4.0, 4.0), goal=(4.0, 4.0),
                    obstacles=(ObstacleSpec(start=(0.0, 0.0), velocity=(1.0, 0.0), **spec),),
                    duration=4.0, noise=QUIET)


def test_every_case_builds_and_steps():
    for name, case in STRESS_SUITE.items():
        assert case.name == name and case.description
        env = gym.make("SafeNav/Custom-v0", **case.env_kwargs())
        env.reset(seed=0)
        for _ in range(3):
            env.step(np.zeros(2))
        env.close()


def test_stopping_obstacle_halts_in_its_window_and_is_never_predicted_to():
    env = gym.make("SafeNav/Custom-v0", scenario=_one_obstacle(stop_window=(0.6, 0.6)))
    _, info = env.reset(seed=0)
    xs, predicted_first = [info["obstacle_positions"][0, 0]], []
    for _ in range(8):
        predicted_first.append(info["predictions"][0, 0, 0, 0])
        info = env.step(np.zeros(2))[4]
        xs.append(info["obstacle_positions"][0, 0])
    steps = np.diff(xs)
    np.testing.assert_allclose(steps[:3], DT * 1.0, atol=1e-12)  # moves until t = 0.6 s
    np.testing.assert_allclose(steps[3:], 0.0, atol=1e-12)  # then holds station at x = 0.6
    # The predictions still expect one lane step: they lag the halted obstacle by v dt.
    np.testing.assert_allclose(np.array(predicted_first[3:]) - np.array(xs[3:-1]), DT,
                               atol=1e-12)
    np.testing.assert_allclose(info["obstacle_velocities"][0], (1.0, 0.0))


def test_stop_times_are_drawn_per_episode_inside_the_window():
    env = gym.make("SafeNav/Custom-v0", scenario=STOPPING)
    times = []
    for seed in range(20):
        env.reset(seed=seed)
        times.append(env.unwrapped._model.stop_times.copy())
    times = np.array(times)
    assert np.all((times >= 1.0) & (times <= 4.0))
    assert np.unique(times).size == times.size  # random, per obstacle and episode


def test_stop_window_is_validated():
    for bad in ((2.0, 1.0), (-1.0, 1.0), (0.0, np.inf), "soon"):
        with pytest.raises(ScenarioError, match="stop_window"):
            ObstacleSpec(start=(0.0, 0.0), velocity=(1.0, 0.0), stop_window=bad)


def _last_position(history, *, dt, horizon, n_samples, rng):
    """A deterministic predictor: the last observed position, at every step and sample."""
    last = np.asarray(history)[-1]
    return np.broadcast_to(last[:, None, None, :], (last.shape[0], n_samples, horizon, 2))


@pytest.mark.parametrize("delay", [0, 1, 2])
def test_stale_predictions_lag_the_true_positions_by_k_steps(delay):
    env = gym.make("SafeNav/Custom-v0", scenario=_one_obstacle(),
                   predictor=StalePredictor(_last_position, delay=delay))
    _, info = env.reset(seed=0)
    observed = [info["obstacle_positions"][0].copy()]
    for t in range(1, 7):
        info = env.step(np.zeros(2))[4]
        observed.append(info["obstacle_positions"][0].copy())
        np.testing.assert_array_equal(info["predictions"][0, 0, 0], observed[max(0, t - delay)])


def test_stale_predictor_is_validated():
    with pytest.raises(ConfigError, match="history"):
        StalePredictor(None)
    with pytest.raises(ConfigError, match="delay"):
        StalePredictor("kalman", delay=-1)
    with pytest.raises(ConfigError, match="delay"):
        StalePredictor("kalman", delay=1.5)
    assert "delay=2" in repr(StalePredictor("kalman", delay=2))


def _ego_run(actions, **options):
    env = gym.make("SafeNav/Custom-v0", scenario=_one_obstacle(), **options)
    env.reset(seed=0)
    states = [env.unwrapped.ego_state.copy()]
    for action in actions:
        env.step(action)
        states.append(env.unwrapped.ego_state.copy())
    return np.array(states)


def test_actuator_lag_and_drag_follow_their_equations_and_default_off():
    actions = [np.array([2.0, -1.0])] * 4 + [np.zeros(2)] * 3
    plain = _ego_run(actions)
    np.testing.assert_array_equal(plain, _ego_run(actions, actuator_lag=0.0, drag=0.0))
    # Double integrator: v_{t+1} = v_t + dt u_t.
    np.testing.assert_allclose(np.diff(plain[:, 2:], axis=0), DT * np.array(actions))
    tau, c = 0.2, 0.5
    beta = 1.0 - np.exp(-DT / tau)
    lagged = _ego_run(actions, actuator_lag=tau)
    a, expected = np.zeros(2), []
    for u in actions:  # ā_t = ā_{t-1} + β (u_t - ā_{t-1})
        a = a + beta * (u - a)
        expected.append(a.copy())
    np.testing.assert_allclose(np.diff(lagged[:, 2:], axis=0), DT * np.array(expected),
                               atol=1e-12)
    assert np.abs(lagged[-1, :2] - plain[-1, :2]).max() > 0.05  # a different trajectory
    dragged = _ego_run(actions, drag=c)
    np.testing.assert_allclose(np.diff(dragged[:, 2:], axis=0),
                               DT * (np.array(actions) - c * dragged[:-1, 2:]), atol=1e-12)
    # A new episode starts with no lagged acceleration, whatever the last one left.
    env = gym.make("SafeNav/Custom-v0", scenario=_one_obstacle(), actuator_lag=tau)
    env.reset(seed=0)
    for action in actions[:4]:
        env.step(action)
    env.reset(seed=0)
    v0 = env.unwrapped.ego_state[2:].copy()
    env.step(actions[0])
    np.testing.assert_allclose(env.unwrapped.ego_state[2:] - v0, DT * beta * actions[0],
                               atol=1e-12)


@pytest.mark.parametrize("option", ["actuator_lag", "drag"])
@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf"), "fast", True])
def test_actuation_options_are_validated(option, bad):
    with pytest.raises(ConfigError, match=option):
        gym.make("SafeNav/HeadOn-v0", **{option: bad})
    with pytest.raises(ConfigError, match=option):
        Actuation(**{"actuator_lag": 0.0, "drag": 0.0, option: bad}, dt=DT)


def test_understated_noise_is_wider_than_predicted_by_the_factor():
    for factor in (1.5, 2.0):
        noise = understated_noise(factor)
        ratio = np.sqrt(noise.reality.covariance / noise.prediction.covariance)
        assert ratio == pytest.approx(factor)
        draws = noise.reality.sample(np.random.default_rng(0), (200_000, 2))
        assert draws.std() == pytest.approx(0.1 * factor, rel=0.02)
    for bad in (0.5, float("nan"), "2x"):
        with pytest.raises(ScenarioError, match="factor"):
            understated_noise(bad)


def test_crossing_scenarios_and_the_faster_family():
    assert DENSE8.n_obstacles == 8
    xs = [spec.start[0] for spec in DENSE8.obstacles]
    np.testing.assert_allclose(np.diff(xs), 0.8)
    with pytest.raises(ScenarioError, match="xs"):
        crossing_scenario("bad", [5.0])
    family = FasterObstacles()
    rng = np.random.default_rng(0)
    for _ in range(20):
        scene = family(rng)
        base = next(s for s in family.scenes if scene.name == f"{s.name}_fast")
        factors = [np.hypot(*o.velocity) / np.hypot(*b.velocity)
                   for o, b in zip(scene.obstacles, base.obstacles, strict=True)]
        assert 1.5 <= factors[0] <= 2.0 and np.allclose(factors, factors[0])
    with pytest.raises(ScenarioError, match="low"):
        FasterObstacles(low=2.0, high=1.5)
