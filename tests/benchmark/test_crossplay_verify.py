"""`leaderboard --verify` re-derives the cross-play matrices: a pull request that edits a pair's
counts (and regenerates the pages, so `--check` passes) or a decider's label is refused; an
unchanged matrix is sampled, a changed one re-run in full."""

import json
import subprocess

import pytest
from test_benchmark_cli import one_line_error

from overtakezoo.benchmark.cli import main

DECIDERS = "rule-fsm,always-overtake"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """A 2 x 2 duel matrix on 5 roads, its pages generated (no rows): the bytes of crossplay/duel.json."""
    root = tmp_path_factory.mktemp("xp") / "lb"
    assert main(["crossplay", "--suite", "duel", "--limit", "5", "--deciders", DECIDERS, "--root", str(root)]) == 0
    return (root / "crossplay" / "duel.json").read_bytes()


def _board(tmp_path, data: bytes, edit=None):
    root = tmp_path / "lb"
    (root / "crossplay").mkdir(parents=True)
    doc = json.loads(data)
    if edit is not None:
        edit(doc)
    (root / "crossplay" / "duel.json").write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    assert main(["leaderboard", "--root", str(root)]) == 0  # the forger regenerates: --check passes
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0
    return root


def _verify(root, *extra):
    return ["leaderboard", "--root", str(root), "--verify", "--seed", "3", *extra]


def test_an_honest_matrix_reproduces_without_a_base(tmp_path, measured, capsys):
    root = _board(tmp_path, measured)
    capsys.readouterr()
    assert main(_verify(root, "--sample", "1")) == 0
    out = capsys.readouterr().out
    assert "every row counts as changed" in out  # outside git: no base
    assert "verified crossplay/duel.json: 4 of 4 pairs reproduce exactly" in out  # (12 pairs: all 4 here)
    assert main(_verify(root, "--only", "crossplay/duel")) == 0  # --only selects a matrix (and no row)


def test_an_edited_pair_is_refused_naming_the_pair(tmp_path, measured, capsys):
    def lift(doc):  # always-overtake beside itself: one more joint success, still a valid count
        pair = next(p for p in doc["pairs"] if p["a"] == p["b"] == "always-overtake")
        k, n = pair["all_succeed"]
        pair["all_succeed"] = [k + 1 if k < n else k - 1, n]

    root = _board(tmp_path, measured, lift)
    capsys.readouterr()
    err = one_line_error(capsys, _verify(root))
    assert "crossplay/duel.json: pair A=always-overtake, B=always-overtake: all_succeed" in err
    assert "the re-run gives" in err


def test_a_declared_label_is_refused(tmp_path, measured, capsys):
    def relabel(doc):
        doc["deciders"][0]["version"] = "99"

    root = _board(tmp_path, measured, relabel)
    capsys.readouterr()
    err = one_line_error(capsys, _verify(root))
    assert "crossplay/duel.json: deciders: recorded" in err and "labels are derived" in err


def test_against_a_base_an_unchanged_matrix_is_sampled_and_a_changed_one_rerun(tmp_path, measured, capsys, monkeypatch):
    from overtakezoo.benchmark.leaderboard import crossplay

    monkeypatch.setattr(crossplay, "VERIFY_PAIRS", 1)  # (12 of a real matrix; this one has 4 pairs)
    root = _board(tmp_path, measured)
    git = ["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", "init", "-q", str(root)], check=True)
    subprocess.run([*git, "add", "-A"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "board"], check=True)
    capsys.readouterr()
    assert main(_verify(root, "--sample", "1", "--base", "HEAD")) == 0
    assert "verified crossplay/duel.json: 1 of 4 pairs reproduce exactly" in capsys.readouterr().out
    doc = json.loads(measured)
    pair = doc["pairs"][-1]
    pair["av_crash"] = [
        pair["av_crash"][0] + (1 if pair["av_crash"][0] < pair["av_crash"][1] else -1),
        pair["av_crash"][1],
    ]
    (root / "crossplay" / "duel.json").write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    err = one_line_error(capsys, _verify(root, "--sample", "1", "--base", "HEAD"))
    assert f"pair A={pair['a']}, B={pair['b']}: av_crash" in err  # changed: every pair, so the edit is met


def test_pairs_batched_together_count_as_a_pair_run_alone(monkeypatch):
    """verify and `crossplay` step many pairs as one batch (crossplay.BATCH_ROADS); each pair's counts
    are those of its own run (a Pairing on the suite's first roads, run_suite as a user runs it)."""
    from overtakezoo import zoo
    from overtakezoo.benchmark.leaderboard import crossplay
    from overtakezoo.benchmark.run.pairing import Pairing
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    suite = load_suite("platoon")
    pairs = [("fuzzy", "dqn"), ("dqn", "fuzzy"), ("rule-fsm", "ppo")]
    monkeypatch.setattr(crossplay, "BATCH_ROADS", 80)  # two pairs of 40 roads per batch: two batches
    batched = crossplay.run_pairs(suite, pairs, 40)
    for a, b in pairs:
        alone = Pairing(
            [zoo.load(a, suite.config), *(zoo.load(b, suite.config) for _ in range(suite.num_avs - 1))],
            suite.config.decision_interval,
        )
        summary = run_suite(suite, alone, limit=40, progress=False).summary
        assert batched[a, b] == {"a": a, "b": b, **crossplay._counts(summary)}
