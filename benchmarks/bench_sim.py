"""Environment steps per second: crowdplan's batched ``World`` against a CrowdNav-style reference.

    python benchmarks/bench_sim.py [--quick] [--seconds 1.5] [--humans 5 10 20 50]

A full environment step is: human ORCA velocities, the robot's move, the swept robot-human
collision test, the reward (paper eq. 8) and the observation. The robot takes uniformly random
actions from the 81-action table (seeded generator); an environment whose episode ended is reset
with the next seed (1000, 1001, ...). Reset time is excluded from the timing on both sides (both
draw initial states with the same ``crowdplan.sim.scenarios.generate``).

crowdplan: ``World(config, E)`` with E = 1 and E = 64 environments stepped together (one Numba
ORCA solve for all humans of all environments), ``step`` + ``observe`` per batch step;
env-steps = E x batch steps.

Reference, the way CrowdNav (vita-epfl/CrowdNav, ``crowd_sim/envs/crowd_sim.py`` and
``crowd_sim/envs/policy/orca.py``) does it: Python ``Human`` objects; at each step, for each human,
the list of the other humans' observable states is built and the human's own ORCA policy object
runs one RVO2 ``doStep`` over that human plus all the others (robot invisible), reading back only
that human's new velocity. As in CrowdNav, each human's policy keeps its own ``RVOSimulator``
(created on the first step of the episode, then updated with ``set_agent_position`` /
``set_agent_velocity``); the human's preferred velocity points to its goal, the others' are (0, 0)
(CrowdNav: "unknown goal position of other humans"; agent 0's new velocity does not depend on
them). Then the Python loop over humans for the swept collision test, the reward and the
observation (a list of observable-state objects), as in ``crowd_sim.py`` (which, unlike
crowdplan, sweeps each human with its previous-step velocity; the cost is the same). CrowdNav's
debug-only human-human distance loop and its per-step state logging are left out (they would only
slow the reference). The "fresh sim" column is the costlier variant that builds a new
``RVOSimulator`` for every human at every step (``RVOSimulator(dt, 10, 10, 5, 5, r, v_max)`` + one
``add_agent`` per agent with its current velocity).

Rates are env-steps per second of this process's CPU time (``time.process_time``): on an idle
core that equals wall-clock time, and it is much steadier when other work shares the machine.

The two simulations are checked to agree: a few steps of both from the same seed and actions
give the same human positions up to RVO2's float32 rounding (printed).

Both sides run in this one process on one thread (Numba kernels are not parallel; BLAS threads
are pinned to 1), so "ratio per core" equals "ratio". Circle radius: 4 m for N <= 10, 8 m for
N = 20 and 12 m for N >= 50 (placement in a 4 m circle fails for dense crowds); both sides use the
same configs. Output: stdout only.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import math  # noqa: E402
import platform  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numba  # noqa: E402
import numpy as np  # noqa: E402

from crowdplan.config import WorldConfig  # noqa: E402
from crowdplan.sim import scenarios  # noqa: E402
from crowdplan.sim.actions import N_ACTIONS, action_table  # noqa: E402
from crowdplan.sim.world import (  # noqa: E402
    DISCOMFORT_SCALE,
    REWARD_COLLISION,
    REWARD_GOAL,
    RUNNING,
    TIMEOUT_REWARD_SCALE,
    World,
)

try:
    import pyrvo
except ImportError:  # optional: crowdplan[orca-ref]
    pyrvo = None

SEED_BASE = 1000
# CPU time of this (single-threaded) process: on an idle core it equals wall-clock time, and it
# is far less disturbed than wall-clock time when other work shares the machine.
CLOCK = time.process_time
BATCH_ENVS = 64


def config_for(humans: int) -> WorldConfig:
    """The benchmark scene: circle_crossing, radius enlarged for dense crowds."""
    radius = 4.0 if humans <= 10 else 8.0 if humans <= 20 else 12.0
    return WorldConfig(humans=humans, circle_radius=radius)


# ---------------------------------------------------------------------- crowdplan
def bench_crowdplan(config: WorldConfig, num_envs: int, seconds: float, seed: int = 0) -> float:
    """Env-steps per second of ``World.step`` + ``World.observe`` with autoreset (excluded)."""
    rng = np.random.default_rng(seed)
    world = World(config, num_envs)
    next_seed = SEED_BASE + num_envs
    world.reset(list(range(SEED_BASE, SEED_BASE + num_envs)))
    for _ in range(3):  # warm-up (loads the cached Numba kernels)
        world.step(rng.integers(0, N_ACTIONS, num_envs))
        world.observe()
    world.reset(list(range(SEED_BASE, SEED_BASE + num_envs)))
    steps = 0
    reset_time = 0.0
    start = CLOCK()
    while True:
        result = world.step(rng.integers(0, N_ACTIONS, num_envs))
        world.observe()
        steps += num_envs
        done = result.outcome != RUNNING
        if done.any():
            t0 = CLOCK()
            ids = np.flatnonzero(done)
            world.reset(list(range(next_seed, next_seed + len(ids))), ids)
            next_seed += len(ids)
            reset_time += CLOCK() - t0
        elapsed = CLOCK() - start
        if elapsed >= seconds:
            return steps / (elapsed - reset_time)


def bench_vector_api(humans: int, num_envs: int, seconds: float, seed: int = 0) -> dict:
    """Env-steps per second through ``gymnasium.make_vec`` (the native vector env: step, info,
    observation dict, same-step autoreset) and of ``World.step`` + ``observe`` with the same
    autoreset, each with the reset time included and excluded (resets timed on both sides)."""
    import gymnasium as gym

    import crowdplan  # noqa: F401  (registers the environments)

    env = gym.make_vec("crowdplan/CircleCrossing-v0", num_envs=num_envs, humans=humans)
    world = env.world
    reset_seconds = [0.0]
    world_reset = world.reset

    def timed_reset(*args, **kwargs):
        start = CLOCK()
        world_reset(*args, **kwargs)
        reset_seconds[0] += CLOCK() - start

    world.reset = timed_reset  # the vector env resets finished envs inside step()

    def vector_step(actions: np.ndarray) -> None:
        env.step(actions)

    def world_step(actions: np.ndarray) -> None:
        result = world.step(actions)
        world.observe()
        done = np.flatnonzero(result.outcome != RUNNING)
        if done.size:
            world.reset(np.arange(env.next_seed, env.next_seed + done.size), done)
            env.next_seed += done.size

    rates = {}
    for name, step in (("vector", vector_step), ("world", world_step)):
        rng = np.random.default_rng(seed)
        env.reset(seed=SEED_BASE)
        for _ in range(3):  # warm-up
            step(rng.integers(0, N_ACTIONS, num_envs))
        reset_seconds[0] = 0.0
        steps = 0
        start = CLOCK()
        while (elapsed := CLOCK() - start) < seconds:
            step(rng.integers(0, N_ACTIONS, num_envs))
            steps += num_envs
        rates[name] = (steps / elapsed, steps / (elapsed - reset_seconds[0]))
    env.close()
    return rates


# ---------------------------------------------------------------------- CrowdNav-style reference
@dataclass
class ObservableState:
    px: float
    py: float
    vx: float
    vy: float
    radius: float


@dataclass
class FullState:
    px: float
    py: float
    vx: float
    vy: float
    radius: float
    gx: float
    gy: float
    v_pref: float
    theta: float


@dataclass
class JointState:
    self_state: FullState
    human_states: list


class OrcaPolicy:
    """CrowdNav's ORCA policy: one RVO2 simulator per human, one ``doStep`` per prediction."""

    neighbor_dist, max_neighbors, time_horizon, time_horizon_obst = 10.0, 10, 5.0, 5.0
    radius, max_speed, radius_pad = 0.3, 1.0, 0.01

    def __init__(self, time_step: float, fresh_sim: bool) -> None:
        self.time_step = time_step
        self.fresh_sim = fresh_sim
        self.sim = None

    def predict(self, state: JointState) -> tuple[float, float]:
        me = state.self_state
        params = self.neighbor_dist, self.max_neighbors, self.time_horizon, self.time_horizon_obst
        if self.sim is not None and (
            self.fresh_sim or self.sim.get_num_agents() != len(state.human_states) + 1
        ):
            self.sim = None
        if self.sim is None:
            self.sim = pyrvo.RVOSimulator(self.time_step, *params, self.radius, self.max_speed)
            self.sim.add_agent(
                (me.px, me.py), *params, me.radius + self.radius_pad, me.v_pref, (me.vx, me.vy)
            )
            for other in state.human_states:
                self.sim.add_agent(
                    (other.px, other.py),
                    *params,
                    other.radius + self.radius_pad,
                    self.max_speed,
                    (other.vx, other.vy),
                )
        else:
            self.sim.set_agent_position(0, (me.px, me.py))
            self.sim.set_agent_velocity(0, (me.vx, me.vy))
            for i, other in enumerate(state.human_states):
                self.sim.set_agent_position(i + 1, (other.px, other.py))
                self.sim.set_agent_velocity(i + 1, (other.vx, other.vy))
        velocity = np.array((me.gx - me.px, me.gy - me.py))
        speed = np.linalg.norm(velocity)
        pref = velocity / speed if speed > 1 else velocity
        self.sim.set_agent_pref_velocity(0, tuple(pref))
        for i in range(len(state.human_states)):
            self.sim.set_agent_pref_velocity(i + 1, (0, 0))
        self.sim.do_step()
        v = self.sim.get_agent_velocity(0)
        return v.x, v.y


