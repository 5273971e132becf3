"""The fenced code blocks of the README and the documentation pages, with how each one is run.

A block is *run* by ``tests/docs/test_doc_blocks.py`` as written unless the HTML comment on the line
just above its fence says otherwise (both are invisible on GitHub and on the site):

- ``<!-- run by TEST_FILE ... -->`` (a path under ``tests/``): that test runs it (a slow one, usually, as training
  does) and reads it from this page, so the file must name the page;
- ``<!-- not run: reason -->``: never run, with the reason (it installs into the environment, it
  needs a GPU, it is an excerpt of a file that is run whole, ...).

Only shell and Python blocks are code; others (TOML, JSON, text) are shown data.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CODE = ("python", "bash")
FENCE = re.compile(r"^```(\S*)\s*$")
MARK = re.compile(r"^<!-- (run by (tests/[\w/]+\.py)\b.*|not run: .+) -->$")


@dataclass(frozen=True)
class Block:
    page: str  # repository-relative path of the Markdown file
    line: int  # 1-based line of the opening fence
    lang: str
    body: str
    mark: str  # "" (run here), "run by TEST_FILE ...", or "not run: ..."
    runner: str  # the test file of a "run by" mark, else ""

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def pages() -> list[Path]:
    """The README and every documentation page (docs/, the site's sources)."""
    return [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]


def blocks(page: Path) -> list[Block]:
    lines = page.read_text("utf-8").splitlines()
    found, i = [], 0
    while i < len(lines):
        opening = FENCE.match(lines[i])
        if not opening:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        above = lines[i - 1] if i else ""
        mark = MARK.match(above)
        found.append(
            Block(
                page=page.relative_to(REPO).as_posix(),
                line=i + 1,
                lang=opening.group(1),
                body="\n".join(lines[i + 1 : end]) + "\n",
                mark=mark.group(1) if mark else "",
                runner=(mark.group(2) or "") if mark else "",
            )
        )
        i = end + 1
    return found


def all_blocks() -> list[Block]:
    return [b for page in pages() for b in blocks(page)]


def run_by(test_file: str, page: str = "README.md") -> list[Block]:
    """The blocks of ``page`` whose mark names ``test_file`` (a path under ``tests/``): what that test runs."""
    return [b for b in blocks(REPO / page) if b.runner == test_file]
