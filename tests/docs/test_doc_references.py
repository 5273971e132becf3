"""Docstrings, comments and docs name files and modules that exist: a module that moves takes its
mentions along (before: `envs.rsl_rl_env` named in zoo/train/ppo.py, `.space` in the failures
package, an io module under benchmark/ in docs/failures.md, all long gone)."""

from __future__ import annotations

import importlib
import importlib.util
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("envs", "zoo", "benchmark")
# test_layers.py writes made-up modules into a scratch copy on purpose.
SKIP = {"tests/project/test_layers.py"}
PATH = re.compile(r"(?<![\w./-])((?:envs|zoo|benchmark|scripts|tests|docs|leaderboards)/[\w/.-]*\.(?:py|md|toml|json))")
DOTTED = re.compile(r"\bovertakezoo\.((?:envs|zoo|benchmark)(?:\.\w+)+)")
RELATIVE = re.compile(r":mod:`(\.\w+)`")


def _texts() -> list[tuple[str, str]]:
    files = [
        p
        for top in (*PACKAGES, "scripts", "tests", "docs")
        for p in (REPO / top).rglob("*")
        if p.suffix in (".py", ".md") and p.is_file()
    ]
    files += [REPO / "README.md", REPO / "leaderboards" / "README.md"]
    return [
        (p.relative_to(REPO).as_posix(), p.read_text(errors="replace"))
        for p in files
        if p.relative_to(REPO).as_posix() not in SKIP
    ]


def _resolves(dotted: str) -> bool:
    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):  # the longest importable module, then attributes of it
        name = "overtakezoo." + ".".join(parts[:i])
        try:
            found = importlib.util.find_spec(name) is not None
        except ModuleNotFoundError:
            found = False
        if found:
            obj = importlib.import_module(name)
            for attr in parts[i:]:
                if not hasattr(obj, attr):
                    return False
                obj = getattr(obj, attr)
            return True
    return False


def test_named_files_exist():
    missing = sorted(
        {
            (rel, path)
            for rel, text in _texts()
            for path in PATH.findall(text)
            if not (REPO / path).exists() and path == path.lower()
        }
    )  # (ALGO.toml: a placeholder)
    assert not missing, missing


def test_named_modules_and_objects_exist():
    missing = sorted(
        {(rel, name) for rel, text in _texts() for name in DOTTED.findall(text) if not _resolves(name.rstrip("."))}
    )
    assert not missing, missing


@pytest.mark.parametrize(
    "init", sorted(p.relative_to(REPO).as_posix() for top in PACKAGES for p in (REPO / top).rglob("__init__.py"))
)
def test_a_package_docstring_names_its_own_submodules(init):
    folder = (REPO / init).parent
    for rel in RELATIVE.findall((REPO / init).read_text()):
        assert (folder / f"{rel[1:]}.py").is_file() or (folder / rel[1:]).is_dir(), f"{init}: {rel}"
