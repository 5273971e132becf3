"""A leaderboard pull request is hostile input: regeneration, --check and --verify must not remove
files they did not generate, follow a link or hang on a FIFO a PR planted, and every string from
input must come out of the pages as inert text."""

import json
import os
import shutil
import threading

import pytest
from test_benchmark_cli import one_line_error
from test_benchmark_leaderboard import REPO_LEADERBOARDS, fake_board, file_row
from test_benchmark_results import fake_results

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.generate import generate
from overtakezoo.benchmark.leaderboard.untrusted import md, plot_text

HOSTILE = "1 | ![t](https://x/t.png) | <b>x</b> `c` *e* _u_ [l] $m$ ~~s~~ &amp; \\ #h\nnext\x00\u202e"


@pytest.fixture
def root(tmp_path):
    return fake_board(tmp_path)


def _regenerate(root):
    assert main(["leaderboard", "--root", str(root)]) == 0


def test_escape_leaves_ordinary_names_and_neutralises_markup():
    for plain in [
        "double-dqn",
        "always-follow",
        "ps-dqn",
        "rule-fsm",
        "0.4.1",
        "v2.1+cpu",
        "92.2 %",
        "planner.abort_clearance",
        "suite table1 v2 (abc123; now v3, def456)",
        "core-train+multi-train",
    ]:
        assert md(plain) == plain and plot_text(plain) == plain
    out = md(HOSTILE)
    assert "\n" not in out and "\x00" not in out and "\u202e" not in out
    for raw in ["<b>", "![t]", "[l]", "`c`", "*e*", "_u_", "$m$", "~~s~~", " | "]:
        assert raw not in out, raw
    assert "&amp;amp;" in out  # an entity in the input shows as typed, not as the character
    assert out.count("|") == out.count("\\|") == 2  # no cell boundary left
    assert md("#h").startswith("\\#") and md("-->") == "--&gt;"
    assert plot_text("$\\frac{$") == "\\$\\frac{\\$" and plot_text("_hidden").startswith(" ")


def test_regeneration_keeps_files_it_did_not_generate(root):
    foreign = {"notes.md": b"# my notes\n", "data.json": b"{}\n", "photo.png": b"\x89PNG not really"}
    for name, data in foreign.items():
        (root / name).write_bytes(data)
    _regenerate(root)  # no index.json yet: owns only what it generates now
    _regenerate(root)  # with index.json's list of files
    assert {name: (root / name).read_bytes() for name in foreign} == foreign
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0  # not reported as obsolete
    assert "notes.md" not in json.loads((root / "index.json").read_text())["files"]


@pytest.mark.parametrize("listed", [True, False], ids=["files-list", "index-without-list"])
def test_regeneration_removes_what_it_generated_before(root, tmp_path, listed):
    r = fake_results(n=1000, suite="dense")
    r.meta["decider"] = {**r.meta["decider"], "name": "gamma"}
    file_row(r, root, "gamma", b"dense")
    _regenerate(root)
    assert {"dense.md", "dense.png"} <= set(json.loads((root / "index.json").read_text())["files"])
    if not listed:  # an index written before the list: its tables and plots are what it owned
        index = json.loads((root / "index.json").read_text())
        del index["files"]
        (root / "index.json").write_text(json.dumps(index))
    (root / "notes.md").write_text("mine")
    shutil.rmtree(root / "submissions" / "dense")
    assert main(["leaderboard", "--root", str(root), "--check"]) == 1  # dense.md, dense.png obsolete
    _regenerate(root)
    assert not (root / "dense.md").exists() and not (root / "dense.png").exists()
    assert (root / "notes.md").read_text() == "mine"
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0


