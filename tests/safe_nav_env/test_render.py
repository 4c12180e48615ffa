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


def _background_and_transform(renderer):
    """The cached background as an array, and the data -> pixel map of the renderer."""
    renderer.canvas.restore_region(renderer._background)
    return np.asarray(renderer.canvas.buffer_rgba()).copy(), renderer._transform


def test_sample_dots_blend_like_a_slow_reference():
    from safe_nav_env.rendering import SAMPLE_ALPHA

    env = gym.make("SafeNav/MultiObstacle-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.render()
    renderer = env.unwrapped._renderer
    background, transform = _background_and_transform(renderer)
    rng = np.random.default_rng(3)
    # Three obstacles, repeated and overlapping points, some outside the axes, one inf.
    predictions = rng.normal(scale=0.4, size=(3, 30, 4, 2))
    predictions[1] = predictions[0] + 0.01  # obstacle 1 draws over obstacle 0
    predictions[2, :5] = predictions[2, 0]  # five identical samples
    predictions[2, 6, 0] = (40.0, 0.0)  # outside the axes
    predictions[0, 7, 1] = (np.inf, np.inf)
    fast = background.copy()
    renderer._composite_samples(fast, predictions)

    slow = background[..., :3].astype(np.float64)
    height = background.shape[0]
    c0, c1, r0, r1 = renderer._clip
    for i in range(3):
        colour = renderer._sample_rgb[i]
        for point in predictions[i].reshape(-1, 2):
            if not np.all(np.isfinite(point)):
                continue
            x, y = transform.transform(point[None])[0]
            col, row = int(np.floor(x - 0.5)), int(np.floor(height - y - 0.5))
            for dr in (0, 1):
                for dc in (0, 1):
                    r, c = row + dr, col + dc
                    if r0 <= r < r1 and c0 <= c < c1:
                        slow[r, c] = SAMPLE_ALPHA * colour + (1 - SAMPLE_ALPHA) * slow[r, c]
        slow = np.rint(slow)  # the fast path stores uint8 after each obstacle
    assert np.abs(fast[..., :3].astype(int) - slow.astype(int)).max() <= 1
    assert (fast[..., :3] != background[..., :3]).any()
    np.testing.assert_array_equal(fast[..., 3], background[..., 3])
    env.close()


def test_cached_caption_glyphs_give_the_same_frame_as_drawing_them():
    env = gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array")
    env.reset(seed=0)
    env.step(np.zeros(2, np.float32))
    first = env.render()  # glyphs drawn by matplotlib and cached ...
    caption = env.unwrapped._renderer._caption
    assert set("t=0.2sHeadOn") <= set(caption._glyphs)  # the canonical scenario name
    second = env.render()  # ... and composed from the cache
    caption._glyphs.clear()
    third = env.render()  # drawn again
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first, third)
    strip = first[caption._rows]
    assert (strip < 128).any(axis=-1).sum() > 100  # there is dark text in the strip
    env.step(np.zeros(2, np.float32))
    fourth = env.render()  # t = 0.4 s: the strip changes, the arena background does not
    assert not np.array_equal(strip, fourth[caption._rows])
    env.close()


def test_hook_artists_are_drawn_once_and_do_not_pile_up():
    env = gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array")
    env.reset(seed=0)
    plain = env.render()
    hook = lambda ax: ax.axvline(-5.2, color=(0.0, 1.0, 0.0), lw=4)  # noqa: E731
    env.unwrapped.render_hooks.append(hook)
    with_hook = env.render()
    green = (with_hook[..., 1] == 255) & (with_hook[..., 0] == 0) & (with_hook[..., 2] == 0)
    assert green.sum() > 500  # the hook's line is in the frame
    children = len(env.unwrapped._renderer.ax.get_children())
    env.render()
    assert len(env.unwrapped._renderer.ax.get_children()) == children
    env.unwrapped.render_hooks.remove(hook)
    np.testing.assert_array_equal(env.render(), plain)  # and gone without the hook
    env.close()


def test_filter_halfspaces_are_drawn_through_the_hook():
    from filters import SafetyFilterWrapper

    env = SafetyFilterWrapper(gym.make("SafeNav/HeadOn-v0", render_mode="rgb_array"),
                              risk="dr_cvar")
    env.reset(seed=0)
    env.step(np.zeros(2))
    with_halfspaces = env.render()
    env.unwrapped.render_hooks.clear()
    without = env.render()
    assert (with_halfspaces != without).any(axis=-1).sum() > 100
    env.close()


def test_halfspace_segments_lie_on_the_boundaries_and_cross_the_view():
    from filters.plotting import halfspace_segments

    rng = np.random.default_rng(3)
    normals = rng.normal(size=(6, 2))
    normals[2] = 0.0  # switched off: left out
    offsets = rng.normal(size=6)
    segments = halfspace_segments(normals, offsets, (-5.0, 5.0), (-4.0, 6.0))
    kept = np.delete(np.arange(6), 2)
    assert segments.shape == (5, 2, 2)
    for seg, i in zip(segments, kept, strict=True):
        np.testing.assert_allclose(seg @ normals[i], offsets[i], atol=1e-9)
        assert np.linalg.norm(seg[1] - seg[0]) >= 2 * np.hypot(10.0, 10.0)
