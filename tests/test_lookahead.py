"""The batched one-step lookahead equals stepping a copy of the world, action by action."""

import copy
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from crowdplan.config import WorldConfig
from crowdplan.nets.value import make_value_network
from crowdplan.sim import initial_state
from crowdplan.sim.actions import N_ACTIONS
from crowdplan.sim.lookahead import (
    Timing,
    action_values,
    check_mode,
    next_humans,
    one_step,
    step_discount,
)
from crowdplan.sim.world import COLLISION, GOAL, TIMEOUT, StepResult, World


def _busy_world(config: WorldConfig) -> World:
    """Six environments a few steps in, arranged so that the candidates of one step reach the
    goal (env 0), collide and feel discomfort (env 1) and time out (env 2)."""
    world = World(config, 6)
    world.reset(np.arange(6) + 2000)
    rng = np.random.default_rng(0)
    for _ in range(3):
        world.step(rng.integers(0, N_ACTIONS, size=6))
    world.robot_pos[0] = world.robot_goal[0] - [0.0, 0.45]
    if config.humans:
        world.human_pos[1, 0] = world.robot_pos[1] + [0.7, 0.0]
        world.human_vel[1, 0] = 0.0
        world.human_kind[1, 0] = initial_state.STATIC
    world.steps[2] = config.max_steps - 1
    return world


def _stepped_copy(world: World, action: int, mode: str) -> tuple[World, StepResult]:
    shadow = copy.deepcopy(world)
    if mode == "constant_velocity":  # unsolved humans keep their velocity: constant velocity
        shadow.human_kind[:] = initial_state.STATIC
    return shadow, shadow.step(np.full(world.num_envs, action, dtype=np.int64))


CASES = [
    ({}, "constant_velocity"),
    ({}, "oracle"),
    ({"visible_robot": True}, "oracle"),
    ({"action_frame": "world"}, "constant_velocity"),
    ({"kinematics": "unicycle", "humans": 10}, "oracle"),
    ({"humans": 0}, "constant_velocity"),
]


@pytest.mark.parametrize(("options", "mode"), CASES)
def test_batched_lookahead_equals_stepping_the_world(options, mode):
    config = WorldConfig(**{"humans": 5, **options})
    world = _busy_world(config)
    robot, humans, mask = world.observe()
    before = copy.deepcopy(world.__dict__)
    timing = Timing(world.steps, world.start_dist, config.max_steps)
    cand = one_step(robot, humans, mask, config, mode, world, timing)
    for key, value in before.items():  # the lookahead leaves the world alone
        if isinstance(value, np.ndarray):
            assert np.array_equal(getattr(world, key), value), key
    outcomes = set()
    for action in range(N_ACTIONS):
        shadow, step = _stepped_copy(world, action, mode)
        next_robot, next_hum, next_mask = shadow.observe()
        np.testing.assert_allclose(cand.robot[:, action], next_robot, rtol=0, atol=1e-12)
        np.testing.assert_allclose(cand.humans, next_hum, rtol=0, atol=1e-12)
        assert np.array_equal(cand.mask, next_mask)
        np.testing.assert_allclose(cand.rewards[:, action], step.reward, rtol=0, atol=1e-12)
        assert np.array_equal(cand.outcome[:, action], step.outcome)
        outcomes.update(step.outcome.tolist())
    expected = {GOAL, TIMEOUT} if config.humans == 0 else {GOAL, TIMEOUT, COLLISION}
    assert expected <= outcomes
    if config.humans:
        assert (cand.rewards[1] < 0).any() and (cand.rewards[1] > -0.25).any()  # discomfort


def test_constant_velocity_ignores_the_world_and_oracle_needs_one():
    humans = np.array([[[1.0, 2.0, 0.5, -1.0, 0.3]]])
    mask = np.ones((1, 1), dtype=bool)
    moved, vel, next_mask = next_humans(humans, mask, 0.25)
    np.testing.assert_allclose(moved[0, 0], [1.125, 1.75, 0.5, -1.0, 0.3])
    np.testing.assert_allclose(vel, humans[..., 2:4])
    assert next_mask is mask
    with pytest.raises(ValueError, match="needs the world"):
        next_humans(humans, mask, 0.25, "oracle")
    with pytest.raises(ValueError, match="unknown lookahead 'psychic'"):
        check_mode("psychic")


def _sarl_candidates():
    """The candidates of a busy 3-human world, a fresh SARL network and the step discount."""
    config = WorldConfig(humans=3)
    world = _busy_world(config)
    torch.manual_seed(0)
    return (
        one_step(*world.observe(), config),
        make_value_network("sarl"),
        step_discount(0.9, config),
    )


