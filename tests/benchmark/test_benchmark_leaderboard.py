"""Leaderboard: byte-identical regeneration, --check catches stale files, submit guards versions."""

import hashlib
import json
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_benchmark_results import fake_results

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.generate import generate, stale_files
from overtakezoo.benchmark.leaderboard.submission import submit
from overtakezoo.benchmark.results.metrics import summarize
from overtakezoo.benchmark.results.results import Results

REPO_LEADERBOARDS = Path(__file__).resolve().parents[2] / "leaderboards"


@pytest.fixture
def root(tmp_path):
    return fake_board(tmp_path)


def fake_board(tmp_path):
    """A board of two fake rows (alpha, beta) on table1 beside the paper's reference numbers."""
    root = tmp_path / "lb"
    shutil.copytree(REPO_LEADERBOARDS / "reference", root / "reference")
    for seed, name in ((1, "alpha"), (2, "beta")):
        r = fake_results(seed=seed)
        r.meta["decider"] = {**r.meta["decider"], "name": name}
        file_row(r, root, name, name.encode())
    return root


def file_row(results, root, name, artifact):
    """A row as a pull request adds it (no `submit`, whose re-run these fake results would fail):
    generation reads rows and never runs their policies."""
    sha = hashlib.sha256(artifact).hexdigest()
    store = root / "submissions" / "artifacts"
    store.mkdir(parents=True, exist_ok=True)
    (store / f"{sha}.onnx").write_bytes(artifact)
    # a fresh draw whose rates match the public ones (its first scenarios' outcomes): not flagged
    outcome = results.per["outcome"][:500]
    block = {
        "name": name,
        "policy": {"artifact": f"artifacts/{sha}.onnx", "sha256": sha},
        "fresh": {"seed": 7, "count": outcome.size, "outcomes": "".join(map(str, outcome.tolist()))},
    }
    Results({**results.meta, "submission": block}, results.per, results.summary, results.timing).save(
        root / "submissions" / results.suite["name"] / f"{name}.json"
    )


def test_repo_leaderboard_is_current_checked_from_another_folder(tmp_path, monkeypatch, capsys):
    # The CI check: the committed generated files match the committed inputs (one full generation,
    # about 100 s; the only test that runs it on the repository's board). Run from outside the
    # repository root, the default is the checkout's leaderboards/, not an empty ./leaderboards.
    # The README's block (the lines of README.md this test runs) says the same: --check, then a
    # regeneration that, the board being current, writes the same bytes.
    from doc_blocks import run_by

    (block,) = run_by("tests/benchmark/test_benchmark_leaderboard.py")
    commands = [shlex.split(line, comments=True) for line in block.body.splitlines()]
    assert commands == [["overtakezoo", "leaderboard", "--check"], ["overtakezoo", "leaderboard"]], commands
    monkeypatch.chdir(tmp_path)
    assert main(commands[0][1:]) == 0, capsys.readouterr().err
    assert "up to date" in capsys.readouterr().out
    assert not (tmp_path / "leaderboards").exists()


