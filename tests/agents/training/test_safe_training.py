"""The safe-RL workflow: safety metrics, normalised actions, PPO-Lagrangian, the train CLI."""

from __future__ import annotations

import csv
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
import stable_baselines3  # noqa: F401  (the train extra of the set-up)
from stable_baselines3 import PPO  # noqa: E402
from stable_baselines3.common.logger import Logger  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

import safe_nav_env  # noqa: E402,F401
from agents.cli.main import main  # noqa: E402
from agents.training.callbacks import SafetyMetricsCallback  # noqa: E402
from agents.training.lagrangian import CostPenaltyVecEnv, PPOLagrangian, dual_ascent_step  # noqa: E402
from agents.training.ppo import make_training_env, metrics_path_for, train_ppo  # noqa: E402
from agents.training.wrappers import (  # noqa: E402
    FILTER_STATUSES,
    EpisodeCostInfo,
    NormalisedActions,
    PhysicalUnitsPolicy,
    SafetyTally,
    is_normalised_policy,
)
from filters import InvalidParameterError, SafetyFilterWrapper  # noqa: E402
from filters.errors import InvalidTypeError  # noqa: E402

TINY_PPO = {"n_steps": 64, "batch_size": 64, "n_epochs": 1}


# ----------------------------------------------------------------------------- helpers
class _ModelStub:
    """What BaseCallback.init_callback reads from a model."""

    def __init__(self, venv):
        self._venv = venv
        self.logger = Logger(folder=None, output_formats=[])
        self.num_timesteps = 0

    def get_env(self):
        return self._venv


def _actions(rng: np.random.Generator, steps: int, n_envs: int) -> np.ndarray:
    """Normalised actions, biased forward so that some episodes reach the goal or collide."""
    actions = rng.uniform(-1.0, 1.0, size=(steps, n_envs, 2)).astype(np.float32)
    actions[..., 0] = np.abs(actions[..., 0])
    return actions


def _direct_count(env_id, seed, actions, *, filter_kwargs=None):
    """Episodes of each copy, stepped one by one as DummyVecEnv does (reset with seed + k
    first, then without a seed after each episode), counted with plain Python."""
    episodes, steps_by_status, interventions = [], {}, []
    for k in range(actions.shape[1]):
        env = gym.make(env_id)
        if filter_kwargs is not None:
            env = SafetyFilterWrapper(env, **filter_kwargs)
        env.reset(seed=seed + k)
        collided, cost, length, ep_interventions = False, 0.0, 0, []
        finished = []
        for t in range(actions.shape[0]):
            _, _, terminated, truncated, info = env.step(10.0 * actions[t, k].astype(float))
            collided = collided or info["collision"]
            cost += info["cost"]
            length += 1
            if "filter" in info:
                status = info["filter"].status
                steps_by_status[status] = steps_by_status.get(status, 0) + 1
                interventions.append(info["filter"].intervention)
                ep_interventions.append(info["filter"].intervention)
            if terminated or truncated:
                finished.append((t, collided, cost, bool(info["is_success"]), length,
                                 float(np.mean(ep_interventions)) if ep_interventions else 0.0))
                collided, cost, length, ep_interventions = False, 0.0, 0, []
                env.reset()
        episodes.extend(finished)
        env.close()
    episodes.sort(key=lambda e: e[0])  # completion order (ties: by env index, stable)
    return episodes, steps_by_status, interventions


def _run_callback(venv, actions):
    callback = SafetyMetricsCallback()
    callback.init_callback(_ModelStub(venv))
    callback.on_training_start({}, {})
    callback.on_rollout_start()
    venv.reset()
    for t in range(actions.shape[0]):
        _, _, dones, infos = venv.step(actions[t])
        callback.update_locals({"infos": infos, "dones": dones})
        callback.on_step()
    callback.on_rollout_end()
    return callback


