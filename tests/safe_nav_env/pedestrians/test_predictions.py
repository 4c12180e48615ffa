"""Pedestrian predictions see only the past, and residuals never come from the test scene."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env.pedestrians import SCENES, Forecaster, load_recording, residual_bank
from safe_nav_env.pedestrians.forecast import KALMAN_SETTINGS, MOVING, STRATA, headings
from safe_nav_env.pedestrians.recording import parse_tracks, resample, scene_path
from safe_nav_env.pedestrians.residuals import scene_residuals
from safe_nav_env.predictors import ConstantVelocityKalman

ID = "SafeNav/Pedestrians-v0"


def _actions(n: int) -> np.ndarray:
    return np.random.default_rng(7).uniform(-2.0, 2.0, (n, 2)).astype(np.float32)


def _run(recording, predictor: str, seed: int, steps: int, arena, start: int) -> list[dict]:
    env = gym.make(ID, scene=recording, predictor=predictor, arena=arena)
    _, info = env.reset(seed=seed, options={"start_step": start})
    base = env.unwrapped
    records = [dict(info, filter_view=base.predictions.copy())]
    for action in _actions(steps):
        _, _, terminated, truncated, info = env.step(action)
        assert not (terminated or truncated)
        records.append(dict(info, filter_view=base.predictions.copy()))
    return records


@pytest.mark.parametrize("predictor", ["constant_velocity", "kalman"])
def test_changing_the_recorded_future_leaves_every_prediction_up_to_now_unchanged(predictor):
    recording = load_recording("students003")
    t, seed, start = 12, 4, 300
    # The episode's set-up is fixed: the scene's map (arena) and its start step. Drawing
    # a start step rejects candidates crowded at *their* time, which may lie after t.
    arena = recording.walkable_box()
    original = _run(recording, predictor, seed, t + 3, arena, start)
    now = original[t]["recording_step"]
    # Rewrite the future: every recorded position after step `now` moves 2 m and jitters.
    positions = np.array(recording.positions)
    rng = np.random.default_rng(0)
    positions[now + 1 :] += 2.0 + rng.normal(0.0, 0.5, positions[now + 1 :].shape)
    altered = _run(recording.with_positions(positions), predictor, seed, t + 3, arena, start)
    for step in range(t + 1):
        for key in ("predictions", "filter_view", "obstacle_positions", "obstacle_velocities",
                    "pedestrian_index", "distance_to_collision"):
            np.testing.assert_array_equal(original[step][key], altered[step][key],
                                          err_msg=f"{key} at step {step}")
    # Not vacuous: pedestrians were around, and the very next step does see the change.
    assert original[t]["obstacle_present"].sum() >= 3
    assert not np.array_equal(original[t + 1]["obstacle_positions"],
                              altered[t + 1]["obstacle_positions"])
    assert not np.array_equal(original[t + 1]["predictions"], altered[t + 1]["predictions"])


def _small(name: str, lines: int = 1500):
    text = "\n".join(scene_path(name).read_text().splitlines()[:lines])
    return resample(parse_tracks(text, name), dt=0.2, name=name)


def test_packaged_bank_leaves_the_test_scene_out():
    forecaster = Forecaster("constant_velocity")
    for scene in SCENES:
        bank = residual_bank(scene, forecaster, 10)
        assert scene not in bank.scenes and len(bank.scenes) == 5
        for source in bank.sources:
            assert bank.scenes.index(next(s for s in SCENES if s != scene)) in source
            assert set(np.unique(source)) <= set(range(5))
    path_bank = residual_bank("/data/my_scene.txt", forecaster, 10)
    assert path_bank.scenes == tuple(SCENES)


def test_bank_for_a_scene_is_blind_to_that_scene_and_sees_the_others():
    forecaster = Forecaster("kalman")
    recordings = {name: _small(name) for name in SCENES}
    base = {name: residual_bank(name, forecaster, 10, recordings) for name in ("eth", "hotel")}
    scrambled = dict(recordings)
    positions = np.array(recordings["eth"].positions)
    positions[1::3] *= 1.7  # wreck every third step of eth
    scrambled["eth"] = recordings["eth"].with_positions(positions)
    blind = residual_bank("eth", forecaster, 10, scrambled)
    seeing = residual_bank("hotel", forecaster, 10, scrambled)
    for a, b in zip(base["eth"].residuals, blind.residuals, strict=True):
        np.testing.assert_array_equal(a, b)  # nothing in eth's bank comes from eth
    assert not all(np.array_equal(a, b) for a, b in
                   zip(base["hotel"].residuals, seeing.residuals, strict=True))
    # The bank is exactly the other scenes' residuals, stratum by stratum.
    for code in range(len(STRATA)):
        expected = np.concatenate([scene_residuals(recordings[n], forecaster, 10)[code]
                                   for n in SCENES if n != "eth"])
        np.testing.assert_array_equal(base["eth"].residuals[code], expected)


def test_kalman_forecaster_is_the_project_kalman_filter():
    rng = np.random.default_rng(1)
    window = np.cumsum(rng.normal(0.2, 0.1, (8, 2)), axis=0)
    kalman = ConstantVelocityKalman(**KALMAN_SETTINGS)
    mean, _ = kalman.filter(window[:, None, :], 0.2)
    for length in (1, 2, 5, 8):
        position, velocity = Forecaster("kalman").estimate(window[-length:])
        mean, _ = ConstantVelocityKalman(**KALMAN_SETTINGS).filter(window[-length:, None], 0.2)
        np.testing.assert_allclose(position, mean[0, :, 0], atol=1e-12)
        np.testing.assert_allclose(velocity, mean[0, :, 1], atol=1e-12)


def test_constant_velocity_uses_the_last_observed_velocity():
    window = np.array([[0.0, 0.0], [0.1, 0.3], [0.4, 0.5]])
    position, velocity = Forecaster("constant_velocity").estimate(window)
    np.testing.assert_allclose(position, [0.4, 0.5])
    np.testing.assert_allclose(velocity, [1.5, 1.0])
    nominal = Forecaster("constant_velocity").nominal(position, velocity, 3)
    np.testing.assert_allclose(nominal, [[0.7, 0.7], [1.0, 0.9], [1.3, 1.1]])


def test_samples_are_nominal_plus_rotated_bank_rows():
    forecaster = Forecaster("constant_velocity")
    bank = residual_bank("zara1", forecaster, 10)
    nominal = np.zeros((1, 10, 2))
    angle = 0.7
    frames = np.array([[[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]]])
    heading = headings(np.array([[np.cos(angle), np.sin(angle)]]) * 1.3, np.array([MOVING]))
    samples = bank.sample(np.random.default_rng(3), nominal, np.array([MOVING]), heading, 50)
    u = np.random.default_rng(3).random((1, 50))
    rows = bank.residuals[MOVING][(u[0] * bank.residuals[MOVING].shape[0]).astype(int)]
    np.testing.assert_allclose(samples[0], rows @ frames[0].T, atol=1e-12)
