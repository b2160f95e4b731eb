"""The HTML report (crowdplan report --out) loaded in a real headless browser."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from crowdplan.cli import main

ROOT = Path(__file__).resolve().parent.parent
RUN = ROOT / "results" / "train" / "lsa_dsac_ent05-h1-s0"  # a small committed training run
BROWSER = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A small results tree of every kind the report reads (3 test cases each)."""
    root = tmp_path_factory.mktemp("results")
    circle = root / "records" / "circle"
    for source in (["--model", "lsa-dsac"], ["--policy", "orca"]):
        out = circle / source[1]
        argv = ["eval", *source, "--default-world", "--episodes", "3", "--record", "-q"]
        argv += ["--out", str(out)]
        assert main(argv) == 0
        shutil.copytree(out, root / "generalization" / "circle" / source[1])
    run = root / "train" / RUN.name
    run.mkdir(parents=True)
    for name in ("config.yaml", "meta.json", "validation.csv"):
        shutil.copy(RUN / name, run / name)
    lines = (RUN / "episodes.csv").read_text().splitlines(keepends=True)
    (run / "episodes.csv").write_text("".join(lines[:400]))
    shutil.copytree(circle / "orca", run / "test", ignore=shutil.ignore_patterns("records.npz"))
    return root


@pytest.fixture(scope="module")
def page(results, tmp_path_factory):
    out = tmp_path_factory.mktemp("report")
    assert main(["report", "--out", str(out), "--results", str(results)]) == 0
    return out / "index.html"


def test_report_files_and_tables(page):
    text = page.read_text()
    markdown = (page.parent / "tables.md").read_text()
    assert text.count("<table>") == markdown.count("\n|---") >= 8
    for heading in ("Strategies", "Interpretability", "Training curves", "Transfer", "Paired"):
        assert heading in text
    assert "crowdplan eval --model lsa-dsac --default-world --episodes 3 --record --out" in text
    assert "src='data:image/gif;base64," in text and "paper: LSA-DSAC" in text


def test_report_refuses_folders_with_out(tmp_path, capsys):
    assert main(["report", "--out", str(tmp_path), "results"]) == 2
    assert "give no folders" in capsys.readouterr().err


@pytest.mark.skipif(
    BROWSER is None,
    reason="no chromium on this machine: apt-get install -y chromium (.ci/run installs it)",
)
def test_page_in_a_headless_browser(page):
    dom = subprocess.run(
        [
            BROWSER,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--virtual-time-budget=10000",
            "--dump-dom",
            page.as_uri(),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    images = len(re.findall(r"<img ", dom))
    loaded = re.search(r'data-images-loaded="(\d+)"', dom)
    assert images >= 5 and loaded is not None and int(loaded.group(1)) == images
    assert len(re.findall(r"<table>", dom)) == page.read_text().count("<table>")
    assert len(re.findall(r"<tr>", dom)) > 20


def test_same_cases_needs_same_seeds_and_world():
    from crowdplan.analysis.html_report import same_cases

    def summary(**world):
        return {"meta": {"seeds": [1000, 1499], "world": world}}

    assert same_cases(summary(humans=5, action_frame="goal"), summary(humans=5, new_option=1))
    assert not same_cases(summary(humans=5), summary(humans=10))
    other = {"meta": {"seeds": [1000, 1009], "world": {"humans": 5}}}
    assert not same_cases(summary(humans=5), other)
