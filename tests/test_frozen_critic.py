"""DSAC networks kept at each validation (``keep_validation_networks``) and the frozen-critic
reading over them (crowdplan.analysis.frozen_critic)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import yaml

from crowdplan.algos.dsac_networks import NETWORKS_FORMAT
from crowdplan.analysis.frozen_critic import load_networks, main, read_states
from crowdplan.analysis.timeouts import last_state
from crowdplan.cli import main as crowdplan_main
from crowdplan.config import WorldConfig
from crowdplan.evaluation import run_episodes
from crowdplan.policy import PolicyOutput
from crowdplan.sim.actions import STOP
from crowdplan.training.checkpoint import read_checkpoint
from crowdplan.training.config import config_from_dict
from tests.test_sweep import TINY


@pytest.fixture(scope="module")
def networks_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("networks")
    config = root / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY))
    run = root / "run"
    argv = ["train", "--config", str(config), "--out", str(run), "-q"]
    assert crowdplan_main([*argv, "--keep-validation-networks"]) == 0
    return run


def test_each_validation_keeps_the_networks_and_the_last_are_the_final_ones(networks_run):
    kept = sorted((networks_run / "validation_networks").iterdir())
    validated = [
        int(line.split(",")[0])
        for line in (networks_run / "validation.csv").read_text().splitlines()[1:]
    ]
    assert [int(p.stem.split("-")[1]) for p in kept] == validated == [2, 4]
    last = torch.load(kept[-1], weights_only=False)
    assert last["format"] == NETWORKS_FORMAT
    final = read_checkpoint(networks_run / "checkpoint.pt")["agent"]["dsac"]
    for key in ("actor", "critic", "critic_target"):
        assert all(torch.equal(v, final[key][k]) for k, v in last["networks"][key].items())
    assert torch.equal(last["networks"]["log_alpha"], final["log_alpha"])
    first = torch.load(kept[0], weights_only=False)["networks"]["actor"]
    assert any(not torch.equal(v, last["networks"]["actor"][k]) for k, v in first.items())


def test_keeping_networks_is_refused_for_an_algorithm_without_a_critic():
    with pytest.raises(ValueError, match="keep_validation_networks keeps DSAC's critic"):
        config_from_dict({"algo": "value_rl", "keep_validation_networks": True})


def test_readings_follow_the_actor_and_critic_outputs(networks_run):
    core, _ = load_networks(sorted((networks_run / "validation_networks").iterdir())[-1])
    # the actor all but certain to stop, the critic rating action 7 highest by 0.25
    actor_bias = core.actor.head.net[-1].bias
    with torch.no_grad():
        for layer in (core.actor.head.net[-1], core.critic.head.q1[-1], core.critic.head.q2[-1]):
            layer.weight.zero_()
        actor_bias.zero_()
        actor_bias[STOP] = 50.0
        for head in (core.critic.head.q1[-1], core.critic.head.q2[-1]):
            head.bias.zero_()
            head.bias[7] = 0.25
    robot = np.array([[0.0, -4.0, 0.0, 0.0, 0.3, 0.0, 4.0, 1.0, np.pi / 2]] * 2)
    humans = np.zeros((2, 2, 5))
    humans[..., 4] = 0.3
    humans[:, 1, :2] = [1.0, 1.0]
    readings = read_states(core, robot, humans, np.ones((2, 2), bool), unicycle=False)
    assert readings.p_stop == pytest.approx([1.0, 1.0])
    assert not readings.critic_prefers_stop.any()
    assert readings.regret == pytest.approx([0.25, 0.25])
    assert readings.log_p_gap == pytest.approx([50.0, 50.0], abs=1e-4)


class _Recorder:
    """Walks at half speed along +x and records every observation it is given."""

    name, kinematics = "recorder", "holonomic"

    def __init__(self):
        self.robots, self.humans = [], []

    def act(self, robot, humans, mask):
        self.robots.append(robot.copy())
        self.humans.append(humans.copy())
        return PolicyOutput(np.full(len(robot), 17), None)


def test_the_last_state_of_a_cut_trace_is_the_observation_the_world_gave():
    world = WorldConfig(humans=3, time_limit=3.0)
    recorder = _Recorder()
    (record,) = run_episodes(recorder, world, [1000], record_traces=True)
    trace = record.trace
    for t in (1, 5, 9):
        cut = dataclasses.replace(
            trace,
            robot_pos=trace.robot_pos[: t + 1],
            robot_vel=trace.robot_vel[:t],
            human_pos=trace.human_pos[: t + 1],
            human_vel=trace.human_vel[: t + 1],
            human_present=None if trace.human_present is None else trace.human_present[: t + 1],
        )
        robot, humans, present = last_state(cut, world.robot_v_pref)
        np.testing.assert_allclose(robot[0], recorder.robots[t][0], atol=1e-9)
        np.testing.assert_allclose(humans[0], recorder.humans[t][0], atol=1e-9)
        assert present.all()
    moving, _, _ = last_state(trace, world.robot_v_pref, moving=True)
    to_goal = trace.robot_goal - trace.robot_pos[-1]
    np.testing.assert_allclose(moving[0, 2:4], to_goal / np.linalg.norm(to_goal))


def test_cli_reads_a_networks_file_and_a_checkpoint(networks_run, capsys):
    kept = sorted((networks_run / "validation_networks").iterdir())[-1]
    main([str(kept), str(networks_run / "checkpoint.pt"), "--episodes", "3", "--humans", "2"])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")]
    assert len(rows) == 3  # the header and one row per file
    # the same networks: the same row but for the path
    assert rows[1].split(" | ")[1:] == rows[2].split(" | ")[1:]


def test_cli_explains_a_file_that_is_no_dsac_networks(tmp_path, capsys):
    foreign = tmp_path / "model.pt"
    torch.save({"format": "something else"}, foreign)
    with pytest.raises(SystemExit):
        main([str(foreign)])
    assert "not a crowdplan training checkpoint" in capsys.readouterr().err
