"""One RL update of the value baselines (SARL by default): cached target values against a target
forward pass per drawn batch.

    python benchmarks/bench_value_update.py [--network sarl] [--humans 5] [--updates 1000]
        [--threads 2]

crowdplan (:meth:`crowdplan.algos.value_rl.ValueRLAgent.update`): ``V_target(s')`` of every stored
transition is cached and recomputed in batches of 4096 once per target copy. Its cost per update
counts that refresh of a full replay buffer (100k transitions) spread over the updates between two
copies in CrowdNav's recipe (100 batches per episode x 50 episodes = 5000).

Reference, measured in the same run: the same update evaluating the target network on the drawn
batch's next states (what every update did before the cache). Both draw batches of 100 from the
same buffer of real transitions (random actions in circle_crossing).

Times are this process's CPU time (``time.process_time``), steadier than wall-clock time when
other work shares the machine; one torch thread. Output: stdout only.

A second table (``--threads N``, N > 1) times crowdplan's update on one torch thread and on N, by
wall clock this time (the CPU time of N threads adds up), alternating the two settings within
each round; the rounds' medians and the ratio. Only meaningful on an otherwise idle machine with
N free cores.

``--compile`` adds a table: the same cached update with the value network's forward pass and
the loss compiled by ``torch.compile`` (inductor: the element-wise layers fused into C++ kernels
around the matmuls; compiled once before the timing) against eager, on one thread by CPU time and,
with ``--threads N``, on N threads by wall clock. It answers whether compiling would shorten
SARL's training; training itself stays eager.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from thread_timing import ratio_text, seconds_on_threads  # noqa: E402

from crowdplan.algos.registry import get_algorithm  # noqa: E402
from crowdplan.features import robot_centric  # noqa: E402
from crowdplan.sim.actions import N_ACTIONS  # noqa: E402
from crowdplan.sim.world import World  # noqa: E402
from crowdplan.training import config_from_dict  # noqa: E402

UPDATES_PER_COPY = 100 * 50  # train_batches x target_update_episodes


def fill(agent, capacity: int, envs: int = 64) -> None:
    """Fill the agent's replay buffer with transitions of random actions."""
    world = World(agent.config.world, envs)
    world.reset(np.arange(envs))
    rng = np.random.default_rng(0)
    obs = world.observe()
    while len(agent.buffer) < capacity:
        actions = rng.integers(0, N_ACTIONS, size=envs)
        result = world.step(actions)
        after = world.observe()
        agent.buffer.add_batch(
            *robot_centric(*obs),
            actions,
            result.reward.astype(np.float32),
            *robot_centric(*after),
            result.terminated.astype(np.float32),
        )
        done = np.flatnonzero(result.terminated | result.truncated)
        if len(done):
            world.reset(done + rng.integers(10_000), done)
        obs = world.observe()


def reference_update(agent) -> None:
    """One update evaluating the target network on the drawn batch (no cache)."""
    batch = agent.buffer.sample(agent.params.batch_size)
    with torch.no_grad():
        next_value, _ = agent.target(batch["next_robot"], batch["next_humans"], batch["next_mask"])
    target = batch["reward"] + agent.gamma_step * (1.0 - batch["done"]) * next_value
    loss = agent.value_loss(batch["robot"], batch["humans"], batch["mask"], target)
    agent.optimizer.zero_grad()
    loss.backward()
    agent.optimizer.step()


def cached_updates(agent, updates: int) -> None:
    agent.batch_credit = updates
    agent.update()


def seconds_per_update(agent, loss, updates: int, clock) -> float:
    """``clock`` seconds per update over ``updates`` cached updates with ``loss`` as the agent's
    forward pass and loss (:meth:`~crowdplan.algos.value_rl.ValueRLAgent.value_loss`)."""
    agent.value_loss = loss
    start = clock()
    cached_updates(agent, updates)
    return (clock() - start) / updates


