"""A non-editable install works from any folder: the wheel carries the shipped models.

The slow test builds a wheel offline (``--no-build-isolation``, the build tools of this
environment), installs it without dependencies into a temporary venv that borrows this
environment's packages, and runs the README's evaluation from an unrelated folder.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_shipped_model_is_in_the_wheel():
    data_files = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"][
        "data-files"
    ]
    for model in sorted(p.parent for p in (ROOT / "models").glob("*/model.pt")):
        target = f"share/crowdplan/models/{model.name}"
        assert data_files.get(target) == [f"models/{model.name}/*"], (
            f'add \'"{target}" = ["models/{model.name}/*"]\' to [tool.setuptools.data-files]'
        )


def _run(*args, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(a) for a in args], cwd=cwd, capture_output=True, text=True, timeout=300, check=True
    )


@pytest.mark.slow
def test_installed_wheel_evaluates_the_shipped_model_from_another_folder(tmp_path):
    source = tmp_path / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info")
    for name in ("src", "models"):
        shutil.copytree(ROOT / name, source / name, ignore=ignore)
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    _run(*pip, "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index",
         "-w", tmp_path / "dist", source, cwd=tmp_path)  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("crowdplan-*.whl")

    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", "--without-pip", venv, cwd=tmp_path)
    python = venv / "bin" / "python"
    purelib = _run(python, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))",
                   cwd=tmp_path).stdout.strip()  # fmt: skip
    # the dependencies come from this environment; its editable crowdplan does not (.pth files
    # of a folder added this way are not processed)
    (Path(purelib) / "_deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    _run(*pip, "--python", python, "install", "-q", "--no-deps", "--no-index", wheel, cwd=tmp_path)

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    where = _run(python, "-c", "import crowdplan; print(crowdplan.__file__)", cwd=elsewhere)
    assert where.stdout.startswith(str(venv)), where.stdout
    _run(venv / "bin" / "crowdplan", "eval", "--model", "lsa-dsac", "--episodes", "5", "-q",
         "--out", "res", cwd=elsewhere)  # fmt: skip
    meta = json.loads((elsewhere / "res" / "summary.json").read_text())["meta"]
    assert meta["model"].startswith(str(venv / "share" / "crowdplan" / "models" / "lsa-dsac"))
    assert meta["eval_git"] is None and meta["crowdplan_version"]
