"""``crowdplan report --fill FILE.md``: the tables of a markdown page, regenerated in place.

Every block of the page between ``<!-- crowdplan report DIR [DIR ...] -->`` and
``<!-- end report -->`` is replaced by the output of that report, so that the tables of
docs/results.md are always the output of the command written above them:

- ``<!-- crowdplan report DIR ... -->``: evaluations and training runs under the folders
  (:func:`crowdplan.analysis.report.report`);
- ``<!-- crowdplan report --transfer DIR -->``: the planner x test-world table of a folder written
  by ``python -m crowdplan.analysis.test_worlds`` and its paired comparisons;
- ``<!-- crowdplan report --paper METHOD=DIR ... -->``: the paper's comparison tables
  (:mod:`crowdplan.analysis.paper_tables`);
- ``<!-- crowdplan report --seeds RUN ... -->``: the seed targets of one preset's runs
  (:mod:`crowdplan.analysis.seed_targets`).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

from crowdplan.analysis.html_report import transfer_tables
from crowdplan.analysis.paper_tables import paper_report
from crowdplan.analysis.report import report
from crowdplan.analysis.seed_targets import seed_table
from crowdplan.io import atomic_write

_BLOCK = re.compile(
    r"(?P<head><!-- crowdplan report (?P<args>[^>]*?) -->\n).*?(?P<end><!-- end report -->)", re.S
)


def fill_markdown(path: str | Path) -> int:
    """Regenerate the report blocks of a markdown file in place; returns how many were filled."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"markdown file {path} does not exist")
    text = path.read_text()
    count = 0

    def regenerate(match: re.Match) -> str:
        nonlocal count
        count += 1
        args = shlex.split(match["args"])
        if args[:1] == ["--transfer"]:
            if len(args) != 2 or not Path(args[1]).is_dir():
                raise ValueError(f"{path}: a --transfer block names one existing folder: {args}")
            body = "\n".join(t.markdown() for t in transfer_tables(Path(args[1])))
        elif args[:1] == ["--seeds"]:
            body = seed_table(args[1:]).rstrip("\n")
        elif args[:1] == ["--paper"]:
            body = paper_report(args[1:])
        else:
            body = report(args)
        return f"{match['head']}\n{body}\n{match['end']}"

    new_text = _BLOCK.sub(regenerate, text)
    if count == 0:
        raise ValueError(
            f"{path} has no '<!-- crowdplan report DIR ... -->' ... '<!-- end report -->' block"
        )
    atomic_write(path, lambda f: f.write(new_text))
    return count
