"""``crowdplan train``: what --resume and --out refuse, and that config.yaml and meta.json agree."""

import json
from pathlib import Path

import pytest
import yaml

from crowdplan.cli import main

TINY = {
    "name": "tiny",
    "episodes": 2,
    "num_envs": 2,
    "val_interval": 2,
    "val_episodes": 2,
    "checkpoint_interval": 2,
    "log_interval": 2,
    "test_episodes": 0,
    "world": {"humans": 2, "time_limit": 2.0, "action_frame": "world"},
    "encoder": {"name": "aw"},
    "dsac": {"batch_size": 8, "random_steps": 8, "learning_starts": 8},
}


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("train")
    config = root / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY))
    run = root / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    return config, run


@pytest.mark.parametrize(
    ("extra", "fragment"),
    [
        (["--seed", "3"], "--seed cannot apply"),
        (["--humans", "4"], "--humans cannot apply"),
        (["--config", "configs/lsa_dsac.yaml"], "--config cannot apply"),
        (["--episodes", "1"], "already trained 2 episodes; --episodes must be at least"),
        (["--set", "dsac.lr=1e-3"], "--set cannot apply"),
    ],
)
def test_resume_refuses_what_it_cannot_honour(finished_run, extra, fragment, capsys):
    _, run = finished_run
    before = (run / "config.yaml").read_text()
    assert main(["train", "--out", str(run), "--resume", *extra]) == 2
    assert fragment in capsys.readouterr().err
    assert (run / "config.yaml").read_text() == before  # nothing rewritten


def test_resume_with_a_larger_budget_keeps_config_and_meta_consistent(finished_run, tmp_path):
    config, run = finished_run
    copy = tmp_path / "copy"
    copy.mkdir()
    for item in run.iterdir():
        if item.is_file():
            (copy / item.name).write_bytes(item.read_bytes())
    assert main(["train", "--out", str(copy), "--resume", "--episodes", "4", "--no-progress"]) == 0
    meta = json.loads((copy / "meta.json").read_text())
    resolved = yaml.safe_load((copy / "config.yaml").read_text())
    assert resolved["episodes"] == meta["episodes_budget"] == 4
    assert meta["episodes"] >= 4


def test_new_run_refuses_a_folder_with_unrelated_files(finished_run, tmp_path, capsys):
    config, _ = finished_run
    (tmp_path / "notes.txt").write_text("mine")
    assert main(["train", "--config", str(config), "--out", str(tmp_path)]) == 2
    assert "not a crowdplan run (notes.txt)" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_resume_without_checkpoint_is_explained(tmp_path, capsys):
    assert main(["train", "--out", str(tmp_path), "--resume"]) == 2
    assert "holds no checkpoint.pt" in capsys.readouterr().err


def test_runs_from_before_the_action_frame_option_resume_in_the_world_frame(finished_run, tmp_path):
    _, run = finished_run
    old = tmp_path / "old"
    old.mkdir()
    for item in run.iterdir():
        if item.is_file():
            (old / item.name).write_bytes(item.read_bytes())
    config = yaml.safe_load((old / "config.yaml").read_text())
    del config["world"]["action_frame"]  # as runs made before the option wrote it
    (old / "config.yaml").write_text(yaml.safe_dump(config))
    # the checkpoint's copy says "world" (TINY is a world-frame run here): resume must agree
    assert main(["train", "--out", str(old), "--resume", "--episodes", "3", "--no-progress"]) == 0
    assert yaml.safe_load((old / "config.yaml").read_text())["world"]["action_frame"] == "world"


def test_parallel_update_flag_is_refused_for_other_algorithms(tmp_path, capsys):
    config = tmp_path / "a2c.yaml"
    config.write_text(yaml.safe_dump({"algo": "a2c", "world": {"humans": 2}}))
    argv = ["train", "--config", str(config), "--out", str(tmp_path / "run"), "--parallel-update"]
    assert main(argv) == 2
    assert "applies to DSAC's two-thread update; this run trains 'a2c'" in capsys.readouterr().err


def test_lookahead_flag_sets_the_value_rl_mode_and_is_refused_elsewhere(tmp_path, capsys):
    config = tmp_path / "sarl.yaml"
    data = yaml.safe_load(Path("configs/sarl.yaml").read_text())
    data.update(episodes=1, test_episodes=0, val_episodes=1, val_interval=1)
    data["value_rl"].update(il_episodes=0)
    config.write_text(yaml.safe_dump(data))
    run = tmp_path / "run"
    argv = ["train", "--config", str(config), "--out", str(run), "--lookahead", "oracle", "-q"]
    assert main(argv) == 0
    assert yaml.safe_load((run / "config.yaml").read_text())["value_rl"]["lookahead"] == "oracle"
    dsac = ["train", "--config", "configs/lsa_dsac_ent05.yaml", "--out", str(tmp_path / "d")]
    assert main([*dsac, "--lookahead", "oracle"]) == 2
    assert "--lookahead applies to the value-network baselines" in capsys.readouterr().err
    assert main(["train", "--out", str(run), "--resume", "--lookahead", "oracle"]) == 2
    assert "--lookahead cannot apply" in capsys.readouterr().err


def test_set_assigns_config_keys_of_a_new_run(finished_run, tmp_path):
    config, _ = finished_run
    run = tmp_path / "run"
    sets = ["--set", "dsac.lr=1e-3", "--set", "dsac.q_hidden=[16,16]", "--set", "world.humans=1"]
    assert main(["train", "--config", str(config), "--out", str(run), *sets, "-q"]) == 0
    written = yaml.safe_load((run / "config.yaml").read_text())
    assert written["dsac"]["lr"] == 1e-3
    assert written["dsac"]["q_hidden"] == [16, 16]
    assert written["world"]["humans"] == 1


@pytest.mark.parametrize(
    ("sets", "fragment"),
    [
        (["dsac.lr=fast"], "--set: dsac.lr must be a number, got 'fast'"),
        (["dsac.lrr=1"], "unknown key 'lrr' in dsac; valid keys: ['actor_warmup_updates'"),
        (["value_rl.gamma=0.9"], "'value_rl' is the section of another algorithm; this config"),
        (["valu_rl.gamma=0.9"], "unknown key 'valu_rl' in the top level"),
        (["dsac.lr=1e-4,3e-4"], "takes one value, got 2; to train each, use crowdplan sweep"),
        (["world.humans=3"], "--set world.humans and --humans both set world.humans"),
        (["dsac.lr"], "--set takes KEY=VALUE"),
    ],
)
def test_set_refuses_bad_keys_values_and_contradictions(
    finished_run, tmp_path, sets, fragment, capsys
):
    config, _ = finished_run
    argv = ["train", "--config", str(config), "--out", str(tmp_path / "run"), "--humans", "2"]
    assert main([*argv, *(arg for s in sets for arg in ("--set", s))]) == 2
    assert fragment in capsys.readouterr().err
    assert not (tmp_path / "run").exists()
