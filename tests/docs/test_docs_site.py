"""The documentation site builds with warnings as errors (broken links, missing anchors, pages left
out of the navigation, API references that do not resolve), its generated pages come from their
sources, and, in headless Chromium, every page kind loads with no console error, no failed request
and no dead link; the leaderboard's tables sort; the episode viewer plays inside its page.
Screenshots of each page kind go to the test's folder (and ``$OVERTAKEZOO_SCREENSHOTS``)."""

from __future__ import annotations

import os
import subprocess
import sys
import urllib.request
from pathlib import Path
from urllib.parse import urldefrag, urljoin

import pytest

from browser import chromium, need_browser, open_page, serve, shoot
from overtakezoo.benchmark.leaderboard.guide import GUIDE

REPO = Path(__file__).resolve().parents[2]
# One page of each kind: front page, prose, generated board pages, API reference, viewer, changelog.
PAGES = [
    "",
    "getting-started/",
    "leaderboard/",
    "leaderboard/table1/",
    "leaderboard/crossplay-duel/",
    "leaderboard/failures/",
    "guides/submit/",
    "api/envs/",
    "episodes/",
    "changelog/",
]


@pytest.fixture(scope="module")
def built(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site") / "site"
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet", "--site-dir", str(site)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        env={"NO_MKDOCS_2_WARNING": "1", **os.environ},
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-5000:]
    return site


def _text(path: Path) -> str:
    return path.read_text("utf-8")


def test_the_site_builds_strict_with_its_generated_pages_from_their_sources(built):
    for page in PAGES:
        assert (built / page / "index.html").is_file(), page
    # the leaderboard is the generated board: its score table's first row, as generated
    board = _text(REPO / "leaderboards" / "README.md")
    first_row = next(line for line in board.splitlines() if line.startswith("| 1 |"))
    decider = first_row.split("|")[2].strip()
    assert f"<td>{decider}</td>" in _text(built / "leaderboard" / "index.html")
    # the submit guide is the one GUIDE; the home page is the README; the viewer is served as is
    assert GUIDE.splitlines()[0].split("`")[0] in _text(built / "guides" / "submit" / "index.html")
    assert "Quickstart" in _text(built / "index.html")
    assert (built / "viewer" / "episode.json").read_bytes() == (REPO / "docs" / "viewer" / "episode.json").read_bytes()
    # the API reference is generated from the docstrings
    assert "OvertakeCore" in _text(built / "api" / "envs" / "index.html")


@pytest.fixture(scope="module")
def served(built):
    need_browser()
    with serve(built) as url:
        yield url


def _links(page, base: str) -> set[str]:
    hrefs = page.eval_on_selector_all("a[href]", "els => els.map(e => e.href)")
    return {urldefrag(h)[0] for h in hrefs if h.startswith(base)}


def test_every_page_kind_loads_clean_with_no_dead_link(served, tmp_path):
    problems: list[str] = []
    checked: set[str] = set()
    with chromium() as browser:
        for page_path in PAGES:
            page = open_page(browser, problems, width=1280, height=900)
            page.goto(urljoin(served, page_path), wait_until="networkidle")
            shoot(page, tmp_path / f"site-{page_path.strip('/').replace('/', '-') or 'home'}.png")
            for link in _links(page, served) - checked:
                checked.add(link)
                with urllib.request.urlopen(link, timeout=10) as response:  # a dead link raises HTTPError
                    assert response.status == 200, link
            page.close()
    assert not problems, problems
    assert len(checked) > 100  # the board pages link every results file


def test_the_leaderboard_sorts_and_the_viewer_plays_in_its_page(served, tmp_path):
    problems: list[str] = []
    with chromium() as browser:
        page = open_page(browser, problems, width=1280, height=900)
        page.goto(urljoin(served, "leaderboard/"), wait_until="networkidle")
        table = page.locator("article table").first
        ranks = lambda: table.locator("tbody tr td:first-child").all_inner_texts()  # noqa: E731
        assert ranks()[0] == "1"
        table.locator("th", has_text="score").click()  # ascending: the lowest score first
        table.locator("th", has_text="score").click()
        table.locator("th", has_text="decider").click()  # by name: rank order is gone
        assert ranks()[0] != "1" or ranks() != sorted(ranks())
        names = table.locator("tbody tr td:nth-child(2)").all_inner_texts()
        assert names in (sorted(names), sorted(names, reverse=True))
        shoot(page, tmp_path / "site-leaderboard-sorted.png")

        page.goto(urljoin(served, "episodes/"), wait_until="networkidle")
        viewer = page.frame_locator("iframe")
        before = viewer.locator("#step").inner_text()
        viewer.locator("#play").click()
        page.wait_for_timeout(1500)
        assert viewer.locator("#step").inner_text() != before
        shoot(page, tmp_path / "site-episodes-playing.png")
    assert not problems, problems
