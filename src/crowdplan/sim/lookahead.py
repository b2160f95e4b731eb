"""Batched one-step lookahead over every discrete action (the value-based baselines, SPEC 6).

The candidate next states, their rewards and features come from :mod:`crowdplan.sim.candidates`
(numpy only, shared with the deployment runtime); :func:`action_values` evaluates the value
network on all of them in one torch call and scores each candidate ``r + gamma_step * V(s')``,
without the bootstrap term where the candidate ends the episode (collision or goal).

The value call runs in float32 or, on request, under bfloat16 autocast on the CPU: about twice
as fast where the CPU has bfloat16 instructions, but its rounding moves the values by up to about
0.006 and so changes some greedy actions (docs/benchmarks.md, "bfloat16 and torch.compile for
the lookahead"). Either precision can run through a network compiled by
:func:`compiled_value_network` (``torch.compile``: the element-wise layers fused into C++
kernels), which changes the values only by float32 rounding.
"""

from __future__ import annotations

import shutil
from typing import Any

import numpy as np
import torch
from torch import nn

from crowdplan.sim.candidates import (
    LOOKAHEAD_MODES,
    Candidates,
    Timing,
    candidate_values,
    check_mode,
    next_humans,
    one_step,
    step_discount,
)

PRECISIONS = ("float32", "bfloat16")

# The value network sees the candidates in chunks of about this many (state, human) pairs: a
# 64-environment decision has 81 x 64 x N of them, and in one call every layer's activations
# (tens of MB in float32) leave the cache and are paged in afresh by each call. Chunks of a few
# thousand pairs run faster (docs/benchmarks.md). A chunk starts at a multiple of
# STATES_ALIGNED states, so that each row keeps its place in the matmul kernels' row blocks and
# gets the same value as in one call (on one thread; measured, not promised by the libraries).
PAIRS_PER_CALL = 4096
STATES_ALIGNED = 64

__all__ = [
    "LOOKAHEAD_MODES",
    "PRECISIONS",
    "Candidates",
    "check_precision",
    "Timing",
    "action_values",
    "compiled_value_network",
    "check_mode",
    "next_humans",
    "one_step",
    "step_discount",
]


def check_precision(precision: str) -> None:
    """Refuse a precision of the value call other than :data:`PRECISIONS`."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {precision!r}")


def compiled_value_network(net: nn.Module) -> nn.Module:
    """``net`` compiled for the lookahead's value calls: it shares ``net``'s parameters, and
    any batch size and crowd size runs without recompiling (``dynamic=True``); the first call
    compiles (seconds). torch's CPU backend builds C++, so a C++ compiler must be installed."""
    if shutil.which("g++") is None and shutil.which("clang++") is None:
        raise RuntimeError(
            "compiling the value network needs a C++ compiler (torch.compile builds C++ kernels "
            "on the CPU) and none was found: install one (e.g. apt install g++) or run "
            "without compiling"
        )
    # dynamic_threads: the fused kernels follow torch.set_num_threads at run time, not the count
    # at compile time
    return torch.compile(net, dynamic=True, options={"cpp.dynamic_threads": True})


@torch.no_grad()
def action_values(
    candidates: Candidates, value_net: Any, gamma_step: float, precision: str = "float32"
) -> torch.Tensor:
    """(E, A) ``r + gamma_step * V(s')`` of every candidate; terminal candidates score ``r``.

    ``precision``: ``float32``, or ``bfloat16`` for the value call alone under autocast (on
    the network's device); the candidates, rewards and scores are computed as in float32."""
    check_precision(precision)
    device = next(value_net.parameters()).device
    features = [torch.from_numpy(np.ascontiguousarray(x)).to(device) for x in candidates.features]
    per_chunk = PAIRS_PER_CALL // max(features[1].shape[1], 1)
    per_chunk = max(STATES_ALIGNED, per_chunk - per_chunk % STATES_ALIGNED)
    chunks = zip(*(x.split(per_chunk) for x in features), strict=True)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
        values = torch.cat([value_net(*chunk)[0] for chunk in chunks])
    values = values.float().cpu().numpy()
    return torch.from_numpy(candidate_values(candidates, values, gamma_step))