def test_action_values_add_the_discounted_value_of_non_terminal_candidates():
    cand, net, gamma = _sarl_candidates()
    q = action_values(cand, net, gamma).numpy()
    with torch.no_grad():
        v, _ = net(*(torch.from_numpy(x) for x in cand.features))
    v = v.numpy().reshape(q.shape)
    expected = cand.rewards + np.where(cand.terminal, 0.0, gamma * v)
    np.testing.assert_allclose(q, expected, rtol=1e-5, atol=1e-6)
    assert cand.terminal[0].any()  # goal candidates are scored by their reward alone
    assert gamma == pytest.approx(0.9**0.25)


@pytest.mark.filterwarnings("error")
def test_action_values_of_an_empty_crowd_score_every_action_without_warnings():
    config = WorldConfig(humans=0)
    world = _busy_world(config)
    cand = one_step(*world.observe(), config)
    torch.manual_seed(0)
    q = action_values(cand, make_value_network("sarl"), step_discount(0.9, config)).numpy()
    assert q.shape == (6, N_ACTIONS) and np.isfinite(q).all()


def test_action_values_are_the_same_in_chunks_as_in_one_call(monkeypatch):
    from crowdplan.sim import lookahead

    cand, net, gamma = _sarl_candidates()
    one_call = action_values(cand, net, gamma)
    monkeypatch.setattr(lookahead, "PAIRS_PER_CALL", 1)  # chunks of STATES_ALIGNED states
    assert len(cand.features[0]) > 2 * lookahead.STATES_ALIGNED  # several, the last one short
    # bitwise on the machines measured (docs/benchmarks.md); the libraries do not promise it
    torch.testing.assert_close(action_values(cand, net, gamma), one_call, rtol=1e-6, atol=1e-7)


def test_bfloat16_action_values_round_the_value_call_only():
    cand, net, gamma = _sarl_candidates()
    q32 = action_values(cand, net, gamma).numpy()
    q16 = action_values(cand, net, gamma, precision="bfloat16").numpy()
    assert q16.dtype == q32.dtype and q16.shape == q32.shape
    # terminal candidates score their reward alone, whatever the precision
    np.testing.assert_array_equal(q16[cand.terminal], q32[cand.terminal])
    # bfloat16 keeps 8 mantissa bits: values of size ~0.1 move by ~1e-3, not more
    assert 0.0 < np.abs(q16 - q32).max() < 0.01
    with pytest.raises(ValueError, match="precision must be one of"):
        action_values(cand, net, gamma, precision="float16")


def test_compiled_value_network_gives_the_eager_values_at_any_batch_and_crowd_size():
    from crowdplan.sim.lookahead import compiled_value_network

    cand, net, gamma = _sarl_candidates()
    compiled = compiled_value_network(net)
    robot, humans, mask = cand.features
    for features in (cand.features, (robot[:7], humans[:7, :2], mask[:7, :2])):
        with torch.no_grad():
            eager, _ = net(*(torch.from_numpy(x) for x in features))
            fused, _ = compiled(*(torch.from_numpy(x) for x in features))
        torch.testing.assert_close(fused, eager, rtol=1e-5, atol=1e-6)  # float32 rounding only
    torch.testing.assert_close(
        action_values(cand, compiled, gamma), action_values(cand, net, gamma), rtol=1e-5, atol=1e-6
    )


def test_compiling_without_a_cpp_compiler_says_what_to_install(monkeypatch):
    from crowdplan.sim import lookahead

    monkeypatch.setattr(lookahead.shutil, "which", lambda name: None)
    with pytest.raises(RuntimeError, match="needs a C\\+\\+ compiler.*install one"):
        lookahead.compiled_value_network(make_value_network("sarl"))


def test_bench_lookahead_quick():
    script = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_lookahead.py"
    args = ["--quick", "--humans", "2", "--envs", "2", "--threads", "2"]
    result = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    row = next(line for line in result.stdout.splitlines() if line.startswith("| 2 | 2 |"))
    assert float(row.split("|")[-2]) < 1e-5  # batched and reference action values agree
    threads_table = result.stdout.split("1 and 2 torch threads")[1]
    row = next(line for line in threads_table.splitlines() if line.startswith("| 2 | 2 |"))
    assert re.fullmatch(r"\d+\.\d\dx (faster|slower)", row.split("|")[-2].strip())
