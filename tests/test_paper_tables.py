"""The paper's comparison tables (crowdplan report --paper) from small hand-made result folders."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from crowdplan.analysis import paper_tables
from crowdplan.analysis.markdown_fill import fill_markdown
from crowdplan.analysis.paper_tables import METHODS, paper_report, paper_values
from crowdplan.cli import main

ROOT = Path(__file__).resolve().parent.parent
PAGE = ROOT / "docs" / "paper.md"


def _summary(folder: Path, policy: str, success: float, scenario: str, humans: int = 5, **meta):
    metrics = {
        "success_rate": success,
        "collision_rate": 1 - success,
        "timeout_rate": 0.0,
        "time_to_goal": 11.0,
        "mean_distance": 0.15,
        "mean_reward": success / 2,
    }
    summary = {key: {"value": v, "ci95": [v - 0.01, v + 0.01]} for key, v in metrics.items()}
    summary["episodes"] = {"value": 500}
    world = {"scenario": scenario, "humans": humans}
    summary["meta"] = {"policy": policy, "world": world, **meta}
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps(summary))


def _run(root: Path, name: str, circle: float, square: float, rewards: list[float], **kw) -> Path:
    """A published training run: config, meta, validation log, circle and square tests."""
    run = root / name
    algo = kw.get("algo", "value_rl")
    _summary(run / "test", name.split("-")[0], circle, "circle_crossing", **kw)
    _summary(run / "test-square", name.split("-")[0], square, "square_crossing", **kw)
    config = {"name": name, "algo": algo, "world": {"humans": kw.get("train_humans", 5)}}
    if "val_humans" in kw:
        config["val_humans"] = kw["val_humans"]
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    meta = {"episodes": 100 * len(rewards), "hours_per_10k_episodes": kw.get("hours", 2.0)}
    meta |= {"torch_threads": 1, "pretrain_seconds": 3600.0 if algo == "value_rl" else None}
    (run / "meta.json").write_text(json.dumps(meta))
    lines = ["episode,env_steps,success_rate,mean_reward"]
    lines += [f"{100 * (i + 1)},0,0.5,{r}" for i, r in enumerate(rewards)]
    (run / "validation.csv").write_text("\n".join(lines) + "\n")
    return run


@pytest.fixture()
def runs(tmp_path):
    """ORCA (planner), SARL with two seeds, LSA-DSAC with one."""
    _summary(tmp_path / "orca" / "circle_crossing", "orca", 0.4, "circle_crossing")
    _summary(tmp_path / "orca" / "square_crossing", "orca", 0.7, "square_crossing")
    kw = {"algo": "value_rl", "encoder": None}
    s0 = _run(tmp_path, "sarl-s0", 0.98, 0.90, [0.1, 0.5, 0.6, 0.7], **kw)
    s1 = _run(tmp_path, "sarl-s1", 1.00, 0.94, [0.2, 0.5, 0.5], hours=4.0, **kw)
    lsa = _run(tmp_path, "lsa-s2", 0.99, 0.93, [0.57], algo="dsac", encoder="lsa")
    return {"ORCA": tmp_path / "orca", "SARL": [s0, s1], "LSA-DSAC": lsa}


def _args(runs, tmp_path) -> list[str]:
    return [
        f"ORCA={runs['ORCA']}",
        f"SARL={runs['SARL'][0]}",
        f"SARL={runs['SARL'][1]}",
        f"LSA-DSAC={runs['LSA-DSAC']}",
        f"CADRL?={tmp_path / 'cadrl-s0'}",  # published later
    ]


def _rows(markdown: str, title: str) -> dict[str, list[str]]:
    """Rows of the table under the '### title...' heading, by method."""
    block = markdown.split(f"### {title}")[1].split("###")[0]
    cells = [
        [c.strip() for c in line.strip("|").split("|")]
        for line in block.splitlines()
        if line.startswith("| ") and not line.startswith("| method")
    ]
    return {row[0]: row[1:] for row in cells}


def test_every_paper_table_parses_from_docs():
    paper = paper_values(PAGE)
    assert set(paper["VI"]) == set(METHODS) and set(paper["VIII"]) == set(METHODS)
    assert set(paper["II"]) == set(paper["VII"]) == set(METHODS) - {"ORCA"}
    assert (paper["II"]["SARL"], paper["VII"]["SARL"], paper["VIII"]["SARL"]) == (
        "0.55",
        "14.72",
        "0.92",
    )
    assert paper["VI"]["LSA-DSAC"]["success"] == "0.996"
    assert paper_tables.paper_robustness(paper, "LSA-DSAC") == pytest.approx(0.066)


def test_rows_from_result_folders(runs, tmp_path):
    text = paper_report(_args(runs, tmp_path), PAGE)
    vi = _rows(text, "Table VI")
    assert list(vi) == list(METHODS)
    assert vi["ORCA"][:4] == ["orca", "planner", "0.400 [0.390, 0.410]", "0.43"]
    assert vi["LSA-DSAC"][:4] == ["lsa-s2", "5 humans", "0.990 [0.980, 1.000]", "0.996"]
    # two seeds: the mean with its Student-t interval over seeds
    assert vi["SARL"][0] == "sarl-s0, sarl-s1"
    assert vi["SARL"][1] == "5 humans"
    assert vi["SARL"][2].startswith("0.990 [") and vi["SARL"][2].endswith("(2 seeds)")
    assert vi["SARL"][3] == "0.99"

    ii = _rows(text, "Table II")
    # converged: mean of the last three validations of each seed, then over seeds
    assert ii["SARL"][2] == "200, 300, 400; 100, 200, 300"
    assert ii["SARL"][3].startswith(f"{((0.5 + 0.6 + 0.7) / 3 + 0.4) / 2:.3f} [")
    assert ii["LSA-DSAC"][2:] == ["100", "0.570", "0.57"]
    assert ii["ORCA"] == ["planner: no training", "-", "-", "-", "-"]

    vii = _rows(text, "Table VII")
    assert vii["SARL"][2] == "400, 300" and vii["SARL"][3].startswith("3.00 [")
    assert vii["SARL"][4].startswith("1.00")  # one hour of imitation learning per seed
    assert vii["LSA-DSAC"][1:] == ["cpu, 1", "100", "2.00", "-", "4.56"]

    assert _rows(text, "Table VIII")["LSA-DSAC"] == ["lsa-s2", "0.930 [0.920, 0.940]", "0.93"]
    ix = _rows(text, "Table IX")
    assert ix["ORCA"] == ["orca", "0.400", "0.700", "0.300", "0.310"]
    assert ix["LSA-DSAC"][3:] == ["0.060", "0.066"]

    notes = text.split("Reading notes")[1]
    assert "Table VI, success: as good as the paper or better (SARL)" in notes
    inside = "worse, the paper's value inside our 95% interval (LSA-DSAC)"
    assert f"{inside}; worse than the paper (ORCA)" in notes
    assert "no result yet (CADRL, LSTM-RL, LSTM-A2C, RG-DSAC)" in notes
    # several seeds: compared with the interval over seeds that table II prints (SARL 0.4, 0.6)
    assert (
        "Table II, converged reward: as good as the paper or better (LSA-DSAC); "
        + inside.replace("LSA-DSAC", "SARL")
        in notes
    )


def test_a_run_validated_in_another_world_says_so(runs, tmp_path):
    cadrl = _run(tmp_path, "cadrl-s3", 0.96, 0.73, [0.5], train_humans=1, val_humans=5)
    text = paper_report([*_args(runs, tmp_path)[:-1], f"CADRL={cadrl}"], PAGE)
    assert _rows(text, "Table II")["CADRL"][:2] == ["cadrl-s3", "1 human, validated with 5"]
    assert _rows(text, "Table II")["SARL"][1] == "5 humans"
    # the paper's converged reward is in the training world: not compared with a 5-human one
    notes = text.split("Reading notes")[1]
    table_ii = next(line for line in notes.splitlines() if "Table II" in line)
    assert table_ii.endswith(
        "; not compared, validated with another crowd than trained with (CADRL)."
    )
    assert "Table VI, success: as good as the paper or better (CADRL, SARL)" in notes


def test_methods_without_runs_show_the_paper_value(runs, tmp_path):
    text = paper_report(_args(runs, tmp_path), PAGE)
    vi, ii, viii = _rows(text, "Table VI"), _rows(text, "Table II"), _rows(text, "Table VIII")
    for method, success, reward in (("CADRL", "0.89", "0.61"), ("LSTM-RL", "0.96", "0.49")):
        assert vi[method][:4] == ["not trained", "-", "n/a", success]
        assert ii[method] == ["not trained", "-", "-", "n/a", reward]
        assert viii[method][:2] == ["not trained", "n/a"]
    only_lsa = paper_report([f"LSA-DSAC={runs['LSA-DSAC']}"], PAGE)
    assert _rows(only_lsa, "Table VI")["ORCA"][:4] == ["not evaluated", "-", "n/a", "0.43"]


@pytest.mark.parametrize(
    ("word", "error", "message"),
    [
        ("SARLX={sarl}", ValueError, "unknown method 'SARLX'"),
        ("sarl", ValueError, "METHOD=DIR"),
        ("SARL={tmp}/sarl-s9", FileNotFoundError, "SARL?="),
        ("LSA-DSAC={sarl}", ValueError, "evaluates SARL, not LSA-DSAC"),
        ("SARL={tmp}/orca", ValueError, "evaluates ORCA, not SARL"),
        ("LSA-DSAC={tmp}", FileNotFoundError, "test/summary.json"),
    ],
)
def test_bad_input_names_the_word(runs, tmp_path, word, error, message):
    word = word.format(sarl=runs["SARL"][0], tmp=tmp_path)
    with pytest.raises(error, match=message) as raised:
        paper_report([word], PAGE)
    if "unknown" in message or "METHOD" in message:
        assert ", ".join(METHODS) in str(raised.value)


def test_tests_must_be_the_papers_setting(tmp_path):
    run = _run(tmp_path, "sarl-h10-s0", 0.9, 0.8, [0.5], humans=10)
    with pytest.raises(ValueError, match="with 10 humans; the paper's tables are 500"):
        paper_report([f"SARL={run}"], PAGE)


def test_fill_block_and_cli(runs, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(ROOT)  # docs/paper.md is read from the repository root
    args = " ".join(_args(runs, tmp_path))
    page = tmp_path / "results.md"
    page.write_text(f"# R\n\n<!-- crowdplan report --paper {args} -->\nold\n<!-- end report -->\n")
    assert fill_markdown(page) == 1
    filled = page.read_text()
    assert "old" not in filled and filled.count("### Table") == 5
    assert fill_markdown(page) == 1 and page.read_text() == filled  # regenerates identically

    assert main(["report", "--paper", *args.split()]) == 0
    assert capsys.readouterr().out in filled
    assert main(["report", "--paper", f"SARL={tmp_path / 'none'}"]) == 2
    assert "SARL?=" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("dsac", "trained_with"),
    [
        (
            {"target_entropy_scale": 0.5, "n_actions": 81},
            "5 humans, target entropy 0.5 log 81 (preset rg-s0)",
        ),
        (
            {"target_entropy_scale": 0.98, "target_entropy": -162.0},
            "5 humans, target entropy -162 (preset rg-s0)",
        ),
    ],
)
def test_a_dsac_run_says_its_target_entropy(tmp_path, dsac, trained_with):
    run = _run(tmp_path, "rg-s0", 0.95, 0.5, [0.5], algo="dsac", encoder="rg")
    config = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump(config | {"dsac": dsac}))
    text = paper_report([f"RG-DSAC={run}"], PAGE)
    assert _rows(text, "Table VI")["RG-DSAC"][:2] == ["rg-s0", trained_with]
