"""The training table of ``crowdplan report``: the minutes a run took to first reach a validation
success of 0.99, and the lowest validation success after the first 0.95, from its own logs."""

from __future__ import annotations

import json

from crowdplan.analysis.report import (
    lowest_success_after,
    minutes_to_success,
    read_run,
    training_table,
)


def make_run(folder, successes, pretrain_seconds=None):
    """A run folder whose validation every 100 episodes has the given successes; episode k ends
    at 6k training seconds."""
    folder.mkdir()
    meta = {
        "seed": 3,
        "episodes": 100 * len(successes),
        "env_steps": 1,
        "hours_per_10k_episodes": 1,
    }
    if pretrain_seconds is not None:
        meta["pretrain_seconds"] = pretrain_seconds
    (folder / "meta.json").write_text(json.dumps(meta))
    rows = [f"{100 * (i + 1)},0,{s},0,0,10,0.5" for i, s in enumerate(successes)]
    header = "episode,env_steps,success_rate,collision_rate,timeout_rate,time_to_goal,mean_reward"
    (folder / "validation.csv").write_text("\n".join([header, *rows]) + "\n")
    episodes = [f"{k},0,goal,40,1,0.5,0,{6.0 * k}" for k in range(1, 100 * len(successes) + 1)]
    header = "episode,seed,outcome,steps,return,discounted_return,env_steps,train_seconds"
    (folder / "episodes.csv").write_text("\n".join([header, *episodes]) + "\n")
    return folder


def test_minutes_to_the_first_validation_success_of_0_99(tmp_path):
    run = make_run(tmp_path / "run", [0.9, 0.99, 0.95, 1.0], pretrain_seconds=120)
    meta, validations = read_run(run)
    # first 0.99 at episode 200: 1200 s of training + 120 s of pretraining
    assert minutes_to_success(run, meta, validations) == 22.0
    # first >= 0.95 at episode 200 (0.99); the lowest from there on is the 0.95 after it
    assert training_table([run]).splitlines()[-1].endswith("| 22 | 0.95 (200) |")


def test_a_run_that_never_gets_there(tmp_path):
    run = make_run(tmp_path / "run", [0.5, 0.98])
    meta, validations = read_run(run)
    assert minutes_to_success(run, meta, validations) is None
    # 0.98 >= 0.95 at episode 200, the last validation
    assert training_table([run]).splitlines()[-1].endswith("| never | 0.98 (200) |")


def test_the_lowest_success_after_the_first_0_95_counts_a_later_collapse(tmp_path):
    run = make_run(tmp_path / "run", [0.3, 0.96, 1.0, 0.42, 0.99])
    _, validations = read_run(run)
    assert lowest_success_after(validations) == (0.42, 200)
    assert lowest_success_after(validations[:1]) is None  # never reached 0.95
