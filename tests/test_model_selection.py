"""Best-model selection: by validation reward (CrowdNav's rule) or success first, in training,
on resume from older checkpoints, and in the offline replay."""

import dataclasses
import json
import math

import pytest
import torch
import yaml

from crowdplan import evaluation
from crowdplan.analysis import averaged_validation as averaged_validation_module
from crowdplan.analysis.averaged_validation import main as averaged_validation
from crowdplan.cli import main
from crowdplan.models import load_model_policy, load_payload
from crowdplan.training import config_from_dict
from crowdplan.training.config import load_config
from crowdplan.training.loop import _best_val_score, improves, selection_score, validation_row
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


def test_with_the_papers_world_selection_means_the_two_worlds_scores():
    row = {"success_rate": 0.9, "mean_reward": 0.2, "paper_success_rate": 1.0}
    row["paper_mean_reward"] = 0.4
    assert selection_score(row, "success") == pytest.approx((0.95, 0.3))
    assert selection_score(row, "reward") == pytest.approx((0.3,))
    # a policy that gives up the paper's world for the mixture loses to a balanced one
    mixture_only = {**row, "success_rate": 0.98, "paper_success_rate": 0.8}
    assert improves(selection_score(row, "success"), selection_score(mixture_only, "success"))


def test_val_paper_world_validates_in_both_worlds_and_selects_on_their_mean(tmp_path):
    config = tmp_path / "both.yaml"
    config.write_text(
        yaml.safe_dump(
            {
                **TINY,
                "val_paper_world": True,
                "select_by": "success",
                "val_episodes": 2,
                "keep_validation_models": True,
            }
        )
    )
    run = tmp_path / "both"
    assert main(["train", "--config", str(config), "--out", str(run), "-q"]) == 0
    rows = _csv(run / "validation.csv")
    # training never sees the second world: the same episodes as a run validating in its own
    alone = tmp_path / "alone.yaml"
    alone.write_text(yaml.safe_dump({**TINY, "val_episodes": 2}))
    assert main(["train", "--config", str(alone), "--out", str(tmp_path / "alone"), "-q"]) == 0
    played = ("seed", "outcome", "steps", "return")
    assert [[r[k] for k in played] for r in _csv(run / "episodes.csv")] == [
        [r[k] for k in played] for r in _csv(tmp_path / "alone" / "episodes.csv")
    ]
    # the paper_* columns are the validation cases of the paper's world (5 humans, 25 s)
    trained = load_config(run / "config.yaml")
    policy, _ = load_model_policy(str(run / "best_model.pt"))
    seeds = evaluation.validation_seeds(trained.val_episodes)
    paper = evaluation.summarize(
        evaluation.run_episodes(policy, trained.world.paper_world(), seeds)
    )
    row = validation_row(policy, trained, 0, 0)
    assert trained.world.paper_world().humans == 5
    for key in ("success_rate", "time_to_goal", "mean_reward"):
        assert row["paper_" + key] == paper[key]["value"]
    mean = [
        (
            (float(r["success_rate"]) + float(r["paper_success_rate"])) / 2,
            (float(r["mean_reward"]) + float(r["paper_mean_reward"])) / 2,
        )
        for r in rows
    ]
    selected = load_payload(run / "best_model.pt")["info"]["selected_at_episode"]
    assert selected == int(rows[mean.index(max(mean))]["episode"])

    # the replay selects the same policies as if the run had validated in its own world alone
    out = tmp_path / "mixture_only"
    assert (
        averaged_validation([str(run), "--average", "1", "--no-val-paper-world", "--out", str(out)])
        == 0
    )
    replayed = _csv(out / "validation.csv")
    assert "paper_success_rate" not in replayed[0]
    assert [r["success_rate"] for r in replayed] == [r["success_rate"] for r in rows]
    own = [(float(r["success_rate"]), float(r["mean_reward"])) for r in rows]
    expected = int(rows[own.index(max(own))]["episode"])
    assert load_payload(out / "best_model.pt")["info"]["selected_at_episode"] == expected
    assert yaml.safe_load((out / "config.yaml").read_text())["val_paper_world"] is False