def test_index_files_list_cannot_name_inputs_or_paths_outside(root, tmp_path):
    _regenerate(root)
    outside = tmp_path / "outside.md"
    outside.write_text("precious")
    index = json.loads((root / "index.json").read_text())
    index["files"] += [
        "../outside.md",
        "submissions/table1/alpha.json",
        "reference/paper.json",
        "submissions",
        str(outside),
    ]
    (root / "index.json").write_text(json.dumps(index))
    _regenerate(root)
    assert outside.read_text() == "precious"
    assert (root / "submissions" / "table1" / "alpha.json").is_file() and (root / "reference" / "paper.json").is_file()
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0


def _plant_link(root, tmp_path, where):
    """A symlink at ``where`` under the root, pointing at a file (or folder) of tmp_path outside it."""
    outside = tmp_path / "outside"
    outside.mkdir()
    target = outside / "precious.json"
    target.write_bytes((REPO_LEADERBOARDS / "reference" / "paper.json").read_bytes())  # a valid input, too
    link = root / where
    link.parent.mkdir(parents=True, exist_ok=True)
    if link.exists():
        link.unlink() if link.is_file() else shutil.rmtree(link)
    link.symlink_to(outside if where == "seeds" else target)
    return link, {p: p.read_bytes() for p in outside.iterdir()}


@pytest.mark.parametrize("where", ["table1.md", "submissions/table1/evil.json", "reference/paper.json", "seeds"])
@pytest.mark.parametrize("mode", [[], ["--check"], ["--verify"]], ids=["regenerate", "check", "verify"])
def test_symlinks_under_the_root_are_refused(root, tmp_path, capsys, where, mode):
    _regenerate(root)
    link, before = _plant_link(root, tmp_path, where)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), *mode])
    assert str(link) in err and "symbolic link" in err
    assert {p: p.read_bytes() for p in before} == before  # the file outside is untouched
    assert link.is_symlink()  # and the link not replaced either


def test_a_symlinked_root_is_refused(root, tmp_path, capsys):
    link = tmp_path / "lb-link"
    link.symlink_to(root)
    assert "symbolic link" in one_line_error(capsys, ["leaderboard", "--root", str(link)])


@pytest.mark.parametrize("where", ["seeds/evil.json", "table1.md"], ids=["read", "write"])
def test_fifo_under_the_root_is_refused_without_hanging(root, capsys, where):
    _regenerate(root)
    fifo = root / where
    fifo.parent.mkdir(exist_ok=True)
    fifo.unlink(missing_ok=True)
    os.mkfifo(fifo)
    result = {}
    worker = threading.Thread(target=lambda: result.update(rc=main(["leaderboard", "--root", str(root)])), daemon=True)
    worker.start()
    worker.join(30)
    if worker.is_alive():  # blocked on the FIFO: open its other end so the thread can finish
        for flags in (os.O_RDONLY | os.O_NONBLOCK, os.O_WRONLY | os.O_NONBLOCK):
            try:
                os.close(os.open(fifo, flags))
            except OSError:
                pass
        pytest.fail(f"regeneration hung on the FIFO {fifo}")
    err = capsys.readouterr().err.strip()
    assert result["rc"] == 2 and err.startswith("error: ") and "\n" not in err
    assert str(fifo) in err and "FIFO" in err


def test_reference_suite_name_cannot_write_outside_the_root(root, tmp_path, capsys):
    paper = root / "reference" / "paper.json"
    doc = json.loads(paper.read_text())
    doc["suite"] = "../outside"
    paper.write_text(json.dumps(doc))
    assert "not a plain file name" in one_line_error(capsys, ["leaderboard", "--root", str(root)])
    assert not (tmp_path / "outside.md").exists()


def _hostile_lines(text):
    """Lines of a page that carry the hostile marker; each must be inert."""
    lines = [line for line in text.splitlines() if "t.png" in line or "onerror" in line]
    assert lines, "the hostile string is not on the page at all"
    for line in lines:
        for raw in ["<b>", "<img", "![t]", "[l]", "`c`", "*e*", "$m$", "~~s~~", "| ![", "<!--", "-->"]:
            assert raw not in line.replace("<!-- generated by", ""), (raw, line)
    return lines


