"""bfloat16 for the value baselines' lookahead: speed against float32, and whether it keeps the
greedy action.

    python benchmarks/bench_lookahead_bf16.py --model MODEL [--envs 64] [--cases 100] [--steps 40]
        [--threads 2]

Speed: one greedy decision of ``--envs`` environments (the candidates of the 81 actions, the
value network on all of them, the argmax: ``ValuePolicy.greedy``) with the value call in float32
and under ``torch.autocast(cpu, bfloat16)``, CPU time per decision on one torch thread in the
same run; ``--threads N`` adds both by wall clock on N threads (median of the repeats, only
meaningful on an otherwise idle machine).

Agreement: the model plays ``--cases`` test cases (seeds 1000...) greedily in float32 for
``--steps`` steps (or to the end of each episode); at every decision both precisions score the
same candidates, and the table gives how often their argmax agrees and how much float32 value
the bfloat16 choice gives up.
Output: stdout only.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from thread_timing import cpu_seconds, ratio_text, seconds_on_threads  # noqa: E402

from crowdplan.models import load_model_policy  # noqa: E402
from crowdplan.sim.lookahead import PRECISIONS, action_values, one_step  # noqa: E402
from crowdplan.sim.world import World  # noqa: E402

CALLS_PER_TIMING = 5


def decision(policy, world: World, precision: str) -> np.ndarray:
    """The greedy actions of ``world``'s environments with the value call in ``precision``."""
    policy.set_precision(precision)
    robot, humans, mask = world.observe()
    return policy.greedy(robot, humans, mask.astype(bool), world)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", required=True, help="a value_rl model (cadrl, sarl, ...)")
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--cases", type=int, default=100)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument(
        "--threads", type=int, default=1, help="also time both by wall clock on this many threads"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, config = load_model_policy(args.model)
    if not hasattr(policy, "lookahead"):
        parser.error(f"{args.model} is not a value_rl model (no lookahead)")

    world = World(config, args.envs)
    world.reset(np.arange(args.envs) + 1000)
    times: dict[str, list[float]] = {p: [] for p in PRECISIONS}
    for _ in range(2):  # alternate, so that a slow spell of the machine hits both
        for precision in PRECISIONS:
            seconds = cpu_seconds(lambda p=precision: decision(policy, world, p), args.repeats)
            times[precision].append(seconds / args.envs)
    fp32, bf16 = (min(times[p]) * 1e3 for p in PRECISIONS)
    threaded = {}
    if args.threads > 1:
        for precision in PRECISIONS:

            def calls(p=precision) -> None:
                for _ in range(CALLS_PER_TIMING):
                    decision(policy, world, p)

            one, many = seconds_on_threads(calls, args.threads, args.repeats)
            threaded[precision] = [t / (CALLS_PER_TIMING * args.envs) * 1e3 for t in (one, many)]

    world = World(config, args.cases)
    world.reset(np.arange(args.cases) + 1000)
    running = np.ones(args.cases, dtype=bool)
    agree, decisions, lost = 0, 0, []
    for _ in range(args.steps):
        robot, humans, mask = world.observe()
        found = one_step(robot, humans, mask.astype(bool), config, policy.lookahead, world)
        q32 = action_values(found, policy.net, policy.gamma_step).numpy()
        q16 = action_values(found, policy.net, policy.gamma_step, "bfloat16").numpy()
        a32, a16 = q32.argmax(axis=1), q16.argmax(axis=1)
        agree += int((a32 == a16)[running].sum())
        decisions += int(running.sum())
        lost.append((q32.max(axis=1) - q32[np.arange(len(a16)), a16])[running])
        result = world.step(a32, running)
        running &= ~(result.terminated | result.truncated)
    lost = np.concatenate(lost)
    print(f"# {args.model}: greedy decision of {args.envs} envs x 81 actions, CPU ms per decision")
    print("| precision of the value call | ms per decision | ratio |")
    print("|---|---|---|")
    print(f"| float32 | {fp32:.3f} | 1.00 |")
    print(f"| bfloat16 (autocast) | {bf16:.3f} | {ratio_text(fp32, bf16)} |")
    print()
    if threaded:
        n = args.threads
        print(
            f"# the same decision by wall clock, 1 and {n} torch threads (median of {args.repeats})"
        )
        print(f"| precision | 1 thread ms/decision | {n} threads ms/decision | ratio |")
        print("|---|---|---|---|")
        for precision, (one, many) in threaded.items():
            print(f"| {precision} | {one:.3f} | {many:.3f} | {ratio_text(one, many)} |")
        print()
    print(f"# greedy action, bfloat16 against float32, {decisions} decisions")
    print("| same action | mean float32 value given up | max |")
    print("|---|---|---|")
    print(f"| {agree / decisions:.3f} | {lost.mean():.2e} | {lost.max():.2e} |")


if __name__ == "__main__":
    main()