# ----------------------------------------------------------------------------- the callback
@pytest.mark.parametrize("filter_kwargs", [None, {"risk": "cvar"}], ids=["plain", "filtered"])
def test_callback_numbers_equal_a_direct_count(filter_kwargs):
    env_id, seed, n_envs = "SafeNav/RandomCrossing-v0", 3, 3
    steps = 150 if filter_kwargs is None else 90
    actions = _actions(np.random.default_rng(0), steps, n_envs)
    venv = make_training_env(env_id, n_envs=n_envs, seed=seed, filter_kwargs=filter_kwargs)
    callback = _run_callback(venv, actions)
    episodes, statuses, interventions = _direct_count(env_id, seed, actions,
                                                      filter_kwargs=filter_kwargs)

    assert len(callback.history) == len(episodes) >= 5
    collisions = [e[1] for e in episodes]
    assert 0 < sum(collisions) < len(collisions) or filter_kwargs is not None
    assert sorted((h.collision, h.cost, h.success, h.steps) for h in callback.history) == sorted(
        (e[1], e[2], e[3], e[4]) for e in episodes)
    metrics = callback.rollout_metrics[-1]
    assert metrics["episodes"] == len(episodes)
    assert metrics["collision_rate"] == pytest.approx(np.mean(collisions), abs=1e-12)
    assert metrics["episode_cost"] == pytest.approx(np.mean([e[2] for e in episodes]), abs=1e-12)
    assert metrics["goal_rate"] == pytest.approx(np.mean([e[3] for e in episodes]), abs=1e-12)
    if filter_kwargs is None:
        assert "intervention" not in metrics and "status_optimal" not in metrics
    else:
        total = sum(statuses.values())
        assert total == steps * n_envs
        assert metrics["intervention"] == pytest.approx(np.mean(interventions), rel=1e-12)
        assert set(FILTER_STATUSES) <= {k[len("status_"):] for k in metrics if "status_" in k}
        for status, count in statuses.items():
            assert metrics[f"status_{status}"] == pytest.approx(count / total, abs=1e-12)
        assert sum(v for k, v in metrics.items() if k.startswith("status_")) == pytest.approx(1)
        assert sorted(h.intervention for h in callback.history) == pytest.approx(
            sorted(e[5] for e in episodes), rel=1e-12)
    venv.close()


def test_monitor_records_the_episode_cost_as_the_callback_counts_it():
    venv = make_training_env("SafeNav/RandomCrossing-v0", n_envs=2, seed=5)
    actions = _actions(np.random.default_rng(1), 120, 2)
    callback = SafetyMetricsCallback()
    callback.init_callback(_ModelStub(venv))
    callback.on_training_start({}, {})
    monitor_rows = []
    venv.reset()
    for t in range(actions.shape[0]):
        _, _, dones, infos = venv.step(actions[t])
        callback.update_locals({"infos": infos, "dones": dones})
        callback.on_step()
        for info, done in zip(infos, dones, strict=True):
            if done:
                episode = info["episode"]  # Monitor's record, with the info keywords
                monitor_rows.append((bool(episode["episode_collision"]),
                                     float(episode["episode_cost"]), int(episode["l"])))
    assert len(monitor_rows) >= 5
    assert monitor_rows == [(h.collision, h.cost, h.steps) for h in callback.history]


def test_tally_rates_on_synthetic_infos():
    tally = SafetyTally(2)
    tally.step(0, {"cost": 1.0, "collision": True}, False)
    tally.step(1, {"cost": 0.0, "collision": False, "is_success": True}, True)
    tally.step(0, {"cost": 1.0, "collision": True, "is_success": False}, True)
    metrics = tally.metrics()
    assert metrics == {"episodes": 2.0, "collision_rate": 0.5, "episode_cost": 1.0,
                       "goal_rate": 0.5}


