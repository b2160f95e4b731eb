"""Every generated table of the docs matches the committed result folders it is generated from.

Each ``<!-- crowdplan report ... -->`` block of these pages is regenerated from ``results/`` (as
``crowdplan report --fill PAGE`` does) and must come out as committed: a result folder changed
without regenerating its page, or a page edited by hand inside a block, fails here.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from crowdplan.analysis.markdown_fill import fill_markdown

ROOT = Path(__file__).resolve().parents[1]
PAGES = ["docs/results.md", "docs/training.md", "docs/generalization.md", "docs/scenarios.md"]


@pytest.mark.parametrize("page", PAGES)
def test_generated_tables_match_the_committed_results(page, tmp_path, monkeypatch):
    monkeypatch.chdir(ROOT)  # the blocks name result folders relative to the repository
    copy = tmp_path / Path(page).name
    shutil.copy(ROOT / page, copy)
    assert fill_markdown(copy) > 0
    regenerated, committed = copy.read_text(), (ROOT / page).read_text()
    assert regenerated == committed, f"run `crowdplan report --fill {page}` and commit the result"
