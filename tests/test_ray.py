"""Sweeps and sharded evaluation on Ray (the ``[ray]`` extra), on private Ray instances that bind
the loopback interface only; a killed worker's trial resumes elsewhere with the same results."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from crowdplan.backends.sweep import SweepFolder, expand, run_sweep
from crowdplan.cli import main
from crowdplan.training import config_from_dict
from tests.test_sweep import TINY, InlineBackend

pytest.importorskip("ray")

CROWDPLAN = [sys.executable, "-m", "crowdplan.cli"]
ENV = {**os.environ, "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}


def _start(argv: list[str], log: Path) -> subprocess.Popen:
    """A crowdplan command in its own session (so that the test can always end it)."""
    with open(log, "w") as out:
        return subprocess.Popen(
            [*CROWDPLAN, *argv],
            stdout=out,
            stderr=subprocess.STDOUT,
            env=ENV,
            start_new_session=True,
        )


def _finish(process: subprocess.Popen, timeout: float) -> int:
    try:
        return process.wait(timeout=timeout)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def test_unreachable_address_is_a_clear_error_not_a_hang(tmp_path, capsys):
    argv = ["sweep", "--config", "configs/lsa_dsac.yaml", "--out", str(tmp_path / "s")]
    assert main([*argv, "--backend", "ray", "--address", "127.0.0.1:1"]) == 2
    assert "no Ray cluster answers at 127.0.0.1:1" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_killed_worker_trial_resumes_and_the_sweep_gives_the_same_results(tmp_path):
    data = {**TINY, "episodes": 12}
    base = config_from_dict(data).to_dict()
    trials = expand(base, [], [0], 1)
    straight = run_sweep(tmp_path / "straight", base, trials, 1, InlineBackend, lambda _: None)

    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(data))
    out = tmp_path / "ray"
    argv = ["sweep", "--config", str(config), "--out", str(out), "--backend", "ray"]
    process = _start(argv, tmp_path / "sweep.log")
    folder = SweepFolder(out)
    name = trials[0].name
    try:
        pid = None
        while pid is None and process.poll() is None:  # kill the worker after a checkpoint
            time.sleep(0.2)
            log = folder.log(name).read_text() if folder.log(name).is_file() else ""
            checkpoint = folder.run(name) / "checkpoint.pt"
            if (match := re.search(r"pid (\d+)", log)) and checkpoint.is_file():
                pid = int(match[1])
                os.kill(pid, signal.SIGKILL)
        assert pid is not None, (tmp_path / "sweep.log").read_text()
    finally:
        status = _finish(process, timeout=600)
    assert status == 0, (tmp_path / "sweep.log").read_text()
    attempts = re.findall(r"pid (\d+)", folder.log(name).read_text())
    assert (
        len(attempts) == 2
        and attempts[0] == str(pid)
        and "--resume" in folder.log(name).read_text()
    )

    def clockless(summary):
        return [{k: v for k, v in r.items() if k != "hours_per_10k_episodes"} for r in summary]

    ray_summary = json.loads((out / "summary.json").read_text())
    assert clockless(ray_summary["trials"]) == clockless(straight["trials"])
    straight_csv = (tmp_path / "straight" / "runs" / name / "validation.csv").read_text()
    assert (folder.run(name) / "validation.csv").read_text() == straight_csv


def test_sharded_evaluation_on_ray_equals_the_single_process_one(tmp_path):
    common = ["eval", "--policy", "orca", "--episodes", "6", "--humans", "2", "-q"]
    assert main([*common, "--out", str(tmp_path / "one")]) == 0
    process = _start(
        [*common, "--out", str(tmp_path / "ray"), "--backend", "ray", "--shards", "3"],
        tmp_path / "eval.log",
    )
    assert _finish(process, timeout=300) == 0, (tmp_path / "eval.log").read_text()
    one = json.loads((tmp_path / "one" / "summary.json").read_text())
    ray = json.loads((tmp_path / "ray" / "summary.json").read_text())
    for meta in (one["meta"], ray["meta"]):
        del meta["wall_seconds"], meta["eval_git"]  # the clock, and commits made meanwhile
    assert ray == one