def test_hostile_package_version_is_refused_and_stale_rows_show_names_only(root, tmp_path, capsys):
    r = fake_results(seed=3)
    r.meta["decider"] = {**r.meta["decider"], "name": "gamma"}
    file_row(r, root, "gamma", b"gamma")
    # A pull request writes the bytes it likes; the results schema holds provenance to patterns, so
    # the hostile version never reaches a page.
    path = root / "submissions" / "table1" / "gamma.json"
    doc = json.loads(path.read_text())
    doc["package"]["version"] = HOSTILE[:64]
    path.write_text(json.dumps(doc))
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--check"])
    assert "gamma.json" in err and "package.version" in err
    file_row(r, root, "gamma", b"gamma")
    md_page = generate(root)["table1.md"].decode()
    assert "[gamma](submissions/table1/gamma.json)" in md_page

    # Stale: listed apart by name (and the escaped reason), no numbers, no version.
    doc = json.loads((root / "submissions" / "table1" / "gamma.json").read_text())
    doc["sim_version"] += 1
    (root / "submissions" / "table1" / "gamma.json").write_text(json.dumps(doc))
    files = generate(root)
    page = files["table1.md"].decode()
    assert "t.png" not in page and "t.png" not in files["README.md"].decode()
    ranked, stale = page.split("## Stale submissions")
    assert "gamma" not in ranked and "[gamma](submissions/table1/gamma.json): measured on simulator" in stale
    entry = json.loads(files["index.json"])["suites"]["table1"]
    assert [e["name"] for e in entry["entries"]] == ["alpha", "beta"]
    assert entry["stale"] == [
        {
            "file": "submissions/table1/gamma.json",
            "reasons": [{"field": "sim_version", "measured_on": entry["stale"][0]["reasons"][0]["measured_on"]}],
        }
    ]


def test_hostile_crossplay_seeds_and_reference_strings_are_escaped(root):
    evil = ["<img src=x onerror=alert(1)> ![t](https://x/t.png)", "$\\frac{$ [l] `c` *e* | x -->"]
    pairs = [
        {
            "a": a,
            "b": b,
            **{
                k: [1, 2]
                for k in ("all_succeed", "av_crash", "any_crash", "a_success", "b_success", "a_yielded", "b_yielded")
            },
        }
        for a in evil
        for b in evil
    ]
    (root / "crossplay").mkdir()
    (root / "crossplay" / "duel.json").write_text(
        json.dumps(
            {
                "suite": {"name": "duel", "version": "1 <b>x</b>", "hash": "`" * 64, "count": "<b>1000</b>"},
                "config_sha256": "x" * 64,
                "sim_version": 0,
                "scenarios": 2,
                "deciders": [{"name": n, "version": "<b>1</b>", "weights_sha256": "` <b>"} for n in evil],
                "pairs": pairs,
            }
        )
    )
    seeds = json.loads((REPO_LEADERBOARDS / "seeds" / "dqn.json").read_text())
    # the member is the file's name (checked) and the seeds' entries are re-run or pinned: the rule is free text
    seeds.update(selection_rule="[l] `c` *e* <b>x</b> t.png")
    (root / "seeds").mkdir()
    (root / "seeds" / "dqn.json").write_text(json.dumps(seeds))
    paper = json.loads((root / "reference" / "paper.json").read_text())
    paper["source"] = "<b>x</b> ![t](https://x/t.png)"
    paper["rows"][0]["decider"] = "*e* | [l] t.png"
    (root / "reference" / "paper.json").write_text(json.dumps(paper))
    files = generate(root)  # the heatmap's labels would be mathtext (and fail to parse) unescaped
    for page in ("crossplay-duel.md", "README.md", "table1.md"):
        _hostile_lines(files[page].decode())
    assert files["crossplay-duel.png"].startswith(b"\x89PNG")


