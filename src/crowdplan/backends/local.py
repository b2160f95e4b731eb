"""Jobs on a pool of local worker processes (spawned, so each starts with clean state).

Stopping: a map stopped by an interrupt or an error sets the pool's stop event and sends
SIGTERM to its workers; a sweep trial then saves its checkpoint and exits, and a job that starts
afterwards (one the pool had already queued, picked up by a replacement worker) is refused. A
worker takes SIGTERM and SIGINT as a fresh Python process does only while it runs a job; idle or
passing a result back, it notes them instead, since dying there could leave the pool's result
queue locked and the map waiting forever.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from crowdplan.backends import JobInterrupted, run_with_threads

# New pools started after a worker process died, before the map gives up.
POOL_RESTARTS = 3
STOP_SIGNALS = {signal.SIGTERM: signal.SIG_DFL, signal.SIGINT: signal.default_int_handler}
_stop_noted = False  # in a worker: a stop signal arrived while no job ran
_stop_event: Any = None  # in a worker: its pool's stop event (set by the map that stops)


class LocalBackend:
    """``workers`` processes at a time (default: as many as the CPUs hold jobs of ``threads``)."""

    def __init__(self, workers: int | None = None):
        self.workers = workers

    def map(
        self, fn: Callable[..., Any], jobs: Sequence[tuple], threads: int
    ) -> Iterator[tuple[int, Any]]:
        """Yield ``(index, fn(*jobs[index]))`` as jobs finish; a dead worker's jobs run again
        in a new pool (up to ``POOL_RESTARTS`` times)."""
        workers = self.workers or max(1, (os.cpu_count() or 1) // threads)
        pending = dict(enumerate(jobs))
        context = multiprocessing.get_context("spawn")
        for _ in range(POOL_RESTARTS + 1):
            stop = context.Event()
            pool = ProcessPoolExecutor(
                min(workers, max(len(pending), 1)),
                mp_context=context,
                max_tasks_per_child=1,
                initializer=_start_worker,
                initargs=(stop,),
            )
            futures: dict[Future, int] = {
                pool.submit(_run_job, threads, fn, job): index for index, job in pending.items()
            }
            try:
                while futures:
                    done, _ = wait(futures, return_when=FIRST_COMPLETED)
                    for future in done:
                        index = futures.pop(future)
                        try:
                            result = future.result()
                        except BrokenProcessPool:
                            continue  # a worker died: rerun its jobs in a new pool
                        del pending[index]
                        yield index, result
            except BaseException:
                stop.set()
                _stop_workers()
                raise
            finally:
                pool.shutdown(wait=True, cancel_futures=True)
            if not pending:
                return
        raise RuntimeError(
            f"worker processes kept dying ({POOL_RESTARTS + 1} pools); {len(pending)} job(s) "
            "did not finish - run the same command again to resume them"
        )

    def close(self) -> None:
        """Nothing to release: each map shuts its pool down."""


def _start_worker(stop: Any) -> None:
    """Worker initializer: keep the pool's stop event; outside jobs, note stop signals."""
    global _stop_event
    _stop_event = stop
    _note_stop_signals()


def _note_stop_signals() -> None:
    """Outside jobs, a stop signal is noted, not acted on."""
    for sig in STOP_SIGNALS:
        signal.signal(sig, _note_stop)


def _note_stop(signum, frame) -> None:
    global _stop_noted
    _stop_noted = True


def _run_job(threads: int, fn: Callable[..., Any], job: tuple) -> Any:
    """In a worker: ``fn(*job)`` with the usual signal handling (a training run installs its
    own); refused if a stop signal, or the map's stop, came before it started."""
    if _stop_noted or (_stop_event is not None and _stop_event.is_set()):
        raise JobInterrupted("the map was stopped before the job started")
    for sig, handler in STOP_SIGNALS.items():
        signal.signal(sig, handler)
    try:
        return run_with_threads(threads, fn, job)
    finally:
        _note_stop_signals()


def _stop_workers() -> None:
    """SIGTERM to this process's worker processes, so that a map stopped by an interrupt (or an
    error) does not leave its jobs running: a sweep trial then saves its checkpoint and exits,
    and the pool's shutdown waits for it."""
    for worker in multiprocessing.active_children():
        if worker.pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(worker.pid, signal.SIGTERM)