@pytest.mark.slow
def test_callback_in_a_real_learn_run_with_subprocess_environments():
    venv = make_training_env("SafeNav/HeadOn-v0", n_envs=2, seed=0, vec_env="subproc")
    model = PPO("MlpPolicy", venv, seed=0, device="cpu", **TINY_PPO)
    callback = SafetyMetricsCallback()
    model.learn(256, callback=callback)
    costs = [e["episode_cost"] for e in model.ep_info_buffer]
    assert len(callback.history) == len(costs) >= 1
    assert [h.cost for h in callback.history][-len(costs):] == costs
    assert len(callback.rollout_metrics) == 2
    venv.close()


# ----------------------------------------------------------------------------- actions
def test_normalised_view_maps_back_exactly():
    env = gym.make("SafeNav/HeadOn-v0")
    view = NormalisedActions(env)
    assert view.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    a = np.random.default_rng(0).uniform(-1, 1, size=(1000, 2)).astype(np.float32)
    physical = np.array([view.action(x) for x in a])
    assert np.array_equal(physical, 10.0 * a.astype(np.float64))  # exactly, not approx
    assert np.array_equal(view.normalise(physical), a.astype(np.float64))
    # The environment behind the view sees exactly 10 a: same trajectory as stepping 10 a.
    plain = gym.make("SafeNav/HeadOn-v0")
    view.reset(seed=4)
    plain.reset(seed=4)
    for x in a[:10]:
        obs_view = view.step(x)[0]
        obs_plain = plain.step(10.0 * x.astype(np.float64))[0]
        assert np.array_equal(obs_view, obs_plain)


def test_normalised_view_silences_sb3_check_env():
    from stable_baselines3.common.env_checker import check_env

    def action_warnings(env):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env, warn=True)
        return [w for w in caught if "symmetric and normalized Box action" in str(w.message)]

    assert action_warnings(gym.make("SafeNav/HeadOn-v0"))  # the physical box: SB3 warns
    assert not action_warnings(NormalisedActions(gym.make("SafeNav/HeadOn-v0")))
    filtered = NormalisedActions(SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0"),
                                                     risk="cvar"))
    assert not action_warnings(filtered)


def test_physical_and_normalised_policies_both_act_in_m_per_s2(tmp_path):
    from agents import load_ppo
    from agents.evaluation.records import EpisodeSpec
    from agents.evaluation.runner import make_env, run_episode

    space = gym.make("SafeNav/HeadOn-v0").action_space
    shipped = load_ppo()  # trained on the ±10 box
    assert not is_normalised_policy(shipped, space)
    model, _ = train_ppo("SafeNav/HeadOn-v0", total_timesteps=64, n_envs=1,
                         progress_bar=False, ppo_kwargs=TINY_PPO)
    assert is_normalised_policy(model, space)
    obs = np.random.default_rng(0).normal(size=(5, *model.observation_space.shape))
    obs = obs.astype(np.float32)
    adapter = PhysicalUnitsPolicy(model, space)
    for o in obs:
        normalised = model.predict(o, deterministic=True)[0]
        assert np.array_equal(adapter.predict(o, deterministic=True)[0],
                              10.0 * normalised.astype(np.float64))
    spec = EpisodeSpec("SafeNav/HeadOn-v0", "cvar", seed=0)
    env, _ = make_env(spec, policy=model)
    assert isinstance(env, NormalisedActions)
    assert isinstance(env.env.reference.policy, PhysicalUnitsPolicy)
    env_shipped, _ = make_env(spec, policy=shipped)
    assert isinstance(env_shipped, SafetyFilterWrapper)
    for policy in (model, shipped):
        record = run_episode(spec, policy=policy)[0]
        assert record.error == "" and record.steps > 0
    with pytest.raises(InvalidTypeError, match="neither"):
        is_normalised_policy(type("P", (), {"action_space": gym.spaces.Box(-2, 2, (2,))})(),
                             space)


