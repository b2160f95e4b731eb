"""Time one DSAC update and compare its FLOP rate with a large matmul measured in the same run.

    python benchmarks/bench_update.py [--encoder lsa] [--threads 1] [--humans 5] [--batch 128]
        [--cpu-clock] [--parallel-update] [--bf16] [--profile] [--device cuda [--cuda-graph]]

Prints a markdown table: ms per update (best of ``--rounds`` rounds of ``--iters`` updates after
``--warmup``; the best round is the least disturbed by other processes), GFLOP per update counted
by ``torch.utils.flop_counter.FlopCounterMode`` (matmul-like ops: the LSTM is counted by running
that one counting update with oneDNN off so that it decomposes into matmuls; elementwise ops are
not counted), the achieved GFLOP/s, the GFLOP/s of a float32 1024x1024 @ 1024x1024 matmul on the
same thread count, and their ratio: the fraction of the machine's dense-matmul rate the update
reaches.
"""

from __future__ import annotations

import argparse
import platform
import time
import warnings
from collections.abc import Callable

import torch
from torch.utils.flop_counter import FlopCounterMode

from crowdplan.algos.dsac import DSAC, DSACConfig
from crowdplan.nets.encoders import EncoderConfig


def make_batch(batch: int, humans: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """A random replay batch with every human real."""
    g = torch.Generator().manual_seed(seed)
    mask = torch.ones(batch, humans, dtype=torch.bool)
    return {
        "robot": torch.randn(batch, 6, generator=g),
        "humans": torch.randn(batch, humans, 7, generator=g),
        "mask": mask,
        "action": torch.randint(0, 81, (batch,), generator=g),
        "reward": torch.randn(batch, generator=g),
        "next_robot": torch.randn(batch, 6, generator=g),
        "next_humans": torch.randn(batch, humans, 7, generator=g),
        "next_mask": mask.clone(),
        "done": (torch.rand(batch, generator=g) < 0.1).float(),
    }


def time_update(
    agent: DSAC,
    batch: dict[str, torch.Tensor],
    warmup: int,
    iters: int,
    rounds: int,
    clock: Callable[[], float] = time.perf_counter,
) -> float:
    """Seconds per update: the best of ``rounds`` rounds of ``iters`` updates."""
    for _ in range(warmup):
        agent.update(batch)
    best = float("inf")
    for _ in range(rounds):
        start = clock()
        for _ in range(iters):
            agent.update(batch)
        best = min(best, (clock() - start) / iters)
    return best


class BF16Update:
    """A serial DSAC update run under ``torch.autocast("cpu", dtype=torch.bfloat16)``: matmuls
    and the LSTM in bfloat16 (oneDNN's AVX512-BF16 kernels where the CPU has them), parameters
    and optimiser state in float32."""

    def __init__(self, encoder: EncoderConfig, batch: int):
        self.agent = DSAC(DSACConfig(batch_size=batch), encoder)

    def update(self, batch: dict[str, torch.Tensor]) -> dict[str, float]:
        with torch.autocast("cpu", dtype=torch.bfloat16):
            return self.agent.update(batch)


def count_update_flops(agent: DSAC, batch: dict[str, torch.Tensor]) -> int:
    """FLOPs of one update (forward + backward of all networks) as counted by FlopCounterMode."""
    # oneDNN's fused LSTM kernel is invisible to the counter; the reference path is made of mm's
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torch warns about TF32 when toggling the oneDNN flags
        with torch.backends.mkldnn.flags(enabled=False), FlopCounterMode(display=False) as c:
            agent.update(batch)
    return c.get_total_flops()


# (category, predicate on a profiler event name): the first match wins
OP_CATEGORIES: list[tuple[str, Callable[[str], bool]]] = [
    ("LSTM (oneDNN kernels)", lambda name: "rnn" in name or "lstm" in name),
    ("matmul (mm, addmm, bmm)", lambda name: name in ("aten::mm", "aten::addmm", "aten::bmm")),
    (
        "optimiser (Adam, target Polyak)",
        lambda name: "adam" in name.lower() or name.startswith(("Optimizer.", "aten::_foreach")),
    ),
    ("everything else (elementwise, copies, views, ...)", lambda name: True),
]


def profile_update(
    agent: DSAC, batch: dict[str, torch.Tensor], iters: int
) -> list[tuple[str, float, float]]:
    """(category, ms per update, share) of the update's profiled CPU time (op self times)."""
    from torch.profiler import ProfilerActivity, profile

    for _ in range(10):
        agent.update(batch)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(iters):
            agent.update(batch)
    totals = {name: 0.0 for name, _ in OP_CATEGORIES}
    for event in prof.key_averages():
        category = next(name for name, matches in OP_CATEGORIES if matches(event.key))
        totals[category] += event.self_cpu_time_total
    whole = sum(totals.values())
    return [(name, us / iters / 1e3, us / whole) for name, us in totals.items()]


def matmul_gflops(
    n: int = 1024,
    iters: int = 20,
    clock: Callable[[], float] = time.perf_counter,
    device: str = "cpu",
) -> float:
    """Achieved GFLOP/s of an ``n x n @ n x n`` float32 matmul (best of three rounds)."""
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    out = torch.empty(n, n, device=device)
    sync = torch.cuda.synchronize if device != "cpu" else lambda: None
    for _ in range(3):
        torch.mm(a, b, out=out)
    best = float("inf")
    for _ in range(3):
        sync()
        start = clock()
        for _ in range(iters):
            torch.mm(a, b, out=out)
        sync()
        best = min(best, (clock() - start) / iters)
    return 2 * n**3 / best / 1e9


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--encoder", default="lsa", help="raw | rg | aw | sa | lsa")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    parser.add_argument("--batch", type=int, default=128)
    parser.add_argument("--humans", type=int, default=5)
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--iters", type=int, default=50)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--cpu-clock",
        action="store_true",
        help="time with the thread's CPU clock instead of the wall clock (robust to other "
        "processes sharing the cores; single-threaded runs only)",
    )
    parser.add_argument(
        "--device",
        default="cpu",
        help="cpu or a CUDA device; on CUDA the ceiling is a 8192^3 float32 matmul (TF32 off)",
    )
    parser.add_argument(
        "--parallel-update",
        action="store_true",
        help="also time DSACConfig(parallel_update=True) (critic and policy halves of the update "
        "on two threads) and print its speed-up over the serial update of the same run",
    )
    parser.add_argument(
        "--bf16",
        action="store_true",
        help="also time the serial update under torch.autocast(cpu, bfloat16) and print its "
        "speed-up over float32, timed back to back (CPU only)",
    )
    parser.add_argument(
        "--cuda-graph",
        action="store_true",
        help="also time the update captured in one CUDA graph (DSACConfig(cuda_graph=True)) and "
        "print its speed-up over the eager update on the same device, timed back to back",
    )
    parser.add_argument(
        "--profile",
        action="store_true",
        help="also print where the serial update's CPU time goes, by op category "
        "(torch.profiler self time; the profiler's own overhead inflates the total)",
    )
    args = parser.parse_args()
    if args.cpu_clock and (args.device != "cpu" or args.parallel_update):
        parser.error("--cpu-clock times one host thread: not with CUDA or --parallel-update")
    if args.bf16 and args.device != "cpu":
        parser.error("--bf16 times CPU autocast; on CUDA use the device's own precision options")
    if args.cuda_graph and not args.device.startswith("cuda"):
        parser.error("--cuda-graph needs --device cuda")

    torch.set_num_threads(args.threads)
    encoder = EncoderConfig(name=args.encoder, max_humans=args.humans)
    agent = DSAC(DSACConfig(batch_size=args.batch), encoder, device=args.device)
    batch = {k: v.to(args.device) for k, v in make_batch(args.batch, args.humans).items()}

    clock = time.thread_time if args.cpu_clock else time.perf_counter
    seconds = time_update(agent, batch, args.warmup, args.iters, args.rounds, clock)
    # counted on a CPU copy: fused CUDA kernels (cuDNN's LSTM) are invisible to the counter
    cpu_agent = DSAC(DSACConfig(batch_size=args.batch), encoder)
    gflop = count_update_flops(cpu_agent, make_batch(args.batch, args.humans)) / 1e9
    achieved = gflop / seconds
    # (every update ends in a host sync: its statistics are read back with .tolist())
    peak = (
        matmul_gflops(clock=clock)
        if args.device == "cpu"
        else matmul_gflops(n=8192, iters=10, device=args.device)
    )

    print(
        f"torch {torch.__version__}, {platform.processor() or platform.machine()}, "
        f"device={args.device}, threads={args.threads}, "
        f"clock={'cpu' if args.cpu_clock else 'wall'}, "
        f"encoder={args.encoder}, batch={args.batch}, "
        f"humans={args.humans}, best of {args.rounds} x {args.iters} updates after "
        f"{args.warmup} warm-up\n"
    )
    print("| update ms | update GFLOP | achieved GFLOP/s | matmul GFLOP/s | ratio |")
    print("|---:|---:|---:|---:|---:|")
    print(
        f"| {seconds * 1e3:.2f} | {gflop:.3f} | {achieved:.1f} | {peak:.1f} | "
        f"{achieved / peak:.3f} |"
    )
    if args.parallel_update:
        config = DSACConfig(batch_size=args.batch, parallel_update=True)
        parallel_agent = DSAC(config, encoder, device=args.device)
        timing = time_update(parallel_agent, batch, args.warmup, args.iters, args.rounds, clock)
        # the serial update timed again right after, so that both saw the same machine state
        serial = time_update(agent, batch, 0, args.iters, args.rounds, clock)
        print("\n| serial update ms | parallel update ms | speed-up |")
        print("|---:|---:|---:|")
        print(f"| {serial * 1e3:.2f} | {timing * 1e3:.2f} | {serial / timing:.2f}x |")
    if args.bf16:
        bf16 = time_update(
            BF16Update(encoder, args.batch), batch, args.warmup, args.iters, args.rounds, clock
        )
        serial = time_update(agent, batch, 0, args.iters, args.rounds, clock)
        print("\n| float32 update ms | bfloat16 autocast update ms | speed-up |")
        print("|---:|---:|---:|")
        print(f"| {serial * 1e3:.2f} | {bf16 * 1e3:.2f} | {serial / bf16:.2f}x |")
    if args.cuda_graph:
        config = DSACConfig(batch_size=args.batch, cuda_graph=True)
        graphed = time_update(
            DSAC(config, encoder, device=args.device),
            batch,
            args.warmup,
            args.iters,
            args.rounds,
            clock,
        )
        eager = time_update(agent, batch, 0, args.iters, args.rounds, clock)
        print("\n| eager update ms | CUDA-graph update ms | speed-up |")
        print("|---:|---:|---:|")
        print(f"| {eager * 1e3:.2f} | {graphed * 1e3:.2f} | {eager / graphed:.2f}x |")
    if args.profile:
        print("\n| op category (serial update, profiled) | ms per update | share |")
        print("|---|---:|---:|")
        for name, ms, share in profile_update(agent, batch, args.iters):
            print(f"| {name} | {ms:.2f} | {share:.1%} |")


if __name__ == "__main__":
    main()
