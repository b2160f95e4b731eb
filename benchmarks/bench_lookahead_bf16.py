"""bfloat16 for the value baselines' lookahead: speed against float32, and whether it keeps the
greedy action.

    python benchmarks/bench_lookahead_bf16.py --model MODEL [--envs 64] [--cases 100] [--steps 40]

Speed: the value network's forward pass over the lookahead candidates of ``--envs``
environments x 81 actions (the part of a decision that grows with the network), float32 against
``torch.autocast(cpu, bfloat16)``, CPU time per decision in the same run.

Agreement: the model plays ``--cases`` test cases (seeds 1000...) greedily in float32 for
``--steps`` steps (or to the end of each episode); at every decision both precisions score the
same candidates, and the table gives how often their argmax agrees and how much float32 value
the bfloat16 choice gives up.
One torch thread. Output: stdout only.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from thread_timing import ratio_text  # noqa: E402

from crowdplan.models import load_model_policy  # noqa: E402
from crowdplan.sim.lookahead import candidate_values, one_step  # noqa: E402
from crowdplan.sim.world import World  # noqa: E402


def values(net, features, bf16: bool) -> np.ndarray:
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        return net(*features)[0].float().numpy()


def candidates(policy, world: World):
    robot, humans, mask = world.observe()
    found = one_step(robot, humans, mask.astype(bool), world.config, policy.lookahead, world)
    return found, [torch.from_numpy(np.ascontiguousarray(x)) for x in found.features]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--model", required=True, help="a value_rl model (cadrl, sarl, ...)")
    parser.add_argument("--envs", type=int, default=64)
    parser.add_argument("--cases", type=int, default=100)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=10)
    args = parser.parse_args()
    torch.set_num_threads(1)
    policy, config = load_model_policy(args.model)
    if not hasattr(policy, "lookahead"):
        parser.error(f"{args.model} is not a value_rl model (no lookahead)")

    world = World(config, args.envs)
    world.reset(np.arange(args.envs) + 1000)
    _, features = candidates(policy, world)
    times = {}
    for bf16 in (False, True, False, True):
        values(policy.net, features, bf16)
        start = time.process_time()
        for _ in range(args.repeats):
            values(policy.net, features, bf16)
        times.setdefault(bf16, []).append((time.process_time() - start) / args.repeats)
    fp32, bf16 = (min(times[k]) / args.envs * 1e3 for k in (False, True))

    world = World(config, args.cases)
    world.reset(np.arange(args.cases) + 1000)
    running = np.ones(args.cases, dtype=bool)
    agree, decisions, lost = 0, 0, []
    for _ in range(args.steps):
        found, features = candidates(policy, world)
        q32 = candidate_values(found, values(policy.net, features, False), policy.gamma_step)
        q16 = candidate_values(found, values(policy.net, features, True), policy.gamma_step)
        a32, a16 = q32.argmax(axis=1), q16.argmax(axis=1)
        agree += int((a32 == a16)[running].sum())
        decisions += int(running.sum())
        lost.append((q32.max(axis=1) - q32[np.arange(len(a16)), a16])[running])
        result = world.step(a32, running)
        running &= ~(result.terminated | result.truncated)
    lost = np.concatenate(lost)
    print(f"# {args.model}: value forward over {args.envs} envs x 81 actions, CPU ms per decision")
    print("| precision | ms per decision | ratio |")
    print("|---|---|---|")
    print(f"| float32 | {fp32:.3f} | 1.00 |")
    print(f"| bfloat16 (autocast) | {bf16:.3f} | {ratio_text(fp32, bf16)} |")
    print()
    print(f"# greedy action, bfloat16 against float32, {decisions} decisions")
    print("| same action | mean float32 value given up | max |")
    print("|---|---|---|")
    print(f"| {agree / decisions:.3f} | {lost.mean():.2e} | {lost.max():.2e} |")


if __name__ == "__main__":
    main()
