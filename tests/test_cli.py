"""End-to-end smoke runs of every CLI entry point, and their bad-input errors."""

import json

import pytest
import yaml

from crowdplan.cli import main

TINY_TRAIN = {
    "name": "tiny",
    "episodes": 4,
    "num_envs": 2,
    "random_steps": 20,
    "learning_starts": 20,
    "val_interval": 2,
    "val_episodes": 3,
    "checkpoint_interval": 2,
    "log_interval": 2,
    "test_episodes": 4,
    "world": {"humans": 2, "time_limit": 3.0},
    "encoder": {"name": "lsa"},
    "dsac": {"batch_size": 16},
}


def test_eval_writes_summary_and_episodes(tmp_path, capsys):
    assert main(["eval", "--policy", "orca", "--episodes", "4", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    for key in (
        "success_rate",
        "collision_rate",
        "timeout_rate",
        "time_to_goal",
        "mean_distance",
        "discomfort_frequency",
        "mean_reward",
        "path_length",
    ):
        ci = summary[key]["ci95"]
        assert "value" in summary[key] and (ci is None or len(ci) == 2)
    lines = (tmp_path / "episodes.jsonl").read_text().splitlines()
    assert [json.loads(x)["seed"] for x in lines] == [1000, 1001, 1002, 1003]
    assert "success" in capsys.readouterr().out


def test_eval_square_and_humans(tmp_path):
    out = tmp_path / "sq"
    args = [
        "eval",
        "--scenario",
        "square_crossing",
        "--humans",
        "2",
        "--episodes",
        "2",
        "--out",
        str(out),
    ]
    assert main(args) == 0
    assert json.loads((out / "summary.json").read_text())["meta"]["world"]["humans"] == 2


def test_render_png_and_gif(tmp_path):
    for name in ("case.png", "case.gif"):
        assert (
            main(
                [
                    "render",
                    "--policy",
                    "orca",
                    "--case",
                    "1",
                    "--humans",
                    "2",
                    "--out",
                    str(tmp_path / name),
                ]
            )
            == 0
        )
        assert (tmp_path / name).stat().st_size > 0


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["eval", "--policy", "nope"], "unknown policy 'nope'"),
        (["eval", "--humans", "-2"], "humans must be an integer >= 0"),
        (["eval", "--option", "warp=1"], "unknown key(s) ['warp']"),
        (["eval", "--episodes", "0"], "--episodes must be >= 1"),
        (["eval", "--batch-size", "0"], "--batch-size must be >= 1"),
        (["eval", "--option", "kinematics=unicycle"], "drives holonomic robots"),
        (["render", "--case", "-1", "--out", "x.png"], "--case must be >= 0"),
        (["eval", "--model", "no-such-model"], "no model found"),
        (["render", "--case", "0", "--out", "x.bmp"], ".bmp"),
        (["train", "--config", "missing.yaml"], "does not exist"),
        (["train", "--config", "configs/lsa_dsac.yaml", "--val-interval", "0"], "val_interval"),
        (["train", "--config", "configs/lsa_dsac.yaml", "--episodes", "-1"], "episodes must be"),
    ],
)
def test_bad_input_is_explained(argv, fragment, capsys):
    assert main(argv) == 2
    assert fragment in capsys.readouterr().err


def test_train_eval_render_model(tmp_path, capsys):
    config = tmp_path / "tiny.yaml"
    config.write_text(yaml.safe_dump(TINY_TRAIN))
    run = tmp_path / "run"
    assert main(["train", "--config", str(config), "--out", str(run), "--no-progress"]) == 0
    for name in (
        "config.yaml",
        "meta.json",
        "episodes.csv",
        "validation.csv",
        "checkpoint.pt",
        "best_model.pt",
        "final_model.pt",
        "test/summary.json",
    ):
        assert (run / name).exists(), name
    meta = json.loads((run / "meta.json").read_text())
    assert meta["episodes"] >= 4 and meta["hours_per_10k_episodes"] > 0
    assert main(["eval", "--model", str(run), "--episodes", "2", "--humans", "2"]) == 0
    assert (
        main(
            [
                "render",
                "--model",
                str(run),
                "--case",
                "0",
                "--humans",
                "2",
                "--out",
                str(tmp_path / "m.png"),
            ]
        )
        == 0
    )
    # a second fresh run into the same folder is refused instead of overwriting it
    assert main(["train", "--config", str(config), "--out", str(run)]) == 2
    assert "already holds a run" in capsys.readouterr().err
    # --resume extends the episode budget (and may change the validation interval and threads)
    resume = ["train", "--out", str(run), "--resume", "--no-progress", "--episodes", "6"]
    assert main([*resume, "--val-interval", "1", "--parallel-update"]) == 0
    resolved = yaml.safe_load((run / "config.yaml").read_text())
    assert resolved["val_interval"] == 1 and resolved["dsac"]["parallel_update"] is True
    assert json.loads((run / "meta.json").read_text())["episodes"] >= 6


def test_report_from_result_folders(tmp_path, capsys):
    assert main(["eval", "--episodes", "2", "--out", str(tmp_path / "orca")]) == 0
    capsys.readouterr()
    assert main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "| orca | circle_crossing | 5 | 2 |" in out
    assert main(["report", str(tmp_path / "missing")]) == 2


def test_report_fills_markdown_blocks(tmp_path, capsys):
    assert main(["eval", "--episodes", "2", "--out", str(tmp_path / "orca")]) == 0
    page = tmp_path / "results.md"
    page.write_text(
        f"# Results\n\n<!-- crowdplan report {tmp_path / 'orca'} -->\nstale table\n"
        "<!-- end report -->\n\nprose stays\n"
    )
    capsys.readouterr()
    assert main(["report", "--fill", str(page)]) == 0
    text = page.read_text()
    assert "stale table" not in text and "prose stays" in text
    assert "| orca | circle_crossing | 5 | 2 |" in text
    before = text
    assert main(["report", "--fill", str(page)]) == 0
    assert page.read_text() == before  # regenerating is idempotent
    (tmp_path / "plain.md").write_text("no blocks\n")
    assert main(["report", "--fill", str(tmp_path / "plain.md")]) == 2
    assert "no '<!-- crowdplan report" in capsys.readouterr().err
