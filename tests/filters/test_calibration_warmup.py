"""Held-out calibration of the wrapper (split conformal) and episode independence."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)
from filters import SafetyFilterWrapper
from filters.calibration import OnlineCalibration
from filters.config import CALIBRATION_EPISODES, CALIBRATION_SEED
from filters.errors import InvalidParameterError, InvalidTypeError
from filters.wrapper import calibration_settings
from tests.filters.test_calibration import clopper_pearson


def _hand_fed(episodes: int, *, seed: int = CALIBRATION_SEED, horizon: int = 10,
              alpha: float = 0.2) -> OnlineCalibration:
    """The calibration fed by hand with held-out HeadOn episodes (a different brake)."""
    env = gym.make("SafeNav/HeadOn-v0")
    base = env.unwrapped
    calibration = OnlineCalibration(horizon, alpha)
    for episode in range(episodes):
        base.reset(seed=seed + episode)
        calibration.reset()
        calibration.update(base.predictions[:, :, :horizon], base.obstacle_positions)
        done = False
        while not done:
            low, high = base.input_bounds
            # Not the filter's braking gain: the obstacles must not depend on the ego.
            action = np.clip(-np.asarray(base.ego_state)[2:] / base.dt, low, high)
            _, _, terminated, truncated, _ = base.step(action)
            calibration.update(base.predictions[:, :, :horizon], base.obstacle_positions)
            done = terminated or truncated
    calibration.reset()
    calibration.radii()  # as the wrapper does before its snapshot
    return calibration


def test_warm_up_gives_what_the_calibration_gives_on_the_same_stream_fed_by_hand():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                              epsilon="auto", calibration_episodes=3)
    hand = _hand_fed(3)
    snapshot = env._calibrated
    assert np.array_equal(snapshot.margins(), hand.margins())
    assert np.array_equal(snapshot.radii(), hand.radii())
    assert np.array_equal(snapshot.conformal.levels, hand.conformal.levels)  # ACI too
    assert snapshot.conformal.n_scored.tolist() == hand.conformal.n_scored.tolist()
    assert snapshot.conformal.n_scored.min() >= 3 * 30  # 3 x (41 - k) scores
    # Calibrated from step 0: neither fallback (1 m margins, 0.05 m radii) is in force.
    env.reset(seed=0)
    assert np.all(env._calibration.margins() < 1.0)
    assert np.all(env._calibration.radii() != 0.05)
    assert env.calibration_time > 0.0


def test_defaults_validation_and_no_warm_up_without_calibration():
    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="dr_cvar", epsilon="auto")
    assert env.calibration_episodes == CALIBRATION_EPISODES
    assert env.calibration_memory == "episode" and env.calibration_seed == CALIBRATION_SEED
    for risk, epsilon in (("dr_cvar", 0.05), ("none", "auto"), ("mean", 0.05)):
        plain = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk=risk, epsilon=epsilon,
                                    calibration_episodes=4)
        assert plain.calibration_episodes == 0
        assert plain._calibration is None or plain._calibration.conformal.n_scored.sum() == 0
    off = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                              calibration_episodes=0)
    off.reset(seed=0)
    assert np.all(off._calibration.margins() == 1.0)  # the fallback: no held-out data
    for bad in (-1, 1.5, True, "5"):
        with pytest.raises(InvalidParameterError, match=f"calibration_episodes.*{bad!r}"):
            SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                                calibration_episodes=bad)
        with pytest.raises(InvalidParameterError, match=f"calibration_seed.*{bad!r}"):
            SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                                calibration_seed=bad)
    with pytest.raises(InvalidParameterError, match="calibration_memory.*'forever'"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                            calibration_memory="forever")
    with pytest.raises(InvalidTypeError, match="calibration_memory"):
        SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk="conformal",
                            calibration_memory=None)
    assert calibration_settings("dr_cvar", 0.05) is None
    assert calibration_settings("none", "auto") is None
    assert calibration_settings("conformal", soft=True) == {
        "calibration_episodes": CALIBRATION_EPISODES, "calibration_seed": CALIBRATION_SEED,
        "calibration_memory": "episode"}


def test_warm_up_restores_the_seed_state_and_leaves_the_render_mode():
    inner = gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array")
    env = SafetyFilterWrapper(inner, risk="conformal", calibration_episodes=1)
    assert env.unwrapped.render_mode == "rgb_array"
    assert env.unwrapped._np_random is None  # never seeded: an unseeded reset stays random


def _episode(env: gym.Env, seed: int, steps: int = 12) -> tuple[np.ndarray, np.ndarray]:
    obs, _ = env.reset(seed=seed)
    actions, offsets = [], []
    for _ in range(steps):
        obs, _, terminated, truncated, info = env.step(np.array([1.5, 0.0], dtype=np.float32))
        actions.append(info["filter"].applied_action)
        offsets.append(info["filter"].offsets)
        if terminated or truncated:
            break
    return np.array(actions), np.array(offsets)


@pytest.mark.parametrize(("risk", "epsilon"), [("conformal", 0.05), ("dr_cvar", "auto")])
def test_same_seed_same_episode_whatever_ran_before_in_the_wrapper(risk, epsilon):
    def make(memory: str) -> SafetyFilterWrapper:
        return SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"), risk=risk, epsilon=epsilon,
                                   calibration_episodes=2, calibration_memory=memory)

    fresh = _episode(make("episode"), 7)
    env = make("episode")
    _episode(env, 3)
    _episode(env, 4)
    again = _episode(env, 7)
    assert np.array_equal(fresh[0], again[0]) and np.array_equal(fresh[1], again[1])
    # The carry-over behaviour is still there, and it does change the episode.
    persistent = make("persistent")
    _episode(persistent, 3)
    _episode(persistent, 4)
    carried = _episode(persistent, 7)
    assert carried[1].shape != fresh[1].shape or not np.array_equal(carried[1], fresh[1])


class _KnownLawEnv(gym.Env):
    """One obstacle at a fixed centre, realised at centre + N(0, sigma^2 I) each step.

    The two prediction samples are the centre +- a fixed offset, so their mean is the
    centre and the conformal score ``||p - mean||`` is Rayleigh(sigma): i.i.d., with
    CDF ``1 - exp(-q^2 / (2 sigma^2))``. Follows :class:`filters.protocol.FilterableEnv`.
    """

    sigma = 0.1
    horizon = 2
    length = 40

    def __init__(self) -> None:
        self.dt = 0.2
        eye, zero = np.eye(2), np.zeros((2, 2))
        A = np.block([[eye, self.dt * eye], [zero, eye]])
        B = np.vstack([0.5 * self.dt**2 * eye, self.dt * eye])
        self.dynamics = (A, B, np.hstack([eye, zero]))
        self.ego_radius = 0.3
        self.obstacle_radii = np.array([0.3])
        self.obstacle_velocities = np.zeros((1, 2))
        self.input_bounds = (-5.0 * np.ones(2), 5.0 * np.ones(2))
        self.position_bounds = (-5.0 * np.ones(2), 5.0 * np.ones(2))
        self.goal = np.array([4.0, 0.0])
        self.render_hooks: list = []
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (4,))
        self.action_space = gym.spaces.Box(-5.0, 5.0, (2,))
        centre = np.array([2.0, 0.0])
        offset = np.array([[0.05, 0.0], [-0.05, 0.0]])
        self.predictions = np.broadcast_to(
            centre + offset[:, None, :], (1, 2, self.horizon, 2)).copy()
        self._centre = centre
        self.ego_state = np.array([-4.0, 0.0, 0.0, 0.0])
        self.obstacle_positions = centre[None].copy()

    def observe(self, ego_state, obstacle_positions, obstacle_velocities):
        return np.zeros(4, dtype=np.float32)

    def _draw(self) -> None:
        self.obstacle_positions = self._centre + self.sigma * self.np_random.normal(size=(1, 2))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.ego_state = np.array([-4.0, 0.0, 0.0, 0.0])
        self.steps = 0
        self._draw()
        return self.observe(None, None, None), {}

    def step(self, action):
        A, B, _ = self.dynamics
        self.ego_state = A @ self.ego_state + B @ np.asarray(action, dtype=float)
        self.steps += 1
        self._draw()
        return self.observe(None, None, None), 0.0, False, self.steps >= self.length, {}


def test_conformal_margin_after_warm_up_covers_a_known_law_at_its_binomial_rate():
    # Conditional on the held-out data, the margin q_1 in force at step 0 of every
    # episode is the snapshot's, and the first realised score of independent episodes
    # is covered with probability exactly F(q_1): the count is Binomial(N, F(q_1)).
    alpha, trials = 0.2, 300
    env = SafetyFilterWrapper(_KnownLawEnv(), risk="conformal", alpha=alpha)
    assert env._calibrated.conformal.n_scored[0] == CALIBRATION_EPISODES * 40
    q = env._calibrated.conformal.margin(1)
    coverage = 1.0 - math.exp(-q * q / (2.0 * _KnownLawEnv.sigma**2))
    # Split conformal over 200 held-out scores: F(q) ~ Beta(r, n + 1 - r), sd 0.03.
    assert abs(coverage - (1.0 - alpha)) < 0.1
    covered = 0
    for seed in range(trials):
        env.reset(seed=seed)
        assert env._calibration.conformal.margin(1) == q  # every episode starts calibrated alike
        mean = env.unwrapped.predictions[0, :, 0].mean(axis=0)
        env.step(np.zeros(2, dtype=np.float32))
        covered += int(np.linalg.norm(env.unwrapped.obstacle_positions[0] - mean) <= q)
    low, high = clopper_pearson(covered, trials)
    assert low <= coverage <= high


def test_run_key_records_the_calibration_and_changes_with_it():
    from agents.evaluation.records import EpisodeSpec, run_key

    def key(risk: str, **options) -> dict:
        return run_key([EpisodeSpec("HeadOn", risk, seed, filter_options=options)
                        for seed in range(2)])

    assert "calibration" not in key("dr_cvar")
    default = key("conformal")
    assert default["calibration"] == [calibration_settings("conformal")]
    assert default["calibration"][0]["calibration_episodes"] == CALIBRATION_EPISODES
    assert key("conformal", calibration_episodes=9) != default
    assert key("conformal", calibration_memory="persistent") != default
    with pytest.raises(InvalidParameterError, match="epsilon"):
        EpisodeSpec("HeadOn", "dr_cvar", 0, filter_options={"epsilon": "auto"})


def test_the_calibrated_state_is_shared_between_wrappers_of_the_same_environment_only():
    from filters import wrapper

    wrapper._SNAPSHOTS.clear()

    def make(**env_kwargs) -> SafetyFilterWrapper:
        return SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0", **env_kwargs), risk="dr_cvar",
                                   epsilon="auto", calibration_episodes=2)

    first, second = make(), make()
    assert len(wrapper._SNAPSHOTS) == 1
    for a, b in ((first._calibrated, second._calibrated), (first._calibrated, _hand_fed(2))):
        assert np.array_equal(a.radii(), b.radii())
        assert np.array_equal(a.margins(), b.margins())
        assert np.array_equal(a.conformal.levels, b.conformal.levels)
    other = make(noise="authors_code")  # another law: its own held-out data
    assert len(wrapper._SNAPSHOTS) == 2
    assert not np.array_equal(other._calibrated.radii(), first._calibrated.radii())
    assert np.array_equal(_episode(first, 5)[1], _episode(second, 5)[1])
    # Settings that are not plain values are never keys (no sharing, never a wrong hit).
    assert wrapper._plain_settings({"predictor": lambda history: history}) is None
    assert wrapper._plain_settings({"a": (1, 2.0)}) != wrapper._plain_settings({"a": (1.0, 2)})


def test_copy_equals_a_deep_copy_and_never_shares_state():
    import copy

    original = _hand_fed(1)
    fast, deep = original.copy(), copy.deepcopy(original)
    before = (original.margins(), original.radii(), original.conformal.levels.copy(),
              original.record.scores(1), original.conformal.n_scored.copy())
    for clone in (fast, deep):  # the same new data into both copies
        stream = np.random.default_rng(1)
        clone.reset()
        for _ in range(25):
            samples = stream.normal(size=(1, 20, 10, 2))
            clone.update(samples, stream.normal(size=(1, 2)) + 0.5)
    assert np.array_equal(fast.radii(), deep.radii())
    assert np.array_equal(fast.margins(), deep.margins())
    assert np.array_equal(fast.conformal.levels, deep.conformal.levels)
    assert not np.array_equal(fast.radii(), before[1])  # the new data moved the copy ...
    after = (original.margins(), original.radii(), original.conformal.levels,
             original.record.scores(1), original.conformal.n_scored)
    for old, new in zip(before, after, strict=True):  # ... and never the original
        assert np.array_equal(old, new)


def test_sorted_window_margins_equal_the_partition_of_the_window():
    from filters.calibration import ConformalMargin, conformal_rank

    rng = np.random.default_rng(5)
    margin = ConformalMargin(0.2, horizon=2, window=30, gamma=0.05, fallback=9.0)
    for step in range(300):
        k = 1 + step % 2
        margin.update_scores(k, np.round(rng.exponential(size=rng.integers(1, 4)), 1))  # ties
        for j in (1, 2):
            window = np.array(margin._windows[j - 1])
            rank = conformal_rank(window.size, float(margin.levels[j - 1]))
            expected = (0.0 if rank <= 0 else 9.0 if rank > window.size
                        else np.partition(window, rank - 1)[rank - 1])
            assert margin.margin(j) == expected
            assert margin._sorted[j - 1] == sorted(window.tolist())


def test_noise_models_with_a_bias_are_plain_settings_and_keys_tell_them_apart():
    """A drifting law (the stress suite's "biased") is shared too, and never confused."""
    from filters import wrapper
    from safe_nav_env.noise import Gaussian, Laplace, NoiseModel

    def key(mean):
        noise = NoiseModel(Gaussian(0.01), Laplace(0.01, mean=mean), n_samples=100)
        return wrapper._plain_settings({"noise": noise})

    assert key((-0.03, 0.03)) is not None
    assert key((-0.03, 0.03)) == key((-0.03, 0.03))
    assert key((-0.03, 0.03)) != key((-0.03, 0.04))
    assert key((-0.03, 0.03)) != key(0.0)
