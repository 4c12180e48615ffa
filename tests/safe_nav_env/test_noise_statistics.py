"""The noise model, checked statistically.

Tolerances. With ``n`` independent draws the standard error (SE) of a sample mean is
``σ/√n``, of a sample variance ``σ²·sqrt(2/n)`` (Gaussian), of a sample covariance
``σ²/√n``, and of the sample excess kurtosis (delta method on standardised
moments, ``Var ≈ (μ8 − μ4² − 4 μ4 (μ6 − μ4) + 4 μ4² (μ4 − 1))/n``) ``sqrt(24/n)`` for
a Gaussian and ``sqrt(1188/n)`` for a Laplace law (``μ4, μ6, μ8 = 6, 90, 2520``).
Every tolerance below is at least 4 SE; the seeds are fixed, so the tests are
deterministic.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env import (
    NOISE_PRESETS,
    Gaussian,
    Laplace,
    NoiseModel,
    ObstacleModel,
    ObstacleSpec,
    Scenario,
    StudentT,
)


def excess_kurtosis(x: np.ndarray) -> float:
    x = x - x.mean()
    return float((x**4).mean() / (x**2).mean() ** 2 - 3.0)


def lane_scenario(noise: NoiseModel | str = "paper") -> Scenario:
    """One obstacle on the lane y = 1 moving along +x at 1 m/s."""
    return Scenario(name="lane", ego_start=(-4.0, -3.0), goal=(4.0, -3.0), noise=noise,
                    obstacles=[ObstacleSpec(start=(-3.0, 1.0), velocity=(1.0, 0.0))])


@pytest.mark.parametrize(
    "law", [Gaussian(0.01), Laplace(0.01), StudentT(0.01, dof=5.0),
            Gaussian(((0.02, 0.01), (0.01, 0.03)), mean=(0.1, -0.2)), Laplace((0.01, 0.04))]
)
def test_laws_have_their_mean_and_covariance(law):
    w = law.sample(np.random.default_rng(0), (200_000, 2))
    cov = law.covariance_matrix(2)
    n = w.shape[0]
    se_mean = np.sqrt(np.diag(cov) / n)
    np.testing.assert_array_less(np.abs(w.mean(0) - law.mean_vector(2)), 5 * se_mean)
    # SE of a sample variance: σ² sqrt((κ - 1)/n), κ = 3 / 6 / 9 (Gaussian / Laplace / t_5).
    np.testing.assert_allclose(np.cov(w.T), cov, atol=5 * cov.max() * math.sqrt(8 / n))


def test_laplace_scale_matches_the_covariance():
    assert Laplace(0.01).scale == pytest.approx(math.sqrt(0.005))
    assert Laplace.from_scale(0.1).covariance == pytest.approx(0.02)


def test_prediction_samples_have_the_configured_mean_and_covariance():
    n = 20_000
    env = gym.make("SafeNav/Custom-v0", scenario=lane_scenario(), n_samples=n, horizon=10)
    _, info = env.reset(seed=0)
    for _ in range(2):  # also from a position that has drifted off the lane
        _, _, _, _, info = env.step(np.zeros(2, np.float32))
    p = info["obstacle_positions"][0]
    k = np.arange(1, 11)[:, None]
    nominal = np.array([p[0], 1.0]) + 0.2 * k * np.array([1.0, 0.0])  # lane projection + k v T_s
    deviation = info["predictions"][0] - nominal  # (n, T, 2)
    assert np.abs(deviation.mean(axis=0)).max() < 5 * 0.1 / math.sqrt(n)
    for step in range(10):
        cov = np.cov(deviation[:, step].T)
        np.testing.assert_allclose(cov, 0.01 * np.eye(2), atol=5 * 0.01 * math.sqrt(2 / n))
    # Independent across predicted steps.
    cross = np.mean(deviation[:, 0, 0] * deviation[:, 1, 0])
    assert abs(cross) < 5 * 0.01 / math.sqrt(n)


def test_prediction_bias_and_authors_code_preset():
    n = 20_000
    biased = NoiseModel(prediction=Gaussian(0.1, mean=(0.05, -0.02)), n_samples=n)
    env = gym.make("SafeNav/Custom-v0", scenario=lane_scenario(biased))
    _, info = env.reset(seed=1)
    nominal = np.array([-3.0, 1.0]) + 0.2 * np.arange(1, 11)[:, None] * np.array([1.0, 0.0])
    deviation = info["predictions"][0] - nominal
    np.testing.assert_allclose(deviation.mean(axis=(0, 1)), [0.05, -0.02],
                               atol=5 * math.sqrt(0.1 / (10 * n)))
    np.testing.assert_allclose(np.cov(deviation[:, 4].T), 0.1 * np.eye(2),
                               atol=5 * 0.1 * math.sqrt(2 / n))

    authors = NOISE_PRESETS["authors_code"]
    assert authors.n_samples == 20
    assert authors.prediction == Gaussian(0.1)  # std sqrt(0.1) = 0.316 per axis
    assert authors.reality.scale == pytest.approx(0.1)


def test_realised_one_step_deviations_are_laplace_in_the_environment():
    """20 000 draws (10 000 steps x 2 axes): SE of the kurtosis 0.24 (Laplace), 0.035 (Gaussian)."""
    env = gym.make("SafeNav/Custom-v0", scenario=lane_scenario(), n_samples=1, horizon=1,
                   episode_length=1e6)
    env.reset(seed=0)
    u = env.unwrapped
    zero = np.zeros(2, np.float32)
    deviations = np.empty((10_000, 2))
    for i in range(deviations.shape[0]):
        p = u.obstacle_positions[0]
        nominal = np.array([p[0] + 0.2 * 1.0, 1.0])  # lateral drift pulled back to y = 1
        env.step(zero)
        deviations[i] = u.obstacle_positions[0] - nominal
    assert np.abs(deviations.mean(axis=0)).max() < 5 * 0.1 / 100
    np.testing.assert_allclose(deviations.var(axis=0), 0.01, rtol=0.1)
    for axis in range(2):
        assert excess_kurtosis(deviations[:, axis]) == pytest.approx(3.0, abs=1.0)


@pytest.mark.parametrize(
    ("noise", "kurtosis", "tolerance"),
    [
        ("paper", 3.0, 0.25),  # Laplace: SE 0.054 with 400 000 draws
        ("gaussian_reality", 0.0, 0.05),  # Gaussian: SE 0.008
        (NoiseModel(reality=StudentT(0.01, dof=10.0)), 1.0, 0.3),  # 6/(ν - 4)
    ],
)
def test_realised_kurtosis_by_noise_option(noise, kurtosis, tolerance):
    """One step of 200 000 independent obstacles: deviations from the one-step nominal."""
    model = NOISE_PRESETS[noise] if isinstance(noise, str) else noise
    specs = [ObstacleSpec(start=(0.0, 0.0), velocity=(1.0, 0.5))] * 200_000
    obstacles = ObstacleModel(specs, dt=0.2)
    rng = np.random.default_rng(0)
    obstacles.reset(rng)
    nominal = obstacles.nominal_next()
    np.testing.assert_allclose(nominal[0], [0.2, 0.1])
    deviations = obstacles.step(rng, model.reality) - nominal
    np.testing.assert_allclose(np.cov(deviations.T), 0.01 * np.eye(2), atol=4e-4)
    for axis in range(2):
        assert excess_kurtosis(deviations[:, axis]) == pytest.approx(kurtosis, abs=tolerance)


def test_reality_bias_shifts_the_realised_mean():
    model = NoiseModel(reality=Laplace(0.01, mean=(0.03, 0.0)))
    obstacles = ObstacleModel([ObstacleSpec(start=(0, 0), velocity=(1, 0))] * 50_000, dt=0.2)
    rng = np.random.default_rng(2)
    obstacles.reset(rng)
    deviations = obstacles.step(rng, model.reality) - obstacles.anchors
    np.testing.assert_allclose(deviations.mean(axis=0), [0.03, 0.0], atol=5 * 0.1 / math.sqrt(5e4))


def test_lateral_drift_is_pulled_back_along_lane_drift_accumulates():
    obstacles = ObstacleModel([ObstacleSpec(start=(0, 0), velocity=(1, 0))] * 20_000, dt=0.2)
    rng = np.random.default_rng(3)
    obstacles.reset(rng)
    for _ in range(25):
        obstacles.step(rng, Laplace(0.01))
    spread = obstacles.positions.var(axis=0)
    assert spread[0] == pytest.approx(25 * 0.01, rel=0.1)  # random walk along the lane
    assert spread[1] == pytest.approx(0.01, rel=0.1)  # one step of noise across it
    assert obstacles.positions[:, 0].mean() == pytest.approx(5.0, abs=0.01)


def test_turning_obstacle_has_bimodal_predictions():
    spec = ObstacleSpec(start=(0.0, 0.0), velocity=(1.0, 0.0), turn_rate=1.0,
                        turn_probability=0.5)
    scenario = Scenario(name="turn", ego_start=(-4.0, -4.0), goal=(4.0, -4.0), obstacles=[spec],
                        noise=NoiseModel(prediction=Gaussian(1e-4), n_samples=4000))
    env = gym.make("SafeNav/Custom-v0", scenario=scenario)
    _, info = env.reset(seed=0)
    final = info["predictions"][0, :, -1]  # positions 2 s ahead
    straight = np.isclose(final[:, 1], 0.0, atol=0.05)
    # Turning at 1 rad/s from heading 0: y(2 s) = T_s sum_{m<10} sin(0.2 m) > 0.6 m.
    expected_y = 0.2 * np.sin(0.2 * np.arange(10)).sum()
    turned = np.isclose(final[:, 1], expected_y, atol=0.05)
    assert np.all(straight | turned)
    assert turned.mean() == pytest.approx(0.5, abs=4 * 0.5 / math.sqrt(4000))


def test_turning_obstacle_turns_in_reality():
    spec = ObstacleSpec(start=(0.0, 0.0), velocity=(1.0, 0.0), turn_rate=0.5, turn_start=0.4,
                        turn_angle=math.pi / 4)
    scenario = Scenario(name="turn", ego_start=(-4.0, -4.0), goal=(4.0, -4.0), obstacles=[spec])
    env = gym.make("SafeNav/Custom-v0", scenario=scenario)
    env.reset(seed=0)
    angles = []
    for _ in range(15):
        env.step(np.zeros(2, np.float32))
        v = env.unwrapped.obstacle_velocities[0]
        angles.append(math.atan2(v[1], v[0]))
        assert math.hypot(*v) == pytest.approx(1.0)
    # Starts turning at 0.4 s, 0.1 rad per step, stops at pi/4.
    np.testing.assert_allclose(angles[:4], [0.0, 0.0, 0.1, 0.2], atol=1e-12)
    assert angles[-1] == pytest.approx(math.pi / 4)
