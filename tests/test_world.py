"""World, scenarios, reward and options (SPEC.md sections 1-2)."""

import numpy as np
import pytest

from crowdplan.config import WorldConfig
from crowdplan.sim import initial_state, scenarios
from crowdplan.sim.actions import N_ACTIONS, action_table, speed_levels
from crowdplan.sim.world import (
    COLLISION,
    GOAL,
    RUNNING,
    TIMEOUT,
    World,
    compute_reward,
    point_to_segment_distance,
)


def test_action_table_layout():
    table = action_table()
    assert table.shape == (N_ACTIONS, 2) == (81, 2)
    assert table[0, 0] == 0.0  # stop
    np.testing.assert_allclose(table[1:6, 0], [0.2, 0.4, 0.6, 0.8, 1.0])
    np.testing.assert_allclose(np.unique(table[1:, 1]), np.arange(16) * np.pi / 8)


def test_exponential_speeds_match_crowdnav():
    expected = [(np.exp(i / 5) - 1) / (np.e - 1) for i in range(1, 6)]
    np.testing.assert_allclose(speed_levels(1.0, "exponential"), expected)


def test_circle_crossing_rules():
    cfg = WorldConfig(humans=5)
    for seed in range(20):
        init = scenarios.generate(cfg, seed)
        np.testing.assert_allclose(init.human_goal, -init.human_pos)
        radius = np.hypot(*init.human_pos.T)
        assert np.all(np.abs(radius - 4.0) <= np.sqrt(2) * 0.5 + 1e-9)
        agents = np.vstack([init.robot_pos, init.human_pos])
        goals = np.vstack([init.robot_goal, init.human_goal])
        for i in range(1, 6):  # each human vs every agent placed before it
            for j in range(i):
                assert np.linalg.norm(agents[i] - agents[j]) >= 0.8 - 1e-12
                assert np.linalg.norm(agents[i] - goals[j]) >= 0.8 - 1e-12


def test_circle_radius_follows_crowd_size():
    # 0-10 humans on a 5 m circle, never smaller than 4 m: the robot starts at -R(n)
    cfg = WorldConfig(humans=10, humans_min=0, circle_radius=5.0, circle_radius_min=4.0)
    seen = {}
    for seed in range(200):
        init = scenarios.generate(cfg, seed)
        seen[len(init.human_pos)] = -init.robot_pos[1]
    assert seen[10] == 5.0
    assert seen[7] == pytest.approx(5.0 * np.sqrt(0.7))
    assert all(seen[n] == 4.0 for n in range(7))
    # without a minimum, or with the full crowd, the scene is the one without the option
    fixed = WorldConfig(humans=10, circle_radius=5.0)
    np.testing.assert_array_equal(
        scenarios.generate(fixed, 3).human_pos,
        scenarios.generate(fixed.replace(circle_radius_min=4.0), 3).human_pos,
    )
    # square_crossing keeps its robot at circle_radius whatever the crowd
    square = cfg.replace(scenario="square_crossing")
    assert all(scenarios.generate(square, seed).robot_pos[1] == -5.0 for seed in range(20))


def test_plain_episodes_have_nominal_orca_humans():
    mixed = WorldConfig(
        humans=5,
        randomize_attributes=True,
        social_force_fraction=0.3,
        static_fraction=0.1,
        waiting_fraction=0.1,
        plain_fraction=0.5,
    )
    plain = mixed.replace(randomize_attributes=False, social_force_fraction=0.0)
    plain = plain.replace(static_fraction=0.0, waiting_fraction=0.0, plain_fraction=0.0)
    nominal = 0
    for seed in range(100):
        init = scenarios.generate(mixed, seed)
        if np.all(init.human_radius == 0.3) and np.all(init.human_kind == 0):
            nominal += 1
            # a plain episode is the scene of the world without the mixture options
            expected = scenarios.generate(plain, seed)
        else:  # any other is the scene of the mixture without plain episodes
            expected = scenarios.generate(mixed.replace(plain_fraction=0.0), seed)
        np.testing.assert_array_equal(init.human_pos, expected.human_pos)
        np.testing.assert_array_equal(init.human_kind, expected.human_kind)
    assert 35 <= nominal <= 65


def test_square_crossing_sides():
    cfg = WorldConfig(scenario="square_crossing", humans=5)
    for seed in range(20):
        init = scenarios.generate(cfg, seed)
        assert np.all(np.abs(init.human_pos) <= 5.0)
        # start and goal on opposite sides of x = 0
        assert np.all(np.sign(init.human_pos[:, 0]) != np.sign(init.human_goal[:, 0]))


