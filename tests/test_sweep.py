"""crowdplan sweep: grid and seed parsing, the sweep folder's checks and lock, skip / resume of
trials, the summary across seeds, and sharded evaluation on a local process pool."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from crowdplan.backends import make_backend
from crowdplan.backends.sweep import (
    TRIAL_METRICS,
    SweepFolder,
    expand,
    parse_grid,
    parse_seeds,
    run_sweep,
    summarize,
    trial_result,
)
from crowdplan.cli import main
from crowdplan.training import config_from_dict

TINY = {
    "name": "tiny",
    "episodes": 4,
    "num_envs": 2,
    "val_interval": 2,
    "val_episodes": 3,
    "checkpoint_interval": 1,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 2, "time_limit": 3.0},
    "encoder": {"name": "aw"},
    "dsac": {"batch_size": 8, "random_steps": 8, "learning_starts": 8},
}
BASE = config_from_dict(TINY).to_dict()


class InlineBackend:
    """Runs jobs one after another in this process (the sweep logic without worker processes)."""

    def __init__(self):
        self.jobs: list[tuple] = []

    def map(self, fn, jobs, threads):
        for index, job in enumerate(jobs):
            self.jobs.append(job)
            yield index, fn(*job)

    def close(self):
        pass


def _clockless(result: dict) -> dict:
    clock = ("hours_per_10k_episodes", "minutes_to_val_success_0.99")
    return {k: v for k, v in result.items() if k not in clock}


# ---------------------------------------------------------------------- parsing
def test_seeds_ranges_lists_and_single_values():
    assert parse_seeds("0-9") == list(range(10))
    assert parse_seeds("3") == [3]
    assert parse_seeds("0,2,5-6,2") == [0, 2, 5, 6]


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("5-2", "range '5-2' is empty: write it as 2-5"),
        ("a", "--seeds must look like"),
        ("-1", "--seeds must look like"),
    ],
)
def test_bad_seeds_are_refused(text, fragment):
    with pytest.raises(ValueError, match=fragment):
        parse_seeds(text)


def test_grid_values_are_numbers_yaml_or_lists():
    grid = parse_grid(
        ["dsac.lr=1e-4,3e-4", "dsac.q_hidden=[64,64],[32]", "encoder.name=lsa,aw"], BASE
    )
    assert grid == [
        ("dsac.lr", [1e-4, 3e-4]),
        ("dsac.q_hidden", [[64, 64], [32]]),
        ("encoder.name", ["lsa", "aw"]),
    ]


@pytest.mark.parametrize(
    ("assignment", "fragment"),
    [
        ("dsac.lrr=1e-4", "unknown key 'lrr' in dsac"),
        ("nope.lr=1", "unknown key 'nope' in the top level"),
        ("dsac.lr=", "--set dsac.lr: empty value"),
        ("dsac.lr=1e-4,,3e-4", "--set dsac.lr: empty value"),
        ("dsac.lr", "--set takes KEY=VALUE"),
        ("seed=1,2", "give seeds with --seeds"),
    ],
)
def test_bad_grids_are_refused(assignment, fragment):
    with pytest.raises(ValueError) as error:
        parse_grid([assignment], BASE)
    assert fragment in str(error.value)


def test_a_key_given_twice_is_refused():
    with pytest.raises(ValueError, match="given twice"):
        parse_grid(["dsac.lr=1e-4", "dsac.lr=3e-4"], BASE)


def test_expand_makes_every_setting_and_seed_with_checked_configs():
    trials = expand(BASE, parse_grid(["dsac.lr=1e-4,3e-4", "dsac.tau=0.01"], BASE), [0, 1], 2)
    assert [t.name for t in trials] == [
        "dsac.lr=0.0001,dsac.tau=0.01-s0",
        "dsac.lr=0.0001,dsac.tau=0.01-s1",
        "dsac.lr=0.0003,dsac.tau=0.01-s0",
        "dsac.lr=0.0003,dsac.tau=0.01-s1",
    ]
    assert trials[3].config["dsac"]["lr"] == 3e-4 and trials[3].config["seed"] == 1
    assert all(t.config["torch_threads"] == 2 for t in trials)
    assert [t.name for t in expand(BASE, [], [4], 1)] == ["tiny-s4"]
    with pytest.raises(ValueError, match=r"setting dsac.lr=-1: dsac.lr must be > 0"):
        expand(BASE, parse_grid(["dsac.lr=-1"], BASE), [0], 1)


# ---------------------------------------------------------------------- the folder
def test_a_second_sweep_on_the_same_folder_is_refused(tmp_path):
    folder = SweepFolder(tmp_path / "sweep")
    with folder.lock():
        with pytest.raises(ValueError, match="being written by another sweep"), folder.lock():
            pass
        assert (tmp_path / "sweep" / "sweep.lock").is_file()
    assert not (tmp_path / "sweep" / "sweep.lock").exists()


def test_a_lock_left_by_a_dead_process_is_taken_over(tmp_path):
    dead = subprocess.run(
        [sys.executable, "-c", "import os; print(os.getpid())"],
        text=True,
        capture_output=True,
        check=True,
    )
    (tmp_path / "sweep.lock").write_text(
        json.dumps({"pid": int(dead.stdout), "host": os.uname().nodename, "started": 0})
    )
    with SweepFolder(tmp_path).lock():
        assert json.loads((tmp_path / "sweep.lock").read_text())["pid"] == os.getpid()


def test_folders_of_something_else_or_another_sweep_are_not_touched(tmp_path):
    trials = expand(BASE, [], [0], 1)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("keep")
    with pytest.raises(ValueError, match="is not a sweep folder"):
        SweepFolder(other).prepare(BASE, 1, trials)
    assert sorted(p.name for p in other.iterdir()) == ["notes.txt"]

    SweepFolder(tmp_path / "s").prepare(BASE, 1, trials)
    with pytest.raises(ValueError, match=r"another config \(differs in \['threads_per_trial'\]\)"):
        SweepFolder(tmp_path / "s").prepare(BASE, 2, trials)
    changed = {**BASE, "episodes": 9}
    with pytest.raises(ValueError, match=r"differs in \['base'\]"):
        SweepFolder(tmp_path / "s").prepare(changed, 1, expand(changed, [], [0], 1))


def test_a_sweep_from_before_an_option_existed_still_resumes(tmp_path):
    trials = expand(BASE, [], [0], 1)
    folder = SweepFolder(tmp_path / "s")
    folder.prepare(BASE, 1, trials)
    marker = tmp_path / "s" / "sweep.json"
    saved = json.loads(marker.read_text())
    del saved["base"]["policy_average"]  # as a version without the option wrote it
    marker.write_text(json.dumps(saved))
    config = folder.config(trials[0].name)
    old = yaml.safe_load(config.read_text())
    del old["policy_average"]
    config.write_text(yaml.safe_dump(old))
    folder.prepare(BASE, 1, trials)  # no error: the missing option takes its default
    assert json.loads(marker.read_text())["base"]["policy_average"] == 1


def test_cli_refuses_bad_input_before_any_work(tmp_path, capsys):
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY))
    out = tmp_path / "out"
    for extra, fragment in [
        (["--seeds", "5-2"], "is empty"),
        (["--set", "dsac.nope=1"], "unknown key 'nope'"),
        (["--set", "dsac.lr="], "empty value"),
        (["--threads-per-trial", "0"], "--threads-per-trial must be >= 1"),
        (["--address", "localhost:1"], "--address applies to --backend ray only"),
    ]:
        argv = ["sweep", "--config", str(config), "--out", str(out), *extra]
        assert main(argv) == 2
        assert fragment in capsys.readouterr().err
    assert not out.exists()


# ---------------------------------------------------------------------- running
def test_trials_take_the_configs_thread_count_unless_told(tmp_path):
    config = tmp_path / "two_threads.yaml"
    config.write_text(
        yaml.safe_dump({**TINY, "episodes": 1, "val_interval": 1, "torch_threads": 2})
    )
    for flag, threads in [([], 2), (["--threads-per-trial", "1"], 1)]:
        out = tmp_path / f"sweep{threads}"
        assert main(["sweep", "--config", str(config), "--out", str(out), *flag]) == 0
        assert json.loads((out / "sweep.json").read_text())["threads_per_trial"] == threads
        meta = json.loads((out / "runs" / "tiny-s0" / "meta.json").read_text())
        assert meta["torch_threads"] == threads


def test_sweep_runs_skips_finished_and_resumes_stopped_trials(tmp_path):
    trials = expand(BASE, parse_grid(["dsac.lr=1e-4,3e-4"], BASE), [0], 1)
    straight = run_sweep(tmp_path / "a", BASE, trials, 1, InlineBackend, report=lambda _: None)
    results = {r["trial"]: r for r in straight["trials"]}
    assert set(results) == {"dsac.lr=0.0001-s0", "dsac.lr=0.0003-s0"}
    assert all(r["episodes"] == 4 and "error" not in r for r in results.values())

    # b: one trial stopped after 2 episodes (its checkpoint on disk), as a killed worker leaves it
    folder = SweepFolder(tmp_path / "b")
    with folder.lock():
        folder.prepare(BASE, 1, trials)
    name = trials[1].name
    argv = ["train", "--config", str(folder.config(name)), "--out", str(folder.run(name))]
    assert main([*argv, "--episodes", "2", "--no-progress"]) == 0
    backend = InlineBackend()
    resumed = run_sweep(folder.root, BASE, trials, 1, lambda: backend, report=lambda _: None)
    log = folder.log(name).read_text()
    assert "--resume" in log and "resuming" in log
    assert [_clockless(r) for r in resumed["trials"]] == [_clockless(r) for r in straight["trials"]]
    assert (folder.run(name) / "episodes.csv").read_text().count("\n") == 5  # header + 4

    # re-running the same command does nothing but write the summary again
    again = InlineBackend()
    run_sweep(folder.root, BASE, trials, 1, lambda: again, report=lambda _: None)
    assert again.jobs == []
    summary = json.loads((folder.root / "summary.json").read_text())
    assert [row["setting"] for row in summary["settings"]] == ["dsac.lr=0.0001", "dsac.lr=0.0003"]
    table = (folder.root / "summary.md").read_text()
    assert "| dsac.lr=0.0001 | 1 |" in table
    # one row per trial: episodes, test or validation metrics, then its training stability
    (row,) = [line for line in table.splitlines() if line.startswith("| dsac.lr=0.0001-s0 |")]
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    first_095 = results["dsac.lr=0.0001-s0"]["first_val_success_0.95_episode"]
    assert cells[:3] == ["dsac.lr=0.0001-s0", "0", "4"]
    assert cells[6] == ("never" if first_095 is None else str(first_095))
    assert cells[-1].startswith("last validation (episode 4)")


@pytest.mark.parametrize(
    ("test_world", "source"), [(None, "test (3 cases)"), ("paper", "test (3 cases, paper world)")]
)
def test_trial_result_names_the_world_of_its_test(tmp_path, monkeypatch, test_world, source):
    monkeypatch.setattr("crowdplan.backends.sweep.training_stability", lambda run_dir: {})
    meta = {"seed": 0, "episodes": 4, "hours_per_10k_episodes": 1.0}
    (tmp_path / "meta.json").write_text(json.dumps(meta))
    config = {"name": "tiny"} if test_world is None else {"name": "tiny", "test_world": test_world}
    (tmp_path / "config.yaml").write_text(yaml.safe_dump(config))
    (tmp_path / "test").mkdir()
    metrics = ["episodes", *TRIAL_METRICS]
    summary = {key: {"value": 3 if key == "episodes" else 0.5} for key in metrics}
    (tmp_path / "test" / "summary.json").write_text(json.dumps(summary))
    assert trial_result("trial", tmp_path)["source"] == source


def test_a_trial_trained_past_its_budget_without_a_result_is_finished_not_refused(tmp_path):
    # a trial whose last batch of episodes ended past its budget (2 envs finish 6 episodes of 5)
    # and that stopped before writing its result: resuming must not ask for fewer episodes
    trials = expand(BASE, [], [0], 1)
    folder = SweepFolder(tmp_path / "sweep")
    with folder.lock():
        folder.prepare(BASE, 1, trials)
    name = trials[0].name
    argv = ["train", "--config", str(folder.config(name)), "--out", str(folder.run(name))]
    assert main([*argv, "--episodes", "5", "--no-progress"]) == 0  # the config says 4
    summary = run_sweep(folder.root, BASE, trials, 1, InlineBackend, report=lambda _: None)
    (result,) = summary["trials"]
    assert "error" not in result and result["episodes"] >= 5


def test_summary_gives_mean_and_interval_across_seeds():
    trials = expand(BASE, [], [0, 1, 2], 1)
    values = [0.8, 0.9, 1.0]
    results = {
        t.name: {
            "trial": t.name,
            "seed": t.seed,
            "success_rate": v,
            "collision_rate": 1 - v,
            "timeout_rate": 0.0,
            "time_to_goal": 10.0 + v,
            "mean_reward": -0.1,
            "hours_per_10k_episodes": 1.0,
        }
        for t, v in zip(trials, values, strict=True)
    }
    results["tiny-s2"] = {"trial": "tiny-s2", "error": "crowdplan train exited with status 1"}
    (row,) = summarize(trials, results)["settings"]
    assert row["seeds"] == [0, 1] and row["failed"] == ["tiny-s2"]
    assert row["success_rate"]["mean"] == pytest.approx(0.85)
    assert row["success_rate"]["n"] == 2
    low, high = row["success_rate"]["ci95"]
    assert low < 0.85 < high <= 1.0
    assert row["mean_reward"]["ci95"] == [-0.1, -0.1]  # negative values are not clipped at 0


def test_local_process_pool_backend_runs_jobs_and_survives_a_dead_worker(tmp_path):
    flag = tmp_path / "died-once"
    backend = make_backend("local", 2)
    results = dict(backend.map(_die_once, [(str(flag), 1), (str(flag), 2), (str(flag), 3)], 1))
    assert results == {0: 1, 1: 4, 2: 9}
    assert flag.exists()


def _die_once(flag: str, x: int) -> int:
    if x == 2 and not Path(flag).exists():
        Path(flag).touch()
        os._exit(1)  # as a killed worker process
    return x * x


@pytest.mark.parametrize("target", ["sweep", "worker"])
def test_sigterm_stops_the_sweep_and_its_running_trial_with_a_checkpoint(tmp_path, target):
    # A scheduler's or `kill`'s SIGTERM reaches one process only (not the process group, as
    # Ctrl-C does). Sent to the sweep, the trial in the pool's worker must not go on training on
    # its own; sent to the worker, the sweep must stop cleanly, not with a traceback. Either
    # way the second trial, queued in the pool behind the first, must not start.
    config = tmp_path / "long.yaml"
    config.write_text(yaml.safe_dump({**TINY, "episodes": 100_000}))
    out = tmp_path / "sweep"
    argv = ["sweep", "--config", str(config), "--out", str(out), "--workers", "1"]
    argv += ["--seeds", "0-1"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "crowdplan.cli", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        episodes = out / "runs" / "tiny-s0" / "episodes.csv"
        deadline = time.monotonic() + 120
        while not (episodes.is_file() and episodes.read_text().count("\n") >= 3):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.2)
        log = out / "logs" / "tiny-s0.log"
        worker = int(log.read_text().split()[1])  # "pid N on HOST: crowdplan train ..."
        os.kill(proc.pid if target == "sweep" else worker, signal.SIGTERM)
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 130, err
        last = err.strip().splitlines()[-1]
        assert "Traceback" not in err
        if target == "sweep":
            assert last == "crowdplan sweep: interrupted"
        else:
            assert "trial tiny-s0 was stopped; its checkpoint is in" in last
        with pytest.raises(ProcessLookupError):
            os.kill(worker, 0)
        assert "stopped at episode" in log.read_text()
        assert (out / "runs" / "tiny-s0" / "checkpoint.pt").is_file()
        assert not (out / "logs" / "tiny-s1.log").exists()
    finally:  # nothing left running if the test fails
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)


def test_sharded_evaluation_equals_the_single_process_one(tmp_path):
    common = ["eval", "--policy", "orca", "--episodes", "7", "--humans", "3", "-q"]
    assert main([*common, "--out", str(tmp_path / "one")]) == 0
    assert main([*common, "--out", str(tmp_path / "sharded"), "--shards", "3"]) == 0
    one = json.loads((tmp_path / "one" / "summary.json").read_text())
    sharded = json.loads((tmp_path / "sharded" / "summary.json").read_text())
    for meta in (one["meta"], sharded["meta"]):
        del meta["wall_seconds"], meta["eval_git"]  # the clock, and commits made meanwhile
    assert sharded == one
    lines = (tmp_path / "sharded" / "episodes.jsonl").read_text()
    assert lines == (tmp_path / "one" / "episodes.jsonl").read_text()