class Human:
    """CrowdNav's agent: a bag of floats and a policy."""

    def __init__(self, px, py, gx, gy, radius, v_pref, time_step, fresh_sim) -> None:
        self.px, self.py, self.gx, self.gy = px, py, gx, gy
        self.vx = self.vy = 0.0
        self.theta = 0.0
        self.radius, self.v_pref = radius, v_pref
        self.time_step = time_step
        self.policy = OrcaPolicy(time_step, fresh_sim)

    def get_observable_state(self) -> ObservableState:
        return ObservableState(self.px, self.py, self.vx, self.vy, self.radius)

    def get_full_state(self) -> FullState:
        return FullState(
            self.px,
            self.py,
            self.vx,
            self.vy,
            self.radius,
            self.gx,
            self.gy,
            self.v_pref,
            self.theta,
        )

    def act(self, ob: list) -> tuple[float, float]:
        return self.policy.predict(JointState(self.get_full_state(), ob))

    def step(self, action: tuple[float, float]) -> None:
        self.vx, self.vy = action
        self.px += self.vx * self.time_step
        self.py += self.vy * self.time_step


def point_to_segment_dist(x1, y1, x2, y2, x3, y3) -> float:
    """CrowdNav's helper: distance from (x3, y3) to the segment (x1, y1)-(x2, y2)."""
    px, py = x2 - x1, y2 - y1
    if px == 0 and py == 0:
        return float(np.linalg.norm((x3 - x1, y3 - y1)))
    u = ((x3 - x1) * px + (y3 - y1) * py) / (px * px + py * py)
    u = min(max(u, 0.0), 1.0)
    x, y = x1 + u * px, y1 + u * py
    return float(np.linalg.norm((x - x3, y - y3)))