# ----------------------------------------------------------------------------- Lagrangian
def test_dual_ascent_rises_above_the_limit_and_falls_to_zero_below():
    lam, limit, lr = 0.0, 0.5, 0.1
    rising = []
    for cost in (2.0, 1.5, 3.0, 0.9):  # every rollout costs more than the limit
        lam = dual_ascent_step(lam, cost, cost_limit=limit, lr=lr)
        rising.append(lam)
    assert np.all(np.diff([0.0, *rising]) > 0)
    assert lam == pytest.approx(lr * sum(c - limit for c in (2.0, 1.5, 3.0, 0.9)))
    falling = []
    for cost in (0.0, 0.2, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0):
        lam = dual_ascent_step(lam, cost, cost_limit=limit, lr=lr)
        falling.append(lam)
    assert np.all(np.diff([rising[-1], *falling]) <= 0)
    assert falling[-1] == 0.0 and min(falling) == 0.0  # projected: never negative
    assert dual_ascent_step(0.0, 0.0, cost_limit=0.0, lr=1.0) == 0.0
    for bad in ({"multiplier": -1.0}, {"episode_cost": math.nan}, {"cost_limit": -0.1},
                {"lr": 0.0}):
        kwargs = {"multiplier": 0.0, "episode_cost": 1.0, "cost_limit": 0.0, "lr": 0.1, **bad}
        with pytest.raises(InvalidParameterError, match=next(iter(bad))):
            dual_ascent_step(kwargs.pop("multiplier"), kwargs.pop("episode_cost"), **kwargs)


def test_cost_penalty_subtracts_lambda_times_cost():
    actions = _actions(np.random.default_rng(2), 80, 2)
    plain = make_training_env("SafeNav/RandomCrossing-v0", n_envs=2, seed=7)
    penalised = CostPenaltyVecEnv(make_training_env("SafeNav/RandomCrossing-v0", n_envs=2,
                                                    seed=7))
    penalised.multiplier = 2.5
    plain.reset()
    penalised.reset()
    total_cost = 0.0
    for t in range(actions.shape[0]):
        _, r_plain, _, infos = plain.step(actions[t])
        _, r_pen, _, _ = penalised.step(actions[t])
        costs = np.array([i["cost"] for i in infos], dtype=np.float32)
        total_cost += costs.sum()
        np.testing.assert_allclose(r_pen, r_plain - np.float32(2.5) * costs, rtol=0, atol=1e-6)
    assert total_cost > 0  # the comparison saw costs
    finished = penalised.pop_episode_costs()
    assert finished and penalised.pop_episode_costs() == []


@pytest.mark.parametrize(("cost_limit", "lambda_init"), [(0.0, 0.0), (50.0, 0.3)])
def test_ppo_lagrangian_learn_updates_the_multiplier_by_dual_ascent(cost_limit, lambda_init):
    venv = make_training_env("SafeNav/RandomCrossing-v0", n_envs=4, seed=0)
    model = PPOLagrangian("MlpPolicy", venv, cost_limit=cost_limit, lambda_lr=0.2,
                          lambda_init=lambda_init, seed=0, device="cpu", **TINY_PPO)
    model.learn(512)
    history = model.multiplier_history
    assert len(history) >= 2
    lam = lambda_init
    for _, cost, after in history:  # each update is exactly the projected dual-ascent step
        lam = dual_ascent_step(lam, cost, cost_limit=cost_limit, lr=0.2)
        assert after == lam
    assert model.lagrange_multiplier == lam
    costs = [c for _, c, _ in history]
    if cost_limit == 0.0:
        assert any(c > 0 for c in costs)
        assert lam > lambda_init  # cost above the limit: the multiplier rose
    else:
        assert max(costs) < cost_limit
        assert lam == 0.0  # cost below the limit: it fell to 0