def test_the_replay_of_the_runs_own_policies_takes_its_rows_as_a_new_validation_would(
    tmp_path, monkeypatch
):
    config = tmp_path / "both.yaml"
    both = {**TINY, "val_paper_world": True, "val_episodes": 2, "keep_validation_models": True}
    config.write_text(yaml.safe_dump(both))
    run = tmp_path / "both"
    assert main(["train", "--config", str(config), "--out", str(run), "-q"]) == 0
    out = tmp_path / "mixture_only"
    with monkeypatch.context() as patched:  # nothing is validated again: the rows are the run's
        patched.setattr(averaged_validation_module, "validation_row", None)
        args = [str(run), "--average", "1", "--no-val-paper-world", "--out", str(out)]
        assert averaged_validation(args) == 0
    replayed = _csv(out / "validation.csv")
    mixture_only = dataclasses.replace(load_config(run / "config.yaml"), val_paper_world=False)
    models = sorted((run / "validation_models").glob("episode-*.pt"))
    assert len(replayed) == len(models) > 1
    for row, model in zip(replayed, models, strict=True):
        policy, _ = load_model_policy(str(model))
        fresh = validation_row(policy, mixture_only, int(row["episode"]), int(row["env_steps"]))
        assert list(row.items()) == [(key, str(value)) for key, value in fresh.items()]


def test_val_paper_world_with_too_few_raw_slots_is_refused():
    raw = {**TINY, "encoder": {"name": "raw"}, "val_paper_world": True}
    with pytest.raises(ValueError, match="paper's 5 humans, more than the raw encoder's fixed 3"):
        config_from_dict(raw)


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


def test_the_replay_with_more_validation_cases_is_the_run_trained_with_them(tmp_path, capsys):
    def train(name, **changes):
        config = tmp_path / f"{name}.yaml"
        config.write_text(yaml.safe_dump({**TINY, **changes}))
        assert main(["train", "--config", str(config), "--out", str(tmp_path / name), "-q"]) == 0
        return tmp_path / name

    # averaged policies, as the general preset validates: the kept models are the averages
    few = train("few", val_episodes=2, keep_validation_models=True, policy_average=2)
    more = train("more", val_episodes=3, policy_average=2)
    assert json.loads((more / "meta.json").read_text())["validation_seeds"] == [0, 2]
    with pytest.raises(SystemExit):
        averaged_validation([str(few), "--average", "2", "--out", str(tmp_path / "twice")])
    assert "already averaged policies: replay them with --average 1" in capsys.readouterr().err
    out = tmp_path / "replayed"
    args = [str(few), "--average", "1", "--val-episodes", "3", "--out", str(out)]
    assert averaged_validation(args) == 0
    assert _csv(out / "validation.csv") == _csv(more / "validation.csv")
    assert _csv(out / "validation.csv") != _csv(few / "validation.csv")
    replayed, trained = load_payload(out / "best_model.pt"), load_payload(more / "best_model.pt")
    assert replayed["info"]["selected_at_episode"] == trained["info"]["selected_at_episode"]
    for key, value in trained["actor"].items():
        assert torch.equal(value, replayed["actor"][key])
    too_many = tmp_path / "too_many"
    with pytest.raises(SystemExit):
        averaged_validation(
            [str(few), "--average", "1", "--val-episodes", "1001", "--out", str(too_many)]
        )
    assert "val_episodes must be >= 1 and <= 1000, got 1001" in capsys.readouterr().err
    assert not too_many.exists()
    written = yaml.safe_load((out / "config.yaml").read_text())
    assert (written["val_episodes"], written["policy_average"]) == (3, 2)


def test_validation_takes_up_to_1000_cases_apart_from_the_test_and_training_seeds():
    seeds = evaluation.validation_seeds(1000)
    assert seeds == list(range(1000))
    assert evaluation.validation_seeds() == list(range(100))  # the default count
    assert max(seeds) < min(evaluation.test_seeds())
    assert config_from_dict({**TINY, "val_episodes": 1000}).val_episodes == 1000
    with pytest.raises(ValueError, match="val_episodes"):
        config_from_dict({**TINY, "val_episodes": 1001})
