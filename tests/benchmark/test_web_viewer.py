"""The browser episode viewer (docs/viewer/): ``replay --out ep.json`` exports an archived episode,
and the page plays it in a real headless Chromium.

The fast part (always run) checks the export against the archive reader and its refusals. The
browser part needs Debian's ``/usr/bin/chromium`` and the ``playwright`` package (``[browser]`` extra;
never ``playwright install``: it downloads browsers); it is skipped, saying which is missing, without
them. ``OVERTAKEZOO_SCREENSHOTS=DIR`` also copies its screenshots into DIR.

The sample the docs serve, ``docs/viewer/episode.json``, is fuzzy on table1's scenario 8 (an
overtake, an abort, a second overtake, success), made with::

    overtakezoo eval --suite table1 --decider fuzzy --shard 8/3000 --out /tmp/ep8.json --archive /tmp/ep8.mcap
    overtakezoo replay /tmp/ep8.mcap --episode 8 --out docs/viewer/episode.json
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_benchmark_cli import one_line_error

from browser import chromium, need_browser, open_page, serve, shoot
from conftest import suite_file
from overtakezoo.benchmark.archive import web
from overtakezoo.benchmark.archive.reader import list_episodes, read_episode
from overtakezoo.benchmark.cli import main
from overtakezoo.envs import MODE_NAMES, OUTCOME_NAMES

VIEWER = Path(__file__).resolve().parents[2] / "docs" / "viewer"


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    """rule-fsm on table1's first 3 scenarios: two successes and a crash with the oncoming NPC2."""
    d = tmp_path_factory.mktemp("viewer-archive")
    suite = suite_file(d / "tiny.toml", 3)
    mcap = d / "run.mcap"
    argv = ["eval", "--suite", str(suite), "--decider", "rule-fsm", "--archive", str(mcap), "--no-progress"]
    assert main([*argv, "--out", str(d / "res.json")]) == 0
    return mcap


def _crash(mcap: Path) -> int:
    return next(e.index for e in list_episodes(mcap) if e.outcome == "crash")


def _export(mcap: Path, episode: int, out: Path) -> dict:
    assert main(["replay", str(mcap), "--episode", str(episode), "--out", str(out)]) == 0
    return json.loads(out.read_text())


def _leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_export_matches_the_archive(archive, tmp_path):
    entries = list_episodes(archive)
    assert sorted(e.outcome for e in entries) == ["crash", "success", "success"]
    for entry in entries:
        out = tmp_path / f"ep{entry.index}.json"
        doc = _export(archive, entry.index, out)
        ep = read_episode(archive, entry.index)
        n = ep.steps + 1
        assert (doc["format"], doc["version"]) == (web.FORMAT, web.VERSION)
        assert (doc["episode"], doc["steps"]) == (ep.index, ep.steps)
        assert doc["mode_names"] == list(MODE_NAMES) and doc["outcome_names"] == list(OUTCOME_NAMES)
        assert doc["outcome"] == ep.outcome == entry.outcome
        assert doc["crash_npc"] == ep.summary["crash_npc"]
        assert doc["source"]["decider"] == "rule-fsm" and doc["source"]["suite"] == "tiny"
        track = doc["track"]
        assert all(
            len(track[k]) == n for k in ("t", "ego_x", "ego_y", "ego_psi", "ego_v", "mode", "rollout", "blocked")
        )
        # Every step, rounded to the millimetre (the viewer's precision), as the reader reads it.
        assert track["ego_x"] == np.round(ep.ego["x"], 3).tolist()
        assert track["ego_y"] == np.round(ep.ego["y"], 3).tolist()
        assert track["npc_s"] == np.round(ep.npc_s.T, 3).tolist()
        assert track["mode"] == [0, *ep.mode.tolist()] and track["rollout"] == [-1, *ep.rollout.tolist()]
        assert track["blocked"][1:] == ["".join("1" if b else "0" for b in row) for row in ep.blocked]
        assert track["offsets"] == np.round(ep.offsets[0], 3).tolist()  # the same rollouts at every step
        assert doc["scenario"]["npc_reveal"] == [None, None]  # inf (seen from the start) as null
        assert doc["summary"]["episode_return"] == pytest.approx(ep.summary["episode_return"], abs=1e-4)
        assert out.stat().st_size < 40_000  # small: about 70 bytes a step
    assert _leftovers(tmp_path) == []  # written through a temp file, renamed when whole


@pytest.mark.parametrize("case", ["missing episode", "not an archive", "no such archive", "unknown suffix"])
def test_bad_input_is_one_line_and_writes_nothing(archive, tmp_path, capsys, case):
    out = tmp_path / "ep.json"
    args = {
        "missing episode": (archive, "999", out, "episode 999 is not in"),
        "not an archive": (tmp_path / "notes.mcap", "0", out, "not a readable MCAP archive"),
        "no such archive": (tmp_path / "gone.mcap", "0", out, "cannot read archive"),
        "unknown suffix": (archive, "0", tmp_path / "ep.txt", "--out must end in"),
    }[case]
    (tmp_path / "notes.mcap").write_text("not an archive\n")
    err = one_line_error(capsys, ["replay", str(args[0]), "--episode", args[1], "--out", str(args[2])])
    assert args[3] in err
    assert not out.exists() and not (tmp_path / "ep.txt").exists() and _leftovers(tmp_path) == []
    out.write_text("old\n")  # a file already there is kept as it was
    one_line_error(capsys, ["replay", str(args[0]), "--episode", args[1], "--out", str(args[2])])
    assert out.read_text() == "old\n"