class ReferenceEnv:
    """A CrowdNav-style environment (Python objects, per-human RVO2 solves)."""

    def __init__(self, config: WorldConfig, fresh_sim: bool = False) -> None:
        self.config = config
        self.fresh_sim = fresh_sim
        self.actions = action_table(config.robot_v_pref, config.kinematics, config.speed_sampling)

    def reset(self, seed: int) -> list:
        cfg = self.config
        init = scenarios.generate(cfg, seed)
        self.robot = Human(
            *init.robot_pos,
            *init.robot_goal,
            cfg.robot_radius,
            cfg.robot_v_pref,
            cfg.dt,
            self.fresh_sim,
        )
        self.robot.theta = math.pi / 2
        self.start_dist = float(np.linalg.norm(init.robot_goal - init.robot_pos))
        self.humans = [
            Human(
                *init.human_pos[i],
                *init.human_goal[i],
                float(init.human_radius[i]),
                float(init.human_v_pref[i]),
                cfg.dt,
                self.fresh_sim,
            )
            for i in range(cfg.humans)
        ]
        self.global_time = 0.0
        return [human.get_observable_state() for human in self.humans]

    def step(self, action: int):
        cfg = self.config
        speed, angle = self.actions[action]
        vx, vy = speed * math.cos(angle), speed * math.sin(angle)
        human_actions = []
        for human in self.humans:
            ob = [other.get_observable_state() for other in self.humans if other is not human]
            human_actions.append(human.act(ob))

        # Swept collision test: each human's motion relative to the robot during dt.
        dmin = float("inf")
        collision = False
        for human in self.humans:
            px = human.px - self.robot.px
            py = human.py - self.robot.py
            ex = px + (human.vx - vx) * cfg.dt
            ey = py + (human.vy - vy) * cfg.dt
            closest = point_to_segment_dist(px, py, ex, ey, 0, 0) - human.radius - self.robot.radius
            if closest < 0:
                collision = True
                break
            if closest < dmin:
                dmin = closest
        end = np.array((self.robot.px + vx * cfg.dt, self.robot.py + vy * cfg.dt))
        goal_dist = float(np.linalg.norm(end - np.array((self.robot.gx, self.robot.gy))))
        reaching_goal = goal_dist < self.robot.radius
        timeout = self.global_time + cfg.dt >= cfg.time_limit - 1e-9
        if collision:
            reward, done = REWARD_COLLISION, True
        elif reaching_goal:
            reward, done = REWARD_GOAL, True
        elif timeout:
            progress = (self.start_dist - goal_dist) / self.start_dist
            reward, done = TIMEOUT_REWARD_SCALE * progress, True
        elif dmin < cfg.discomfort_dist:
            reward, done = (dmin - cfg.discomfort_dist) * DISCOMFORT_SCALE, False
        else:
            reward, done = 0.0, False

        self.robot.step((vx, vy))
        for human, human_action in zip(self.humans, human_actions, strict=True):
            human.step(human_action)
        self.global_time += cfg.dt
        ob = [human.get_observable_state() for human in self.humans]
        return (self.robot.get_full_state(), ob), reward, done