def test_ppo_lagrangian_validates_and_round_trips(tmp_path):
    venv = make_training_env("SafeNav/HeadOn-v0", n_envs=1, seed=0)
    for kwargs, name in (({"cost_limit": -1.0}, "cost_limit"), ({"lambda_lr": 0.0}, "lambda_lr"),
                         ({"lambda_init": math.inf}, "lambda_init")):
        with pytest.raises(InvalidParameterError, match=name):
            PPOLagrangian("MlpPolicy", venv, **kwargs)
    with pytest.raises(InvalidTypeError, match="VecEnv"):
        PPOLagrangian("MlpPolicy", object())
    model = PPOLagrangian("MlpPolicy", venv, lambda_init=0.7, device="cpu", **TINY_PPO)
    model.save(tmp_path / "lag.zip")
    loaded = PPOLagrangian.load(tmp_path / "lag.zip", device="cpu")
    assert loaded.lagrange_multiplier == 0.7 and loaded.cost_limit == 0.0
    from agents import load_ppo

    assert load_ppo(tmp_path / "lag.zip").predict(np.zeros(26, np.float32))[0].shape == (2,)


# ----------------------------------------------------------------------------- train_ppo
@pytest.mark.parametrize(("kwargs", "match"), [
    ({"total_timesteps": 0}, "total_timesteps"),
    ({"n_envs": 0}, "n_envs"),
    ({"eval_freq": -5}, "eval_freq"),
    ({"eval_episodes": 0}, "eval_episodes"),
    ({"filter_kwargs": {"risk": "dr_cvar", "alpha": 0.0}}, "alpha"),
    ({"filter_kwargs": {"risk": "dr_cvar", "alpha": 1.5}}, "alpha"),
    ({"filter_kwargs": {"risk": "dr_cvar", "delta": -0.1}}, "delta"),
    ({"filter_kwargs": {"risk": "dr_cvar", "epsilon": math.nan}}, "epsilon"),
    ({"filter_kwargs": {"risk": "bogus"}}, "risk"),
    ({"filter_kwargs": {"risk": "cvar"}, "intervention_penalty": -1.0}, "intervention_penalty"),
    ({"intervention_penalty": 1.0}, "intervention_penalty"),
    ({"lagrangian": True, "cost_limit": -1.0}, "cost_limit"),
    ({"cost_limit": 1.0}, "lagrangian"),
    ({"vec_env": "ray"}, "vec_env"),
    ({"filter_reference": "rollout"}, "filter"),
    ({"filter_kwargs": {"risk": "cvar"}, "filter_reference": "rollout", "vec_env": "subproc"},
     "in-process"),
    ({"env_kwargs": {"random_start": 1.5}}, "random_start.probability"),
    ({"env_kwargs": {"time_penalty": -1.0}}, "time_penalty"),
    ({"ppo_kwargs": {"seed": 3}}, "ppo_kwargs must not set"),
])
def test_train_ppo_validates_before_training(kwargs, match, monkeypatch):
    import agents.training.ppo as training

    def no_training(*args, **kw):  # raising here would mean validation came too late
        raise AssertionError("a training environment was built before validation finished")

    monkeypatch.setattr(training, "make_training_env", no_training)
    with pytest.raises(InvalidParameterError, match=match):
        train_ppo("SafeNav/HeadOn-v0", **{"total_timesteps": 10, **kwargs})


def test_unknown_environment_keywords_are_rejected_before_training(monkeypatch):
    import agents.training.ppo as training

    monkeypatch.setattr(training, "make_training_env", None)  # must not be reached
    with pytest.raises(InvalidTypeError, match="no_such_option"):
        train_ppo("SafeNav/HeadOn-v0", total_timesteps=10, env_kwargs={"no_such_option": 1})
    with pytest.raises(InvalidTypeError, match="env_kwargs must be a dict"):
        train_ppo("SafeNav/HeadOn-v0", total_timesteps=10, env_kwargs=[("a", 1)])


def test_training_environments_get_the_env_kwargs():
    env = make_training_env("SafeNav/RandomCrossing-v0", n_envs=2, seed=0,
                            env_kwargs={"random_start": {"probability": 1.0, "rest": 1.0,
                                                         "near_goal": 1.0}})
    obs = env.reset()
    # Every copy starts at rest near its goal: velocity 0, goal offset within 2 m.
    assert np.all(obs[:, 2:4] == 0.0)
    assert np.all(np.hypot(obs[:, 4], obs[:, 5]) <= 2.0 + 1e-6)
    env.close()


