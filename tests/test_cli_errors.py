"""Every bad input gets a clear answer, nothing is overwritten, and the CLI keeps its habits.

One parametrised table per kind of answer (docs/cli.md): refused before any work (exit 2, one
message), accepted with a warning, stopped cleanly (Ctrl-C, closed pipe), plus the output
conventions (progress display, help, missing values, intervals, render titles).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from crowdplan import evaluation
from crowdplan.cli import build_parser, main
from crowdplan.config import WorldConfig
from crowdplan.evaluation import episode_record, summarize
from crowdplan.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
SHIPPED_MODEL = ROOT / "models" / "lsa-dsac" / "model.pt"


@pytest.fixture
def no_episodes(monkeypatch):
    """Fail the test if any episode runs: refusals must come before the work."""

    def refuse(*args, **kwargs):
        raise AssertionError("episodes ran before the input was refused")

    monkeypatch.setattr(evaluation, "run_episodes", refuse)


def _files(tmp_path: Path) -> None:
    """The inputs the table refers to, made fresh in ``tmp_path``."""
    (tmp_path / "file").write_text("a file\n")
    (tmp_path / "notes.txt").write_text("not a model\n")
    (tmp_path / "empty-run").mkdir()
    (tmp_path / "done").mkdir()
    (tmp_path / "done" / "summary.json").write_text('{"mine": 1}\n')
    (tmp_path / "picture.png").write_bytes(b"mine")
    (tmp_path / "a-folder.png").mkdir()
    run = tmp_path / "run"
    run.mkdir()
    # a training checkpoint holds non-plain objects (numpy arrays), like the real ones
    torch.save(
        {"format": "crowdplan-dsac-checkpoint/1", "world": {"arrays": np.zeros(3)}},
        run / "checkpoint.pt",
    )


REFUSED = [
    # the splits have a size
    (["eval", "--episodes", "600"], "the test split has 500 cases"),
    (["eval", "--episodes", "1200"], "episodes must be in 1..500, got 1200"),
    (["eval", "--split", "val", "--episodes", "1001"], "the val split has 1000 cases"),
    (["eval", "--episodes", "0"], "--episodes must be >= 1"),
    (["eval", "--batch-size", "0"], "--batch-size must be >= 1"),
    (["render", "--case", "99999", "--out", "{tmp}/x.png"], "test split has cases 0..499"),
    (["render", "--case", "500", "--out", "{tmp}/x.png"], "got case 500"),
    (["render", "--split", "val", "--case", "1000", "--out", "{tmp}/x.png"], "cases 0..999"),
    (["render", "--case", "-1", "--out", "{tmp}/x.png"], "--case must be >= 0"),
    # world options: typed, named, given once, not twice through another flag
    (["eval", "--option", "visible_robot=maybe"], "visible_robot"),
    (["eval", "--option", "humans=many"], "humans"),
    (["eval", "--option", "warp=1"], "['warp']"),
    (["eval", "--option", "visible_robot"], "must look like KEY=VALUE"),
    (["eval", "--option", "circle_radius=[1"], "cannot read the value"),
    (["eval", "--option", "humans=3"], "set humans with --humans"),
    (["eval", "--option", "scenario=square_crossing"], "set scenario with --scenario"),
    (
        ["eval", "--option", "visible_robot=true", "--option", "visible_robot=false"],
        "'visible_robot' given twice",
    ),
    (["eval", "--humans", "-2"], "humans must be"),
    # --model: say what the file is and what was expected
    (["eval", "--model", "{tmp}/run/checkpoint.pt"], "is a training checkpoint"),
    (["eval", "--model", str(ROOT / "configs" / "lsa_dsac.yaml")], "is a YAML file, not a model"),
    (["eval", "--model", "{tmp}/notes.txt"], "is not a torch archive, not a model file"),
    (["eval", "--model", "{tmp}/empty-run"], "holds no model"),
    (["eval", "--model", "no-such-model"], "or a shipped model name ("),
    # --lookahead: a value-network model's option only
    (["eval", "--lookahead", "oracle"], "use with --model"),
    (["eval", "--model", "lsa-dsac", "--lookahead", "oracle"], "lsa-dsac is not one"),
    (["render", "--model", "lstm-a2c", "--lookahead", "oracle", "--out", "{tmp}/x.png"], "drop"),
    (["eval", "--lookahead-precision", "bfloat16"], "use with --model"),
    (["eval", "--model", "lsa-dsac", "--lookahead-precision", "bfloat16"], "drop --lookahead-pre"),
    # outputs: checked before the work, never replaced without --force
    (["eval", "--out", "{tmp}/file"], "is a file; give a folder"),
    (["eval", "--out", "{tmp}/file/sub"], "is a file, not a folder"),
    (["eval", "--out", "{tmp}/done"], "already holds summary.json; pass --force"),
    (["render", "--out", "{tmp}/picture.png"], "exists; pass --force"),
    (["render", "--out", "{tmp}/a-folder.png"], "is a folder"),
    (["render", "--out", "{tmp}/x.bmp"], "'.bmp'"),
    (["render", "--out", "{tmp}/file/x.png"], "is a file, not a folder"),
]


@pytest.mark.parametrize(("argv", "fragment"), REFUSED)
def test_bad_input_is_refused_before_any_work(argv, fragment, tmp_path, capsys, no_episodes):
    _files(tmp_path)
    before = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert fragment in err
    assert err.count("\n") == 1 and err.startswith(f"crowdplan {argv[0]}: error: ")
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == before
    assert (tmp_path / "done" / "summary.json").read_text() == '{"mine": 1}\n'
    assert (tmp_path / "picture.png").read_bytes() == b"mine"


def test_unwritable_out_is_refused_before_any_work(tmp_path, monkeypatch, capsys, no_episodes):
    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr("crowdplan.io.tempfile.mkstemp", denied)
    assert main(["eval", "--out", str(tmp_path / "results")]) == 2
    assert "cannot write to" in capsys.readouterr().err
    assert not (tmp_path / "results").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_read_only_folder_is_refused(tmp_path, capsys, no_episodes):
    tmp_path.chmod(0o500)
    try:
        assert main(["render", "--out", str(tmp_path / "x.png")]) == 2
    finally:
        tmp_path.chmod(0o700)
    assert "Permission denied" in capsys.readouterr().err


WARNED = [
    (["--humans", "0"], "trained with humans=5, this world has humans=0"),
    (["--scenario", "square_crossing"], "trained with scenario=circle_crossing"),
    (["--option", "visible_robot=true"], "trained with visible_robot=False"),
    (["--option", "orca={max_speed: 2.0}"], "trained with orca.max_speed=1.0"),
]


@pytest.mark.parametrize(("extra", "fragment"), WARNED)
def test_model_in_another_world_is_warned(extra, fragment, tmp_path, capsys):
    out = tmp_path / "res"
    argv = ["eval", "--model", "lsa-dsac-paper", "--episodes", "1", "-q", "--out", str(out), *extra]
    assert main(argv) == 0
    warnings = [x for x in capsys.readouterr().err.splitlines() if "warning" in x]
    assert len(warnings) == 1 and fragment in warnings[0]
    differs = json.loads((out / "summary.json").read_text())["meta"]["world_differs_from_training"]
    assert len(differs) == 1


def test_same_world_and_planners_are_not_warned(capsys):
    assert main(["eval", "--model", "lsa-dsac", "--episodes", "1", "-q"]) == 0
    assert main(["eval", "--policy", "orca", "--humans", "0", "--episodes", "1", "-q"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_summary_records_evaluating_and_training_commits(tmp_path):
    argv = ["eval", "--model", "lsa-dsac", "--episodes", "1", "-q", "--out", str(tmp_path)]
    assert main(argv) == 0
    meta = json.loads((tmp_path / "summary.json").read_text())["meta"]
    trained = torch.load(SHIPPED_MODEL, weights_only=True)["info"]["git"]
    assert meta["model_git"] == trained
    assert "git" not in meta and "eval_git" in meta and meta["eval_git"] != trained


def test_existing_results_need_force_and_other_files_stay(tmp_path, capsys):
    out = tmp_path / "res"
    out.mkdir()
    (out / "notes.md").write_text("mine\n")
    base = ["eval", "--episodes", "2", "--humans", "1", "-q", "--out", str(out)]
    assert main(base) == 0
    first = (out / "summary.json").read_text()
    assert main(base) == 2 and "pass --force" in capsys.readouterr().err
    assert (out / "summary.json").read_text() == first
    assert main([*base, "--force"]) == 0
    assert (out / "notes.md").read_text() == "mine\n"


def test_val_split_defaults_to_its_size(tmp_path):
    argv = ["eval", "--split", "val", "--humans", "1", "-q", "--out", str(tmp_path)]
    assert main(argv) == 0
    seeds = [json.loads(x)["seed"] for x in (tmp_path / "episodes.jsonl").read_text().splitlines()]
    assert seeds == list(range(100))


def test_eval_without_out_says_nothing_was_written(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--episodes", "1", "--humans", "1", "-q"]) == 0
    assert "nothing written (no --out)" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------ stopping cleanly
def test_ctrl_c_in_process_is_one_line_and_130(monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(evaluation, "run_episodes", interrupted)
    assert main(["eval", "--episodes", "3"]) == 130
    assert capsys.readouterr().err == "crowdplan eval: interrupted\n"


def _crowdplan(*args: str) -> list[str]:
    return [sys.executable, "-m", "crowdplan.cli", *args]


def test_ctrl_c_during_eval(tmp_path):
    # SARL's lookahead, one episode at a time, takes minutes for the 500 cases (ORCA could finish
    # before the signal arrives).
    argv = _crowdplan(
        "eval", "--model", "sarl", "--batch-size", "1", "--out", str(tmp_path / "res")
    )
    proc = subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # a shell's background job inherits SIGINT ignored; Ctrl-C reaches a foreground command
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    first = proc.stderr.readline()  # the first progress line: episodes are running
    assert first.startswith("eval sarl: "), first
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 130
    assert err.strip().splitlines()[-1] == "crowdplan eval: interrupted"
    assert "Traceback" not in err and out == ""
    assert not (tmp_path / "res").exists()


@pytest.mark.parametrize(
    "args",
    [
        ["eval", "--episodes", "2", "--humans", "1", "-q", "--out", "{tmp}/res"],
        ["report", str(ROOT / "results" / "orca")],
    ],
    ids=["eval", "report"],
)
def test_closed_pipe_is_quiet_and_results_are_kept(args, tmp_path):
    argv = _crowdplan(*(a.format(tmp=tmp_path) for a in args))
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # like `| head` having exited
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=120) == 141
    assert err == ""
    assert args[0] != "eval" or (tmp_path / "res" / "summary.json").is_file()


# ------------------------------------------------------------ progress display
def test_progress_in_a_log_has_lines_not_carriage_returns():
    stream = io.StringIO()
    with Progress(10, "eval x", stream=stream, delay=0.0, log_every=0.0) as progress:
        for _ in range(5):
            progress.update(2, success=0.5, reward=0.25)
    lines = stream.getvalue().splitlines()
    assert "\r" not in stream.getvalue() and len(lines) == 5
    assert lines[-1].startswith("eval x: 10/10 episodes (100%), success=0.500 reward=0.250")


def test_progress_is_silent_when_quiet_or_short():
    for kwargs in ({"quiet": True, "delay": 0.0}, {"delay": 60.0}):
        stream = io.StringIO()
        with Progress(4, "eval", stream=stream, **kwargs) as progress:
            progress.update(4, success=1.0)
        assert stream.getvalue() == ""


def test_progress_on_a_terminal_is_a_bar():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    stream = Terminal()
    with Progress(4, "eval", stream=stream, delay=0.0) as progress:
        progress.update(4, success=1.0)
    assert "4/4" in stream.getvalue() and "success=1.000" in stream.getvalue()


# ------------------------------------------------------------ help and version
def _options():
    parser = build_parser()
    (sub,) = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for name, command in sub.choices.items():
        for action in command._actions:
            if action.option_strings and action.nargs != 0:
                yield name, action


@pytest.mark.parametrize(("command", "action"), list(_options()), ids=lambda x: str(x))
def test_every_option_help_shows_its_default(command, action):
    assert "default" in action.help or action.required, (command, action.option_strings)


def test_version(capsys):
    from crowdplan import __version__

    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0 and capsys.readouterr().out == f"crowdplan {__version__}\n"


# ------------------------------------------------------------ values and intervals
def _record(outcome, speed=1.0):
    """4 steps of 0.25 s at ``speed`` m/s towards a goal 1 m away (SPL 1 at speed 1)."""
    vel = np.tile([0.0, speed], (4, 1))
    return episode_record(0, outcome, np.zeros(4), np.full(4, 0.5), vel, 1.0, WorldConfig())


def test_intervals_stay_in_the_metric_range():
    records = [_record("goal") for _ in range(30)] + [_record("goal", speed=1.1)]
    s = summarize(records, WorldConfig())
    value, (lo, hi) = s["spl"]["value"], s["spl"]["ci95"]
    assert value + (value - lo) > 1.0 and hi == 1.0  # the normal interval would pass 1
    for key in ("time_to_goal", "path_length", "jerk"):
        assert s[key]["ci95"][0] >= 0.0


def test_one_sample_has_no_interval_and_missing_values_are_null_and_na(tmp_path, capsys):
    s = summarize([_record("goal"), _record("timeout")], WorldConfig())
    assert s["time_to_goal"]["ci95"] is None and s["path_length"]["ci95"] is None
    assert math.isnan(s["mean_distance"]["value"]) and s["mean_distance"]["ci95"] is None
    table = evaluation.format_table(s)
    assert "mean distance (m)         n/a\n" in table and "time to goal (s)        1.000\n" in table
    out = tmp_path / "r"
    evaluation.write_results(out, s, [], {"policy": "p", "world": {}})
    saved = json.loads((out / "summary.json").read_text())
    assert saved["mean_distance"] == {"value": None, "ci95": None}
    assert saved["time_to_goal"]["ci95"] is None
    assert main(["report", str(tmp_path)]) == 0
    row = capsys.readouterr().out.splitlines()[-1].split(" | ")
    assert "n/a" in row and "1.00" in row  # mean distance; time to goal without interval


# ------------------------------------------------------------ render titles
def test_render_title_is_inside_gif_frames():
    from crowdplan.algos.orca_planner import OrcaPlanner
    from crowdplan.sim.render import animation_frames

    (record,) = evaluation.run_episodes(
        OrcaPlanner(), WorldConfig(humans=2, time_limit=2.0), [1000], record_traces=True
    )
    frame = animation_frames(record.trace, "a title with tall letters: lbdfhk")[0]
    assert (frame[:2] > 240).all(), "title reaches the top edge of the frame"
    assert (frame[2:20] < 100).any(), "no title drawn"
