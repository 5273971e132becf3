"""CONTRIBUTING.md's checklist for a new zoo member, followed once: a member declared in the registry
alone is listed by the CLI, passes the protocol check and drives a suite, and the board's measured
tables (the cross-play matrices and the failure board) say they do not cover it yet, naming the
command that measures each again: a warning from `leaderboard --check`, and a failure of the default
run for the shipped board."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.leaderboard.coverage import uncovered
from overtakezoo.zoo import base
from overtakezoo.zoo.base import ConstantDecider, Member
from overtakezoo.zoo.testing import check_decider

ROOT = Path(__file__).resolve().parents[2]
LEADERBOARDS = ROOT / "leaderboards"
NEW = "always-overtake-too"


@pytest.fixture
def new_member(monkeypatch: pytest.MonkeyPatch) -> str:
    """Step 1-2 of the checklist: a decider and its line in the member table (and nothing else)."""
    monkeypatch.setitem(base._MEMBERS, NEW, Member(NEW, "rule"))
    monkeypatch.setitem(base._REGISTRY, NEW, lambda config=None, **kwargs: ConstantDecider(1, NEW, config))
    return NEW


@pytest.fixture
def measured(tmp_path: Path) -> Path:
    """A board root holding the shipped measured tables only."""
    root = tmp_path / "lb"
    shutil.copytree(LEADERBOARDS / "crossplay", root / "crossplay")
    (root / "failures").mkdir(parents=True)
    shutil.copy(LEADERBOARDS / "failures" / "board.json", root / "failures")
    return root


def test_the_shipped_tables_cover_the_zoo():
    """The default run fails until the shipped cross-play matrices and failure board cover every member."""
    assert uncovered(LEADERBOARDS) == []


def test_a_new_member_is_listed_checked_and_drives_a_suite(new_member, tiny_suite, tmp_path, capsys):
    assert new_member in zoo.names() and new_member in zoo.names("rule")
    assert main(["zoo", "list", "--names"]) == 0
    assert new_member in capsys.readouterr().out.split()
    check_decider(zoo.load(new_member))  # the protocol check CONTRIBUTING.md names (step 1)
    out = tmp_path / "new.json"
    assert main(["eval", "--suite", tiny_suite(8), "--decider", new_member, "--out", str(out), "--no-progress"]) == 0
    assert out.is_file()


def test_the_measured_tables_name_a_member_they_miss_and_the_command(new_member, measured, capsys):
    lines = uncovered(measured)
    assert sorted(line.split(":")[0] for line in lines) == sorted(
        [*(f"crossplay/{p.name}" for p in (measured / "crossplay").glob("*.json")), "failures/board.json"]
    )
    assert all(f"no entry for {new_member}" in line for line in lines)
    assert "`overtakezoo crossplay --suite duel --jobs 2`" in "\n".join(lines)
    assert "`overtakezoo failure-board --jobs 2`" in "\n".join(lines)
    main(["leaderboard", "--root", str(measured), "--check"])  # (stale too: the root has no generated files)
    err = capsys.readouterr().err
    assert f"warning: {measured}/crossplay/duel.json: no entry for {new_member}" in err


def test_a_removed_member_is_named_too(measured, monkeypatch):
    monkeypatch.delitem(base._MEMBERS, "fuzzy")
    monkeypatch.delitem(base._MEMBERS, "fuzzy+shield")
    lines = uncovered(measured)
    assert lines and all("fuzzy no longer in the zoo" in line for line in lines)


def test_the_front_page_names_every_member_but_the_fixed_mode_baselines():
    """The README's zoo bullet (fixed-mode baselines named as a group)."""
    text = (ROOT / "README.md").read_text()
    named = set(re.findall(r"`([a-z0-9+-]+)`", text))
    missing = [n for n in zoo.names() if not n.startswith("always-") and n not in named]
    assert not missing, f"README.md does not name the zoo members {missing}"
