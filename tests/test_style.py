"""The kit's Python holds to one style (issue 27 §5): ruff's lint and format, configured in pyproject.toml.

Run by hand with `ruff check . && ruff format --check .`; `ruff check --fix . && ruff format .` repairs most of what
these tests report. The notebooks are left out on purpose: they are lessons laid out by hand (pyproject.toml)."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest

KIT_ROOT = Path(__file__).resolve().parents[1]


def ruff(*args: str) -> subprocess.CompletedProcess:
    beside = Path(sys.executable).with_name("ruff")  # the pinned one, installed with this interpreter's packages
    exe = str(beside) if beside.exists() else shutil.which("ruff")
    if exe is None:
        pytest.fail("ruff is not installed: it comes with `python -m pip install -r requirements-test.txt`")
    return subprocess.run([exe, *args], cwd=KIT_ROOT, capture_output=True, text=True, check=False)


def test_ruff_finds_nothing_to_lint():
    result = ruff("check", "--no-cache", "--output-format", "concise", ".")
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_the_code_is_formatted_as_ruff_formats_it():
    result = ruff("format", "--no-cache", "--check", ".")
    assert result.returncode == 0, "run `ruff format .`:\n" + result.stdout[-4000:] + result.stderr[-2000:]


def test_the_style_check_catches_a_defect(tmp_path):
    """The two tests above can fail: an unused import and a badly laid-out line are found under the kit's config."""
    bad = tmp_path / "bad.py"
    bad.write_text("import os\nx = {  'a':1 }\n")
    config = str(KIT_ROOT / "pyproject.toml")
    assert "F401" in ruff("check", "--no-cache", "--config", config, str(bad)).stdout
    assert ruff("format", "--no-cache", "--config", config, "--check", str(bad)).returncode == 1