def test_episode_is_pure_function_of_seed():
    cfg = WorldConfig(humans=5)
    a, b = scenarios.generate(cfg, 1003), scenarios.generate(cfg, 1003)
    np.testing.assert_array_equal(a.human_pos, b.human_pos)
    assert not np.array_equal(a.human_pos, scenarios.generate(cfg, 1004).human_pos)


def test_randomized_attributes_ranges():
    cfg = WorldConfig(humans=5, randomize_attributes=True)
    init = scenarios.generate(cfg, 7)
    assert np.all((init.human_v_pref >= 0.5) & (init.human_v_pref <= 1.5))
    assert np.all((init.human_radius >= 0.3) & (init.human_radius <= 0.5))
    assert len(np.unique(init.human_radius)) == 5


def test_point_to_segment_distance():
    start = np.array([[1.0, 1.0], [-2.0, 0.0], [3.0, 4.0]])
    end = np.array([[1.0, -1.0], [-1.0, 0.0], [3.0, 4.0]])
    np.testing.assert_allclose(point_to_segment_distance(start, end), [1.0, 1.0, 5.0])


def test_swept_collision_catches_pass_through():
    """A human that crosses the robot within one step collides even though both ends are far."""
    world = World(WorldConfig(humans=1))
    world.reset([0])
    world.robot_pos[:] = [0.0, 0.0]
    world.robot_goal[:] = [0.0, 4.0]
    world.human_pos[:] = [[[-0.6, 0.0]]]
    world.human_goal[:] = [[[10.0, 0.0]]]
    world.human_vel[:] = [[[1.0, 0.0]]]
    world.human_v_pref[:] = 5.0  # allow a fast human: it moves 1.25 m in one step
    world.human_vel[:] = [[[5.0, 0.0]]]
    result = world.step(np.array([0]))
    assert result.outcome[0] == COLLISION
    assert result.reward[0] == pytest.approx(-0.25)


def test_reward_priorities_and_values():
    outcome = np.array([COLLISION, GOAL, TIMEOUT, RUNNING, RUNNING, RUNNING])
    d_min = np.array([-0.1, 0.05, 0.05, 0.1, 0.3, np.inf])
    start = np.full(6, 8.0)
    goal_dist = np.array([1.0, 0.1, 2.0, 5.0, 5.0, 5.0])
    reward = compute_reward(outcome, d_min, start, goal_dist, 0.2)
    np.testing.assert_allclose(reward, [-0.25, 1.0, 0.5 * 6 / 8, -0.1 + 0.05, 0.0, 0.0])


@pytest.mark.parametrize(
    ("frame", "straight"),
    [("world", 1 + 4 * 5 + 4), ("goal", 1 + 0 * 5 + 4)],  # pi/2 absolute / 0 from the goal
)
def test_goal_and_timeout(frame, straight):
    world = World(WorldConfig(humans=0, action_frame=frame))
    world.reset([0])
    outcomes = [world.step(np.array([straight])).outcome[0] for _ in range(31)]
    assert outcomes[-1] == GOAL and all(o == RUNNING for o in outcomes[:-1])
    world.reset([0])
    for _ in range(99):
        assert world.step(np.array([0])).outcome[0] == RUNNING
    result = world.step(np.array([0]))
    assert result.outcome[0] == TIMEOUT and result.truncated[0] and not result.terminated[0]
    assert result.reward[0] == pytest.approx(0.0)  # no progress


def test_invisible_robot_is_ignored_by_humans_and_visible_robot_is_not():
    def human_velocity(visible):
        world = World(WorldConfig(humans=1, visible_robot=visible))
        world.reset([0])
        world.robot_pos[:] = [0.0, 0.0]
        world.human_pos[:] = [[[0.0, 1.0]]]
        world.human_goal[:] = [[[0.0, -4.0]]]
        world.step(np.array([0]))
        return world.human_vel[0, 0]

    np.testing.assert_allclose(human_velocity(False), [0.0, -1.0], atol=1e-9)
    assert np.linalg.norm(human_velocity(True) - [0.0, -1.0]) > 1e-3


