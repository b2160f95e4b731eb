"""Replay a whole training update as one captured CUDA graph.

A DSAC update is a few hundred small kernels (forward, backward and the Adam steps of networks
with 128-wide layers), each launched from Python: on a GPU it is bound by launch and host
overhead, not by arithmetic (docs/benchmarks.md). Captured once into a CUDA graph, the same
kernels replay with one launch. The update must then have fixed shapes, read no value back to
the host and take no data-dependent branch while it is captured; :class:`GraphedStep` checks
none of that itself, capture fails loudly when it is broken.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

WARMUP_STEPS = 3


class GraphedStep:
    """Runs ``step(batch) -> Tensor`` eagerly for its first :data:`WARMUP_STEPS` calls (on a side
    stream, as capture requires), captures it on the next and from then on replays the graph.

    Every call performs exactly one step on the batch it is given: the capture itself executes
    nothing, so the capturing call replays once. Batches must keep the keys, shapes, dtypes and
    device of the first one (they are copied into the graph's static input tensors). The returned
    tensor is the graph's output buffer, overwritten by the next call: read it before calling
    again.
    """

    def __init__(self, step: Callable[[dict[str, Tensor]], Tensor]):
        self.step = step
        self.graph: torch.cuda.CUDAGraph | None = None
        self._eager_steps = 0
        self._static_batch: dict[str, Tensor] = {}
        self._static_out: Tensor | None = None

    def __call__(self, batch: dict[str, Tensor]) -> Tensor:
        if self.graph is None and self._eager_steps < WARMUP_STEPS:
            self._eager_steps += 1
            return self._on_side_stream(lambda: self.step(batch))
        if self.graph is None:
            self._static_batch = {name: value.clone() for name, value in batch.items()}
            graph = torch.cuda.CUDAGraph()
            torch.cuda.synchronize()
            with torch.cuda.graph(graph):
                self._static_out = self.step(self._static_batch)
            self.graph = graph
        for name, value in batch.items():
            self._static_batch[name].copy_(value, non_blocking=True)
        self.graph.replay()
        assert self._static_out is not None
        return self._static_out

    @staticmethod
    def _on_side_stream(run: Callable[[], Tensor]) -> Tensor:
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            out = run()
        torch.cuda.current_stream().wait_stream(side)
        return out
