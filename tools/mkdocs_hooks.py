"""MkDocs hooks: the site's generated pages come from the files they describe, at build time.

Nothing here is copied by hand, so a page cannot drift from its source:

- ``index.md`` is the repository's ``README.md`` (its links into ``docs/`` made site-relative);
- ``leaderboard/`` is the generated ``leaderboards/`` folder (pages, plots and the results files
  they link to; ``README.md`` is each folder's index), the board CI re-derives with
  ``overtakezoo leaderboard --verify``;
- ``guides/submit.md`` is :data:`overtakezoo.benchmark.leaderboard.guide.GUIDE`, the one submit
  guide the leaderboard page shows too;
- ``changelog.md`` is ``CHANGELOG.md``;
- ``metrics.md``'s table of every per-scenario array is generated from the arrays' declarations
  (:func:`overtakezoo.benchmark.results.registry.docs_table`) where the page holds :data:`METRICS_TABLE`;
- every measured number on a page of ``docs/`` is a quote (``tools/doc_quotes.py``), written in from
  the file that holds it. Generated pages are never expanded: the leaderboard's carry text from
  pull requests.
"""

from __future__ import annotations

import atexit
import re
import shutil
import sys
import tempfile
from pathlib import Path

from mkdocs.exceptions import PluginError
from mkdocs.plugins import event_priority
from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))  # doc_quotes beside this file
import doc_quotes  # noqa: E402  (found through the line above: mkdocs loads hooks by path)

METRICS_TABLE = "<!-- the table of arrays: generated from benchmark/results/registry.py by tools/mkdocs_hooks.py -->"


def _board_pages() -> list[str]:
    """The leaderboard's pages, in the order its index lists them, the failure board last."""
    board = ROOT / "leaderboards"
    pages = sorted(p.name for p in board.glob("*.md") if p.name != "README.md")
    return ["leaderboard/README.md", *(f"leaderboard/{name}" for name in pages), "leaderboard/failures/README.md"]


def _api_source() -> str:
    """A folder holding ``overtakezoo/`` for the API reference: the package maps three top-level
    folders (pyproject's package-dir), which griffe reads only as one package folder."""
    tmp = Path(tempfile.mkdtemp(prefix="overtakezoo-api-"))
    atexit.register(shutil.rmtree, tmp, ignore_errors=True)
    (tmp / "overtakezoo").mkdir()
    (tmp / "overtakezoo" / "__init__.py").write_text('"""OvertakeZoo."""\n')
    for name in ("envs", "zoo", "benchmark"):
        (tmp / "overtakezoo" / name).symlink_to(ROOT / name, target_is_directory=True)
    return str(tmp)


@event_priority(100)  # before mkdocstrings reads its handler options
def on_config(config):
    for i, entry in enumerate(config["nav"]):
        if isinstance(entry, dict) and "Leaderboard" in entry:
            config["nav"][i] = {"Leaderboard": _board_pages()}
    python = config["plugins"]["mkdocstrings"].config["handlers"]["python"]
    python["paths"] = [_api_source()]
    return config


def _readme_as_index() -> str:
    """README.md with its repository-relative links rewritten for the site's root page."""
    text = (ROOT / "README.md").read_text("utf-8")
    text = re.sub(r"\]\(docs/", "](", text)
    text = re.sub(r"\]\(leaderboards/README\.md", "](leaderboard/README.md", text)
    text = re.sub(r"\]\(leaderboards/", "](leaderboard/", text)
    return text.replace("](CHANGELOG.md)", "](changelog.md)")


def _submit_guide() -> str:
    from overtakezoo.benchmark.leaderboard.guide import GUIDE, GUIDE_HEADING

    return f"# {GUIDE_HEADING.lstrip('# ')}\n\n{GUIDE}"


def on_files(files: Files, config) -> Files:
    def add(uri: str, content: str | bytes | None = None, source: Path | None = None) -> None:
        abs_src = None if source is None else str(source)
        files.append(File.generated(config, uri, content=content, abs_src_path=abs_src))

    add("index.md", _readme_as_index())
    add("guides/submit.md", _submit_guide())
    add("changelog.md", (ROOT / "CHANGELOG.md").read_text("utf-8"))
    board = ROOT / "leaderboards"
    for path in sorted(board.rglob("*")):
        rel = path.relative_to(board)
        if path.is_file():  # pages, plots, and the results files and suites they link to
            add(f"leaderboard/{rel.as_posix()}", source=path)
    return files


def on_page_markdown(markdown: str, page, config, files) -> str:
    if page.file.generated_by is None:  # a page of docs/, written by hand
        try:
            markdown = doc_quotes.expand(markdown)
        except doc_quotes.QuoteError as exc:
            raise PluginError(f"docs/{page.file.src_uri}: {exc}") from None
    if page.file.src_uri != "metrics.md":
        return markdown
    if METRICS_TABLE not in markdown:  # the page was edited: say so rather than drop the table
        raise PluginError(f"docs/metrics.md: the line {METRICS_TABLE} is missing")
    from overtakezoo.benchmark.results.registry import docs_table

    return markdown.replace(METRICS_TABLE, docs_table())
