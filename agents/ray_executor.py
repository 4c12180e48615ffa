"""Run evaluation episodes as Ray tasks (``safe-nav evaluate --executor ray``).

For sweeps larger than one machine: each :class:`agents.evaluation.EpisodeSpec`
becomes one Ray task that returns its :class:`agents.evaluation.EpisodeRecord`.
Episodes are seeded individually, so the records are identical to a local run;
:func:`agents.evaluation.evaluate` sorts them, so the CSV's summary is too.

Connects to the cluster named by ``RAY_ADDRESS`` if set (``ray start --head`` on
the head node, ``ray start --address=...`` on the others, the project installed
on every node), otherwise starts a local Ray instance. Needs the ``ray`` extra.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

from agents.evaluation import EpisodeRecord, EpisodeSpec


def _run_spec_task(spec: EpisodeSpec) -> EpisodeRecord:
    from agents.evaluation import _run_spec, _worker_init

    _worker_init()
    return _run_spec(spec)


def run_on_ray(
    specs: Sequence[EpisodeSpec], *, address: str | None = None, max_in_flight: int = 256
) -> Iterator[EpisodeRecord]:
    """Yield the records of ``specs`` as their Ray tasks finish.

    Parameters
    ----------
    specs
        Episodes to run.
    address
        Ray cluster address; ``None`` uses ``RAY_ADDRESS`` or a running/local instance.
    max_in_flight
        At most this many tasks are submitted at once (bounded memory for big sweeps).
    """
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - depends on the extra
        raise ImportError(
            "--executor ray needs Ray: pip install -e '.[ray]'"
        ) from exc
    if not ray.is_initialized():
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
    task = ray.remote(num_cpus=1)(_run_spec_task)
    pending = list(specs)[::-1]
    in_flight = []
    while pending or in_flight:
        while pending and len(in_flight) < max_in_flight:
            in_flight.append(task.remote(pending.pop()))
        done, in_flight = ray.wait(in_flight, num_returns=1)
        yield from ray.get(done)