def test_unknown_filter_keywords_are_rejected_by_the_wrapper_constructor():
    with pytest.raises(InvalidTypeError, match="no_such_option"):
        train_ppo("SafeNav/HeadOn-v0", total_timesteps=10,
                  filter_kwargs={"risk": "cvar", "no_such_option": 1})


def test_filter_in_the_loop_with_the_policy_rollout_reference(tmp_path):
    model, report = train_ppo("SafeNav/HeadOn-v0", total_timesteps=64, n_envs=1,
                              filter_kwargs={"risk": "cvar", "alpha": 0.3, "epsilon": 0.1},
                              filter_reference="rollout", progress_bar=False,
                              save_path=tmp_path / "m.zip", ppo_kwargs=TINY_PPO)
    assert report.safety["status_optimal"] + report.safety["status_shifted"] > 0
    assert report.metrics_path == metrics_path_for(tmp_path / "m.zip")
    rows = list(csv.DictReader(open(report.metrics_path)))
    assert rows and float(rows[-1]["safety/intervention"]) == pytest.approx(
        report.safety["intervention"])


def test_the_training_policy_answers_with_its_numpy_export_refreshed_per_rollout():
    import torch

    from agents.training.callbacks import RefreshActor
    from agents.training.ppo import TrainingPolicy

    space = gym.make("SafeNav/HeadOn-v0").action_space
    model = PPO("MlpPolicy", make_training_env("SafeNav/HeadOn-v0", n_envs=1), seed=0,
                device="cpu", **TINY_PPO)
    policy = TrainingPolicy()
    policy.bind(model, space)
    sb3 = PhysicalUnitsPolicy(model, space)  # the reference: SB3's predict in m/s²
    observations = np.random.default_rng(3).standard_normal((50, 26)).astype(np.float32)
    tolerance = 1e-6 * float(np.max(space.high))  # float32 rounding, stretched to the box

    def error() -> float:
        return max(float(np.max(np.abs(policy.predict(obs, deterministic=True)[0]
                                       - sb3.predict(obs, deterministic=True)[0])))
                   for obs in observations)

    assert error() <= tolerance
    with torch.no_grad():  # an update: the export is stale until the next rollout starts
        model.policy.action_net.bias.add_(0.3)
    assert error() > 1e-3
    callback = RefreshActor(policy)
    callback.init_callback(model)
    callback.on_rollout_start()
    assert error() <= tolerance
    stochastic, _ = policy.predict(observations[0], deterministic=False)  # SB3's sampler
    assert stochastic.shape == (2,)


# ----------------------------------------------------------------------------- the CLI
@pytest.mark.slow
def test_train_cli_smoke_prints_metrics_and_writes_csv_and_tensorboard(tmp_path, capsys):
    import tensorboard  # noqa: F401  (the train extra)
    output = tmp_path / "ppo.zip"
    code = main(["train", "--env-id", "HeadOn", "--timesteps", "256", "--n-envs", "2",
                 "--output", str(output), "--no-progress", "--filter", "dr_cvar",
                 "--alpha", "0.25", "--delta", "0.05", "--epsilon", "0.1",
                 "--eval-freq", "128", "--eval-episodes", "1",
                 "--tensorboard", str(tmp_path / "tb")])
    assert code == 0
    out = capsys.readouterr().out
    for key in ("collision_rate", "episode_cost", "goal_rate", "intervention", "status_optimal",
                "eval/"):
        assert key in out
    assert output.exists() and (tmp_path / "ppo_best" / "best_model.zip").exists()
    rows = list(csv.DictReader(open(metrics_path_for(output))))
    assert any(row.get("safety/collision_rate") for row in rows)
    assert any(row.get("eval/collision_rate") for row in rows)
    events = list((tmp_path / "tb").rglob("events.out.tfevents.*"))
    assert events and events[0].stat().st_size > 0


