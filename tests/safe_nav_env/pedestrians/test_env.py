"""SafeNav/Pedestrians-v0: every scene steps, Gymnasium conformance, slots, determinism."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import safe_nav_env  # noqa: F401  (registers the ids)
from safe_nav_env.errors import ConfigError
from safe_nav_env.pedestrians import SCENES, PedestrianEnv, load_recording, time_limit
from safe_nav_env.pedestrians.replay import PARK_DISTANCE

pytestmark = pytest.mark.filterwarnings("ignore:.*normalized:UserWarning")

ID = "SafeNav/Pedestrians-v0"


def _actions(n: int, seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-3.0, 3.0, (n, 2)).astype(np.float32)


@pytest.mark.parametrize("scene", list(SCENES))
def test_every_packaged_scene_makes_resets_and_steps(scene):
    env = gym.make(ID, scene=scene)
    obs, info = env.reset(seed=3)
    base = env.unwrapped
    k = base.max_obstacles
    assert k == 8 and obs.shape == (6 + 5 * k,) and env.observation_space.contains(obs)
    assert info["predictions"].shape == (k, 100, 10, 2)
    low, high = base.position_bounds
    assert np.all(low <= base.ego_state[:2]) and np.all(base.ego_state[:2] <= high)
    assert np.hypot(*(base.goal - base.ego_state[:2])) >= 5.0
    assert base.max_episode_steps == int(np.ceil(
        time_limit(np.hypot(*(base.goal - base.ego_state[:2]))) / 0.2 - 1e-9))
    for action in _actions(15):
        obs, reward, terminated, truncated, info = env.step(action)
        assert env.observation_space.contains(obs) and np.isfinite(reward)
        present = info["obstacle_present"]
        # Absent slots: infinitely far in info, parked (finite) for the filter, flag 0.
        assert np.isinf(info["predictions"][~present]).all()
        assert np.isinf(info["distance_to_collision"][~present]).all()
        assert np.isfinite(info["predictions"][present]).all()
        assert np.isfinite(base.predictions).all() and np.isfinite(base.obstacle_positions).all()
        assert np.allclose(base.obstacle_positions[~present], high + PARK_DISTANCE)
        flags = obs[6 + 4 :: 5]
        assert flags.sum() == present.sum()
        if terminated or truncated:
            break


def test_gymnasium_check_env_passes():
    check_env(gym.make(ID, scene="zara1", render_mode="rgb_array").unwrapped)


def test_a_file_path_is_a_scene(tmp_path):
    lines = load_text("zara2").splitlines()[:3000]
    path = tmp_path / "my_scene.txt"
    path.write_text("\n".join(lines) + "\n")
    env = gym.make(ID, scene=str(path), predictor="kalman")
    env.reset(seed=0)
    for action in _actions(5):
        env.step(action)
    assert env.unwrapped.scene == str(path)
    assert env.unwrapped.residuals.scenes == tuple(SCENES)  # a user file: all six scenes


def load_text(scene: str) -> str:
    from safe_nav_env.pedestrians.recording import scene_path

    return scene_path(scene).read_text()


def _rollout(env: gym.Env, seed: int, steps: int) -> list[tuple]:
    obs, info = env.reset(seed=seed)
    out = [(obs, info["predictions"], info["obstacle_velocities"], info["pedestrian_index"])]
    for action in _actions(steps):
        obs, reward, terminated, truncated, info = env.step(action)
        out.append((obs, info["predictions"], info["obstacle_velocities"],
                    info["pedestrian_index"], reward, info["collision"]))
    return out


def test_same_seed_same_episode_and_another_seed_another():
    first = _rollout(gym.make(ID, scene="students001"), 5, 10)
    again = _rollout(gym.make(ID, scene="students001"), 5, 10)
    other = _rollout(gym.make(ID, scene="students001"), 6, 10)
    for a, b in zip(first, again, strict=True):
        for x, y in zip(a, b, strict=True):
            np.testing.assert_array_equal(x, y)
    assert not np.array_equal(first[0][0], other[0][0])


def test_slots_hold_the_nearest_present_pedestrians_and_keep_them():
    env = gym.make(ID, scene="students003").unwrapped
    env.reset(seed=2)
    model = env._replay
    previous = model.slots.copy()
    for action in _actions(30):
        env.step(action)
        j = model.step_index
        index, points = model.pedestrians_at(j)
        held = model.slots[model.present]
        assert model.present.sum() == min(env.max_obstacles, index.shape[0])
        dist = np.hypot(*(points - env.ego_state[:2]).T)
        outside = ~np.isin(index, held)
        if outside.any():
            assert dist[np.isin(index, held)].max() <= dist[outside].min()
        for slot, ped in enumerate(previous):
            if ped >= 0 and ped in held:
                assert model.slots[slot] == ped  # kept its slot
        # Each chord starts at the slot's own pedestrian's previous position.
        for slot in np.flatnonzero(model.present):
            ped = model.slots[slot]
            before = env.recording.positions[j - 1, ped]
            expected = before if np.isfinite(before).all() else env.recording.positions[j, ped]
            np.testing.assert_array_equal(model.chord_starts[slot], expected)
        previous = model.slots.copy()


def test_the_calibration_compares_each_pedestrian_with_its_own_prediction():
    # A dense scene where slots change hands: every realisation the record returns
    # (through env.unwrapped.obstacle_ids, as the filter's calibration feeds it) is
    # the recorded position of the same pedestrian minus the mean of the samples
    # issued for that pedestrian k steps before.
    from filters.prediction_record import PredictionRecord

    env = gym.make(ID, scene="students003").unwrapped
    env.reset(seed=2)
    record = PredictionRecord(horizon=env.horizon)
    issued: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # step -> (ids, mean samples)
    handovers = checked = 0
    previous = env.obstacle_ids
    for t, action in enumerate([None, *_actions(40)]):
        if action is not None:
            env.step(action)
        ids = env.obstacle_ids
        handovers += int(np.sum((previous >= 0) & (ids >= 0) & (previous != ids)))
        previous = ids
        means = np.asarray(env.predictions).mean(axis=1)  # (K, T, 2)
        issued[t] = (ids.copy(), means)
        j = env._replay.step_index
        for r in record.update(env.predictions, env.obstacle_positions, ids=ids):
            then_ids, then_means = issued[t - r.lookahead]
            for ped, error in zip(r.ids.tolist(), r.errors, strict=True):
                row = int(np.flatnonzero(then_ids == ped)[0])
                realised = env.recording.positions[j, ped]
                np.testing.assert_allclose(error, realised - then_means[row, r.lookahead - 1],
                                           atol=1e-9)
                checked += 1
    assert handovers > 0 and checked > 100


def test_a_pedestrian_walking_into_the_standing_ego_is_a_collision(tmp_path):
    # One walker along y = 0 at 1 m/s (0.4 m per 10 frames), two people standing still.
    lines = [f"{10 * f}\t1\t{0.4 * f:.2f}\t0.0" for f in range(31)]
    lines += [f"{10 * f}\t{p}\t{x}\t{y}" for f in range(31) for p, x, y in ((2, 0, -4),
                                                                         (3, 12, 4))]
    path = tmp_path / "walker.txt"
    path.write_text("\n".join(lines))
    env = gym.make(ID, scene=str(path), terminate_on_collision=True).unwrapped
    env.reset(seed=0, options={"start_step": 0})
    env.ego_state = np.array([6.1, 0.0, 0.0, 0.0])  # at rest on the walker's line
    steps = 0
    while steps < 40:
        _, _, terminated, truncated, info = env.step(np.zeros(2, np.float32))
        steps += 1
        assert np.array_equal(env.ego_state, [6.1, 0.0, 0.0, 0.0])
        if terminated or truncated:
            break
    assert info["collision"] and info["cost"] == 1.0 and terminated
    # Centres 0.6 m apart when the walker reaches x = 5.5 m, at 5.5 s: inside step 28.
    assert steps == 28
    walker = int(np.flatnonzero(env.recording.ids == 1.0)[0])
    assert walker in info["pedestrian_index"]


def test_options_that_do_not_apply_are_refused():
    with pytest.raises(ConfigError, match="noise"):
        PedestrianEnv("eth", noise="paper")
    with pytest.raises(ConfigError, match="predictor"):
        PedestrianEnv("eth", predictor="oracle")
    with pytest.raises(ConfigError, match="dt"):
        PedestrianEnv(load_recording("eth", dt=0.4), dt=0.2)


def test_the_arena_is_the_scenes_before_the_first_reset():
    # A wrapper builds its filter (arena rows, terminal set) when it is created.
    env = gym.make(ID, scene="eth").unwrapped
    low, high = env.position_bounds
    assert (tuple(low), tuple(high)) == env.arena == load_recording("eth").walkable_box()


def test_safety_filter_wrapper_wraps_and_steps():
    import filters
    env = filters.SafetyFilterWrapper(gym.make(ID, scene="eth"))
    env.reset(seed=0)
    goal = env.unwrapped.goal
    for _ in range(5):  # toward the goal, braking: far from every edge of the arena
        x = env.unwrapped.ego_state
        _, _, terminated, truncated, info = env.step(np.clip(goal - x[:2] - 2 * x[2:], -3, 3))
        assert info["filter"].status == "optimal", info["filter"]
        if terminated or truncated:
            break


def test_id_is_registered_on_import_without_loading_the_scenes():
    import subprocess
    import sys

    code = ("import sys, gymnasium as gym, safe_nav_env; "
            "assert 'SafeNav/Pedestrians-v0' in gym.registry; "
            "assert 'safe_nav_env.pedestrians' not in sys.modules")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_vector_environments_stack_the_fixed_size_info():
    envs = gym.make_vec(ID, num_envs=2, vectorization_mode="sync", scene="zara2")
    obs, info = envs.reset(seed=0)
    assert obs.shape == (2, 46)
    for action in _actions(5):
        obs, _, _, _, info = envs.step(np.stack([action, -action]))
    assert info["predictions"].shape == (2, 8, 100, 10, 2)
    assert info["obstacle_present"].shape == (2, 8)
    envs.close()
