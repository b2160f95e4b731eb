"""One greedy SARL decision (81-action one-step lookahead): batched against a CrowdNav-style loop.

    python benchmarks/bench_lookahead.py [--quick] [--humans 5 10] [--envs 1 64] [--repeats 5]
        [--threads 2]

crowdplan: :func:`crowdplan.sim.lookahead.one_step` + :func:`~crowdplan.sim.lookahead.action_values`
for E environments x 81 actions x N humans in one pass (numpy propagation, the world's reward, one
SARL forward pass over E * 81 next states), then the argmax; ms per decision = time / E.

Reference, the way CrowdNav's ``MultiHumanRL.predict`` does it (vita-epfl/CrowdNav,
``crowd_nav/policy/multi_human_rl.py``): for each environment, for each of the 81 actions, the
robot is propagated in Python, each human is propagated at constant velocity in a Python loop,
the reward is computed in a Python loop over the humans, the joint state is rotated and the value
network is called on that one state (batch 1). Both sides use the same SARL weights, the same
reward definitions and the same features; their action values are checked to agree (printed).

A second table times the same decision with the value network called once on every candidate
against the default, chunks of about ``PAIRS_PER_CALL`` (state, human) pairs
(:data:`crowdplan.sim.lookahead.PAIRS_PER_CALL`), and says whether both give bitwise the same
values.

A third table puts the batched decision beside its arithmetic floor: the SARL forward pass's
floating-point operations per decision (counted by ``torch.utils.flop_counter``) divided by this
core's dense float32 matmul rate, measured in the same run on one large matmul.

Times are this process's CPU time (``time.process_time``), steadier than wall-clock time when
other work shares the machine; one torch thread. Output: stdout only.

``--threads N`` (N > 1) adds a fourth table: the batched decision by wall clock on one torch
thread and on N (the CPU time of N threads adds up), alternating within each repeat, median of
the repeats. Only meaningful on an otherwise idle machine with N free cores.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
from functools import partial  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
from thread_timing import cpu_seconds, ratio_text, seconds_on_threads  # noqa: E402

from crowdplan.config import WorldConfig  # noqa: E402
from crowdplan.features import robot_centric  # noqa: E402
from crowdplan.nets.value import make_value_network  # noqa: E402
from crowdplan.sim import lookahead  # noqa: E402
from crowdplan.sim.actions import N_ACTIONS, action_table  # noqa: E402
from crowdplan.sim.lookahead import action_values, one_step, step_discount  # noqa: E402
from crowdplan.sim.world import (  # noqa: E402
    COLLISION,
    GOAL,
    RUNNING,
    World,
    compute_reward,
)


def _observations(config: WorldConfig, envs: int) -> tuple[np.ndarray, ...]:
    """Raw observations of ``envs`` environments, three steps into their episodes."""
    world = World(config, envs)
    world.reset(np.arange(envs) + 1000)
    rng = np.random.default_rng(0)
    for _ in range(3):
        world.step(rng.integers(0, N_ACTIONS, size=envs))
    return world.observe()


def batched(net, config, gamma, robot, humans, mask) -> np.ndarray:
    """Action values (E, 81) of crowdplan's batched lookahead."""
    return action_values(one_step(robot, humans, mask, config), net, gamma).numpy()


def reference(net, config, gamma, robot, humans, mask) -> np.ndarray:
    """Action values (E, 81), one Python propagation and one value call per action."""
    table = action_table(config.robot_v_pref, config.kinematics, config.speed_sampling)
    values = np.zeros((len(robot), N_ACTIONS))
    dt = config.dt
    for e in range(len(robot)):
        px, py, _, _, r, gx, gy, v_pref, theta = robot[e]
        for a, (speed, angle) in enumerate(table):
            vx, vy = speed * math.cos(angle), speed * math.sin(angle)
            next_robot = np.array([[px + vx * dt, py + vy * dt, vx, vy, r, gx, gy, v_pref, theta]])
            next_humans = humans[e : e + 1].copy()
            d_min = math.inf
            for i in range(humans.shape[1]):
                if not mask[e, i]:
                    continue
                hx, hy, hvx, hvy, hr = humans[e, i]
                next_humans[0, i, 0:2] = hx + hvx * dt, hy + hvy * dt
                sx, sy = hx - px, hy - py
                ex, ey = sx + (hvx - vx) * dt, sy + (hvy - vy) * dt
                seg_x, seg_y = ex - sx, ey - sy
                seg_sq = seg_x * seg_x + seg_y * seg_y
                u = min(max(-(sx * seg_x + sy * seg_y) / seg_sq, 0.0), 1.0) if seg_sq > 0 else 0.0
                cx, cy = sx + u * seg_x, sy + u * seg_y
                d_min = min(d_min, math.sqrt(cx * cx + cy * cy) - hr - r)
            goal_dist = math.hypot(gx - next_robot[0, 0], gy - next_robot[0, 1])
            outcome = COLLISION if d_min < 0 else GOAL if goal_dist < r else RUNNING
            reward = float(
                compute_reward(
                    np.array(outcome), np.array(d_min), 1.0, goal_dist, config.discomfort_dist
                )
            )
            feats = robot_centric(next_robot, next_humans, mask[e : e + 1])
            with torch.no_grad():
                value, _ = net(*(torch.from_numpy(x) for x in feats))
            alive = outcome == RUNNING
            values[e, a] = reward + (gamma * float(value) if alive else 0.0)
    return values