def test_train_cli_lagrangian_smoke(tmp_path, capsys):
    code = main(["train", "--env-id", "RandomCrossing", "--timesteps", "256", "--n-envs", "2",
                 "--output", str(tmp_path / "lag.zip"), "--no-progress", "--lagrangian",
                 "--cost-limit", "0.0", "--lambda-lr", "0.1"])
    assert code == 0
    out = capsys.readouterr().out
    assert "lagrangian/" in out and "lambda " in out and "cost_limit" in out
    assert "final Lagrange multiplier" in out


@pytest.mark.parametrize("argv", [
    ["--eval-freq", "-5"], ["--eval-freq", "x"], ["--timesteps", "0"], ["--n-envs", "0"],
])
def test_train_cli_rejects_bad_numbers(argv, capsys):
    assert main(["train", *argv]) == 2
    assert "expected an integer" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [
    ["--alpha", "0.3"], ["--cost-limit", "1"], ["--filter", "cvar", "--filter-option", "oops"],
    ["--filter", "dr_cvar", "--alpha", "1.5"], ["--filter", "cvar", "--filter-option", "bogus=1"],
    ["--lagrangian", "--cost-limit", "-1"], ["--env-option", "random_start=2"],
    ["--env-option", "bogus=1"], ["--env-option", "no_equals_sign"],
])
def test_train_cli_rejects_inconsistent_options(argv, capsys):
    assert main(["train", "--timesteps", "1", *argv]) == 2
    assert "error" in capsys.readouterr().err


def test_episode_cost_info_rejects_a_non_finite_cost():
    class _NaNCost(gym.Wrapper):
        def step(self, action):
            obs, reward, terminated, truncated, info = self.env.step(action)
            return obs, reward, terminated, truncated, {**info, "cost": math.nan}

    env = EpisodeCostInfo(_NaNCost(gym.make("SafeNav/HeadOn-v0")))
    env.reset(seed=0)
    with pytest.raises(InvalidParameterError, match="cost"):
        env.step(np.zeros(2))


def test_dummy_vec_env_is_the_default():
    venv = make_training_env("SafeNav/HeadOn-v0", n_envs=2, seed=0)
    assert isinstance(venv, DummyVecEnv)
    assert venv.action_space == gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
    raw = make_training_env("SafeNav/HeadOn-v0", n_envs=1, normalise_actions=False)
    assert raw.action_space.high[0] == 10.0


def test_eval_callback_reruns_the_same_held_out_episodes_and_logs_safety(tmp_path):
    from agents.training.callbacks import SafetyEvalCallback

    venv = make_training_env("SafeNav/HeadOn-v0", n_envs=1, seed=0)
    model = PPO("MlpPolicy", venv, seed=0, device="cpu", **TINY_PPO)
    model.set_logger(Logger(folder=None, output_formats=[]))
    eval_env = make_training_env("SafeNav/HeadOn-v0", n_envs=1, seed=123)
    callback = SafetyEvalCallback(eval_env, eval_seed=123, n_eval_episodes=2, eval_freq=1,
                                  best_model_save_path=str(tmp_path), log_path=str(tmp_path),
                                  deterministic=True, verbose=0)
    callback.init_callback(model)
    for _ in range(2):  # two evaluations of the same (untrained) policy
        callback.update_locals({})
        callback.on_step()
    first, second = callback.evaluations_safety
    assert first == second and first["episodes"] == 2
    assert {"collision_rate", "episode_cost", "goal_rate"} <= set(first)
    np.testing.assert_array_equal(callback.evaluations_results[0],
                                  callback.evaluations_results[1])
    assert (tmp_path / "best_model.zip").exists()
    # Another seed gives other episodes (so the equality above is the reseeding's doing).
    other = SafetyEvalCallback(make_training_env("SafeNav/HeadOn-v0", n_envs=1, seed=7),
                               eval_seed=7, n_eval_episodes=2, eval_freq=1,
                               log_path=str(tmp_path / "other"), verbose=0)
    other.init_callback(model)
    other.update_locals({})
    other.on_step()
    assert not np.array_equal(other.evaluations_results[0], callback.evaluations_results[0])
