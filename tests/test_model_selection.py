"""Best-model selection: by validation reward (CrowdNav's rule) or success first, in training,
on resume from older checkpoints, and in the offline replay."""

import math

import pytest
import torch
import yaml

from crowdplan.analysis.averaged_validation import main as averaged_validation
from crowdplan.cli import main
from crowdplan.models import load_payload
from crowdplan.training import config_from_dict
from crowdplan.training.loop import _best_val_score, improves, selection_score
from tests.test_policy_average import TINY, _csv

ROWS = [
    {"episode": 1, "success_rate": 0.97, "mean_reward": 0.58},  # fast, one collision more
    {"episode": 2, "success_rate": 1.00, "mean_reward": 0.57},
    {"episode": 3, "success_rate": 1.00, "mean_reward": 0.57},  # equal to 2: the first wins
]


def _selected(select_by: str) -> int:
    best, best_score = None, None
    for row in ROWS:
        score = selection_score(row, select_by)
        if improves(score, best_score):
            best, best_score = row["episode"], score
    return best


def test_reward_selection_takes_the_faster_policy_and_success_selection_the_safer():
    assert _selected("reward") == 1
    assert _selected("success") == 2


def test_an_unknown_rule_is_refused_and_reward_is_the_default():
    assert config_from_dict(TINY).select_by == "reward"
    with pytest.raises(ValueError, match=r"select_by must be one of \['reward', 'success'\]"):
        config_from_dict({**TINY, "select_by": "speed"})


def test_checkpoints_from_before_the_option_resume_with_their_best_reward():
    assert _best_val_score({"best_val_reward": 0.25}) == (0.25,)
    assert _best_val_score({"best_val_reward": -math.inf}) is None  # no validation yet
    assert _best_val_score({"best_val_score": [1.0, 0.5]}) == (1.0, 0.5)


def test_the_replay_selects_as_a_run_trained_with_select_by_success(tmp_path):
    def train(name, **changes):
        config = tmp_path / f"{name}.yaml"
        config.write_text(yaml.safe_dump({**TINY, **changes}))
        assert main(["train", "--config", str(config), "--out", str(tmp_path / name), "-q"]) == 0
        return tmp_path / name

    own = train("own", keep_validation_models=True)
    by_success = train("by_success", select_by="success")
    rows = _csv(by_success / "validation.csv")
    assert rows == _csv(own / "validation.csv")  # selection never changes training
    best = load_payload(by_success / "best_model.pt")
    expected = max(rows, key=lambda r: (float(r["success_rate"]), float(r["mean_reward"])))
    assert best["info"]["selected_at_episode"] == int(expected["episode"])

    out = tmp_path / "replayed"
    assert (
        averaged_validation(
            [str(own), "--average", "1", "--select-by", "success", "--out", str(out)]
        )
        == 0
    )
    replayed = load_payload(out / "best_model.pt")
    assert replayed["info"]["selected_at_episode"] == best["info"]["selected_at_episode"]
    for key, value in best["actor"].items():
        assert torch.equal(value, replayed["actor"][key])
    assert yaml.safe_load((out / "config.yaml").read_text())["select_by"] == "success"


def test_the_replay_refuses_average_one_without_a_selection_rule(tmp_path, capsys):
    with pytest.raises(SystemExit):
        averaged_validation([str(tmp_path), "--average", "1", "--out", str(tmp_path / "o")])
    assert "--average must be >= 2, or >= 1 with --select-by" in capsys.readouterr().err
