"""Smoke runs of the benchmark scripts (no timing assertions)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"

TINY_TRAIN_YAML = (
    "name: tiny\nnum_envs: 2\nrandom_steps: 16\nlearning_starts: 16\n"
    "world: {humans: 3, time_limit: 4.0}\nencoder: {name: lsa}\ndsac: {batch_size: 16}\n"
)


def _run_bench(name: str, *args: str) -> subprocess.CompletedProcess:
    """Run benchmarks/<name> with ``args`` and check that it succeeded."""
    result = subprocess.run(
        [sys.executable, str(BENCHMARKS / name), *args],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    return result


def test_bench_sim_quick():
    result = _run_bench("bench_sim.py", "--quick", "--seconds", "0.05", "--humans", "5", "20")
    out = result.stdout
    header = next(line for line in out.splitlines() if line.startswith("| N |"))
    assert "ratio" in header and "crowdplan steps/s" in header
    rows = [
        line for line in out.splitlines() if line.startswith("| 5 |") or line.startswith("| 20 |")
    ]
    assert len(rows) == 4  # E = 1 and E = 64 for each N


def test_bench_update_quick():
    args = ["--batch", "16", "--warmup", "1", "--iters", "2", "--rounds", "1"]
    result = _run_bench("bench_update.py", *args, "--parallel-update", "--bf16", "--profile")
    assert "| update ms |" in result.stdout and "ratio" in result.stdout
    assert "| serial update ms | parallel update ms | speed-up |" in result.stdout
    assert "| float32 update ms | bfloat16 autocast update ms | speed-up |" in result.stdout
    shares = [
        float(line.rsplit("|", 2)[1].strip().rstrip("%"))
        for line in result.stdout.splitlines()
        if line.startswith(("| LSTM", "| matmul", "| optimiser", "| everything else"))
    ]
    assert len(shares) == 4 and abs(sum(shares) - 100.0) < 0.5


def test_bench_train_quick(tmp_path):
    config = tmp_path / "tiny.yaml"
    config.write_text(TINY_TRAIN_YAML)
    result = _run_bench("bench_train.py", "--config", str(config), "--episodes", "4")
    assert "identical episodes in both runs: yes" in result.stdout
    assert "| serial | 4 |" in result.stdout and "| two threads | 4 |" in result.stdout


def test_bench_train_resume_from_runs_of_two_algorithms(tmp_path):
    tiny_a2c = "name: tiny\nalgo: a2c\nnum_envs: 2\nworld: {humans: 3, time_limit: 4.0}\n"
    runs = []
    for algo, yaml_text in (("dsac", TINY_TRAIN_YAML), ("a2c", tiny_a2c)):
        config = tmp_path / f"{algo}.yaml"
        config.write_text(yaml_text + "episodes: 2\ntest_episodes: 0\nval_episodes: 2\n")
        run = tmp_path / algo
        train = ["-m", "crowdplan.cli", "train", "--config", str(config), "--out", str(run)]
        subprocess.run([sys.executable, *train, "--no-progress"], check=True, timeout=300)
        runs.append(str(run))
    args = ["--episodes", "2", "--torch-threads", "2"]
    result = _run_bench("bench_train.py", "--resume-from", *runs, *args)
    rows = result.stdout.strip().splitlines()[-2:]
    for row, algo in zip(rows, ("dsac", "a2c"), strict=True):
        cells = [cell.strip() for cell in row.strip("|").split("|")]
        # run, algo, torch threads, continued from, episodes
        assert cells[:5] == [algo, algo, "2", "2", "2"]
        assert float(cells[-2]) > 0 and float(cells[-1].rstrip("x")) > 0  # h / 10k, ratio
    assert rows[0].endswith("| 1.00x |")


def test_bench_value_update_quick():
    args = ["--network", "cadrl", "--humans", "2", "--updates", "3", "--repeats", "1"]
    extra = ["--buffer", "500", "--threads", "2", "--compile"]
    result = _run_bench("bench_value_update.py", *args, *extra)
    assert "| reference: target forward per batch |" in result.stdout
    assert re.search(r"\| \d+\.\d\dx (faster|slower) \|", result.stdout)
    threads_rows = result.stdout.split("1 and 2 torch threads")[1].split("#")[0]
    threads_rows = threads_rows.strip().splitlines()[3:]
    assert [row.split("|")[1].strip() for row in threads_rows] == ["1", "2"]
    compile_rows = result.stdout.split("loss compiled")[1].strip().splitlines()[3:]
    assert [row.split("|")[1].strip() for row in compile_rows] == [
        "CPU time, 1 thread",
        "wall clock, 2 threads",
    ]


def test_bench_two_cores_quick():
    args = ["--network", "cadrl", "--updates", "3", "--rounds", "1"]
    result = _run_bench("bench_two_cores.py", *args)
    medians = result.stdout.split("# medians")[1].strip().splitlines()[3:]
    assert [row.split("|")[1].strip() for row in medians] == [
        "reference: one job, 1 thread",
        "two jobs at once, 1 thread each",
        "one job, 2 threads",
    ]
    assert all(re.search(r"\d\.\d\dx (faster|slower) \|$", row) for row in medians[1:])


def test_bench_lookahead_bf16_quick():
    args = ["--model", "cadrl", "--envs", "2", "--cases", "2", "--steps", "2", "--repeats", "1"]
    result = _run_bench("bench_lookahead_bf16.py", *args, "--threads", "2", "--compile")
    assert "| bfloat16 (autocast) |" in result.stdout
    assert re.search(r"^\| float32, compiled \| 1\.000 \|", result.stdout, re.M)  # same actions
    timed = r"[\d.]+ \| [\d.]+ \| [\d.]+x (faster|slower) \|$"
    assert re.search(r"^\| bfloat16 \(autocast\), compiled \| " + timed, result.stdout, re.M)
    agreement = result.stdout.strip().splitlines()[-1].split("|")[2]
    assert 0.0 <= float(agreement) <= 1.0
