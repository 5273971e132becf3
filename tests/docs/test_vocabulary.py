"""The hold's vocabulary (docs/model.md, "The hold, in one vocabulary") is declared once: each word's
identifier exists where the table says, and the docs, the front page and the code's docstrings
use no other name for these things."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
GLOSSARY = ROOT / "docs" / "model.md"
# Names the project used before it had one vocabulary. The outside world's names for the training
# hold (action repeat, frame skip) appear only where a line explains them.
RETIRED = ("decision hold", "action repeat", "frame skip", "decision period", "decide every step")


def _table() -> list[list[str]]:
    section = GLOSSARY.read_text().split("## The hold, in one vocabulary", 1)[1]
    rows = [line for line in section.splitlines() if line.startswith("| ") and not line.startswith("| word")]
    return [[cell.strip() for cell in row.strip("|").split("|")] for row in rows]


def test_every_word_names_an_identifier_that_exists_where_the_table_says():
    rows = _table()
    assert [r[0] for r in rows][:5] == ["step", "decision interval", "training hold", "decision rate", "hold"]
    for word, identifier, where, _ in rows:
        name = identifier.strip("`")
        files = [ROOT / f for f in re.findall(r"`([\w/.-]+\.(?:py|json))`", where)]
        if not files:  # a suite's table or a card: the suites and the shipped cards hold the key
            files = [*ROOT.glob("envs/suites/*.toml"), *ROOT.glob("zoo/pretrained/*.json"), ROOT / "envs/config.py"]
        assert any(name in f.read_text() for f in files), f"{word}: {name} not in {where}"


def _texts() -> list[Path]:
    docs = [ROOT / "README.md", ROOT / "CONTRIBUTING.md", *sorted((ROOT / "docs").rglob("*.md"))]
    code = [p for layer in ("envs", "zoo", "benchmark") for p in sorted((ROOT / layer).rglob("*.py"))]
    return docs + code


def test_no_retired_name_for_the_hold_outside_a_line_that_explains_it():
    found = []
    for path in _texts():
        for n, line in enumerate(path.read_text().splitlines(), 1):
            low = line.lower()
            if "elsewhere called" in low or "frame skip" in low and "action repeat" in low:
                continue  # the glossary's and the card command's explanation of the outside names
            for name in RETIRED:
                if name in low:
                    found.append(f"{path.relative_to(ROOT)}:{n}: {name!r}")
    assert not found, "use the words of docs/model.md's vocabulary table:\n" + "\n".join(found)
