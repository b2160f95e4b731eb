"""Timing helpers shared by the benchmarks: CPU time of one call, wall-clock time of the same
work on one torch thread and on several (the ``--threads`` tables), and the wording of ratios."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch


def cpu_seconds(work: Callable[[], object], repeats: int) -> float:
    """This process's CPU seconds per call of ``work``, over ``repeats`` calls after one warm-up
    call (CPU time is steadier than wall-clock time when other work shares the machine)."""
    work()
    start = time.process_time()
    for _ in range(repeats):
        work()
    return (time.process_time() - start) / repeats


def seconds_on_threads(
    work: Callable[[], object],
    threads: int,
    repeats: int,
    warmup: Callable[[], object] | None = None,
) -> tuple[float, float]:
    """Median wall-clock seconds of one call of ``work`` on one torch thread and on ``threads``.

    The two settings alternate within each of ``repeats`` rounds, each timing preceded by one
    call of ``warmup`` (default: ``work``) that wakes the thread pool up. The process is left on
    one thread.
    """
    rounds = []
    for _ in range(repeats):
        row = []
        for count in (1, threads):
            torch.set_num_threads(count)
            (warmup or work)()
            start = time.perf_counter()
            work()
            row.append(time.perf_counter() - start)
        rounds.append(row)
    torch.set_num_threads(1)
    one, many = np.median(np.array(rounds), axis=0)
    return float(one), float(many)


def ratio_text(reference: float, ours: float) -> str:
    """``reference`` against ``ours`` (both times): "1.29x faster" or, for a slowdown,
    "1.25x slower"."""
    if ours <= reference:
        return f"{reference / ours:.2f}x faster"
    return f"{ours / reference:.2f}x slower"
