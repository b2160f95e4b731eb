"""policy_average: the averaged validation policy, its exact resume, and the offline replay."""

import csv
import dataclasses
import os
import signal

import pytest
import torch
import yaml
from tiny_runs import restored, train_tiny

from crowdplan.analysis.averaged_validation import main as averaged_validation
from crowdplan.cli import main
from crowdplan.models import load_payload
from crowdplan.training import Trainer, config_from_dict
from crowdplan.training.policy_average import average_payloads

TINY = {
    "name": "tiny",
    "episodes": 6,
    "num_envs": 2,
    "val_interval": 1,
    "val_episodes": 3,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 3, "time_limit": 4.0},
    "encoder": {"name": "lsa"},
    "dsac": {"batch_size": 16, "random_steps": 16, "learning_starts": 16},
}


def test_average_of_payloads_means_the_weights_and_keeps_the_rest():
    def payload(value, episodes):
        weights = {"w": torch.full((2,), value), "steps": torch.tensor(episodes)}
        return {"format": "f", "info": {"episodes_trained": episodes}, "actor": weights}

    averaged = average_payloads([payload(1.0, 10), payload(2.0, 20), payload(6.0, 30)])
    assert torch.equal(averaged["actor"]["w"], torch.full((2,), 3.0))
    assert averaged["actor"]["steps"].item() == 30  # integer tensors are not averaged
    assert averaged["info"] == {"episodes_trained": 30, "averaged_episodes": [10, 20, 30]}
    with pytest.raises(ValueError, match="at least one"):
        average_payloads([])


def _clitrain_tiny(TINY, tmp_path, name, **changes):
    config = tmp_path / f"{name}.yaml"
    config.write_text(yaml.safe_dump({**TINY, **changes}))
    assert main(["train", "--config", str(config), "--out", str(tmp_path / name), "-q"]) == 0
    return tmp_path / name


def _csv(path, skip=()):
    with path.open(newline="") as f:
        return [{k: v for k, v in row.items() if k not in skip} for row in csv.DictReader(f)]


def test_averaging_never_changes_training_and_the_replay_matches_a_real_run(tmp_path):
    own = _clitrain_tiny(TINY, tmp_path, "own", keep_validation_models=True)
    averaging = _clitrain_tiny(TINY, tmp_path, "averaging", policy_average=2)
    clock = ("train_seconds",)
    assert _csv(own / "episodes.csv", clock) == _csv(averaging / "episodes.csv", clock)
    own_final = load_payload(own / "final_model.pt")["actor"]
    for key, value in load_payload(averaging / "final_model.pt")["actor"].items():
        assert torch.equal(value, own_final[key])  # the agent's own policy: the same
    validated = _csv(averaging / "validation.csv")
    assert validated[0] == _csv(own / "validation.csv")[0]  # one policy: nothing averaged yet
    best = load_payload(averaging / "best_model.pt")
    assert best["info"]["averaged_episodes"][-1] == best["info"]["episodes_trained"]

    out = tmp_path / "replayed"
    assert averaged_validation([str(own), "--average", "2", "--out", str(out)]) == 0
    assert _csv(out / "validation.csv") == validated
    replayed_best = load_payload(out / "best_model.pt")
    assert replayed_best["info"]["selected_at_episode"] == best["info"]["selected_at_episode"]
    for key, value in best["actor"].items():
        assert torch.equal(value, replayed_best["actor"][key])
    assert yaml.safe_load((out / "config.yaml").read_text())["policy_average"] == 2


def test_a_stopped_run_resumes_with_the_policies_it_was_averaging(tmp_path, monkeypatch):
    straight = train_tiny(TINY, tmp_path, "straight", policy_average=3)
    config = dataclasses.replace(config_from_dict(TINY), policy_average=3)
    stopped = Trainer(config, tmp_path / "stopped", progress=False, quiet=True)
    step, calls = stopped._train_step, []

    def step_then_signal():
        step()
        calls.append(1)
        if len(calls) == 40:  # after the validations at episodes 2 and 4
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(stopped, "_train_step", step_then_signal)
    assert stopped.run() is False
    resumed = restored(config, tmp_path / "stopped")
    assert resumed.run() is True

    def rewards(trainer):
        return [(row["episode"], row["mean_reward"]) for row in trainer.validations]

    assert len(stopped.validations) == 2 and rewards(resumed) == rewards(straight)


def test_replay_refuses_a_run_without_validation_models_and_a_used_folder(tmp_path, capsys):
    _clitrain_tiny(TINY, tmp_path, "plain", episodes=2)
    with pytest.raises(SystemExit):
        averaged_validation(
            [str(tmp_path / "plain"), "--average", "2", "--out", str(tmp_path / "x")]
        )
    assert "train the run with keep_validation_models: true" in capsys.readouterr().err
    _clitrain_tiny(TINY, tmp_path, "kept", episodes=2, keep_validation_models=True)
    (tmp_path / "used").mkdir()
    (tmp_path / "used" / "notes.txt").write_text("mine")
    with pytest.raises(SystemExit):
        averaged_validation(
            [str(tmp_path / "kept"), "--average", "2", "--out", str(tmp_path / "used")]
        )
    assert "is not empty; give a new folder" in capsys.readouterr().err
    assert (tmp_path / "used" / "notes.txt").read_text() == "mine"


def test_policy_average_below_one_is_refused():
    with pytest.raises(ValueError, match="policy_average"):
        config_from_dict({**TINY, "policy_average": 0})


def test_cli_switches_averaging_on_when_resuming_and_refuses_zero(tmp_path, capsys):
    run = _clitrain_tiny(TINY, tmp_path, "run", episodes=2)
    resume = ["train", "--out", str(run), "--resume", "--episodes", "6", "-q"]
    assert main([*resume, "--policy-average", "0"]) == 2
    assert "policy_average" in capsys.readouterr().err
    assert main([*resume, "--policy-average", "2", "--keep-validation-models"]) == 0
    assert yaml.safe_load((run / "config.yaml").read_text())["policy_average"] == 2
    last = sorted((run / "validation_models").glob("episode-*.pt"))[-1]
    assert load_payload(last)["info"]["averaged_episodes"] == [4, 6]