def test_one_root_rule_for_submit_and_every_leaderboard_mode(tmp_path, monkeypatch, capsys):
    # submit, leaderboard, --check and --verify find their leaderboard by one rule (commands/_options.py).
    from test_submissions import one_line_error, shipped

    from overtakezoo.benchmark.commands import _options

    results = tmp_path / "r.json"
    shipped("always-follow").save(results)
    # A given --root that does not exist is an error in every leaderboard mode, never "out of date".
    missing = tmp_path / "nothing-here"
    for mode in ([], ["--check"], ["--verify"], ["--verify", "--sample", "1"]):
        assert (
            one_line_error(capsys, ["leaderboard", "--root", str(missing), *mode])
            == f"error: no such folder: {missing}"
        ), mode
    assert one_line_error(capsys, ["leaderboard", "--root", str(results)]).startswith(
        f"error: no such folder: {results}"
    )
    assert one_line_error(capsys, ["submit", str(results), "--root", str(results)]).startswith(
        f"error: no such folder: {results}"
    )
    assert not missing.exists()

    # Outside any checkout (none holds a board) and without ./leaderboards: nothing is filed, no folder made.
    monkeypatch.setattr(_options, "CHECKOUT_LEADERBOARDS", tmp_path / "no-checkout" / "leaderboards")
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.delenv("OVERTAKEZOO_VERIFY_BASE", raising=False)  # --verify below: outside git, no base
    for argv in (["submit", str(results)], ["leaderboard"], ["leaderboard", "--check"], ["leaderboard", "--verify"]):
        assert "no leaderboard here" in one_line_error(capsys, argv), argv
    assert list(work.iterdir()) == []

    # The checkout's own board when ./leaderboards has none (an editable install run from elsewhere) ...
    checkout = tmp_path / "checkout" / "leaderboards"
    (checkout / "submissions").mkdir(parents=True)
    monkeypatch.setattr(_options, "CHECKOUT_LEADERBOARDS", checkout)
    assert main(["submit", str(results)]) == 0
    assert (checkout / "submissions" / "table1" / "always-follow.json").is_file() and list(work.iterdir()) == []
    assert main(["leaderboard", "--check"]) == 1  # the checkout's board, not yet generated
    assert f"stale: {checkout}/" in capsys.readouterr().err
    # ... and ./leaderboards where it has submissions/: every command reads the same folder.
    (work / "leaderboards" / "submissions").mkdir(parents=True)
    assert main(["submit", str(results)]) == 0
    assert main(["leaderboard"]) == 0
    assert main(["leaderboard", "--check"]) == 0
    assert main(["leaderboard", "--verify", "--sample", "1"]) == 0
    out = capsys.readouterr().out
    assert "filed leaderboards/submissions/table1/always-follow.json" in out and "started a new" not in out
    assert "leaderboard regenerated in leaderboards:" in out and "verified 1 row(s)" in out
    assert (work / "leaderboards" / "table1.md").is_file() and not (checkout.parent / "table1.md").exists()

    # An explicit --root to a new folder starts a new leaderboard there, and says so.
    assert main(["submit", str(results), "--root", str(tmp_path / "new-lb")]) == 0
    out = capsys.readouterr().out
    assert f"started a new leaderboard in {tmp_path / 'new-lb'}" in out and f"--root {tmp_path / 'new-lb'}" in out

    # Each command's --help says the rule.
    for command in ("submit", "leaderboard"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert ("found by one rule for submit and leaderboard") in text and (
            "without --root: ./leaderboards where "
            "it has a submissions/ folder, else the leaderboards/ of the checkout this package runs from, else an "
            "error (the default never creates a folder)"
        ) in text, command
        assert ("created when nothing is there yet" if command == "submit" else "PATH, which must exist") in text


def test_regeneration_is_byte_identical_and_check_detects_mutation(root, capsys):
    assert main(["leaderboard", "--root", str(root), "--check"]) == 1  # never generated
    assert main(["leaderboard", "--root", str(root)]) == 0
    first = {p.name: p.read_bytes() for p in root.iterdir() if p.is_file()}
    assert {"README.md", "index.json", "table1.md", "table1.png"} <= set(first)
    assert generate(root) == {k: v for k, v in first.items()}
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0
    md = first["table1.md"].decode()
    assert "reported in the paper, different simulator" in md
    measured, reference = md.split("## Reference")
    assert "alpha" in measured and "92.2 %" not in measured and "alpha" not in reference
    capsys.readouterr()

    # A consistent change to a submission (re-saved with new arrays) makes the tables stale.
    sub = root / "submissions" / "table1" / "alpha.json"
    r = Results.load(sub)
    r.per["outcome"] = np.where(r.per["outcome"] == 3, 1, r.per["outcome"]).astype(np.int8)
    r.per["completion_time"] = np.where(
        r.per["outcome"] == 1, np.nan_to_num(r.per["completion_time"], nan=30.0), np.nan
    )
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(sub)
    assert main(["leaderboard", "--root", str(root), "--check"]) == 1
    assert "stale:" in capsys.readouterr().err

    # A hand edit of a submission's summary is refused outright: one line, exit 2.
    doc = json.loads(sub.read_text())
    doc["summary"]["success_rate"]["value"] = 1.0
    sub.write_text(json.dumps(doc))
    assert main(["leaderboard", "--root", str(root), "--check"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "summary" in err and "\n" not in err


def test_obsolete_generated_file_is_stale(root):
    # Obsolete: a file the previous index lists as generated (a suite gone since); others are not ours.
    main(["leaderboard", "--root", str(root)])
    index = json.loads((root / "index.json").read_text())
    (root / "index.json").write_text(json.dumps({**index, "files": index["files"] + ["old-suite.md"]}))
    (root / "old-suite.md").write_text("x")
    (root / "notes.md").write_text("x")
    assert "old-suite.md" in stale_files(root) and "notes.md" not in stale_files(root)
    main(["leaderboard", "--root", str(root)])
    assert not (root / "old-suite.md").exists() and (root / "notes.md").exists() and stale_files(root) == []


def test_submit_refuses_shards_and_other_suite_versions(tmp_path):
    r = fake_results(n=3000)
    r.meta["range"] = [0, 1500]
    with pytest.raises(UserError, match="range"):
        submit(r, tmp_path)
    r = fake_results(n=3000)
    r.meta["suite"] = {**r.meta["suite"], "hash": "0" * 64}
    with pytest.raises(UserError, match="suite.hash"):
        submit(r, tmp_path)
    assert not any(tmp_path.iterdir())


def test_reference_rows_never_rank_and_must_cite_their_source(root, capsys):
    """reference/paper.json is input a pull request can edit: a row claiming 100 % under a ranked
    decider's name changes nothing ranked (tables above the reference section, the index's entries
    and headline), and a file without its `source` is refused."""
    before = generate(root)
    paper_path = root / "reference" / "paper.json"
    paper = json.loads(paper_path.read_text())
    paper["rows"][0] = {**paper["rows"][0], "decider": "alpha", "success_rate": 1.0}
    paper_path.write_text(json.dumps(paper))
    after = generate(root)
    ranked = lambda files: files["table1.md"].decode().split("## Reference")[0]  # noqa: E731
    assert ranked(after) == ranked(before) and "| alpha (reported in the paper" in after["table1.md"].decode()
    index_before, index_after = json.loads(before["index.json"]), json.loads(after["index.json"])
    assert index_after["suites"]["table1"]["entries"] == index_before["suites"]["table1"]["entries"]
    assert index_after.get("headline") == index_before.get("headline")
    del paper["source"]
    paper_path.write_text(json.dumps(paper))
    assert main(["leaderboard", "--root", str(root)]) == 2
    err = capsys.readouterr().err
    assert "paper.json: malformed reference file" in err and "source" in err