def matmul_rate(size: int = 1024, repeats: int = 5) -> float:
    """FLOP/s of one float32 (size x size) @ (size x size) matmul on one thread."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    seconds = cpu_seconds(lambda: a @ b, repeats)
    return 2 * size**3 / seconds


def forward_flops(net, config, gamma, robot, humans, mask) -> int:
    """Floating-point operations of the value network's forward pass in one batched decision."""
    from torch.utils.flop_counter import FlopCounterMode

    with FlopCounterMode(display=False) as counter:
        batched(net, config, gamma, robot, humans, mask)
    return counter.get_total_flops()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--humans", type=int, nargs="+", default=[5, 10])
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 64])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument(
        "--reference-envs",
        type=int,
        default=4,
        help="environments the reference is timed on (its cost is linear in E)",
    )
    parser.add_argument("--quick", action="store_true", help="one repeat, tiny sizes (smoke test)")
    parser.add_argument(
        "--threads", type=int, default=1, help="also time the batched decision on this many threads"
    )
    args = parser.parse_args()
    if args.quick:
        args.repeats, args.reference_envs = 1, 1
    torch.set_num_threads(1)
    torch.manual_seed(0)
    net = make_value_network("sarl").eval()
    floors = []
    print(f"torch {torch.__version__}, 1 thread; SARL, 81 actions, CPU time per decision")
    print()
    print("| N | E | crowdplan ms/decision | reference ms/decision | ratio | max abs diff |")
    print("|---|---|---|---|---|---|")
    for n in args.humans:
        config = WorldConfig(humans=n, action_frame="world")
        gamma = step_discount(0.9, config)
        for envs in args.envs:
            obs = _observations(config, envs)
            fast = cpu_seconds(partial(batched, net, config, gamma, *obs), args.repeats) / envs
            k = min(envs, args.reference_envs)
            sub = tuple(x[:k] for x in obs)
            slow = cpu_seconds(partial(reference, net, config, gamma, *sub), 1) / k
            diff = np.abs(batched(net, config, gamma, *sub) - reference(net, config, gamma, *sub))
            print(
                f"| {n} | {envs} | {fast * 1e3:.3f} | {slow * 1e3:.2f} | {slow / fast:.0f}x "
                f"| {diff.max():.1e} |"
            )
            floors.append((n, envs, fast, forward_flops(net, config, gamma, *obs) / envs))
    print_chunking_table(net, args.humans, args.envs, args.repeats)
    rate = matmul_rate(256 if args.quick else 1024)
    print()
    print(f"arithmetic floor at this core's float32 matmul rate ({rate / 1e9:.1f} GFLOP/s):")
    print()
    print("| N | E | forward MFLOP/decision | floor ms/decision | crowdplan ms/decision | ratio |")
    print("|---|---|---|---|---|---|")
    for n, envs, fast, flops in floors:
        floor = flops / rate
        print(
            f"| {n} | {envs} | {flops / 1e6:.1f} | {floor * 1e3:.3f} | {fast * 1e3:.3f} "
            f"| {fast / floor:.1f}x the floor |"
        )
    if args.threads > 1:
        print_threads_table(net, args.humans, args.envs, args.threads, args.repeats)


def _decisions(net, humans: list[int], envs_list: list[int]):
    """``(N, E, decide)`` for every crowd size and environment count: ``decide()`` runs one
    batched decision of E environments with N humans, a few steps into their episodes."""
    for n in humans:
        config = WorldConfig(humans=n, action_frame="world")
        gamma = step_discount(0.9, config)
        for envs in envs_list:
            yield n, envs, partial(batched, net, config, gamma, *_observations(config, envs))


def print_chunking_table(net, humans: list[int], envs_list: list[int], repeats: int) -> None:
    """CPU ms per batched decision: one value call on every candidate against chunked calls."""
    chunk, one_call = lookahead.PAIRS_PER_CALL, 2**62  # more pairs than any decision has
    print()
    print(
        f"one value call on every candidate against chunks of about {chunk} (state, human) pairs:"
    )
    print()
    print("| N | E | one call ms/decision | chunked ms/decision | ratio | same values |")
    print("|---|---|---|---|---|---|")
    for n, envs, decide in _decisions(net, humans, envs_list):
        times, values = {}, {}
        for pairs in (one_call, chunk, one_call, chunk):  # alternate: a slow spell hits both
            lookahead.PAIRS_PER_CALL = pairs
            seconds = cpu_seconds(decide, repeats) / envs
            times[pairs] = min(times.get(pairs, seconds), seconds)
            values[pairs] = decide()
        lookahead.PAIRS_PER_CALL = chunk
        one, chunked = times[one_call], times[chunk]
        same = np.array_equal(values[one_call], values[chunk])
        print(
            f"| {n} | {envs} | {one * 1e3:.3f} | {chunked * 1e3:.3f} "
            f"| {ratio_text(one, chunked)} | {'bitwise' if same else 'no'} |"
        )


CALLS_PER_TIMING = 5


def print_threads_table(
    net, humans: list[int], envs_list: list[int], threads: int, repeats: int
) -> None:
    """Wall-clock ms per batched decision on one torch thread and on ``threads``."""
    print()
    print(
        f"the batched decision by wall clock, 1 and {threads} torch threads (median of {repeats}):"
    )
    print()
    print(f"| N | E | 1 thread ms/decision | {threads} threads ms/decision | ratio |")
    print("|---|---|---|---|---|")
    for n, envs, decide in _decisions(net, humans, envs_list):

        def calls(decide=decide) -> None:
            for _ in range(CALLS_PER_TIMING):
                decide()

        one, many = seconds_on_threads(calls, threads, repeats, warmup=decide)
        one, many = one / (CALLS_PER_TIMING * envs), many / (CALLS_PER_TIMING * envs)
        print(f"| {n} | {envs} | {one * 1e3:.3f} | {many * 1e3:.3f} | {ratio_text(one, many)} |")


if __name__ == "__main__":
    main()
