"""Where many independent jobs run: a local process pool or a Ray cluster (docs/scaling.md).

A backend runs ``fn(*job)`` for each job of a list, each with its own budget of CPU threads, and
yields ``(index, result)`` as jobs finish. A job whose worker process dies is run again (a sweep
trial then resumes from its checkpoint); a job that raises stops the whole map.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any, Protocol

BACKENDS = ("local", "ray")


class JobInterrupted(RuntimeError):
    """A job stopped early by a signal with its progress saved; Ray runs it again."""


class Backend(Protocol):
    """Runs independent jobs somewhere; see the module docstring."""

    def map(
        self, fn: Callable[..., Any], jobs: Sequence[tuple], threads: int
    ) -> Iterator[tuple[int, Any]]: ...

    def close(self) -> None: ...


def make_backend(name: str, workers: int | None, address: str | None = None) -> Backend:
    """``local``: a pool of ``workers`` processes on this machine; ``ray``: tasks on the Ray
    cluster at ``address`` (None: a private local instance), at most ``workers`` in flight."""
    if name not in BACKENDS:
        raise ValueError(f"unknown backend {name!r}; choose one of {list(BACKENDS)}")
    if workers is not None and workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if name == "local":
        if address is not None:
            raise ValueError("--address applies to --backend ray only")
        from crowdplan.backends.local import LocalBackend

        return LocalBackend(workers)
    from crowdplan.backends.ray import RayBackend

    return RayBackend(address, workers)


def run_with_threads(threads: int, fn: Callable[..., Any], args: tuple) -> Any:
    """``fn(*args)`` with torch (and the libraries under it) on ``threads`` threads."""
    import os

    import torch

    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(threads)
    torch.set_num_threads(threads)
    return fn(*args)
