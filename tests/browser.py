"""Headless Chromium for the site's and the episode viewer's tests: Debian's ``/usr/bin/chromium``
driven by the ``playwright`` package (the ``[browser]`` extra; no ``playwright install``, which
downloads a browser). Tests skip, saying why, when either is absent, except where
``OVERTAKEZOO_BROWSER_TESTS=required`` (set by ``.ci/run``, which installs chromium first): there a
missing browser fails the run instead of hiding the tests."""

from __future__ import annotations

import contextlib
import functools
import http.server
import os
import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
# The machine's network is closed: no background connections, updates or sync at start-up.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def need_browser() -> None:
    required = os.environ.get("OVERTAKEZOO_BROWSER_TESTS") == "required"
    missing = None
    if not CHROMIUM.exists():
        missing = f"{CHROMIUM} is absent (apt-get install chromium)"
    else:
        try:
            import playwright.sync_api  # noqa: F401
        except ImportError:
            missing = "the playwright package is absent (pip install -e '.[browser]')"
    if missing and required:
        pytest.fail(f"OVERTAKEZOO_BROWSER_TESTS=required but {missing}")
    if missing:
        pytest.skip(missing)


@contextlib.contextmanager
def serve(root: Path) -> Iterator[str]:
    """``root`` served on 127.0.0.1 (an ephemeral port) from a thread; yields the base URL."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(Quiet, directory=str(root)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_port}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


@contextlib.contextmanager
def chromium() -> Iterator[object]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


def open_page(browser, problems: list[str], width: int = 1100, height: int = 640):
    """A page whose console errors, page errors, failed requests and HTTP errors go into ``problems``."""
    page = browser.new_page(viewport={"width": width, "height": height})
    page.set_default_timeout(10_000)
    page.on("console", lambda m: m.type == "error" and problems.append(f"console: {m.text}"))
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url} {r.failure}"))
    page.on("response", lambda r: r.status >= 400 and problems.append(f"HTTP {r.status}: {r.url}"))
    return page


def shoot(page, path: Path) -> None:
    """A full-page screenshot at ``path``, copied into ``$OVERTAKEZOO_SCREENSHOTS`` when it is set."""
    page.screenshot(path=str(path), full_page=True)
    shots = os.environ.get("OVERTAKEZOO_SCREENSHOTS")
    if shots:
        Path(shots).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(shots) / path.name)
