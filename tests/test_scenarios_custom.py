"""Custom scenarios (files and the InitialState protocol), crowd mixtures, N = 0 and N = 50."""

import numpy as np
import pytest
import torch

from crowdplan import evaluation
from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.features import robot_centric
from crowdplan.nets.encoders import ENCODER_NAMES, EncoderConfig, make_encoder
from crowdplan.sim import initial_state, scenarios
from crowdplan.sim.env import CrowdNavEnv
from crowdplan.sim.scenario_file import ScenarioFileError, load_scenes, save_scenes
from crowdplan.sim.world import World

SCENE = """\
scenes:
  - robot: {start: [0, -4], goal: [0, 4]}
    humans:
      - {start: [3, 0], goal: [-3, 0]}
      - {start: [-3, 1], goal: [3, 1], kind: social_force, radius: 0.4, v_pref: 1.2}
      - {start: [0.9, 4.5], kind: static}
      - {start: [2, 2], goal: [-2, -2], kind: waiting, wait: [2.0, 5.0]}
  - robot: {start: [1, 1], goal: [-5, 2], heading: 0.5}
"""


def write(tmp_path, text):
    path = tmp_path / "scenes.yaml"
    path.write_text(text)
    return path


def test_file_round_trip(tmp_path):
    config = WorldConfig(
        humans=6, social_force_fraction=0.3, static_fraction=0.2, waiting_fraction=0.2
    )
    states = [scenarios.generate(config, seed) for seed in (1000, 1001, 1002)]
    path = tmp_path / "out" / "scenes.yaml"
    save_scenes(path, states)
    loaded = load_scenes(path, config)
    for a, b in zip(states, loaded, strict=True):
        for name in ("robot_pos", "robot_goal", "human_pos", "human_goal", "human_radius"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        np.testing.assert_array_equal(a.human_v_pref, b.human_v_pref)
        np.testing.assert_array_equal(a.kinds(), b.kinds())
        np.testing.assert_array_equal(a.waits(), b.waits())
    assert {initial_state.SOCIAL_FORCE, initial_state.STATIC, initial_state.WAITING} <= set(
        np.concatenate([s.kinds() for s in states]).tolist()
    )


def test_custom_scenario_through_world_env_and_evaluation(tmp_path):
    path = write(tmp_path, SCENE)
    scenes = load_scenes(path)
    assert scenes[0].kinds().tolist() == [0, 1, 2, 3] and scenes[1].humans == 0
    np.testing.assert_array_equal(scenes[0].human_goal[2], [0.9, 4.5])  # standing: goal = start
    config = WorldConfig(scenario="custom", scenario_file=str(path), humans=4)
    world = World(config, 2)
    world.reset([0, 1])
    np.testing.assert_array_equal(world.robot_pos, [[0, -4], [1, 1]])
    assert world.robot_theta[1] == 0.5
    assert world.observe()[2].tolist() == [[True] * 4, [False] * 4]
    env = CrowdNavEnv(scenario="custom", humans=4, max_humans=6, scenario_file=str(path))
    obs, _ = env.reset(seed=0)
    assert obs["mask"].tolist() == [1, 1, 1, 1, 0, 0]
    env.step(5)
    records = evaluation.run_episodes(OrcaPlanner(), config, [0, 1, 2, 3])
    assert [r.outcome for r in records][1] == "goal"  # the empty scene
    assert records[0].trace is None and len(records) == 4


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (
            SCENE.replace("[0.9, 4.5]", "[0.1, 4.2]"),
            r"line 2, scene 0: the robot's goal is inside standing human 2 .*line 6.*move",
        ),
        (
            SCENE.replace("[3, 0], goal", "[0.2, -3.8], goal"),
            r"line 4, scene 0, human 0 starts overlapping the robot.*move the starts",
        ),
        (SCENE.replace("kind: static", "kind: ghost"), r"line 6.*kind must be one of"),
        (SCENE.replace("radius: 0.4", "size: 0.4"), r"line 5.*unknown key\(s\) \['size'\]"),
        (SCENE.replace("goal: [-3, 0]", "goal: [-3]"), r"line 4.*goal: expected a point"),
        (SCENE.replace("goal: [0, 4]", "goal: [0, -4]"), r"line 2.*within its radius"),
        ("scenes: []\n", r"'scenes' is empty"),
        ("robot: {}\n", r"one key, 'scenes'"),
    ],
    ids=["goal-in-human", "overlap", "kind", "key", "point", "goal-at-start", "empty", "layout"],
)
def test_bad_scenario_files_name_file_line_and_fix(tmp_path, text, pattern):
    path = write(tmp_path, text)
    with pytest.raises(ScenarioFileError, match=pattern) as error:
        load_scenes(path)
    assert str(path) in str(error.value)


