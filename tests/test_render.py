"""Rendering: uint8 frames of constant shape, hooks, human mode."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import safe_nav_env  # noqa: F401  (registers the ids)


def test_rgb_array_frames_and_hooks():
    env = gym.make("SafeNav/RandomCrossing-v0", render_mode="rgb_array")
    calls = []

    def hook(ax):
        calls.append(ax)
        ax.axhline(0.0, color="green")  # like a wrapper drawing a halfspace boundary

    env.unwrapped.render_hooks.append(hook)
    shapes = set()
    for seed in range(2):  # a new episode may change the obstacle count
        env.reset(seed=seed)
        frame = env.render()
        shapes.add(frame.shape)
        lines = []
        for _ in range(3):
            env.step(env.action_space.sample())
            frame = env.render()
            assert frame.dtype == np.uint8
            shapes.add(frame.shape)
            lines.append(len(calls[-1].lines))
        assert len(set(lines)) == 1  # the previous frame's hook artists were removed
    assert shapes == {(600, 600, 3)}
    assert len(calls) == 8
    assert frame.std() > 0  # something was drawn
    env.close()


def test_frames_show_the_scene():
    env = gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    for _ in range(5):
        env.step(np.zeros(2, np.float32))
    assert not np.array_equal(first, env.render())


@pytest.mark.filterwarnings("ignore:.*non-interactive:UserWarning")
def test_human_mode_draws_without_returning_frames():
    env = gym.make("SafeNav/HeadOn-v0", render_mode="human")  # Agg backend in the tests
    env.reset(seed=0)
    env.step(np.zeros(2, np.float32))
    assert env.render() is None
    env.close()


def test_render_without_mode_warns():
    env = gym.make("SafeNav/HeadOn-v0")
    env.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert env.unwrapped.render() is None
