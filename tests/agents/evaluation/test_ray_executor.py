"""``--executor ray``: the same records as the local run, on a local Ray, on a cluster named by
``--address``, and on a cluster that loses a node mid-run (``pytest -m ray``).

Ray is imported inside the tests, so that collecting this module (and deselecting it, the
default) works without the ray extra.
"""

from __future__ import annotations

import csv
import time
from dataclasses import replace
from pathlib import Path

import pytest

from agents.cli import main
from agents.evaluation.evaluate import evaluate
from agents.evaluation.executors import RayExecutor
from agents.evaluation.records import TIMING_FIELDS, read_records

pytestmark = pytest.mark.ray

TIMING = TIMING_FIELDS
"""The CSV columns that measure time (they differ between any two runs)."""

QUICK_NODE_DEATH = {"health_check_initial_delay_ms": 0, "health_check_period_ms": 200,
                    "health_check_timeout_ms": 200, "health_check_failure_threshold": 3}
"""A lost node is declared dead after about 1 s instead of Ray's default 15-30 s."""


def _timeless(records):
    return [replace(r, **dict.fromkeys(TIMING, 0.0)) for r in records]


def _csv_rows(path):
    return sorted(({k: v for k, v in row.items() if k not in TIMING}
                   for row in csv.DictReader(path.open())),
                  key=lambda row: (row["scenario"], row["risk"], int(row["seed"])))


@pytest.fixture
def cluster():
    """A head and a worker node, one CPU each; disconnects and stops both afterwards."""
    import ray
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True,
                      head_node_args={"num_cpus": 1, "_system_config": QUICK_NODE_DEATH})
    worker = cluster.add_node(num_cpus=1)
    cluster.wait_for_nodes()
    yield cluster, worker
    ray.shutdown()
    cluster.shutdown()


def test_ray_executor_reproduces_the_local_records(tmp_path):
    import ray

    kwargs = dict(episodes=2, seed=11, progress=False, planner="mpc")
    scenarios = ["Intersection"]
    local = evaluate(scenarios, ["none", "cvar"], workers=1, **kwargs)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        remote = evaluate(scenarios, ["none", "cvar"], executor="ray",
                          csv_path=tmp_path / "ray.csv", **kwargs)
    finally:
        ray.shutdown()
    assert _timeless(remote) == _timeless(local)
    assert (tmp_path / "ray.csv").read_text().count("\n") == 1 + 4


def test_address_runs_on_the_given_cluster_and_writes_the_local_csv(cluster, tmp_path,
                                                                    monkeypatch):
    import ray

    head, _ = cluster
    argv = ["evaluate", "--scenarios", "HeadOn", "--risks", "none", "mean", "--planner", "mpc",
            "--episodes", "2", "--no-plots", "--no-progress"]
    assert main([*argv, "--workers", "1", "--output", str(tmp_path / "local")]) == 0
    local_rows = _csv_rows(tmp_path / "local" / "episodes.csv")
    assert len(local_rows) == 4
    assert main([*argv, "--executor", "ray", "--address", head.address,
                 "--output", str(tmp_path / "host-port")]) == 0
    assert not ray.is_initialized()  # the command disconnected, the cluster runs on
    assert head.head_node.remaining_processes_alive()
    # auto: the cluster RAY_ADDRESS names, else the one `ray start` started on this machine.
    monkeypatch.setenv("RAY_ADDRESS", head.address)
    assert main([*argv, "--executor", "ray", "--address", "auto",
                 "--output", str(tmp_path / "auto")]) == 0
    assert _csv_rows(tmp_path / "host-port" / "episodes.csv") == local_rows
    assert _csv_rows(tmp_path / "auto" / "episodes.csv") == local_rows


def _busy_workers(node) -> list[int]:
    """Process ids of the worker processes of ``node`` running an episode (their title is
    ``ray::_ray_task``; Linux /proc)."""
    raylet = node.all_processes["raylet"][0].process.pid
    busy = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            parent = int(stat.read_text().rsplit(")", 1)[1].split()[1])
            title = (stat.parent / "cmdline").read_bytes().decode(errors="replace")
        except (OSError, IndexError, ValueError):  # exited meanwhile
            continue
        if parent == raylet and "_ray_task" in title:
            busy.append(int(stat.parent.name))
    return busy


class LosesANode(RayExecutor):
    """Removes a cluster node (its raylet and workers killed) while it runs an episode."""

    def __init__(self, cluster, node) -> None:
        super().__init__()
        self.cluster, self.node = cluster, node
        self.killed: list[int] = []
        """The worker processes running an episode on the node when it was removed."""

    def run(self, specs):
        for record in super().run(specs):
            for _ in range(1000 if not self.killed else 0):  # watch the node for a while
                self.killed = _busy_workers(self.node)
                if self.killed:
                    self.cluster.remove_node(self.node, allow_graceful=False)
                    break
                time.sleep(0.002)
            yield record


def test_a_lost_node_loses_and_repeats_no_episode(cluster, tmp_path):
    import ray

    head, worker = cluster
    kwargs = dict(episodes=8, seed=5, progress=False, planner="mpc")
    clean = evaluate(["HeadOn"], ["none", "dr_cvar"], workers=1, **kwargs)
    ray.init(address=head.address, log_to_driver=False)
    assert sum(node["Alive"] for node in ray.nodes()) == 2
    path = tmp_path / "episodes.csv"
    executor = LosesANode(head, worker)
    faulty = evaluate(["HeadOn"], ["none", "dr_cvar"], executor=executor, csv_path=path,
                      **kwargs)
    assert executor.killed  # removed while an episode was running there
    assert not worker.any_processes_alive()  # its raylet and object store are gone
    rows = read_records(path)
    assert len(rows) == 16 and len({r.key() for r in rows}) == 16  # each episode exactly once
    assert _timeless(faulty) == _timeless(clean)
    assert sorted(_timeless(rows), key=lambda r: r.key()) == sorted(_timeless(clean),
                                                                    key=lambda r: r.key())
