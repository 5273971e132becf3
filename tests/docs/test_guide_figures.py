"""The training guides' measured figures come from one file a command wrote: docs/guides/figures.json,
by ``python scripts/guide_figures.py`` (which runs each guide's example as its slow test does). The file
names when and where it was measured, holds every guide the pages quote, and the command runs."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
FIGURES = ROOT / "docs" / "guides" / "figures.json"
SCRIPT = ROOT / "scripts" / "guide_figures.py"
PAGES = ("sb3.md", "cleanrl.md", "rsl-rl.md", "offline-rl.md", "torchrl.md")
QUOTED = re.compile(r"\{\{\s*docs/guides/figures\.json\s+guides/([\w-]+)/")


def test_the_figures_file_names_its_command_date_and_machine():
    doc = json.loads(FIGURES.read_text())
    assert doc["generated_by"] == "python scripts/guide_figures.py"
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d", doc["date"])
    assert doc["machine"]["cpu"] and doc["machine"]["cores"] >= 1
    for name, guide in doc["guides"].items():
        assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d", guide["date"]), name
        assert guide["machine"]["cpu"] and guide["machine"]["cores"] >= 1, name
        if "duel" in guide:  # the multi-agent guide: both AVs of duel's 1000 roads
            evals = [(guide["duel"], 2000)]
            assert guide["duel"]["joint_n"] == 1000, name
            assert 0 <= guide["duel"]["joint_all_succeed"] <= guide["duel"]["success_rate"] <= 1, name
        else:
            table1s = [guide["table1"]] if "table1" in guide else [run["table1"] for run in guide["runs"]]
            evals = [(table1, 3000) for table1 in table1s]
        for rates_of, n in evals:
            assert rates_of["n"] == n, name
            rates = [rates_of[k] for k in ("success_rate", "crash_rate", "timeout_rate")]
            assert all(0 <= r <= 1 for r in rates) and sum(rates) <= 1 + 1e-9, (name, rates_of)


def test_every_guide_the_pages_quote_is_in_the_file_and_each_page_names_the_command():
    guides = json.loads(FIGURES.read_text())["guides"]
    for page in PAGES:
        text = (ROOT / "docs" / "guides" / page).read_text()
        quoted = set(QUOTED.findall(text))
        assert quoted, f"docs/guides/{page} quotes nothing from docs/guides/figures.json"
        assert quoted <= set(guides), f"docs/guides/{page} quotes guides the file lacks: {quoted - set(guides)}"
        assert "python scripts/guide_figures.py" in text, f"docs/guides/{page} does not name the command"


def test_the_command_runs():
    done = subprocess.run([sys.executable, str(SCRIPT), "--help"], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert "--only" in done.stdout
