"""Policy timings: SB3's ``predict`` against :class:`agents.NumpyPolicy`, alone and in the
roll-out reference (``safe-nav bench`` and ``safe-nav bench --scaling``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from benchmarks.timing import clock, drive, median


def shipped_policy() -> tuple[Any, Any]:
    """The shipped PPO model and its :class:`agents.NumpyPolicy` export, on one torch
    thread as in the evaluation workers."""
    from agents.policies.loading import load_ppo, set_torch_threads
    from agents.policies.numpy_policy import NumpyPolicy

    set_torch_threads(1)
    model = load_ppo()
    return model, NumpyPolicy.from_sb3(model)


@dataclass(frozen=True)
class PolicyTiming:
    """Per-call wall times (µs, medians) of one deterministic action, SB3 vs numpy."""

    calls: int
    sb3_us: float
    numpy_us: float
    batch: int
    sb3_batch_us: float  # one batched call of `batch` observations
    numpy_batch_us: float
    max_difference: float  # max |a_numpy - a_sb3| over the timed observations, m/s^2

    @property
    def ratio(self) -> float:
        """SB3 over numpy."""
        return self.sb3_us / self.numpy_us

    def format(self) -> str:
        return (f"policy forward, one observation, {self.calls} calls, medians: SB3 predict "
                f"{self.sb3_us:.1f} us, NumpyPolicy {self.numpy_us:.1f} us ({self.ratio:.1f}x "
                f"faster)\n    batch of {self.batch}: SB3 {self.sb3_batch_us:.1f} us, "
                f"NumpyPolicy {self.numpy_batch_us:.1f} us; max |a_numpy - a_sb3| = "
                f"{self.max_difference:.2e}")


def benchmark_numpy_policy(*, calls: int = 2000, batch: int = 64, seed: int = 0) -> PolicyTiming:
    """Time the shipped policy's ``model.predict(obs, deterministic=True)`` against
    :class:`NumpyPolicy`, one observation and batches of ``batch``.

    The observations are standard-normal draws from ``numpy.random.default_rng(seed)``
    (the network does not care where they come from); one torch thread, as in the
    evaluation workers.
    """
    model, policy = shipped_policy()
    observations = np.random.default_rng(seed).standard_normal(
        (calls, *policy._obs_shape)).astype(np.float32)
    single, batched, difference = [], [], 0.0
    for obs in observations:
        (torch_action, _), sb3_ms = clock(model.predict, obs, deterministic=True)
        (numpy_action, _), numpy_ms = clock(policy.predict, obs, deterministic=True)
        single.append((sb3_ms, numpy_ms))
        difference = max(difference, float(np.max(np.abs(numpy_action - torch_action))))
    for start in range(0, calls - batch + 1, batch):
        rows = observations[start:start + batch]
        batched.append((clock(model.predict, rows, deterministic=True)[1],
                        clock(policy.predict_batch, rows)[1]))
    (sb3, numpy), (sb3_batch, numpy_batch) = np.array(single).T, np.array(batched).T
    return PolicyTiming(calls, 1e3 * median(sb3), 1e3 * median(numpy), batch,
                        1e3 * median(sb3_batch), 1e3 * median(numpy_batch), difference)


def benchmark_rollout_reference(horizon: int = 10, steps: int = 200, seed: int = 0
                                ) -> dict[str, float]:
    """Median wall time (ms) of one roll-out reference (``T - 1`` policy calls) per step.

    On the states of unfiltered MultiObstacle episodes of the shipped PPO policy (recorded
    first, then replayed to each maker in a loop of its own: the same states for all),
    :class:`filters.references.PolicyRolloutReference` with: ``"sb3"`` the SB3 model's
    ``predict`` at each look-ahead step; ``"numpy"`` the :class:`agents.NumpyPolicy`
    export called the same way (what ``safe-nav evaluate`` runs); ``"hold"`` the
    held-action reference, for scale.
    """
    import gymnasium as gym

    import safe_nav_env  # noqa: F401
    from filters.references import PolicyRolloutReference, hold_action_reference

    model, numpy_policy = shipped_policy()
    makers = {"sb3": PolicyRolloutReference(model),
              "numpy": PolicyRolloutReference(numpy_policy),
              "hold": hold_action_reference}
    env = gym.make("SafeNav/MultiObstacle-v0", horizon=horizon)
    base = env.unwrapped
    fields = ("ego_state", "predictions", "obstacle_positions", "obstacle_velocities")
    situations = []  # what a reference maker reads, recorded along the episodes

    def act(obs: np.ndarray, _: bool) -> np.ndarray:
        situations.append(({name: getattr(base, name) for name in fields},
                           model.predict(obs, deterministic=True)[0]))
        return situations[-1][1]

    list(drive(env, steps, seed, act))
    medians = {}
    for name, maker in makers.items():  # each in a loop of its own, as a control loop runs
        maker(base, situations[0][1], horizon)  # first call: torch's kernels
        times = []
        for state, action in situations:
            for field, value in state.items():
                setattr(base, field, value)
            times.append(clock(maker, base, action, horizon)[1])
        medians[name] = median(times)
    env.close()
    return medians


def format_rollout_reference(rollout: dict[str, float], horizon: int = 10) -> str:
    """The roll-out timings of :func:`benchmark_rollout_reference` as one paragraph."""
    return (f"roll-out reference, T = {horizon} ({horizon - 1} policy calls), MultiObstacle, "
            f"medians: SB3 predict {rollout['sb3']:.3f} ms, NumpyPolicy.predict "
            f"{rollout['numpy']:.3f} ms ({rollout['sb3'] / rollout['numpy']:.1f}x faster); "
            f"the held action {rollout['hold']:.4f} ms")
