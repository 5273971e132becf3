"""Training seeds are rows too (benchmark/leaderboard/seed_verify.py): `overtakezoo seeds` stores every
seed's weights, `leaderboard --verify` re-runs each seed from them and refuses a forged count, swapped
or planted weights; a seed with no weights to re-run (other than the shipped one, the zoo member) is
refused, so a pull request can neither drop a seed nor add one nobody can re-run."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from conftest import PRETRAINED, shipped_as_runs, suite_file
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard import headline
from overtakezoo.benchmark.leaderboard.seed_verify import SAMPLE_PAIRS, sources, verify_seeds

BOARD_SEEDS = PRETRAINED.parents[1] / "leaderboards" / "seeds"


@pytest.fixture
def board(tmp_path, tiny_suite):
    """A board whose seeds file holds three dqn seeds (each the shipped weights, named as its seed),
    written by `overtakezoo seeds` on a tiny test suite and a tiny training split."""
    tiny_suite(6)
    split = suite_file(tmp_path / "suites" / "tiny-train.toml", 6, base="occluded")
    runs = [str(run) for run in shipped_as_runs(tmp_path)]
    root = tmp_path / "leaderboards"
    root.mkdir()
    argv = ["seeds", "dqn", *runs, "--suites", "tiny", "--train-suite", split.stem, "--root", str(root)]
    assert main(argv) == 0
    return root


def _edit(root, change):
    path = root / "seeds" / "dqn.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")


def _verify(root, sample=None):
    lines = []
    verify_seeds(root, sample, 7, None, set(), lines.append)
    return lines


def test_every_seeds_weights_are_stored_and_every_seed_re_runs(board):
    doc = json.loads((board / "seeds" / "dqn.json").read_text())
    for e in doc["seeds"]:
        w = e["weights"]
        assert w["file"] == f"seeds/weights/dqn-seed{e['seed']}.npz"
        assert (board / w["file"]).read_bytes() == (PRETRAINED / "dqn.npz").read_bytes()
        assert json.loads((board / w["file"]).with_suffix(".json").read_text())["seed"] == e["seed"]
    assert _verify(board) == ["verified seeds/dqn.json: 6 (seed, suite) pair(s) re-run"]
    assert _verify(board, sample=2) == ["verified seeds/dqn.json: 2 (seed, suite) pair(s) re-run"]
    assert "| stored weights |" in headline.seed_lines(headline.load_seeds(board), "tiny")


def test_a_forged_count_is_refused_naming_the_seed_and_the_suite(board):
    def forge(doc):
        doc["seeds"][1]["suites"]["tiny"]["crash"] -= 1  # a crash turned into a success
        doc["seeds"][1]["suites"]["tiny"]["success"] += 1

    _edit(board, forge)
    with pytest.raises(UserError, match=r"seeds/dqn.json: seed 1 on tiny: crash re-runs as 1, the file says 0"):
        _verify(board)


def test_swapped_planted_or_misnamed_weights_are_refused(board):
    npz = board / "seeds" / "weights" / "dqn-seed2.npz"
    good = npz.read_bytes()
    npz.write_bytes((PRETRAINED / "ppo.npz").read_bytes())  # other weights, same place
    with pytest.raises(UserError, match=r"seed 2: seeds/weights/dqn-seed2.npz is not the file the entry recorded"):
        _verify(board)
    npz.unlink()
    os.symlink(PRETRAINED / "dqn.npz", npz)  # the right bytes, through a link
    with pytest.raises(UserError, match="is not a regular file"):
        _verify(board)
    npz.unlink()
    npz.write_bytes(good)
    _verify(board)

    def elsewhere(doc):
        doc["seeds"][0]["weights"]["file"] = "../../zoo/pretrained/dqn.npz"

    _edit(board, elsewhere)
    with pytest.raises(UserError, match=r"seed 0: weights.file must be seeds/weights/dqn-seed0.npz"):
        _verify(board)


def test_a_seed_without_weights_or_a_dropped_seed_is_refused(board):
    def unstored(doc):
        del doc["seeds"][0]["weights"]
        doc["shipped_seed"] = 1

    _edit(board, unstored)
    with pytest.raises(UserError, match="seed 0 has no stored weights"):
        headline.load_seeds(board)

    def dropped(doc):
        doc["seeds"] = doc["seeds"][:2]

    _edit(board, dropped)
    with pytest.raises(UserError, match=r"seeds \[0, 1\]: a member reports its seeds 0..n-1, at least 3"):
        headline.load_seeds(board)


@pytest.fixture
def repo_seeds(tmp_path):
    root = tmp_path / "leaderboards"
    shutil.copytree(BOARD_SEEDS, root / "seeds")
    return root


def test_every_seed_on_the_shipped_board_re_runs_from_weights(repo_seeds):
    """No seed's counts are taken on trust: each is stored or the shipped seed (the zoo member)."""
    for member, doc in headline.load_seeds(repo_seeds).items():
        hows = sources(member, doc)
        assert set(hows.values()) <= {"stored", "zoo"}, member
        assert sorted(s for s, h in hows.items() if h == "zoo") in ([], [doc["shipped_seed"]]), member


@pytest.mark.parametrize("member", ["dagger", "ps-dqn"])
def test_a_seed_cannot_lose_its_weights_be_dropped_or_be_joined_by_an_unstored_one(repo_seeds, member):
    path = repo_seeds / "seeds" / f"{member}.json"
    original = path.read_text()
    doc = json.loads(original)
    other = next(e for e in doc["seeds"] if e["seed"] != doc["shipped_seed"])

    del other["weights"]  # a seed whose counts nothing could re-run
    path.write_text(json.dumps(doc))
    with pytest.raises(UserError, match=f"seed {other['seed']} has no stored weights"):
        headline.load_seeds(repo_seeds)

    doc = json.loads(original)
    doc["seeds"] = [e for e in doc["seeds"] if e["seed"] != other["seed"]]  # drop a seed
    for i, e in enumerate(doc["seeds"]):
        e["seed"] = i
    path.write_text(json.dumps(doc))
    with pytest.raises(UserError, match="at least 3|no stored weights|shipped seed|weights.file"):
        headline.load_seeds(repo_seeds)

    doc = json.loads(original)
    extra = {k: v for k, v in doc["seeds"][-1].items() if k != "weights"}
    doc["seeds"].append({**extra, "seed": len(doc["seeds"])})  # a 4th seed, copied, without weights
    path.write_text(json.dumps(doc))
    with pytest.raises(UserError, match=f"seed {len(doc['seeds']) - 1} has no stored weights"):
        headline.load_seeds(repo_seeds)


def test_verify_re_runs_the_shipped_boards_seeds_from_the_cli(capsys):
    """`leaderboard --verify --only seeds/dqn`: a sample of dqn's seeds re-runs from their stored weights,
    no other file is touched; a glob that matches no row, matrix or seeds file is one error."""
    root = str(BOARD_SEEDS.parent)
    argv = ["leaderboard", "--verify", "--sample", "1", "--seed", "3", "--base", "HEAD", "--root", root]
    assert main([*argv, "--only", "seeds/dqn"]) == 0
    out = capsys.readouterr().out
    assert f"verified seeds/dqn.json: {SAMPLE_PAIRS} (seed, suite) pair(s) re-run\n" in out
    assert "seeds/ppo.json" not in out
    assert main([*argv, "--only", "seeds/nobody"]) == 2
    assert "no current row matches" in capsys.readouterr().err