def test_the_shipped_sample_is_in_the_current_format(archive, tmp_path):
    sample = json.loads((VIEWER / "episode.json").read_text())
    fresh = _export(archive, 0, tmp_path / "ep.json")
    assert (sample["format"], sample["version"]) == (web.FORMAT, web.VERSION), "regenerate it (module docstring)"
    for part in (None, "scenario", "track", "planner", "summary"):
        got, want = (sample, fresh) if part is None else (sample[part], fresh[part])
        assert sorted(got) == sorted(want), part
    assert sample["mode_names"] == list(MODE_NAMES) and sample["outcome"] in OUTCOME_NAMES
    assert len(set(sample["track"]["mode"])) == 3  # the sample shows follow, overtake and abort


def test_the_viewer_needs_no_network():
    """Only relative URLs: the docs site serves the folder as it is, and CI has no internet."""
    for name in ("index.html", "viewer.js", "viewer.css"):
        text = (VIEWER / name).read_text()
        assert not re.search(r"(https?:)?//[a-z0-9.-]+\.[a-z]{2,}/", text, re.I), name
    html = (VIEWER / "index.html").read_text()
    assert re.findall(r'(?:src|href)="([^"]+)"', html) == ["data:,", "viewer.css", "viewer.js"]


# ------------------------------------------------------------------------------------- in Chromium


@pytest.fixture(scope="module")
def site(archive, tmp_path_factory):
    """The viewer folder as the docs serve it, plus an exported crash episode under data/, served on
    127.0.0.1 (an ephemeral port) from a thread."""
    need_browser()
    root = tmp_path_factory.mktemp("viewer-site")
    for name in ("index.html", "viewer.js", "viewer.css", "episode.json"):
        shutil.copy(VIEWER / name, root / name)
    (root / "data").mkdir()
    _export(archive, _crash(archive), root / "data" / "crash.json")
    with serve(root) as url:
        yield root, url


@pytest.fixture(scope="module")
def browser(site):
    with chromium() as b:
        yield b


def _step(page) -> int:
    return int(re.fullmatch(r"step (\d+) / \d+", page.inner_text("#step"))[1])


def test_the_viewer_plays_an_episode_to_its_outcome(site, browser, archive, tmp_path):
    _, url = site
    ep = read_episode(archive, _crash(archive))
    problems: list[str] = []
    page = open_page(browser, problems)
    page.goto(url + "index.html?episode=data/crash.json")
    page.wait_for_function(f"document.getElementById('step').textContent === 'step 0 / {ep.steps}'")
    assert page.inner_text("#outcome") == "running" and page.inner_text("#time") == "t = 0.0 s"
    assert f"episode {ep.index}" in page.inner_text("#source") and "rule-fsm" in page.inner_text("#source")
    page.click("#play")
    page.wait_for_function(f"document.getElementById('step').textContent !== 'step 0 / {ep.steps}'")
    assert page.inner_text("#play") == "Pause" and page.inner_text("#time") != "t = 0.0 s"
    page.select_option("#speed", "16")  # 12.6 s of episode in under a second
    want = f"CRASH with NPC{ep.summary['crash_npc'] + 1}"
    page.wait_for_function(f"document.getElementById('outcome').textContent === {json.dumps(want)}")
    assert _step(page) == ep.steps and page.inner_text("#play") == "Play"
    assert page.inner_text("#time") == f"t = {ep.t[-1]:.1f} s"
    # The canvas drew the road, the verge and the ego in its mode's colour.
    colours = page.evaluate("""() => {
        const c = document.getElementById('view'), d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        const seen = new Set();
        for (let i = 0; i < d.length; i += 4) seen.add((d[i] << 16) | (d[i + 1] << 8) | d[i + 2]);
        return [0x555555, 0x6b8e4e, 0x1f77b4, 0xd62728].map((x) => seen.has(x));
    }""")
    assert colours == [True, True, True, True]  # road, verge, ego (follow), the NPC hit
    shoot(page, tmp_path / "viewer-crash-end.png")
    # Step back with the slider and the keyboard: the outcome is the episode's end only.
    page.fill("#slider", "40")
    page.dispatch_event("#slider", "input")
    assert _step(page) == 40 and page.inner_text("#outcome") == "running"
    page.keyboard.press("ArrowRight")
    assert _step(page) == 41
    shoot(page, tmp_path / "viewer-crash-step41.png")
    page.close()
    assert problems == []


def test_the_default_sample_and_a_picked_file_load(site, browser, tmp_path):
    root, url = site
    problems: list[str] = []
    page = open_page(browser, problems)
    page.goto(url + "index.html")  # no query: episode.json beside the page
    sample = json.loads((root / "episode.json").read_text())
    page.wait_for_function(f"document.getElementById('step').textContent === 'step 0 / {sample['steps']}'")
    assert "fuzzy" in page.inner_text("#source")
    page.fill("#slider", "80")
    page.dispatch_event("#slider", "input")
    assert page.inner_text("#mode") == sample["mode_names"][sample["track"]["mode"][80]].upper()
    shoot(page, tmp_path / "viewer-sample-step80.png")
    page.set_input_files("#file", str(root / "data" / "crash.json"))  # the file picker
    page.wait_for_function("document.getElementById('source').textContent.endsWith('crash.json')")
    assert _step(page) == 0 and page.inner_text("#status") == ""
    page.close()
    assert problems == []


def test_a_missing_episode_says_so_on_the_page(site, browser):
    _, url = site
    problems: list[str] = []
    page = open_page(browser, problems)
    page.goto(url + "index.html?episode=nope.json")
    page.wait_for_function("document.getElementById('status').textContent !== ''")
    assert page.inner_text("#status") == "cannot load nope.json: HTTP 404"
    page.close()
    assert problems and all("nope.json" in p or "404" in p for p in problems)