def print_compile_table(agent, threads: int, updates: int, repeats: int) -> None:
    """ms per cached update, eager against the forward pass and loss compiled: CPU time on one
    thread and, with ``threads`` > 1, wall clock on ``threads`` (the two alternate each round)."""
    eager = agent.value_loss
    compiled = torch.compile(eager, dynamic=False)
    seconds_per_update(agent, compiled, 5, time.perf_counter)  # compiles forward and backward
    settings = [("CPU time, 1 thread", 1, time.process_time)]
    if threads > 1:
        settings.append((f"wall clock, {threads} threads", threads, time.perf_counter))
    print()
    print(
        f"# the update with its forward pass and loss compiled, ms per update (median of {repeats})"
    )
    print("| timing | eager | compiled | ratio |")
    print("|---|---|---|---|")
    for label, count, clock in settings:
        torch.set_num_threads(count)
        rounds = [
            [seconds_per_update(agent, loss, updates, clock) for loss in (eager, compiled)]
            for _ in range(repeats)
        ]
        eager_s, compiled_s = np.median(np.array(rounds), axis=0)
        print(
            f"| {label} | {eager_s * 1e3:.3f} | {compiled_s * 1e3:.3f} "
            f"| {ratio_text(eager_s, compiled_s)} |"
        )
    torch.set_num_threads(1)
    agent.value_loss = eager


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--network", default="sarl", choices=["cadrl", "lstm_rl", "sarl"])
    parser.add_argument("--humans", type=int, default=5)
    parser.add_argument("--updates", type=int, default=1000, help="updates per timing")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--buffer", type=int, default=100_000)
    parser.add_argument(
        "--threads", type=int, default=1, help="also time the update on this many torch threads"
    )
    parser.add_argument(
        "--compile", action="store_true", help="also time the update with torch.compile (above)"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    config = config_from_dict(
        {
            "name": "bench",
            "algo": "value_rl",
            "world": {"humans": args.humans},
            "value_rl": {"network": args.network, "il_episodes": 0, "buffer_size": args.buffer},
        }
    )
    agent = get_algorithm("value_rl").make_agent(config, torch.device("cpu"))
    fill(agent, args.buffer)

    def refresh() -> None:
        agent.values_stale = True
        agent._refresh_next_values()

    refresh()  # warm-up
    rows = []
    for _ in range(args.repeats):
        start = time.process_time()
        for _ in range(args.updates):
            reference_update(agent)
        reference = (time.process_time() - start) / args.updates
        start = time.process_time()
        refresh()
        refresh_time = time.process_time() - start
        start = time.process_time()
        cached_updates(agent, args.updates)
        cached = (time.process_time() - start) / args.updates + refresh_time / UPDATES_PER_COPY
        rows.append((reference, cached, refresh_time))
    print(
        f"# {args.network} RL update, batch {agent.params.batch_size}, {args.humans} humans, "
        f"buffer {args.buffer}, CPU ms per update (median of {args.repeats})"
    )
    reference, cached, refresh_time = np.median(np.array(rows), axis=0)
    print("| update | ms per update | ratio |")
    print("|---|---|---|")
    print(f"| reference: target forward per batch | {reference * 1e3:.3f} | 1.00 |")
    print(
        f"| crowdplan: cached target values (full refresh {refresh_time:.2f} s "
        f"per {UPDATES_PER_COPY} updates) | {cached * 1e3:.3f} | {ratio_text(reference, cached)} |"
    )
    if args.threads > 1:
        print_threads_table(agent, args.threads, args.updates, args.repeats)
    if args.compile:
        print_compile_table(agent, args.threads, args.updates, args.repeats)


def print_threads_table(agent, threads: int, updates: int, repeats: int) -> None:
    """Wall-clock ms per cached update on one torch thread and on ``threads``."""
    one, many = seconds_on_threads(
        lambda: cached_updates(agent, updates),
        threads,
        repeats,
        warmup=lambda: cached_updates(agent, 20),
    )
    one, many = one / updates, many / updates
    print()
    print(f"# the same update by wall clock, 1 and {threads} torch threads (median of {repeats})")
    print("| torch threads | ms per update | ratio |")
    print("|---|---|---|")
    print(f"| 1 | {one * 1e3:.3f} | 1.00 |")
    print(f"| {threads} | {many * 1e3:.3f} | {ratio_text(one, many)} |")


if __name__ == "__main__":
    main()
