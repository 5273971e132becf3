"""The documentation cannot go stale: every measured number on a page written by hand is a quote
(``tools/doc_quotes.py``) of the file a command wrote, written in when the site is built, and every
quote names a value that exists. Pages a command writes whole are listed with that command; the
changelog is dated history and keeps its numbers."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))
import doc_quotes  # noqa: E402

DOCS = ROOT / "docs"
# Pages a command writes whole (never edited by hand): the command re-measures every number on them.
GENERATED = {
    "perf.md": "overtakezoo perf --out docs/perf",
    "perf-training.md": "overtakezoo perf --only-training --out docs/perf-training",
    "perf-torch-cpu.md": "overtakezoo perf --backend torch --compile --sizes 256 4096 --out docs/perf-torch-cpu",
    "ablation.md": "python scripts/ablation.py",
    "failure-search-ratio.md": "python scripts/failure_search_ratio.py",
    "paper-setting.md": "python scripts/paper_setting.py",
}
# A measured-looking number: a rate, a ratio, a duration, a size or a speed.
MEASURED = re.compile(
    r"(?<![\w.+-])[-+]?\d[\d,]*(?:\.\d+)?\s?(?:%|x\b|pp\b|percentage points|CPU s\b|ms\b|s\b|min\b|h\b"
    r"|[KMG]i?B\b|env-steps/s|steps/s|decisions/s)"
)
# Numbers that are not measurements: settings, targets and conventions, each with its reason; on
# every page (CONSTANTS), or on one page, declared there in a comment the reader does not see:
# <!-- not measured: "4 s" the rollout horizon (planner.horizon); "16 s" ... -->
CONSTANTS = {
    "0.1 s": "the core's step, dt (envs/suites/*.toml)",
    "1 s": "the zoo's hold (ZOO_DECISION_S)",
    "95 %": "the confidence level of every interval",
    "60 s": "the episodes' time limit on table1 (time_limit)",
    "2 x": "the crash weight K of the score (success - 2 x crash)",
    "92.2 %": "the paper's Table I success rate (leaderboards/reference/paper.json), a published constant",
    "5 %": "the crash rate the paper's level allows (time-to-paper-level's target)",
}
NOT_MEASURED = re.compile(r"<!-- not measured: (.*?)-->", re.S)


def page_constants(text: str) -> dict[str, str]:
    """The page's own declared constants: each ``"NUMBER UNIT"`` followed by its reason."""
    out = {}
    for block in NOT_MEASURED.findall(text):
        for number, reason in re.findall(r'"([^"]+)"\s*([^;"]*)', block):
            assert reason.strip(), f"{number!r} is declared not measured without a reason"
            out[number] = reason.strip()
    return out


def hand_pages() -> list[Path]:
    return [p for p in sorted(DOCS.rglob("*.md")) if p.relative_to(DOCS).as_posix() not in GENERATED]


def prose(text: str) -> str:
    """What a reader sees typed on the page: code, quotes, link targets and comments removed."""
    text = re.sub(r"(?ms)^```.*?^```", "", text)
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    text = doc_quotes.QUOTE.sub("", text)
    text = re.sub(r"`[^`\n]*`", "", text)
    return re.sub(r"\]\([^)]*\)", "]", text)


def test_every_generated_page_says_which_command_wrote_it():
    for page, command in GENERATED.items():
        head = "\n".join((DOCS / page).read_text().splitlines()[:6])
        assert command.split(" --")[0] in head, f"docs/{page} does not name {command!r} at its top"


@pytest.mark.parametrize("page", hand_pages(), ids=lambda p: p.relative_to(DOCS).as_posix())
def test_a_hand_written_page_quotes_every_measured_number(page):
    text = page.read_text()
    doc_quotes.expand(text)  # every quote names a file, a value and a format that exist
    allowed = CONSTANTS | page_constants(text)
    typed = [m for m in MEASURED.findall(prose(text)) if re.sub(r"\s+", " ", m) not in allowed]
    assert not typed, (
        f"docs/{page.relative_to(DOCS)} types measured numbers by hand: {typed}; quote them from the file "
        "that holds them ({{ FILE PATH | FORMAT }}, tools/doc_quotes.py), or move dated history to CHANGELOG.md"
    )


def test_the_front_page_types_no_measured_number():
    """The README is read on GitHub as typed, so it quotes nothing and states no measurement: the
    figures live on the site's pages and the leaderboard."""
    text = (ROOT / "README.md").read_text()
    assert not doc_quotes.QUOTE.search(text)
    typed = [m for m in MEASURED.findall(prose(text)) if re.sub(r"\s+", " ", m) not in CONSTANTS]
    assert not typed, f"README.md types measured numbers: {typed}"


def test_a_quote_reads_the_value_a_command_wrote_and_names_a_bad_one(tmp_path):
    (tmp_path / "docs").mkdir()
    report = {"figures": [{"id": "a", "median": 0.97125}, {"id": "b", "median": 12345.6}]}
    (tmp_path / "docs" / "R.json").write_text(json.dumps(report))
    page = "a {{ docs/R.json figures[id=a]/median | pct }} % b {{ docs/R.json figures[id=b]/median | ,.0f }}"
    assert doc_quotes.expand(page, tmp_path) == "a 97.1 % b 12,346"
    for bad, why in (
        ("{{ docs/R.json figures[id=c]/median }}", "0 elements of 'figures' have id = c"),
        ("{{ docs/R.json figures/0/mean }}", "no 'mean'"),
        ("{{ docs/NOPE.json a }}", "docs/NOPE.json"),
        ("{{ docs/../pyproject.toml project }}", "quotes read only files under"),
        ("{{ tests/CONFTEST.json a }}", "quotes read only files under"),
        ("{{ docs/R.json figures | pct }}", "not a number or a string"),
    ):
        with pytest.raises(doc_quotes.QuoteError, match=re.escape(why)):
            doc_quotes.expand(bad, tmp_path)


def test_the_built_site_shows_the_stored_value_not_the_quote(tmp_path):
    """The hook writes the values in (the strict build itself runs in test_docs_site.py)."""
    sys.path.insert(0, str(ROOT / "tools"))
    import mkdocs_hooks

    class Page:
        class file:
            src_uri = "performance.md"
            generated_by = None

    figures = json.loads((DOCS / "perf-training.json").read_text())["figures"]
    median = next(f["median"] for f in figures if f["id"] == "train-throughput-core-train")
    text = "{{ docs/perf-training.json figures[id=train-throughput-core-train]/median | , }}"
    assert mkdocs_hooks.on_page_markdown(text, Page, None, None) == f"{median:,}"
    Page.file.generated_by = "tools/mkdocs_hooks.py"  # a generated page (the leaderboard's) is never expanded
    assert mkdocs_hooks.on_page_markdown(text, Page, None, None) == text