def bench_reference(config: WorldConfig, seconds: float, fresh_sim: bool, seed: int = 0) -> float:
    """Env-steps per second of the reference environment with autoreset (excluded)."""
    rng = np.random.default_rng(seed)
    env = ReferenceEnv(config, fresh_sim)
    env.reset(SEED_BASE)
    for _ in range(2):
        env.step(int(rng.integers(N_ACTIONS)))
    env.reset(SEED_BASE)
    next_seed = SEED_BASE + 1
    steps = 0
    reset_time = 0.0
    start = CLOCK()
    while True:
        _, _, done = env.step(int(rng.integers(N_ACTIONS)))
        steps += 1
        if done:
            t0 = CLOCK()
            env.reset(next_seed)
            next_seed += 1
            reset_time += CLOCK() - t0
        elapsed = CLOCK() - start
        if elapsed >= seconds:
            return steps / (elapsed - reset_time)


def agreement(humans: int = 5, steps: int = 20, seed: int = SEED_BASE) -> float:
    """Largest human position difference between the two simulations over ``steps`` steps."""
    config = config_for(humans)
    world = World(config, 1)
    world.reset([seed])
    env = ReferenceEnv(config)
    env.reset(seed)
    worst = 0.0
    for _ in range(steps):
        world.step(np.array([0]))  # robot stands still: no early collision ends the episode
        env.step(0)
        ref = np.array([(h.px, h.py) for h in env.humans])
        worst = max(worst, float(np.abs(ref - world.human_pos[0]).max()))
    return worst


