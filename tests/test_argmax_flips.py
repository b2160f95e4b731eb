"""Validation snapshots (``keep_validation_models``) and the argmax-flip analysis over them."""

import math
import shutil

import numpy as np
import pytest
import torch
import yaml

from crowdplan.analysis.argmax_flips import flip_table, main, probe_states, snapshots
from crowdplan.cli import main as crowdplan_main
from crowdplan.config import WorldConfig
from tests.test_sweep import TINY


@pytest.fixture(scope="module")
def snapshot_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("snapshots")
    config = root / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY))
    run = root / "run"
    argv = ["train", "--config", str(config), "--out", str(run), "--episodes", "2", "-q"]
    assert crowdplan_main(argv) == 0
    assert not (run / "validation_models").exists()  # off by default
    # switched on when resuming: it does not change the training trajectory
    argv = ["train", "--out", str(run), "--resume", "--episodes", "4"]
    assert crowdplan_main([*argv, "--keep-validation-models", "-q"]) == 0
    return run


def test_each_validation_after_the_switch_keeps_its_greedy_policy(snapshot_run):
    episodes = [int(p.stem.split("-")[1]) for p in (snapshot_run / "validation_models").iterdir()]
    validated = [
        int(line.split(",")[0])
        for line in (snapshot_run / "validation.csv").read_text().splitlines()[1:]
    ]
    assert sorted(episodes) == [e for e in validated if e > 2]
    assert yaml.safe_load((snapshot_run / "config.yaml").read_text())["keep_validation_models"]


def test_probe_states_are_the_active_steps_of_orca_paths():
    world = WorldConfig(humans=3)
    robot, humans, mask = probe_states(world, 4)
    assert robot.shape[1:] == (9,) and humans.shape[1:] == (3, 5) and mask.shape[1:] == (3,)
    assert len(robot) == len(humans) == len(mask) > 4  # several steps per case
    again = probe_states(world, 4)
    assert all(np.array_equal(a, b) for a, b in zip((robot, humans, mask), again, strict=True))


def test_identical_snapshots_do_not_flip_and_different_ones_are_counted(snapshot_run, tmp_path):
    run = tmp_path / "run"
    (run / "validation_models").mkdir(parents=True)
    first = sorted((snapshot_run / "validation_models").iterdir())[0]
    for episode in (10, 20):
        shutil.copy(first, run / "validation_models" / f"episode-{episode:06d}.pt")
    # a third snapshot whose logits prefer action 0 everywhere: every other argmax flips to it
    payload = torch.load(first, map_location="cpu", weights_only=False)
    (bias,) = [k for k, v in payload["actor"].items() if k.startswith("head") and v.shape == (81,)]
    payload["actor"][bias] = torch.zeros(81)
    payload["actor"][bias][0] = 1e6
    payload["info"]["episodes_trained"] = 30
    torch.save(payload, run / "validation_models" / "episode-000030.pt")

    rows = flip_table(snapshots(run), cases=3)
    assert len(rows) == 3 and rows[2]["episode"] == 30
    assert math.isnan(rows[0]["flipped"]) and rows[1]["flipped"] == 0.0
    assert rows[0]["p_greedy"] == rows[1]["p_greedy"]
    assert rows[2]["changed_from_final"] == 0.0 and rows[2]["p_greedy"] == 1.0
    assert rows[2]["narrow"] == 0.0 and rows[2]["stops"] == 1.0
    assert rows[2]["stop_gap"] > 1e5 and math.isnan(rows[0]["stop_gap"]) == (rows[0]["stops"] == 0)
    assert rows[2]["flipped"] == rows[1]["changed_from_final"]


def test_a_run_without_snapshots_is_explained(tmp_path):
    with pytest.raises(FileNotFoundError, match="--keep-validation-models"):
        main([str(tmp_path)])
