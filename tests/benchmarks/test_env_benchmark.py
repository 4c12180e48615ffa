"""The benchmark helpers run (their numbers are not asserted: machines are noisy)."""

from __future__ import annotations

from benchmarks.env import (
    RENDERED,
    benchmark,
    normal_draws_per_second,
    render_frames,
    steps_per_second,
)


def test_benchmark_reports_a_rate_per_scenario():
    rates = benchmark(n_steps=60, repeats=1, n_samples=10, horizon=3)
    assert set(rates) == {
        "SafeNav/HeadOn-v0",
        "SafeNav/Overtaking-v0",
        "SafeNav/Intersection-v0",
        "SafeNav/MultiObstacle-v0",
        "SafeNav/RandomCrossing-v0",
        "SafeNav/Pedestrians-v0",
        "SafeNav/Crowd-v0",
    }
    assert all(rate > 0 for rate in rates.values())
    assert steps_per_second("SafeNav/HeadOn-v0", n_steps=20, repeats=1) > 0
    assert normal_draws_per_second(size=100, repeats=1) > 0


def test_render_frames_times_each_rendered_scenario():
    times = render_frames(2)
    assert set(times) == set(RENDERED)
    assert all(len(wall) == len(cpu) == 2 and (wall > 0).all() for wall, cpu in times.values())
