"""The training table of ``crowdplan report``: the minutes a run took to first reach a validation
success of 0.99, and the lowest validation success after the first 0.95, from its own logs."""

from __future__ import annotations

import json

import pytest

from crowdplan.analysis.report import (
    lowest_success_after,
    minutes_to_success,
    read_run,
    training_table,
)
from crowdplan.analysis.seed_targets import read_seed, seed_table
from crowdplan.cli import main


def make_run(folder, successes, pretrain_seconds=None, seed=3):
    """A run folder whose validation every 100 episodes has the given successes; episode k ends
    at 6k training seconds."""
    folder.mkdir()
    meta = {
        "seed": seed,
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


def _with_test(run, success, time_to_goal):
    """Give a run folder the summary.json of its 500-case test."""
    (run / "test").mkdir()
    summary = {"success_rate": {"value": success}, "time_to_goal": {"value": time_to_goal}}
    (run / "test" / "summary.json").write_text(json.dumps(summary))
    return run


def test_seed_targets_per_seed_and_across_seeds(tmp_path):
    runs = [
        # meets all three: first 0.95 at 100, never below 0.9 after, 0.99 at episode 200
        _with_test(make_run(tmp_path / "a", [0.95, 0.99, 0.91], seed=0), 0.996, 10.8),
        # success but slow, and a dip to 0.85 after its first 0.95
        _with_test(make_run(tmp_path / "b", [0.96, 0.85, 1.0], seed=1), 0.99, 11.2),
        # never learned; stopped before a test
        make_run(tmp_path / "c", [0.1, 0.2], seed=2),
    ]
    results = [read_seed(run) for run in runs]
    assert [(r.meets_success, r.meets_time, r.stable) for r in results] == [
        (True, True, True),
        (True, False, False),
        (False, False, False),
    ]
    table = seed_table(runs).splitlines()
    assert table[2].endswith("| 0.996 | 10.80 | 100 | 0.91 | 20 | success, time, stable |")
    assert table[3].endswith("| 0.990 | 11.20 | 100 | 0.85 | 30 | success |")
    assert table[4].endswith("| - | - | never | - | never | none |")
    across = table[5]
    assert "| 0.993 [" in across and "(2 seeds)" in across  # the run without a test is left out
    # minutes: 20, 30 and never (slower than any) -> median 30
    assert across.endswith("| 30 | success 2 of 3, time 1 of 3, stable 1 of 3 |")


def test_seed_targets_median_minutes_is_never_when_most_seeds_never_got_there(tmp_path):
    runs = [
        make_run(tmp_path / name, successes, seed=seed)
        for seed, (name, successes) in enumerate([("a", [0.99]), ("b", [0.5]), ("c", [0.2])])
    ]
    assert (
        seed_table(runs)
        .splitlines()[-1]
        .endswith("| never | success 0 of 3, time 0 of 3, stable 1 of 3 |")
    )


def test_runs_of_one_seed_get_no_across_seed_row(tmp_path):
    runs = [make_run(tmp_path / name, [0.99]) for name in ("plain", "with_option")]
    table = seed_table(runs)
    assert len(table.splitlines()) == 4 and "across" not in table


def test_seed_targets_explain_a_folder_that_is_not_a_run(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a training run folder"):
        read_seed(tmp_path)
    with pytest.raises(ValueError, match="training run folders"):
        seed_table([])


def test_report_seeds_prints_and_fills_the_table(tmp_path, capsys):
    run = _with_test(make_run(tmp_path / "a", [0.95, 0.99]), 0.996, 10.8)
    assert main(["report", "--seeds", str(run)]) == 0
    assert (
        capsys.readouterr()
        .out.splitlines()[-1]
        .endswith("success 1 of 1, time 1 of 1, stable 1 of 1 |")
    )
    page = tmp_path / "page.md"
    page.write_text(f"<!-- crowdplan report --seeds {run} -->\nstale\n<!-- end report -->\n")
    assert main(["report", "--fill", str(page)]) == 0
    assert "stale" not in page.read_text() and "| 0.996 | 10.80 |" in page.read_text()
    assert main(["report", "--seeds", "--paper", str(run)]) == 2
    assert main(["report", "--seeds", str(tmp_path)]) == 2
    assert "not a training run folder" in capsys.readouterr().err