def test_too_many_humans_for_the_world_and_nothing_written_half(tmp_path):
    path = write(tmp_path, SCENE)
    world = World(WorldConfig(scenario="custom", scenario_file=str(path), humans=3), 2)
    before = world.robot_pos.copy()
    with pytest.raises(ScenarioFileError, match=r"has 4 humans .* set humans to 4"):
        world.reset([1, 0])  # the second scene is bad: the first environment is not touched
    np.testing.assert_array_equal(world.robot_pos, before)
    with pytest.raises(ValueError, match="scenario 'custom' needs scenario_file"):
        WorldConfig(scenario="custom")
    target = tmp_path / "kept.yaml"
    target.write_text("scenes: []\n")
    bad = scenarios.generate(WorldConfig(scenario="replay", humans=10), 1000)
    with pytest.raises(ValueError, match="replayed humans cannot be written"):
        save_scenes(target, [bad])
    assert target.read_text() == "scenes: []\n"


def test_mixture_options_are_pure_functions_of_the_seed():
    config = WorldConfig(
        humans=10,
        humans_min=0,
        social_force_fraction=0.3,
        static_fraction=0.2,
        random_goal_direction=True,
        randomize_attributes=True,
    )
    states = [scenarios.generate(config, s) for s in range(2000, 2030)]
    again = [scenarios.generate(config, s) for s in range(2000, 2030)]
    counts = {s.humans for s in states}
    assert len(counts) > 4 and min(counts) >= 0 and max(counts) <= 10
    for a, b in zip(states, again, strict=True):
        np.testing.assert_array_equal(a.human_pos, b.human_pos)
        np.testing.assert_array_equal(a.robot_goal, b.robot_goal)
        assert np.hypot(*a.robot_goal) == pytest.approx(4.0)
    angles = [np.arctan2(*s.robot_goal[::-1]) for s in states]
    assert np.ptp(angles) > 3.0  # goals in many directions
    # The paper's cases are unchanged by the options that draw from their own streams.
    plain = scenarios.generate(WorldConfig(humans=5), 1000)
    turned = scenarios.generate(WorldConfig(humans=5, goal_rotation=90.0), 1000)
    np.testing.assert_allclose(turned.human_pos, plain.human_pos @ [[0, 1], [-1, 0]], atol=1e-12)
    world = World(config, 3)
    world.reset([2000, 2001, 2002])
    for _ in range(20):
        world.step(np.array([5, 5, 5]))


@pytest.mark.parametrize("n", [0, 50])
def test_zero_and_fifty_humans_through_world_encoders_and_evaluation(n):
    radius = 4.0 if n == 0 else 12.0
    config = WorldConfig(humans=n, circle_radius=radius)
    world = World(config, 2)
    world.reset([1000, 1001])
    robot, humans, mask = world.observe()
    feats = robot_centric(robot, humans, mask)
    tensors = [torch.from_numpy(x) for x in feats]
    torch.manual_seed(0)
    for name in ENCODER_NAMES:
        encoder = make_encoder(EncoderConfig(name=name, max_humans=max(n, 1)))
        out, _ = encoder(*tensors)
        assert out.shape[0] == 2 and torch.isfinite(out).all(), name
    records = evaluation.run_episodes(OrcaPlanner(), config, [1000, 1001])
    summary = evaluation.summarize(records)
    assert summary["episodes"]["value"] == 2
    if n == 0:
        assert all(r.outcome == "goal" for r in records)
