"""The code passes the linter and the formatter configured in pyproject.toml ([tool.ruff])."""

import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff is a dev extra: pip install -e '.[dev]'")
def test_ruff_finds_nothing():
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True
    )
    assert result.returncode == 0, f"ruff check found problems (fix with `ruff check --fix .`):\n{result.stdout}"


@pytest.mark.skipif(importlib.util.find_spec("ruff") is None, reason="ruff is a dev extra: pip install -e '.[dev]'")
def test_the_code_is_laid_out_by_ruff_format():
    result = subprocess.run(
        [sys.executable, "-m", "ruff", "format", "--check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True
    )
    assert result.returncode == 0, f"run `ruff format .` (or `make format`); these files differ:\n{result.stdout}"
