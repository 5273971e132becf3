"""The lint rules and the code style of pyproject.toml ([tool.ruff*]) hold on the whole repository."""

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _ruff(*args: str) -> subprocess.CompletedProcess:
    pytest.importorskip("ruff")
    return subprocess.run(
        [sys.executable, "-m", "ruff", *args, str(REPO)], capture_output=True, text=True, cwd=REPO, timeout=300
    )


def test_ruff_finds_nothing():
    out = _ruff("check", "--output-format", "concise")
    assert out.returncode == 0, out.stdout + out.stderr


def test_ruff_format_changes_nothing():
    out = _ruff("format", "--check")
    assert out.returncode == 0, out.stdout + out.stderr + "\n(run `ruff format` to apply)"
