"""What the second core gives: two one-thread jobs at once, or one job on two torch threads.

    python benchmarks/bench_two_cores.py [--network sarl] [--updates 300] [--rounds 6]

The work is the value baselines' RL update (forward, backward and SGD step of a fresh network on
one batch of 100 states, 5 humans), timed by wall clock in ``--rounds`` rounds; each round times,
back to back:

- reference: one process, one torch thread, the other core idle;
- two jobs: two processes at once, one torch thread each (as two sweep trials on two cores);
- two threads: one process on two torch threads.

Printed: the ms per update of each setting per round (to show how steady it is), then the
medians, with the updates per second of the whole machine as a ratio against the reference.
Only meaningful on an otherwise idle machine. Output: stdout only.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import multiprocessing as mp  # noqa: E402
import time  # noqa: E402
from collections.abc import Callable  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402
from thread_timing import ratio_text  # noqa: E402

from crowdplan.nets.value import VALUE_NETWORKS, make_value_network  # noqa: E402


def update_loop(network: str) -> Callable[[int], None]:
    """A function running N updates of a fresh ``network`` on one fixed random batch."""
    torch.manual_seed(0)
    net = make_value_network(network)
    optimizer = torch.optim.SGD(net.parameters(), lr=1e-3, momentum=0.9)
    robot, humans = torch.randn(100, 6), torch.randn(100, 5, 7)
    mask, target = torch.ones(100, 5, dtype=torch.bool), torch.randn(100)

    def run(updates: int) -> None:
        for _ in range(updates):
            value, _ = net(robot, humans, mask)
            loss = F.mse_loss(value, target)
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()

    return run


def seconds_per_update(run: Callable[[int], None], updates: int) -> float:
    run(20)  # warm-up
    start = time.perf_counter()
    run(updates)
    return (time.perf_counter() - start) / updates


def _job(network: str, updates: int, barrier, results, slot: int) -> None:
    torch.set_num_threads(1)
    run = update_loop(network)
    run(20)
    barrier.wait()  # both jobs start timing together
    start = time.perf_counter()
    run(updates)
    results[slot] = (time.perf_counter() - start) / updates


def two_jobs(network: str, updates: int) -> float:
    """Mean seconds per update of two one-thread processes timed at the same time."""
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(2), ctx.Array("d", 2)
    jobs = [ctx.Process(target=_job, args=(network, updates, barrier, results, i)) for i in (0, 1)]
    for job in jobs:
        job.start()
    for job in jobs:
        job.join()
        if job.exitcode != 0:
            raise RuntimeError(f"a timing process failed (exit code {job.exitcode})")
    return float(np.mean(results[:]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--network", default="sarl", choices=VALUE_NETWORKS)
    parser.add_argument("--updates", type=int, default=300, help="updates per timing")
    parser.add_argument("--rounds", type=int, default=6)
    args = parser.parse_args()
    run = update_loop(args.network)
    rows = []
    for _ in range(args.rounds):
        torch.set_num_threads(1)
        alone = seconds_per_update(run, args.updates)
        paired = two_jobs(args.network, args.updates)
        torch.set_num_threads(2)
        threaded = seconds_per_update(run, args.updates)
        rows.append((alone, paired, threaded))
    torch.set_num_threads(1)
    print(
        f"# {args.network} update, batch 100, 5 humans, wall ms per update, {args.updates} updates "
        f"per timing, {os.cpu_count()} CPUs, torch {torch.__version__}"
    )
    print("| round | one job, 1 thread | two jobs at once, 1 thread each | one job, 2 threads |")
    print("|---|---|---|---|")
    for i, (alone, paired, threaded) in enumerate(rows, 1):
        print(f"| {i} | {alone * 1e3:.3f} | {paired * 1e3:.3f} | {threaded * 1e3:.3f} |")
    alone, paired, threaded = np.median(np.array(rows), axis=0)
    print()
    print(f"# medians of {args.rounds} rounds; machine throughput = updates per second, all jobs")
    print("| setting | ms per update | machine updates / s | throughput ratio |")
    print("|---|---|---|---|")
    print(f"| reference: one job, 1 thread | {alone * 1e3:.3f} | {1 / alone:.0f} | 1.00 |")
    print(
        f"| two jobs at once, 1 thread each | {paired * 1e3:.3f} | {2 / paired:.0f} | "
        f"{ratio_text(alone, paired / 2)} |"
    )
    print(
        f"| one job, 2 threads | {threaded * 1e3:.3f} | {1 / threaded:.0f} | "
        f"{ratio_text(alone, threaded)} |"
    )


if __name__ == "__main__":
    main()
