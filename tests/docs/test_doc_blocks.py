"""Every code block of the README and the documentation pages runs as written, or says why not.

Each page's runnable blocks (see ``doc_blocks``) run in order, as a reader following the page would,
in one temporary folder holding a copy of the repository's ``leaderboards/`` (the pages run from a
clone's root, and nothing may write into the repository's own board), with ``$OVERTAKEZOO_HOME`` there
too (datasets, caches). ``pip install -e '.[extras]'`` lines are not run: the extras they name must be
ones the test install already has. A block marked ``run by TEST_FILE`` names a test that reads it
from the page; one marked ``not run: ...`` gives its reason.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from doc_blocks import CODE, REPO, all_blocks, blocks, pages

PIP = re.compile(r"^pip install -e '\.\[([\w,-]+)\]'\s*(#.*)?$")


def _test_extras() -> set[str]:
    """The extras the default test install brings (``[test]`` and those it names)."""
    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    named = {m for dep in extras["test"] for m in re.findall(r"overtakezoo\[([\w,-]+)\]", dep)}
    return {"test", *(e for group in named for e in group.split(","))}


def _runnable(page: Path):
    return [b for b in blocks(page) if b.lang in CODE and not b.mark]


RUN_PAGES = [p.relative_to(REPO).as_posix() for p in pages() if _runnable(p)]


def test_every_code_block_is_run_or_says_why_not():
    for block in all_blocks():
        if block.lang not in CODE:
            continue
        if block.runner:  # the named test exists and reads this page
            runner = REPO / block.runner
            assert runner.is_file(), f"{block.id}: {block.runner} does not exist"
            assert block.page in runner.read_text(), f"{block.id}: {block.runner} never names {block.page}"
        elif block.mark:
            assert len(block.mark) > len("not run: ") + 10, f"{block.id}: say why it is not run"


def test_pip_lines_in_run_blocks_name_extras_the_tests_install():
    have = _test_extras()
    for page in pages():
        for block in _runnable(page):
            for line in block.body.splitlines():
                if line.startswith("pip "):
                    m = PIP.match(line)
                    assert m, f"{block.id}: only `pip install -e '.[extras]'` lines can be skipped: {line}"
                    assert set(m.group(1).split(",")) <= have, f"{block.id}: {line} needs extras beyond [test]"


@pytest.mark.parametrize("page", RUN_PAGES)
def test_page_runs_as_written(page, tmp_path):
    work = tmp_path / "clone"
    work.mkdir()
    shutil.copytree(REPO / "leaderboards", work / "leaderboards", ignore=shutil.ignore_patterns("*.png"))
    env = dict(
        os.environ,
        OVERTAKEZOO_HOME=str(tmp_path / "home"),
        MINARI_DATASETS_PATH=str(tmp_path / "home" / "datasets"),
        MPLBACKEND="Agg",
        PYTHONPATH=str(REPO / "tests"),
    )
    env.pop("OVERTAKEZOO_VERIFY_BASE", None)
    for block in _runnable(REPO / page):
        if block.lang == "python":
            argv = [sys.executable, "-c", block.body]
        else:
            body = "\n".join(line for line in block.body.splitlines() if not PIP.match(line))
            argv = ["bash", "-e", "-o", "pipefail", "-c", body]
        done = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=600)
        output = f"{done.stdout[-2000:]}\n{done.stderr[-3000:]}"
        assert done.returncode == 0, f"{block.id} exited {done.returncode}:\n{output}"
        assert "Traceback" not in done.stderr, f"{block.id}:\n{done.stderr[-3000:]}"
