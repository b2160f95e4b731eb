"""bfloat16 and torch.compile for the value baselines' lookahead: speed against float32, and
whether they keep the greedy action.

    python benchmarks/bench_lookahead_bf16.py --model MODEL [--envs 64] [--cases 100] [--steps 40]
        [--threads 2] [--compile]

Speed: one greedy decision of ``--envs`` environments (the candidates of the 81 actions, the
value network on all of them, the argmax: ``ValuePolicy.greedy``) with the value call in float32
and under ``torch.autocast(cpu, bfloat16)``, CPU time per decision on one torch thread in the
same run; ``--compile`` adds both through the compiled network
(:func:`crowdplan.sim.lookahead.compiled_value_network`, compiled before the timing);
``--threads N`` adds every variant by wall clock on N threads (median of the repeats, only
meaningful on an otherwise idle machine).

Agreement: the model plays ``--cases`` test cases (seeds 1000...) greedily in float32 for
``--steps`` steps (or to the end of each episode); at every decision every variant scores the
same candidates, and the table gives how often its argmax agrees with float32's and how much
float32 value its choice gives up.
Output: stdout only.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from thread_timing import cpu_seconds, ratio_text, seconds_on_threads  # noqa: E402

from crowdplan.models import load_model_policy  # noqa: E402
from crowdplan.sim.lookahead import PRECISIONS, one_step  # noqa: E402
from crowdplan.sim.world import World  # noqa: E402

CALLS_PER_TIMING = 5


@dataclass(frozen=True)
class Variant:
    """One way of running the lookahead's value call."""

    precision: str
    compiled: bool

    @property
    def label(self) -> str:
        precision = "bfloat16 (autocast)" if self.precision == "bfloat16" else self.precision
        return precision + (", compiled" if self.compiled else "")

    def use(self, policy) -> None:
        policy.set_precision(self.precision)
        policy.set_compiled(self.compiled)


def decision(policy, world: World, variant: Variant) -> np.ndarray:
    """The greedy actions of ``world``'s environments with the value call run as ``variant``."""
    variant.use(policy)
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
        "--threads",
        type=int,
        default=1,
        help="also time every variant by wall clock on this many threads",
    )
    parser.add_argument("--compile", action="store_true", help="also time both precisions compiled")
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, config = load_model_policy(args.model)
    if not hasattr(policy, "lookahead"):
        parser.error(f"{args.model} is not a value_rl model (no lookahead)")
    variants = [Variant(p, c) for c in (False, True)[: 1 + args.compile] for p in PRECISIONS]
    reference = variants[0]

    world = World(config, args.envs)
    world.reset(np.arange(args.envs) + 1000)
    for variant in variants:  # compile (the first call) before any timing
        decision(policy, world, variant)
    times: dict[Variant, list[float]] = {v: [] for v in variants}
    for _ in range(2):  # alternate, so that a slow spell of the machine hits every variant
        for variant in variants:
            seconds = cpu_seconds(lambda v=variant: decision(policy, world, v), args.repeats)
            times[variant].append(seconds / args.envs)
    threaded = {}
    if args.threads > 1:
        for variant in variants:

            def calls(v=variant) -> None:
                for _ in range(CALLS_PER_TIMING):
                    decision(policy, world, v)

            one, many = seconds_on_threads(calls, args.threads, args.repeats)
            threaded[variant] = [t / (CALLS_PER_TIMING * args.envs) * 1e3 for t in (one, many)]

    world = World(config, args.cases)
    world.reset(np.arange(args.cases) + 1000)
    running = np.ones(args.cases, dtype=bool)
    others = variants[1:]
    agree = dict.fromkeys(others, 0)
    lost: dict[Variant, list[np.ndarray]] = {v: [] for v in others}
    decisions = 0
    for _ in range(args.steps):
        robot, humans, mask = world.observe()
        found = one_step(robot, humans, mask.astype(bool), config, policy.lookahead, world)
        values = {}
        for variant in variants:
            variant.use(policy)
            values[variant] = policy.candidate_values(found).numpy()
        q32 = values[reference]
        a32 = q32.argmax(axis=1)
        for variant in others:
            chosen = values[variant].argmax(axis=1)
            agree[variant] += int((a32 == chosen)[running].sum())
            lost[variant].append((q32.max(axis=1) - q32[np.arange(len(chosen)), chosen])[running])
        decisions += int(running.sum())
        result = world.step(a32, running)
        running &= ~(result.terminated | result.truncated)

    fp32 = min(times[reference]) * 1e3
    print(f"# {args.model}: greedy decision of {args.envs} envs x 81 actions, CPU ms per decision")
    print("| value call | ms per decision | ratio |")
    print("|---|---|---|")
    for variant in variants:
        ms = min(times[variant]) * 1e3
        ratio = "1.00" if variant == reference else ratio_text(fp32, ms)
        print(f"| {variant.label} | {ms:.3f} | {ratio} |")
    print()
    if threaded:
        n = args.threads
        print(
            f"# the same decision by wall clock, 1 and {n} torch threads (median of {args.repeats})"
        )
        print(f"| value call | 1 thread ms/decision | {n} threads ms/decision | ratio |")
        print("|---|---|---|---|")
        for variant, (one, many) in threaded.items():
            print(f"| {variant.label} | {one:.3f} | {many:.3f} | {ratio_text(one, many)} |")
        print()
    print(f"# greedy action against float32, {decisions} decisions")
    print("| value call | same action | mean float32 value given up | max |")
    print("|---|---|---|---|")
    for variant in others:
        given_up = np.concatenate(lost[variant])
        print(
            f"| {variant.label} | {agree[variant] / decisions:.3f} | {given_up.mean():.2e} "
            f"| {given_up.max():.2e} |"
        )


if __name__ == "__main__":
    main()
