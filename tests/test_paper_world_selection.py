"""Selection of a run's kept policies by their success in the paper's world
(crowdplan.analysis.paper_world_selection)."""

import json

import pytest
import yaml

from crowdplan.analysis.paper_world_selection import main as paper_world_selection
from crowdplan.analysis.paper_world_selection import select
from crowdplan.cli import main
from tests.test_policy_average import TINY, _csv


def _row(episode, own, success, reward):
    return {
        "episode": episode,
        "own_success_rate": own,
        "success_rate": success,
        "mean_reward": reward,
    }


def test_selection_needs_the_runs_own_floor_then_takes_paper_success_then_reward():
    rows = [
        _row(1, 0.80, 1.00, 0.60),  # best in the paper's world, unfit for its own
        _row(2, 0.96, 0.99, 0.50),
        _row(3, 0.97, 0.99, 0.55),
        _row(4, 0.95, 0.99, 0.55),  # equal to 3: the first wins
    ]
    assert select(rows, 0.95)["episode"] == 3
    assert select(rows, 0.0)["episode"] == 1
    assert select(rows, 0.99)["episode"] == 1  # none reaches the floor: all are eligible


def test_the_paper_worlds_validation_and_test_are_the_runs_own(tmp_path):
    config = tmp_path / "tiny.yaml"
    changes = {"val_paper_world": True, "keep_validation_models": True, "episodes": 3}
    config.write_text(yaml.safe_dump({**TINY, **changes}))
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "-q"]) == 0
    out = tmp_path / "selected"
    args = [str(run), "--val-episodes", str(TINY["val_episodes"]), "--test", "--out", str(out)]
    assert paper_world_selection(args) == 0

    # the same cases as the run's own validation in the paper's world (val_paper_world)
    kept = _csv(out / "run" / "kept.csv")
    own = _csv(run / "validation.csv")
    assert [r["episode"] for r in kept] == [r["episode"] for r in own]
    for ours, theirs in zip(kept, own, strict=True):
        assert float(ours["own_success_rate"]) == float(theirs["success_rate"])
        for key in ("success_rate", "collision_rate", "mean_reward"):
            assert float(ours[key]) == pytest.approx(float(theirs["paper_" + key]))

    # the test is what `crowdplan eval --default-world` gives the selected model file
    model = out / "run" / "best_model.pt"
    check = tmp_path / "check"
    assert main(["eval", "--model", str(model), "--default-world", "--out", str(check)]) == 0
    ours = json.loads((out / "run" / "test" / "summary.json").read_text())
    theirs = json.loads((check / "summary.json").read_text())
    for key in ("episodes", "success_rate", "collision_rate", "time_to_goal", "mean_reward"):
        assert ours[key] == theirs[key]
    assert f"| run | {len(kept)} |" in (out / "summary.md").read_text()


def test_bad_input_is_refused_before_anything_is_written(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    out = tmp_path / "out"
    with pytest.raises(SystemExit):
        paper_world_selection([str(run), "--out", str(out)])
    assert "has no validation_models/: train it with keep_validation_models" in (
        capsys.readouterr().err
    )
    with pytest.raises(SystemExit):
        paper_world_selection([str(run), "--val-episodes", "0", "--out", str(out)])
    assert "--val-episodes must be 1..1000, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        paper_world_selection([str(run), "--min-own-success", "95", "--out", str(out)])
    assert "--min-own-success is a success rate in 0..1, got 95.0" in capsys.readouterr().err
    assert not out.exists()
    out.mkdir()
    (out / "old.md").write_text("kept")
    with pytest.raises(SystemExit):
        paper_world_selection([str(run), "--out", str(out)])
    assert "is not empty: give a new folder" in capsys.readouterr().err
    assert (out / "old.md").read_text() == "kept"
