"""docs/archives.md's table of the official datasets gives each table1 dataset's episode outcomes as
counts; they are the registry's (what `overtakezoo dataset regenerate` measured), so the table cannot
drift when a recipe's decider ships new weights."""

from __future__ import annotations

import json
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
ROW = re.compile(r"^\| `(?P<name>[\w-]+-v\d+)` \|.*\| (?P<s>\d+) / (?P<c>\d+) / (?P<t>\d+) \|$", re.M)


def test_the_docs_outcome_counts_are_the_registrys():
    registry = json.loads((ROOT / "benchmark/datasets/registry/datasets.json").read_text())["datasets"]
    rows = ROW.findall((ROOT / "docs/archives.md").read_text())
    assert len(rows) == sum(name.startswith("overtakezoo/table1/") for name in registry)  # one row each
    for name, *counts in rows:
        entry = registry[f"overtakezoo/table1/{name}"]
        expected = [round(entry["outcomes"].get(k, 0.0) * entry["episodes"]) for k in ("success", "crash", "timeout")]
        assert list(map(int, counts)) == expected, name
