"""Evaluation split into shards of test cases, run on a backend, merged in seed order.

Every episode is a pure function of its seed and results do not depend on how seeds are batched,
so the merged records (and the summary made from them) equal a single-process run's.
"""

from __future__ import annotations

from collections.abc import Callable

from crowdplan import evaluation
from crowdplan.backends import make_backend
from crowdplan.config import WorldConfig
from crowdplan.policy import Policy


def split(seeds: list[int], shards: int) -> list[list[int]]:
    """``seeds`` in at most ``shards`` contiguous, nearly equal, non-empty chunks."""
    if shards < 1:
        raise ValueError(f"--shards must be >= 1, got {shards}")
    shards = min(shards, len(seeds))
    size, extra = divmod(len(seeds), shards)
    chunks, start = [], 0
    for k in range(shards):
        end = start + size + (k < extra)
        chunks.append(seeds[start:end])
        start = end
    return chunks


def sharded_runner(
    backend: str, shards: int, address: str | None = None
) -> Callable[..., list[evaluation.EpisodeRecord]]:
    """A drop-in for ``evaluation.run_episodes`` that runs ``shards`` chunks of the seeds as
    jobs of ``backend``; ``on_batch`` gets each chunk's records in seed order."""
    if shards < 1:
        raise ValueError(f"--shards must be >= 1, got {shards}")
    if backend == "local" and address is not None:
        raise ValueError("--address applies to --backend ray only")

    def run(
        policy: Policy,
        config: WorldConfig,
        seeds: list[int],
        batch_size: int = 100,
        record_traces: bool = False,
        on_batch: Callable[[list[evaluation.EpisodeRecord]], None] | None = None,
    ) -> list[evaluation.EpisodeRecord]:
        chunks = split(seeds, shards)
        jobs = [(policy, config, chunk, batch_size, record_traces) for chunk in chunks]
        finished: dict[int, list[evaluation.EpisodeRecord]] = {}
        records: list[evaluation.EpisodeRecord] = []
        next_chunk = 0
        runner = make_backend(backend, min(len(chunks), shards), address)
        try:
            for index, chunk_records in runner.map(evaluation.run_episodes, jobs, threads=1):
                finished[index] = chunk_records
                while next_chunk in finished:  # hand chunks on in seed order
                    batch = finished.pop(next_chunk)
                    records.extend(batch)
                    if on_batch is not None:
                        on_batch(batch)
                    next_chunk += 1
        finally:
            runner.close()
        return records

    return run
