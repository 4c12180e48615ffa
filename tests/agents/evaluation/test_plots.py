"""Figures a reader can trust: zero bars, collision marks and radii, GIF legend and label."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from agents.evaluation import plots
from agents.evaluation.contacts import find_collisions, step_clearance
from agents.evaluation.summary import SummaryRow
from filters import InvalidArrayError, InvalidParameterError
from safe_nav_env.collision import swept_clearance


@pytest.fixture
def captured(monkeypatch):
    """Keep the figures the plot functions save, to inspect their artists."""
    figures = []
    save = plots.save_figure

    def keep(fig, path):
        figures.append(fig)
        return save(fig, path)

    monkeypatch.setattr(plots, "save_figure", keep)
    return figures


def _row(scenario: str, risk: str, collisions: int, n: int = 300) -> SummaryRow:
    from agents.evaluation.summary import wilson_interval

    low, high = wilson_interval(collisions, n)
    return SummaryRow(scenario=scenario, planner="mpc", risk=risk, episodes=n, failed=0,
                      collision_rate=collisions / n, collision_low=low, collision_high=high,
                      worst_distance=0.0, cvar_distance=0.0, goal_rate=1.0, time_to_goal=3.0,
                      mean_intervention=0.0, fallback_share=0.0, filter_time_ms=0.3)


def test_a_zero_bar_is_drawn_and_every_bar_shows_its_count(tmp_path, captured):
    rows = [_row("SafeNav/HeadOn-v0", "mean", 120), _row("SafeNav/HeadOn-v0", "dr_cvar", 0),
            _row("SafeNav/Overtaking-v0", "mean", 3), _row("SafeNav/Overtaking-v0", "dr_cvar", 0)]
    path = plots.plot_collision_rates(rows, tmp_path / "rates.png")
    assert path.stat().st_size > 1000
    (ax,) = captured[0].axes
    zero_bars = [line for line in ax.get_lines() if line.get_gid() == "zero-bar"]
    assert len(zero_bars) == 2
    for line in zero_bars:
        ys = np.asarray(line.get_ydata(), dtype=float)
        xs = np.asarray(line.get_xdata(), dtype=float)
        assert np.all(ys == 0.0) and np.ptp(xs) > 0 and line.get_linewidth() >= 3
        assert line.get_label().endswith("0/300") and not line.get_clip_on()
    counts = sorted(t.get_text() for t in ax.texts if t.get_gid() == "bar-count")
    assert counts == sorted(["120/300", "0/300", "3/300", "0/300"])


def _crossing(exact: bool):
    """Ego at 6 m/s straight through a still obstacle between samples 1 and 2."""
    dt = 0.2
    ego = np.array([[-1.8, 0.0], [-0.6, 0.0], [0.6, 0.0], [1.8, 0.0]])
    obstacles = np.tile(np.array([[[0.0, 0.5]]]), (4, 1, 1))  # 0.18 m clearance at samples
    trajectory = SimpleNamespace(ego=ego, obstacles=obstacles, obstacle_radii=np.array([0.3]),
                                 ego_radius=0.3, goal=np.array([3.0, 0.0]), dt=dt)
    if exact:
        trajectory.ego_velocities = np.tile([6.0, 0.0], (4, 1))
        trajectory.inputs = np.zeros((3, 2))
    return trajectory


def test_collisions_between_samples_are_marked_where_and_when(tmp_path, captured):
    trajectory = _crossing(exact=True)
    sampled = (np.linalg.norm(trajectory.ego[:, None] - trajectory.obstacles, axis=2)
               - 0.6).min()
    assert sampled > 0.0  # invisible at the samples
    (mark,) = find_collisions(trajectory)
    assert mark.exact and mark.step == 2 and mark.obstacle == 0
    # The discs (radius sum 0.6) touch when x² + 0.5² = 0.6², on the way in.
    contact_x = -math.sqrt(0.6**2 - 0.5**2)
    assert mark.time == pytest.approx(0.2 + (contact_x + 0.6) / 6.0, abs=1e-9)
    np.testing.assert_allclose(mark.ego_position, [contact_x, 0.0], atol=1e-9)
    assert mark.clearance == pytest.approx(0.5 - 0.6)

    plots.plot_trajectories({"mean": trajectory, "dr_cvar": _far()}, tmp_path / "t.png",
                            every=1)
    (ax,) = captured[-1].axes
    markers = [line for line in ax.get_lines() if line.get_gid() == "collision-marker"]
    assert len(markers) == 1
    np.testing.assert_allclose(np.ravel(markers[0].get_xydata()), mark.ego_position)
    discs = [p for p in ax.patches if p.get_gid() in ("collision-ego-disc",
                                                       "collision-obstacle-disc")]
    assert sorted(d.get_radius() for d in discs) == [0.3, 0.3]
    # Radii drawn at a few instants: every ego and obstacle disc has its true radius.
    instants = [p for p in ax.patches if p.get_gid() is None]
    assert len(instants) == 2 * 4 + 4  # both egos and the (shared) obstacle, 4 samples
    assert {round(p.get_radius(), 9) for p in ax.patches} == {0.3}
    assert any("collision" in t.get_text() for t in ax.get_legend().get_texts())
    assert any(t.get_text().startswith("t = ") for t in ax.texts)


def _far():
    trajectory = _crossing(exact=True)
    trajectory.obstacles = trajectory.obstacles + np.array([0.0, 3.0])
    return trajectory


def test_collision_marks_fall_back_to_the_chord_and_say_so():
    trajectory = _crossing(exact=False)
    (mark,) = find_collisions(trajectory)
    assert not mark.exact and mark.step == 2
    assert find_collisions(_far()) == []


def test_step_clearance_equals_dense_sampling_and_the_environment():
    rng = np.random.default_rng(3)
    dt = 0.2
    s = np.linspace(0.0, dt, 20001)
    for _ in range(200):
        p, v, u = rng.uniform(-1, 1, 2), rng.uniform(-6, 6, 2), rng.uniform(-10, 10, 2)
        q0 = p + rng.uniform(-1.5, 1.5, 2)
        q1 = q0 + rng.uniform(-0.5, 0.5, 2)
        radius = 0.6
        result = step_clearance(p, v, u, q0, q1, radius_sum=radius, dt=dt)
        ego = p + s[:, None] * v + 0.5 * s[:, None] ** 2 * u
        obstacle = q0 + (s[:, None] / dt) * (q1 - q0)
        dense = np.linalg.norm(ego - obstacle, axis=1) - radius
        assert result.clearance <= dense.min() + 1e-12
        assert result.clearance == pytest.approx(dense.min(), abs=1e-6)  # grid 10 µs
        assert result.clearance == pytest.approx(
            swept_clearance(np.concatenate([p, v]), u, dt, [q0], [q1], [radius])[0], abs=1e-9)
        if result.clearance <= 0.0:
            first = s[np.argmax(dense <= 0.0)]
            assert result.contact == pytest.approx(first, abs=2 * dt / 20000)
        else:
            assert math.isnan(result.contact)


def test_step_clearance_rejects_bad_input():
    z = np.zeros(2)
    with pytest.raises(InvalidArrayError, match="finite"):
        step_clearance(z, z, np.array([np.nan, 0.0]), z, z, radius_sum=0.6, dt=0.2)
    with pytest.raises(InvalidParameterError, match="dt"):
        step_clearance(z, z, z, z, z, radius_sum=0.6, dt=0.0)
    with pytest.raises(InvalidParameterError, match="radius_sum"):
        step_clearance(z, z, z, z, z, radius_sum=-1.0, dt=0.2)


def test_gif_has_a_banner_with_the_label_and_legend(tmp_path):
    from PIL import Image

    frames = [np.full((120, 160, 3), 255, dtype=np.uint8) for _ in range(3)]
    frames[1][40:80, 40:80] = (31, 119, 180)
    path = plots.save_gif(frames, tmp_path / "a.gif", label="DR-CVaR (alpha 0.2)")
    with Image.open(path) as gif:
        assert gif.n_frames == 3
        assert gif.size[0] == 160 and gif.size[1] > 120
        banner = np.asarray(gif.convert("RGB"))[120:]
    assert np.any(banner.sum(axis=2) < 200)  # text drawn in the banner
    # Each legend colour is drawn as a swatch.
    for _, color in plots.GIF_LEGEND:
        assert np.any(np.all(np.abs(banner.astype(int) - color) <= 12, axis=2))
    unlabelled = plots.save_gif(frames, tmp_path / "b.gif", legend=())
    with Image.open(unlabelled) as gif:
        assert gif.size[1] < Image.open(path).size[1]
    with pytest.raises(InvalidParameterError, match="frame"):
        plots.save_gif([], tmp_path / "c.gif")
    with pytest.raises(InvalidArrayError, match="shape"):
        plots.save_gif([frames[0], frames[0][:60]], tmp_path / "d.gif")


def test_window_boxplots_draw_one_box_per_sample_and_risk(tmp_path, captured):
    rng = np.random.default_rng(0)
    data = {"SafeNav/HeadOn-v0": {"mean": rng.normal(size=(20, 16)),
                                  "dr_cvar": rng.normal(size=(20, 16)) + 1}}
    path = plots.plot_window_boxplots(data, {"SafeNav/HeadOn-v0": (5, 8)}, tmp_path / "w.png")
    assert path.stat().st_size > 1000
    (ax,) = captured[0].axes
    assert [t.get_text() for t in ax.get_xticklabels()] == [f"{k}\n{0.2 * k:.1f} s"
                                                           for k in (5, 6, 7, 8)]
    assert len(ax.patches) == 8  # 4 samples x 2 risks
