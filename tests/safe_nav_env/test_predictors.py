"""Pluggable predictors, the environment's predictor= keyword and the stress suite."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env import ConfigError, ConstantVelocityKalman, resolve_predictor
from safe_nav_env.stress import CROSSING5, DRIFT, STRESS_SUITE, TURNING


def _episode(seed: int, steps: int = 6, **kwargs):
    env = gym.make("SafeNav/MultiObstacle-v0", **kwargs)
    _, info = env.reset(seed=seed)
    infos = [info]
    for _ in range(steps):
        infos.append(env.step(np.array([0.5, -0.2]))[4])
    return env, infos


def test_default_predictor_keeps_episodes_bit_for_bit():
    # Golden numbers from the environment before the predictor keyword existed
    # (main at 6703966, seed 3, 6 steps of action (0.5, -0.2)).
    for kwargs in ({}, {"predictor": None}, {"predictor": "environment"}):
        _, infos = _episode(3, **kwargs)
        info = infos[-1]
        assert float(info["predictions"].sum()) == -393.49298372809267
        assert float(info["predictions"][1, 7, 4, 0]) == 0.51462861461563
        assert info["obstacle_positions"].tolist() == [
            [-0.25770133909149845, 0.981729018556803],
            [-0.7664993655220986, -0.959814395555325],
            [-0.016340644896218642, -1.9957314764439003],
        ]


def test_a_user_callable_receives_the_observed_history():
    calls = []

    def predictor(history, *, dt, horizon, n_samples, rng):
        calls.append(history.copy())
        last = history[-1]
        return np.broadcast_to(last[:, None, None, :], (last.shape[0], n_samples, horizon, 2)) + (
            0.01 * rng.standard_normal((last.shape[0], n_samples, horizon, 2)))

    env, infos = _episode(0, steps=3, predictor=predictor, n_samples=7, horizon=4)
    assert [c.shape for c in calls] == [(1, 3, 2), (2, 3, 2), (3, 3, 2), (4, 3, 2)]
    for step, info in enumerate(infos):
        np.testing.assert_array_equal(calls[step][-1], info["obstacle_positions"])
        assert info["predictions"].shape == (3, 7, 4, 2)
    _, again = _episode(0, steps=3, predictor=predictor, n_samples=7, horizon=4)
    np.testing.assert_array_equal(again[-1]["predictions"], infos[-1]["predictions"])


@pytest.mark.parametrize(
    "output, match",
    [(np.zeros((3, 5, 10, 3)), "shape"), (np.full((3, 100, 10, 2), np.nan), "NaN"),
     ("oops", "non-numeric")],
)
def test_bad_predictor_output_raises_config_error(output, match):
    env = gym.make("SafeNav/MultiObstacle-v0", predictor=lambda h, **kw: output)
    with pytest.raises(ConfigError, match=match):
        env.reset(seed=0)


@pytest.mark.parametrize("value", ["bogus", 3, ConstantVelocityKalman])
def test_bad_predictor_values_raise_config_error(value):
    with pytest.raises(ConfigError, match="predictor"):
        gym.make("SafeNav/HeadOn-v0", predictor=value)


def test_resolve_predictor():
    assert resolve_predictor(None) is None and resolve_predictor("environment") is None
    assert isinstance(resolve_predictor("kalman"), ConstantVelocityKalman)
    kalman = ConstantVelocityKalman()
    assert resolve_predictor(kalman) is kalman


def test_kalman_on_a_straight_constant_velocity_path_converges():
    dt, velocity = 0.2, np.array([[1.0, -0.5], [0.0, 0.8]])
    start = np.array([[-3.0, 1.0], [2.0, -2.0]])
    history = start[None] + dt * np.arange(40)[:, None, None] * velocity[None]
    kalman = ConstantVelocityKalman(acceleration_psd=0.1, measurement_variance=1e-4)
    early_mean, early_cov = kalman.predictive(history[:3], dt=dt, horizon=5)
    mean, P = kalman.filter(history, dt)
    np.testing.assert_allclose(mean[..., 1], velocity, atol=1e-3)  # velocity estimates
    np.testing.assert_allclose(mean[..., 0], history[-1], atol=1e-3)
    future, cov = kalman.predictive(history, dt=dt, horizon=5)
    truth = history[-1][:, None, :] + dt * np.arange(1, 6)[None, :, None] * velocity[:, None, :]
    np.testing.assert_allclose(future, truth, atol=5e-3)
    assert np.all(np.diag(cov) < np.diag(early_cov))  # more data, tighter predictions
    assert np.all(np.diff(np.diag(cov)) > 0)  # uncertainty grows with the look-ahead
    rng = np.random.default_rng(0)
    samples = kalman(history, dt=dt, horizon=5, n_samples=4000, rng=rng)
    assert samples.shape == (2, 4000, 5, 2)
    np.testing.assert_allclose(samples.mean(axis=1), truth, atol=5e-3 + 4 * np.sqrt(cov[-1, -1]
                                                                                    / 4000))
    for obstacle in range(2):  # the joint law over the look-ahead, per axis
        for axis in range(2):
            empirical = np.cov(samples[obstacle, :, :, axis].T)
            np.testing.assert_allclose(empirical, cov, rtol=0.1, atol=0.05 * cov.max())


def test_a_reused_kalman_predictor_equals_a_fresh_one_and_samples_are_seeded():
    rng = np.random.default_rng(1)
    history = np.cumsum(rng.normal(size=(25, 3, 2)) * 0.1 + 0.2, axis=0)
    incremental = ConstantVelocityKalman()  # reused over growing histories
    for n in range(1, 26):
        mean, P = incremental.filter(history[:n], 0.2)
    fresh_mean, fresh_P = ConstantVelocityKalman().filter(history, 0.2)
    np.testing.assert_allclose(mean, fresh_mean, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(P, fresh_P, rtol=1e-12, atol=1e-15)
    a = incremental(history, dt=0.2, horizon=6, n_samples=9, rng=np.random.default_rng(5))
    b = ConstantVelocityKalman()(history, dt=0.2, horizon=6, n_samples=9,
                                 rng=np.random.default_rng(5))
    c = ConstantVelocityKalman()(history, dt=0.2, horizon=6, n_samples=9,
                                 rng=np.random.default_rng(6))
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)
    with pytest.raises(ConfigError, match="history"):
        incremental(np.zeros((0, 3, 2)), dt=0.2, horizon=6, n_samples=9, rng=rng)
    with pytest.raises(ConfigError, match="measurement_variance"):
        ConstantVelocityKalman(measurement_variance=0.0)


@pytest.mark.filterwarnings("ignore:.*symmetric and normalized")
def test_the_environment_with_the_kalman_predictor_passes_the_checker_and_is_seeded():
    env = gym.make("SafeNav/HeadOn-v0", predictor="kalman")
    check_env(env.unwrapped, skip_render_check=True)
    _, first = _episode(4, predictor="kalman")
    _, second = _episode(4, predictor="kalman")
    for a, b in zip(first, second, strict=True):
        np.testing.assert_array_equal(a["predictions"], b["predictions"])
    assert first[-1]["predictions"].shape == (3, 100, 10, 2)


def test_stress_suite_cases_build_and_break_the_predictions_as_named():
    assert {"heavy_tail", "biased", "turning", "crossing5"} <= set(STRESS_SUITE)
    for name, case in STRESS_SUITE.items():
        assert case.name == name and case.description
        env = gym.make("SafeNav/Custom-v0", **case.env_kwargs())
        env.reset(seed=0)
        env.step(np.zeros(2))
    assert STRESS_SUITE["heavy_tail"].noise.reality.law == "student_t"
    assert STRESS_SUITE["heavy_tail"].noise.reality.dof == 3.0
    assert STRESS_SUITE["biased"].noise.reality.mean == DRIFT
    assert STRESS_SUITE["biased"].noise.prediction.mean == 0.0
    assert CROSSING5.n_obstacles == 5
    # Turning: each prediction sample follows one of two hypotheses -> bimodal at step T.
    env = gym.make("SafeNav/Custom-v0", **STRESS_SUITE["turning"].env_kwargs())
    _, info = env.reset(seed=0)
    for _ in range(5):
        info = env.step(np.zeros(2))[4]
    last = info["predictions"][0, :, -1, 1]  # y of obstacle 0 at the last step
    gap = np.sort(last)
    assert np.max(np.diff(gap)) > 0.3  # two separated clusters
    assert TURNING.obstacles[0].turn_probability == 0.5


def test_biased_case_drifts_by_the_stated_mean():
    env = gym.make("SafeNav/Custom-v0", **STRESS_SUITE["biased"].env_kwargs())
    errors = []
    for seed in range(30):
        _, info = env.reset(seed=seed)
        for _ in range(10):
            predicted = info["predictions"][0, :, 0].mean(axis=0)
            info = env.step(np.zeros(2))[4]
            errors.append(info["obstacle_positions"][0] - predicted)
    np.testing.assert_allclose(np.mean(errors, axis=0), DRIFT, atol=0.02)


def test_kalman_predictive_covariance_is_the_sum_over_the_process_noise():
    """Cov(x_{t+j}, x_{t+k}) = F^j P F^k' + sum_{m=1}^{min(j,k)} F^{j-m} Q F^{k-m}', to 1e-12."""
    rng = np.random.default_rng(5)
    for _ in range(20):
        kalman = ConstantVelocityKalman(acceleration_psd=float(rng.uniform(0.0, 2.0)),
                                        measurement_variance=float(rng.uniform(1e-3, 1.0)),
                                        initial_speed_std=float(rng.uniform(0.1, 3.0)))
        history, dt, horizon = rng.normal(size=(int(rng.integers(1, 12)), 2, 2)), 0.2, 8
        _, cov = kalman.predictive(history, dt=dt, horizon=horizon)
        _, P = kalman.filter(history, dt)
        F = np.array([[1.0, dt], [0.0, 1.0]])
        Q = kalman.acceleration_psd * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
        power = [np.linalg.matrix_power(F, k) for k in range(horizon + 1)]
        expected = np.array([[(power[j] @ P @ power[k].T + sum(
            power[j - m] @ Q @ power[k - m].T for m in range(1, min(j, k) + 1)))[0, 0]
            for k in range(1, horizon + 1)] for j in range(1, horizon + 1)])
        expected += kalman.measurement_variance * np.eye(horizon)
        np.testing.assert_allclose(cov, expected, rtol=1e-12, atol=1e-12 * np.abs(expected).max())
