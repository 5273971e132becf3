"""The lint rules and the code style of pyproject.toml ([tool.ruff*]) hold on the whole repository."""

import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]


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


def test_mypy_finds_nothing():
    """envs/ and zoo/ type-check clean: `mypy` with pyproject.toml's [tool.mypy] (the packages, the
    settings), as run from the repository root. Its cache is the default .mypy_cache/ (git-ignored),
    so a second run takes seconds."""
    pytest.importorskip("mypy")
    out = subprocess.run(
        [sys.executable, "-m", "mypy", "--config-file", str(REPO / "pyproject.toml")],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=600,
    )
    assert out.returncode == 0, out.stdout + out.stderr
