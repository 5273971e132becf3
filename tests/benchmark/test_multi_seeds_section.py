"""Each multi-agent page lists every learned member's training seeds in self-play (from its seeds file,
which `leaderboard --verify` re-runs): joint success and AV-AV crash per seed, the mean over seeds and
its gap to the joint oracle. A seeds file is input: its per-road counts are checked, and its shipped
seed cannot claim more than the member's verified row."""

import json
import shutil

import numpy as np
import pytest
from test_benchmark_leaderboard import REPO_LEADERBOARDS

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.generate import generate
from overtakezoo.benchmark.leaderboard.headline import load_seeds

MEMBER = "ps-dqn-multi"


@pytest.fixture
def board(tmp_path):
    """The shipped platoon rows and every shipped seeds file (with their stored weights)."""
    shutil.copytree(REPO_LEADERBOARDS / "submissions" / "platoon", tmp_path / "submissions" / "platoon")
    shutil.copytree(REPO_LEADERBOARDS / "seeds", tmp_path / "seeds")
    return tmp_path


def _edit_seeds(root, change):
    path = root / "seeds" / f"{MEMBER}.json"
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def test_the_platoon_page_lists_every_seed_the_mean_and_its_gap_to_the_joint_oracle(board):
    doc = json.loads((board / "seeds" / f"{MEMBER}.json").read_text())
    files = generate(board)
    page, index = files["platoon.md"].decode(), json.loads(files["index.json"])
    section = page[page.index("### Learned members over their training seeds") :]
    got = index["multi_agent"]["platoon"]["seeds"][MEMBER]
    rates = [e["suites"]["platoon"]["all_succeed"] / e["suites"]["platoon"]["roads"] for e in doc["seeds"]]
    assert len(rates) >= 3 and [s["all_succeed"] for s in got["per_seed"]] == rates
    assert got["all_succeed"]["value"] == pytest.approx(np.mean(rates))
    assert got["all_succeed"]["lo"] < np.mean(rates) < got["all_succeed"]["hi"]
    bound = index["multi_agent"]["platoon"]["upper_bounds"][0]["joint"]["all_succeed"]
    assert got["gap_to_bound_points"] == round(100 * (bound - np.mean(rates)), 1)
    for rate in rates:  # every seed's row, and the mean's with its gap
        assert f"| {100 * rate:.1f} % [" in section
    assert f"| **{MEMBER}** | mean of {len(rates)} | {100 * np.mean(rates):.1f} % [" in section
    assert f"| {got['gap_to_bound_points']:.1f} |" in section
    shipped = [s for s in got["per_seed"] if s["shipped"]]
    assert [s["seed"] for s in shipped] == [doc["shipped_seed"]]


def test_a_seeds_file_cannot_claim_more_joint_success_for_the_shipped_seed_than_its_row(board):
    def claim_all(doc):
        c = next(e for e in doc["seeds"] if e["seed"] == doc["shipped_seed"])["suites"]["platoon"]
        c["all_succeed"] = c["roads"]

    _edit_seeds(board, claim_all)
    with pytest.raises(UserError, match=f"seeds/{MEMBER}.json: shipped seed .* on platoon: joint success"):
        generate(board)


@pytest.mark.parametrize(
    "key, value", [("all_succeed", 10**6), ("av_av_crash", -1), ("roads", 0), ("all_succeed", 0.5), ("roads", True)]
)
def test_malformed_per_road_counts_are_refused(board, key, value):
    _edit_seeds(board, lambda doc: doc["seeds"][0]["suites"]["platoon"].update({key: value}))
    with pytest.raises(UserError, match=f"{MEMBER}.json: malformed seeds file"):
        load_seeds(board)
