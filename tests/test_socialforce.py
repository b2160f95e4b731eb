"""Social-force humans against the published equations, by hand on 2- and 3-agent scenes."""

import math

import numpy as np
import pytest

from crowdplan.config import SocialForceConfig, WorldConfig
from crowdplan.sim import initial_state
from crowdplan.sim.initial_state import InitialState
from crowdplan.sim.socialforce import social_force_velocities
from crowdplan.sim.world import World

P = SocialForceConfig()  # tau 0.5, a 2.1, b 0.3, lam 0.35, cap 1.3 v_pref
DT = 0.25


def step(pos, vel, pref, radii, solve, params=P, v_pref=None):
    m = len(pos)
    v_pref = np.ones(m) if v_pref is None else np.asarray(v_pref)
    return social_force_velocities(
        np.array([pos], float),
        np.array([vel], float),
        np.array([pref], float),
        np.array([radii], float),
        v_pref[None],
        np.ones((1, m), bool),
        np.array([solve]),
        DT,
        params,
    )[0]


def repulsion(a_pos, b_pos, r_sum, desired, params=P):
    """a * exp((r_i + r_j - d) / b) * n_ji * (lam + (1 - lam) (1 + cos phi) / 2), by hand."""
    dx, dy = a_pos[0] - b_pos[0], a_pos[1] - b_pos[1]
    d = math.hypot(dx, dy)
    nx, ny = dx / d, dy / d
    ex, ey = desired
    cos_phi = -(ex * nx + ey * ny)
    w = params.lam + (1 - params.lam) * (1 + cos_phi) / 2
    mag = params.a * math.exp((r_sum - d) / params.b) * w
    return mag * nx, mag * ny


def test_two_agents_head_on():
    # Agent 0 walks east towards agent 1, who stands 1 m ahead: driving force 1/tau = 2 east,
    # repulsion 2.1 * exp((0.6 - 1) / 0.3) west (cos phi = 1, full weight).
    new = step([[0, 0], [1, 0]], [[0, 0], [0, 0]], [[1, 0], [0, 0]], [0.3, 0.3], [True, False])
    push = 2.1 * math.exp(-0.4 / 0.3)
    assert new[0] == pytest.approx([(2.0 - push) * DT, 0.0], abs=1e-12)
    np.testing.assert_array_equal(new[1], [0.0, 0.0])  # not solved: keeps its velocity


def test_three_agents_with_anisotropy_and_current_velocity():
    pos = [[0.0, 0.0], [0.9, 0.5], [-0.4, -0.8]]
    vel = [[0.3, 0.1], [0.0, 0.0], [0.2, 0.2]]
    pref = [[0.6, 0.8], [0.0, 0.0], [0.0, 0.0]]
    radii = [0.3, 0.4, 0.35]
    new = step(pos, vel, pref, radii, [True, False, False])
    fx = (0.6 - 0.3) / P.tau
    fy = (0.8 - 0.1) / P.tau
    for j in (1, 2):
        rx, ry = repulsion(pos[0], pos[j], radii[0] + radii[j], (0.6, 0.8))
        fx, fy = fx + rx, fy + ry
    assert new[0] == pytest.approx([0.3 + fx * DT, 0.1 + fy * DT], abs=1e-12)
    # Behind the agent (cos phi < 0) the weight is smaller than in front.
    front = repulsion((0, 0), (1, 0), 0.6, (1, 0))[0]
    back = repulsion((0, 0), (-1, 0), 0.6, (1, 0))[0]
    assert abs(back) == pytest.approx(P.lam * abs(front))


def test_speed_cap_and_isotropic_force():
    new = step([[0, 0]], [[0, 0]], [[1, 0]], [0.3], [True], SocialForceConfig(tau=0.01))
    assert np.hypot(*new[0]) == pytest.approx(1.3)
    iso = SocialForceConfig(lam=1.0)
    a = step([[0, 0], [0, 1]], [[0, 0], [0, 0]], [[1, 0], [0, 0]], [0.3, 0.3], [True, False], iso)
    push = 2.1 * math.exp(-0.4 / 0.3)
    assert a[0] == pytest.approx([2.0 * DT, -push * DT], abs=1e-12)


def test_social_force_humans_in_the_world():
    """The world moves a social-force human with the same equations (robot invisible)."""
    state = InitialState(
        robot_pos=np.array([0.0, -4.0]),
        robot_goal=np.array([0.0, 4.0]),
        human_pos=np.array([[-3.0, 0.0], [0.0, 0.2]]),
        human_goal=np.array([[3.0, 0.0], [0.0, 0.2]]),
        human_radius=np.array([0.3, 0.3]),
        human_v_pref=np.array([1.0, 1.0]),
        human_kind=np.array([initial_state.SOCIAL_FORCE, initial_state.STATIC]),
    )
    world = World(WorldConfig(humans=2))
    world.reset_states([state])
    for _ in range(3):
        pos, vel = world.human_pos[0].copy(), world.human_vel[0].copy()
        to_goal = np.array([3.0, 0.0]) - pos[0]
        pref = np.array([to_goal / np.hypot(*to_goal), [0.0, 0.0]])
        expected = step(pos, vel, pref, [0.3, 0.3], [True, False])
        world.step(np.array([0]))
        np.testing.assert_allclose(world.human_vel[0], expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(world.human_pos[0], pos + expected * 0.25, rtol=0, atol=1e-12)
    for _ in range(40):
        world.step(np.array([0]))
    # It passed the standing human without touching it, and the standing human never moved.
    assert world.human_pos[0, 0, 0] > 1.0
    np.testing.assert_array_equal(world.human_pos[0, 1], [0.0, 0.2])


def test_waiting_human_stops_then_resumes():
    config = WorldConfig(humans=1, waiting_fraction=1.0, wait_after=1.0, wait_for=2.0)
    world = World(config)
    world.reset([1000])
    speeds = []
    for _ in range(16):
        world.step(np.array([0]))
        speeds.append(np.hypot(*world.human_vel[0, 0]))
    # Steps start at t = 0, 0.25, ...: the stop covers t in [1, 3): ORCA brings it to rest.
    assert speeds[1] > 0.9 and max(speeds[5:12]) < 1e-9 and speeds[14] > 0.9
