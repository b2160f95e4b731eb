"""Smoke run of the simulation benchmark (no timing assertions)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_sim.py"


def test_bench_sim_quick():
    result = subprocess.run(
        [sys.executable, str(SCRIPT), "--quick", "--seconds", "0.05", "--humans", "5", "20"],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    out = result.stdout
    header = next(line for line in out.splitlines() if line.startswith("| N |"))
    assert "ratio" in header and "crowdplan steps/s" in header
    rows = [
        line for line in out.splitlines() if line.startswith("| 5 |") or line.startswith("| 20 |")
    ]
    assert len(rows) == 4  # E = 1 and E = 64 for each N


def test_bench_update_quick():
    script = SCRIPT.parent / "bench_update.py"
    args = ["--batch", "16", "--warmup", "1", "--iters", "2", "--rounds", "1"]
    result = subprocess.run(
        [sys.executable, str(script), *args], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert "| update ms |" in result.stdout and "ratio" in result.stdout
