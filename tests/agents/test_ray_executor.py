"""``--executor ray`` gives the same records as the local process pool."""

from __future__ import annotations

from dataclasses import replace

import pytest

from agents.evaluation.evaluate import evaluate

ray = pytest.importorskip("ray", reason="the ray extra is part of the README set-up")


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _timeless(records):
    return [replace(r, wall_time=0.0, filter_time_median=0.0, filter_time_max=0.0)
            for r in records]


def test_ray_executor_reproduces_the_local_records(local_ray, tmp_path):
    kwargs = dict(episodes=2, seed=11, progress=False, planner="mpc")
    scenarios = ["Intersection"]
    local = evaluate(scenarios, ["none", "cvar"], workers=1, **kwargs)
    remote = evaluate(scenarios, ["none", "cvar"], executor="ray",
                      csv_path=tmp_path / "ray.csv", **kwargs)
    assert _timeless(remote) == _timeless(local)
    assert (tmp_path / "ray.csv").read_text().count("\n") == 1 + 4
