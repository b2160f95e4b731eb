"""DSAC trace diagnostics (crowdplan.analysis.dsac_traces) on a small synthetic run folder."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from crowdplan.analysis import dsac_traces

LR = 3e-4
LEARNING_STARTS = 1000
STEPS_PER_EPISODE = 100


def _write_csv(path: Path, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def _env_steps(episode: int) -> int:
    return LEARNING_STARTS + episode * STEPS_PER_EPISODE


@pytest.fixture
def run(tmp_path: Path) -> Path:
    """1000 episodes: validation reaches 0.95 at 300, dips to 0.85 at 500 while the sampled
    policy still succeeds, collapses to 0.1 at 700 (training failing from 650), recovers at 800,
    collapses again at 900; qf_mean starts at 5 (initial entropy bonus), settles at 0.4 and
    climbs past return_max (1.5) at 750."""
    folder = tmp_path / "synthetic-s0"
    folder.mkdir()
    (folder / "config.yaml").write_text(
        "name: synthetic\ndsac:\n  target_entropy_scale: 0.5\n  init_alpha: 0.2\n"
        f"  lr: {LR}\n  learning_starts: {LEARNING_STARTS}\n"
    )
    _write_csv(
        folder / "episodes.csv",
        [
            {
                "episode": e,
                "outcome": "timeout" if 650 < e <= 780 else "goal",
                "env_steps": _env_steps(e),
            }
            for e in range(1, 1001)
        ],
    )
    success = {100: 0.2, 200: 0.8, 300: 0.96, 400: 0.99, 500: 0.85, 600: 0.97, 700: 0.1}
    success |= {800: 0.97, 900: 0.3, 1000: 0.98}
    _write_csv(
        folder / "validation.csv",
        [{"episode": e, "success_rate": s, "timeout_rate": 1 - s} for e, s in success.items()],
    )
    updates = []
    for e in range(50, 1001, 50):
        # alpha falls at the Adam rate from 0.2 up to episode 50, then sits at 2e-3
        alpha = 0.2 * math.exp(-LR * (_env_steps(e) - LEARNING_STARTS)) if e == 50 else 2e-3
        q = 5.0 if e == 50 else (2.5 if 750 <= e <= 800 else 0.4)
        row = {"episode": e, "env_steps": _env_steps(e), "qf_loss": 1e-3}
        updates.append(row | {"alpha": alpha, "entropy": 2.2 if e > 50 else 4.3, "qf_mean": q})
    _write_csv(folder / "updates.csv", updates)
    return folder


def test_diagnostics_events(run: Path):
    diag = dsac_traces.diagnose(dsac_traces.load_run(run))
    assert diag.run == "synthetic-s0"
    assert diag.episodes == 1000
    assert diag.training_goals == 1000 - 130
    assert diag.target_entropy == f"{0.5 * math.log(81):.4g}"
    assert diag.first_reached == 300
    assert diag.first_below == 500
    assert diag.collapse == 700
    assert diag.collapse_onsets == [700, 900]
    # 500 (sampled policy fine) and 900 (training success recovered by then) are greedy dips;
    # 700 is not: the sampled policy was failing too
    assert diag.greedy_dips == 2
    assert diag.alpha_rate_start == pytest.approx(-1.0)
    assert diag.alpha_at_collapse == pytest.approx(2e-3)
    assert diag.entropy_at_collapse == pytest.approx(2.2)


def test_q_bound_crossings(run: Path):
    diag = dsac_traces.diagnose(dsac_traces.load_run(run))
    assert diag.max_q == pytest.approx(5.0)
    assert diag.max_q_episode == 50
    # the initial 5.0 is the entropy bonus of the initial temperature, not a crossing
    assert diag.q_over_return_max == 750
    # soft bound at alpha 2e-3: 1.5 + 2e-3 log(81) 0.95 / 0.05 = 1.67 < 2.5
    assert diag.q_over_soft_bound == 750


def test_no_collapse_no_crossing(run: Path):
    trace = dsac_traces.load_run(run)
    healthy = dsac_traces.RunTraces(
        trace.folder,
        trace.config,
        {**trace.updates, "qf_mean": trace.updates["qf_mean"].clip(max=0.5)},
        {**trace.validation, "success_rate": trace.validation["success_rate"].clip(min=0.96)},
        trace.episodes,
    )
    diag = dsac_traces.diagnose(healthy)
    assert diag.first_reached == 100
    assert diag.first_below is None and diag.collapse is None and diag.collapse_onsets == []
    assert diag.q_over_return_max is None and diag.q_over_soft_bound is None
    assert diag.alpha_at_collapse is None
    assert "| 100 | - | - | 0 |" in dsac_traces.markdown_tables([diag])


def test_cli_writes_figures_and_tables(run: Path, tmp_path: Path, capsys):
    out = tmp_path / "img"
    assert dsac_traces.main([str(run), str(run), "--out", str(out), "--overview", "all.png"]) == 0
    for name in ("synthetic-s0.png", "all.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = capsys.readouterr().out
    assert printed.count("| synthetic-s0 | 2.197 | 1000 | 870 | 300 | 500 | 700, 900 | 2 |") == 2
    # one window per run: 400-800 and 600-1000 overlap and are merged
    assert printed.count("synthetic-s0, episodes 400-1000:") == 2
    assert "| 700 | 0.10 | 0.90 | 0.50 | 0.00 | 2.00e-03 | 2.20 | 0.400 | 1.0e-03 |" in printed


def test_run_before_its_first_validation(run: Path, tmp_path: Path):
    (run / "validation.csv").unlink()
    diag = dsac_traces.diagnose(dsac_traces.load_run(run))
    assert diag.first_reached is None and diag.collapse_onsets == [] and diag.greedy_dips == 0
    assert diag.q_over_return_max == 750
    assert dsac_traces.main([str(run), "--out", str(tmp_path / "img")]) == 0
    assert (tmp_path / "img" / "synthetic-s0.png").is_file()


def test_not_a_run_folder(tmp_path: Path):
    with pytest.raises(FileNotFoundError):
        dsac_traces.load_run(tmp_path)


def test_paper_world_validation_is_drawn_beside_the_runs_own(
    run: Path, tmp_path: Path, monkeypatch
):
    with open(run / "validation.csv") as f:
        rows = list(csv.DictReader(f))
    paper = [0.5 + i / 100 for i in range(len(rows))]
    _write_csv(
        run / "validation.csv",
        [row | {"paper_success_rate": p} for row, p in zip(rows, paper, strict=True)],
    )
    figures = []
    monkeypatch.setattr(dsac_traces, "_save", lambda fig, out: figures.append(fig) or out)
    trace = dsac_traces.load_run(run)
    dsac_traces.plot_run(trace, tmp_path / "run.png")
    dsac_traces.plot_overview([trace], tmp_path / "all.png")
    run_lines = {line.get_label(): line for line in figures[0].axes[3].get_lines()}
    assert list(run_lines["validation, paper's world"].get_ydata()) == pytest.approx(paper)
    overview_success = figures[1].axes[2].get_lines()
    assert [list(line.get_ydata()) for line in overview_success][1] == pytest.approx(paper)
    assert overview_success[0].get_color() == overview_success[1].get_color()