# ------------------------------------------------------------------ seeds files
def _seeds_root(tmp_path, name, change=None, source="dqn"):
    doc = json.loads((REPO_LEADERBOARDS / "seeds" / f"{source}.json").read_text())
    if change:
        change(doc)
    (tmp_path / "seeds").mkdir(parents=True, exist_ok=True)
    (tmp_path / "seeds" / f"{name}.json").write_text(json.dumps(doc))
    return tmp_path


def test_a_seeds_file_cannot_lift_another_member(tmp_path):
    from overtakezoo.benchmark.leaderboard.headline import load_seeds

    assert set(load_seeds(REPO_LEADERBOARDS)) >= {"dqn", "ppo"}  # the shipped files pass
    # always-overtake (not learned) claims dqn's seeds under its own name; then ppo's file names dqn.
    with pytest.raises(UserError, match="named after the learned member"):
        load_seeds(_seeds_root(tmp_path, "always-overtake", lambda d: d.update(member="always-overtake")))
    with pytest.raises(UserError, match="says member 'dqn'"):
        load_seeds(_seeds_root(tmp_path / "b", "ppo"))
    # A file for dqn whose shipped seed is not the shipped dqn's weights.
    with pytest.raises(UserError, match="is not the shipped dqn's"):
        load_seeds(_seeds_root(tmp_path / "c", "dqn", lambda d: d.update(shipped_seed=1)))


def test_a_seeds_file_whose_shipped_seed_differs_from_its_verified_row_is_refused(tmp_path):
    from overtakezoo.benchmark.leaderboard.headline import build_table, load_seeds
    from overtakezoo.benchmark.results.results import Results

    row = Results.load(REPO_LEADERBOARDS / "submissions" / "dense" / "dqn.json")
    rows, hashes = {"dqn": {"dense": row.summary}}, {"dense": row.suite["hash"]}
    assert len(build_table(rows, load_seeds(REPO_LEADERBOARDS), hashes)["dqn"]["dense"]) == 3  # honest: 3 seeds

    def claim_all(doc):  # (the other seeds' counts are re-run from their stored weights by verify)
        c = next(e for e in doc["seeds"] if e["seed"] == doc["shipped_seed"])["suites"]["dense"]
        c.update(success=c["n"], crash=0)

    shipped = json.loads((REPO_LEADERBOARDS / "seeds" / "dqn.json").read_text())["shipped_seed"]
    forged = load_seeds(_seeds_root(tmp_path, "dqn", claim_all))
    with pytest.raises(UserError, match=f"shipped seed {shipped} on dense"):
        build_table(rows, forged, hashes)


def test_a_suite_added_to_the_score_never_drops_a_members_seeds_silently(tmp_path, monkeypatch, capsys):
    """A copy of the board whose dqn seeds file covers table1 but not dense, scored on table1, then with
    dense added to the scoring suites: the headline would fall from dqn's 3 seeds to one run (before:
    "regenerated", dqn's score from one run); generation refuses with one line naming the file and
    the suite instead."""
    from overtakezoo.benchmark.leaderboard import generate

    root = tmp_path / "lb"
    for suite in ("table1", "dense"):
        (root / "submissions" / suite).mkdir(parents=True)
        shutil.copy(REPO_LEADERBOARDS / "submissions" / suite / "dqn.json", root / "submissions" / suite)
    doc = json.loads((REPO_LEADERBOARDS / "seeds" / "dqn.json").read_text())
    for entry in doc["seeds"]:
        del entry["suites"]["dense"]  # (as for a suite that joins the score after the seeds were evaluated)
    (root / "seeds").mkdir()
    (root / "seeds" / "dqn.json").write_text(json.dumps(doc))
    monkeypatch.setattr(generate, "CORE", ("table1",))
    scores = json.loads(generate.generate(root)["index.json"])["headline"]["scores"]
    assert scores["dqn"]["seeds"] == 3  # the seeds cover table1
    monkeypatch.setattr(generate, "CORE", ("table1", "dense"))
    assert main(["leaderboard", "--root", str(root)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: seeds/dqn.json: seed 0 has no result on the scoring suite dense") and "\n" not in err