def test_unicycle_rotates_heading():
    world = World(WorldConfig(humans=0, kinematics="unicycle"))
    world.reset([0])
    table = world.actions
    last = N_ACTIONS - 1  # rotation +pi/4, full speed
    world.step(np.array([last]))
    assert world.robot_theta[0] == pytest.approx(np.pi / 2 + table[last, 1])
    np.testing.assert_allclose(
        world.robot_vel[0], [np.cos(3 * np.pi / 4), np.sin(3 * np.pi / 4)], atol=1e-12
    )


def test_respawn_on_arrival_gives_new_goal():
    cfg = WorldConfig(humans=1, respawn_on_arrival=True)
    world = World(cfg)
    world.reset([3])
    world.human_goal[0, 0] = world.human_pos[0, 0] + [0.05, 0.0]
    old_goal = world.human_goal[0, 0].copy()
    world.step(np.array([0]))
    assert not np.allclose(world.human_goal[0, 0], old_goal)
    stay = World(WorldConfig(humans=1))
    stay.reset([3])
    stay.human_goal[0, 0] = stay.human_pos[0, 0] + [0.05, 0.0]
    goal = stay.human_goal[0, 0].copy()
    stay.step(np.array([0]))
    np.testing.assert_array_equal(stay.human_goal[0, 0], goal)


def test_inactive_envs_are_frozen():
    world = World(WorldConfig(humans=3), num_envs=2)
    world.reset([1000, 1001])
    before = world.human_pos[1].copy()
    world.step(np.array([5, 5]), active=np.array([True, False]))
    np.testing.assert_array_equal(world.human_pos[1], before)
    assert world.steps.tolist() == [1, 0]


def test_batched_equals_single():
    cfg = WorldConfig(humans=5)
    batched = World(cfg, num_envs=3)
    batched.reset([1000, 1001, 1002])
    singles = [World(cfg) for _ in range(3)]
    for w, seed in zip(singles, [1000, 1001, 1002], strict=True):
        w.reset([seed])
    rng = np.random.default_rng(0)
    for _ in range(20):
        actions = rng.integers(0, 81, size=3)
        batched.step(actions)
        for k, w in enumerate(singles):
            w.step(actions[k : k + 1])
    for k, w in enumerate(singles):
        np.testing.assert_allclose(batched.human_pos[k], w.human_pos[0], atol=1e-12)


@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"scenario": "hexagon"}, "scenario must be one of"),
        ({"humans": -1}, "humans must be an integer >= 0"),
        ({"robot_radius": 0.0}, "robot_radius must be a positive number"),
        ({"human_v_pref": -1.0}, "human_v_pref must be a positive number"),
        ({"kinematics": "car"}, "kinematics must be one of"),
        ({"speed_sampling": "log"}, "speed_sampling must be one of"),
        ({"bogus": 1}, "unknown key(s) ['bogus']"),
        ({"plain_fraction": 1.5}, "plain_fraction must be in [0, 1], got 1.5"),
        ({"circle_radius_min": 4.5}, "circle_radius_min must be in (0, circle_radius = 4.0]"),
        (
            {"circle_radius_min": 3.0, "respawn_on_arrival": True},
            "circle_radius_min and respawn_on_arrival do not combine",
        ),
    ],
)
def test_bad_config_is_named(changes, fragment):
    with pytest.raises(ValueError, match=None) as error:
        WorldConfig().replace(**changes)
    assert fragment in str(error.value)


def test_unplaceable_crowd_gives_up_quickly():
    cfg = WorldConfig(humans=60, placement_tries=50)
    with pytest.raises(initial_state.PlacementError, match="placement_tries"):
        scenarios.generate(cfg, 0)


@pytest.mark.parametrize("seed", [1.5, "3", -1, None, True])
def test_bad_seed(seed):
    with pytest.raises(TypeError, match="seed must be a non-negative integer"):
        World(WorldConfig()).reset([seed])


@pytest.mark.parametrize("action", [-1, 81])
def test_action_out_of_range(action):
    world = World(WorldConfig())
    world.reset([0])
    with pytest.raises(ValueError, match=r"outside the valid range 0\.\.80"):
        world.step(np.array([action]))


@pytest.mark.parametrize("humans", [0, 1, 2, 3, 4, 5, 10, 50])
def test_any_crowd_size_runs(humans):
    cfg = WorldConfig(humans=humans, circle_radius=4.0 if humans <= 10 else 12.0)
    world = World(cfg, num_envs=2)
    world.reset([1000, 1001])
    for _ in range(5):
        result = world.step(np.array([3, 7]))
    assert result.reward.shape == (2,)
    assert np.all(np.isfinite(world.human_pos))
