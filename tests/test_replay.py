"""Replay of recorded pedestrians: reading, time bases, interpolation, placement, bad files."""

import numpy as np
import pytest

from crowdplan.config import WorldConfig
from crowdplan.sim import initial_state, replay, scenarios
from crowdplan.sim.initial_state import PlacementError
from crowdplan.sim.replay import (
    ETH_SECONDS_PER_FRAME,
    HELD_OUT,
    TrajectoryFileError,
    interpolate,
    load_recording,
    place_case,
)
from crowdplan.sim.world import World


def write(tmp_path, text, name="peds.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


def test_interpolation_at_the_world_time_step(tmp_path):
    # One pedestrian at 1 m/s along x, rows every 10 frame ids = 0.4 s (hotel / UCY time base).
    rows = "".join(f"{10 * k}\t1.0\t{0.4 * k}\t2.0\n" for k in range(6))
    rec = load_recording(write(tmp_path, rows), 0.04)
    times = np.arange(9) * 0.25
    pos, present = interpolate(rec, 0, times)
    np.testing.assert_allclose(pos[:, 0], np.minimum(times, 2.0), atol=1e-12)
    np.testing.assert_array_equal(pos[:, 1], 2.0)
    assert present.tolist() == [True] * 9  # 0 .. 2.0 s
    pos, present = interpolate(rec, 0, np.array([-0.25, 2.25]))
    assert present.tolist() == [False, False]  # before its first and after its last row


def test_eth_time_base_gives_walking_speeds():
    """eth rows are 10/15 s apart (0.4/6 s per frame id); read at 0.4 s they would be too fast."""
    rec = replay.scene_recording("eth")
    pairs = zip(rec.times, rec.positions, strict=True)
    speeds = np.concatenate([np.hypot(*np.diff(p, axis=0).T) / np.diff(t) for t, p in pairs])
    assert 1.3 < np.median(speeds) < 1.6
    assert np.median(speeds) * ETH_SECONDS_PER_FRAME / 0.04 > 2.2  # the wrong time base
    hotel = replay.scene_recording("hotel")
    assert np.diff(hotel.times[0])[0] == pytest.approx(0.4)


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        (
            "0\t1\t0\t0\n10\t1\t0.4\t0\n30\t1\t1.2\t0\n",
            r"line 3: pedestrian 1 jumps from frame 10 to 30.*fill",
        ),
        ("0\t1\t0\t0\n0\t1\t0.1\t0\n", r"line 2: pedestrian 1 appears twice in frame 0.*remove"),
        ("10\t1\t0\t0\n0\t2\t0\t0\n", r"line 2: frame 0 comes after frame 10.*sort the file"),
        ("0\t1\t0\t0\t7\n", r"line 1: expected 4 columns.*got 5.*keep only"),
        ("frame\tid\tx\ty\n", r"line 1: .* is not four numbers.*'#'"),
        ("# only a comment\n", r"holds no trajectory rows"),
    ],
    ids=["gap", "duplicate", "non-monotonic", "unknown-column", "header", "empty"],
)
def test_bad_trajectory_files_name_file_line_and_fix(tmp_path, text, pattern):
    path = write(tmp_path, text)
    with pytest.raises(TrajectoryFileError, match=pattern) as error:
        load_recording(path, 0.04)
    assert str(path) in str(error.value)


def test_too_few_pedestrians_to_place_a_case(tmp_path):
    rows = "".join(f"{10 * k}\t1\t{0.4 * k}\t0\n" for k in range(100))
    rec = load_recording(write(tmp_path, rows), 0.04)
    config = WorldConfig(scenario="replay", humans=10, placement_tries=20)
    with pytest.raises(PlacementError, match=r"peds\.txt.*replay_min_humans=3.*lower"):
        place_case(config, rec, np.random.default_rng(0))


def test_replay_cases_are_deterministic_and_cross_the_flow():
    config = WorldConfig(scenario="replay", humans=10)
    for seed in range(1000, 1010):
        a, b = scenarios.generate(config, seed), scenarios.generate(config, seed)
        np.testing.assert_array_equal(a.track, b.track)
        assert 3 <= a.humans <= 10
        np.testing.assert_array_equal(a.robot_pos, [0.0, -4.0])
        np.testing.assert_array_equal(a.robot_goal, [0.0, 4.0])
        assert np.all(a.kinds() == initial_state.REPLAY)
        # Each replayed pedestrian comes within 2 m of the robot's path at some step.
        near = (np.abs(a.track[..., 0]) < 2.0) & (np.abs(a.track[..., 1]) <= 4.0 + 2.0)
        assert np.all((near & a.track_present).any(axis=1))
        # The start is clear of every pedestrian present at time 0.
        gap = np.hypot(*(a.track[:, 0] - a.robot_pos).T) - 0.6
        assert np.all(gap[a.track_present[:, 0]] >= 0.2)


def test_replayed_humans_follow_their_tracks_and_ignore_the_robot():
    config = WorldConfig(scenario="replay", humans=10, visible_robot=True)
    state = scenarios.generate(config, 1004)
    world = World(config)
    world.reset([1004])
    for step in range(1, 40):
        world.step(np.array([5]))  # straight to the goal, whatever is there
        np.testing.assert_allclose(world.human_pos[0], state.track[:, step], atol=1e-12)
        np.testing.assert_array_equal(world.human_present[0], state.track_present[:, step])
        _, _, mask = world.observe()
        np.testing.assert_array_equal(mask[0], state.track_present[:, step])
        if world.steps[0] < step:
            break


def test_held_out_scenes_are_named_and_shipped():
    assert set(HELD_OUT) == {"zara1", "zara2", "univ"}
    assert replay.TRAINING_SCENES == ("eth", "hotel")
    assert WorldConfig().replay_scenes == ("eth", "hotel")  # never the held-out ones by default
    for name in replay.SCENES:
        assert len(replay.scene_recording(name).ids) > 100
    with pytest.raises(ValueError, match="replay_scenes must be"):
        WorldConfig(scenario="replay", humans=10, replay_scenes=("zara3",))


def test_replay_mixture_and_rotation():
    config = WorldConfig(humans=10, replay_fraction=0.5, random_goal_direction=True)
    kinds = [scenarios.generate(config, s).kinds() for s in range(2000, 2020)]
    replayed = [bool(np.all(k == initial_state.REPLAY)) and len(k) > 0 for k in kinds]
    assert 0 < sum(replayed) < 20
    world = World(config, 4)
    world.reset([2000, 2001, 2002, 2003])
    for _ in range(5):
        world.step(np.array([5, 5, 5, 5]))


def test_replay_case_of_a_world_without_humans_is_an_empty_scene():
    config = WorldConfig(humans=0, replay_fraction=1.0)
    state = scenarios.generate(config, 1000)
    assert state.human_pos.shape == (0, 2)