# ---------------------------------------------------------------------- main
def _version(package: str) -> str:
    from importlib import metadata

    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "missing"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="very short measurements (smoke test)")
    parser.add_argument(
        "--seconds",
        type=float,
        default=None,
        help="CPU seconds per measurement (default 1.5, --quick 0.1)",
    )
    parser.add_argument("--humans", type=int, nargs="+", default=[5, 10, 20, 50])
    args = parser.parse_args(argv)
    seconds = args.seconds if args.seconds is not None else (0.1 if args.quick else 1.5)
    if seconds <= 0:
        parser.error("--seconds must be positive")

    print("# Environment steps per second: crowdplan World vs CrowdNav-style reference\n")
    print(
        f"- python {platform.python_version()}, numpy {np.__version__}, numba {numba.__version__}"
        f", pyrvo {_version('pyrvo') if pyrvo is not None else 'missing'}; "
        f"{platform.machine()}, {os.cpu_count()} logical CPUs, "
        f"load average {os.getloadavg()[0]:.2f} at start"
    )
    print("- single process, single thread on both sides (ratio per core = ratio)")
    print("- circle_crossing; circle radius 4 m for N <= 10, 8 m for N = 20, 12 m for N >= 50")
    print(
        f"- random actions, autoreset with seeds {SEED_BASE}, {SEED_BASE + 1}, ... "
        "(reset time excluded); "
        f"{seconds:g} s of process CPU time per measurement (time.process_time; equals wall "
        "time on an idle core, steadier when other work shares the machine), after warm-up"
    )
    print(
        "- reference: CrowdNav scheme, one persistent RVO2 simulator per human, one doStep per "
        "human per step; 'fresh sim': a new RVOSimulator per human per step"
    )
    print(
        "- reference steps/s do not depend on E (its environments are independent Python "
        "objects stepped one after another): measured once per N"
    )
    if pyrvo is None:
        print(
            "\npyrvo is not installed (pip install --no-deps pyrvo==0.4.3, extra "
            "crowdplan[orca-ref]): reference columns are n/a."
        )
    else:
        print(
            f"- agreement check (N=5, 20 steps, same seed): max |human position difference| = "
            f"{agreement():.1e} m (RVO2 computes in float32)"
        )
    print()
    print(
        "| N | E | crowdplan steps/s | reference steps/s | ref. fresh-sim steps/s "
        "| ratio | ratio per core |"
    )
    print("|---:|---:|---:|---:|---:|---:|---:|")
    for humans in args.humans:
        config = config_for(humans)
        ref = ref_fresh = None
        if pyrvo is not None:
            ref = bench_reference(config, seconds, fresh_sim=False)
            ref_fresh = bench_reference(config, seconds, fresh_sim=True)
        for num_envs in (1, BATCH_ENVS):
            ours = bench_crowdplan(config, num_envs, seconds)
            if ref is None:
                cells = ["n/a", "n/a", "n/a", "n/a"]
            else:
                ratio = ours / ref
                cells = [f"{ref:,.0f}", f"{ref_fresh:,.0f}", f"{ratio:,.1f}x", f"{ratio:,.1f}x"]
            print(
                f"| {humans} | {num_envs} | {ours:,.0f} | " + " | ".join(cells) + " |", flush=True
            )

    humans = 5
    rates = bench_vector_api(humans, BATCH_ENVS, seconds)
    print(
        f"\n## Gymnasium vector API vs World (N={humans}, E={BATCH_ENVS}, same run)\n\n"
        "`gymnasium.make_vec('crowdplan/CircleCrossing-v0', num_envs=64)` (the native vector env) "
        "against `World.step` + `observe` with the same autoreset; resets timed on both sides.\n"
    )
    print("| path | steps/s, resets excluded | steps/s, resets included |")
    print("|---|---:|---:|")
    for name, label in (("world", "World.step + observe"), ("vector", "gymnasium vector API")):
        excluded, included = rates[name][1], rates[name][0]
        print(f"| {label} | {excluded:,.0f} | {included:,.0f} |")
    ratio = [rates["vector"][k] / rates["world"][k] for k in (1, 0)]
    print(f"| ratio vector API / World | {ratio[0]:.2f} | {ratio[1]:.2f} |", flush=True)


if __name__ == "__main__":
    main()
