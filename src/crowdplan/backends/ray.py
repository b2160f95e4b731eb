"""Jobs as Ray tasks, on a private local Ray instance or on an existing cluster (``[ray]`` extra).

``ray`` is imported only here, when this backend is chosen. Each job is a task asking for
``threads`` CPUs; a task whose worker process dies is retried elsewhere (``TASK_RETRIES``).
"""

from __future__ import annotations

import os
import socket
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from crowdplan.backends import JobInterrupted, run_with_threads

TASK_RETRIES = 3
CONNECT_TIMEOUT_S = 5.0


def _import_ray():
    try:
        import ray
    except ImportError as error:
        raise ValueError(
            "--backend ray needs Ray: pip install 'crowdplan[ray]' (or the pinned ray version "
            "in pyproject.toml)"
        ) from error
    return ray


def cluster_address(address: str) -> str:
    """``host:port`` that ``address`` (``auto``, ``ray://host:port`` or ``host:port``) points at,
    checked to answer within ``CONNECT_TIMEOUT_S`` seconds; ValueError otherwise."""
    target = address
    if address == "auto":
        from ray._private import services

        try:
            target = services.canonicalize_bootstrap_address(address)
        except (ConnectionError, ValueError) as error:
            raise ValueError(f"--address auto: no running Ray cluster found ({error})") from error
        if not target:
            raise ValueError(
                "--address auto: no running Ray cluster found on this machine (start one with "
                "`ray start --head`, or give its address)"
            )
    host_port = target.removeprefix("ray://")
    host, _, port = host_port.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"--address must be auto, ray://HOST:PORT or HOST:PORT, got {address!r}")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S):
            pass
    except OSError as error:
        raise ValueError(
            f"no Ray cluster answers at {host_port} ({error}); is it running and reachable?"
        ) from error
    return target


class RayBackend:
    """Ray tasks, at most ``workers`` in flight (default: as many as the cluster schedules)."""

    def __init__(self, address: str | None = None, workers: int | None = None):
        ray = _import_ray()
        self.workers = workers
        if address is None:
            # a private instance serves this process only: keep it on the loopback interface
            os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")
            ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False)
        else:
            ray.init(address=cluster_address(address), log_to_driver=False)
        self._ray = ray

    def map(
        self, fn: Callable[..., Any], jobs: Sequence[tuple], threads: int
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(*jobs[index]))`` as tasks finish."""
        ray = self._ray
        task = ray.remote(run_with_threads).options(
            num_cpus=threads, max_retries=TASK_RETRIES, retry_exceptions=[JobInterrupted]
        )
        waiting = list(enumerate(jobs))
        in_flight: dict[Any, int] = {}
        limit = self.workers or len(waiting)
        try:
            while waiting or in_flight:
                while waiting and len(in_flight) < limit:
                    index, job = waiting.pop(0)
                    in_flight[task.remote(threads, fn, job)] = index
                done, _ = ray.wait(list(in_flight), num_returns=1)
                for ref in done:
                    yield in_flight.pop(ref), ray.get(ref)
        finally:
            for ref in in_flight:
                ray.cancel(ref)

    def close(self) -> None:
        """Disconnect (and stop a private instance)."""
        self._ray.shutdown()
