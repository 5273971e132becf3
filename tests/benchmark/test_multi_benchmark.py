"""Multi-agent benchmark: per-AV and joint metrics, who yielded, the pairing composite, multi-AV
results files (round trip, shards, verification), their leaderboard section and the cross-play matrix."""

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_multi_av import drive, duel

from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard import crossplay
from overtakezoo.benchmark.leaderboard.generate import generate, stale_files
from overtakezoo.benchmark.leaderboard.verify import verify
from overtakezoo.benchmark.results.multi_metrics import summarize_multi, yielded
from overtakezoo.benchmark.results.results import Results, merge, round_per_scenario
from overtakezoo.benchmark.run.pairing import Pairing
from overtakezoo.benchmark.run.runner import _per_scenario, run_suite
from overtakezoo.envs.config import ABORT, FOLLOW, OVERTAKE
from overtakezoo.envs.core import CRASH, SUCCESS, OvertakeCore
from overtakezoo.envs.scenarios import Scenarios
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.base import Decider, load

REPO_LEADERBOARDS = Path(__file__).resolve().parents[2] / "leaderboards"


def _metrics(core):
    per = round_per_scenario(_per_scenario(core))
    return per, summarize_multi(per, 0, core.num_avs)


def test_a_head_on_crash_between_the_avs_counts_once_per_road():
    core = OvertakeCore()
    core.reset(duel())
    drive(core, lambda c: np.array([OVERTAKE, OVERTAKE]))
    per, s = _metrics(core)
    assert per["outcome"].tolist() == [CRASH, CRASH] and per["crash_av"].tolist() == [1, 0]
    assert per["crash_npc"].tolist() == [-1, -1] and per["lead_npc"].tolist() == [0, 1]
    j = s["joint"]
    assert (j["av_crash"]["k"], j["av_crash"]["n"]) == (1, 1)  # one road, one AV-AV crash
    assert j["any_crash"]["k"] == 1 and j["all_succeed"]["k"] == 0 and j["any_yield"]["k"] == 0
    assert (s["crash_rate"]["k"], s["crash_rate"]["n"]) == (2, 2)  # per agent: both AVs crashed
    assert s["crash_share_av"]["value"] == 1.0 and s["crash_share_npc1"]["value"] == 0.0
    assert [a["crash_share_av"]["k"] for a in s["per_av"]] == [1, 1]


def test_the_av_that_aborts_yielded_and_nobody_crashes():
    core = OvertakeCore()
    core.reset(duel())
    drive(core, lambda c: np.array([OVERTAKE, ABORT if c.t[1] >= 8.0 else OVERTAKE]))
    per, s = _metrics(core)
    assert per["outcome"][0] == SUCCESS and CRASH not in per["outcome"].tolist()
    assert per["aborts"].tolist() == [0, 1] and per["crash_av"].tolist() == [-1, -1]
    assert yielded(per, 2)[:, 0].tolist() == [False, True]
    assert s["joint"]["any_yield"]["k"] == 1 and s["joint"]["av_crash"]["k"] == 0
    assert [a["yielded"]["k"] for a in s["per_av"]] == [0, 1]


def test_who_yielded_on_hand_made_arrays():
    # Two roads x two AVs (AV-major). Road 0: AV 0 never pulls out and times out while AV 1 succeeds;
    # road 1: both succeed, AV 1 after an abort, but AV 0 finished first -> AV 1 yielded.
    per = {
        "outcome": np.array([3, 1, 1, 1]),
        "completion_time": np.array([np.nan, 20.0, 25.0, 30.0]),
        "aborts": np.array([0, 0, 0, 1]),
        "opposite_time": np.array([0.0, 5.0, 4.0, 6.0]),
    }
    assert yielded(per, 2).tolist() == [[True, False], [False, True]]
    per["outcome"] = np.array([2, 1, 1, 1])  # an AV that crashed did not yield
    assert yielded(per, 2).tolist() == [[False, False], [False, True]]


class _Counting(Decider):
    """Returns ``mode``; records the rows it was given."""

    name, version = "counting", "1"

    def __init__(self, mode, action_repeat=1):
        super().__init__()
        self.mode, self.action_repeat, self.calls = mode, action_repeat, []

    def act_batch(self, obs):
        self.calls.append(obs.copy())
        return np.full(obs.shape[0], self.mode, np.int64)


def test_a_pairing_drives_each_av_index_with_its_own_decider_on_its_own_schedule():
    core = OvertakeCore()
    obs = core.reset(Scenarios.concat([duel(), duel(distance=140.0)]))  # rows: AV 0 of roads 0, 1; then AV 1
    a, b = _Counting(OVERTAKE, action_repeat=10), _Counting(FOLLOW)
    pairing = Pairing([a, b], decision_interval=1)
    assert pairing.action_repeat == 1 and pairing.every == [10, 1]
    assert pairing.act(obs).tolist() == [OVERTAKE, OVERTAKE, FOLLOW, FOLLOW]
    np.testing.assert_array_equal(a.calls[0], obs[:2])
    np.testing.assert_array_equal(b.calls[0], obs[2:])
    for _ in range(19):
        pairing.act(obs)
    assert len(a.calls) == 2 and len(b.calls) == 20  # a re-decides every 10 steps, as alone
    with pytest.raises(UserError, match="privileged"):
        Pairing([a, load("oracle")], 1)
    with pytest.raises(UserError, match="its own decider object"):
        Pairing([a, a], 1)


def test_a_pairing_of_one_decider_twice_is_self_play_and_results_round_trip(tmp_path):
    suite = load_suite("duel")
    alone = run_suite(suite, load("rule-fsm", suite.config), limit=12, progress=False)
    paired = run_suite(suite, Pairing([load("rule-fsm", suite.config) for _ in range(2)], 1), limit=12, progress=False)
    assert alone.num_avs == 2 and alone.per["outcome"].shape == (24,)
    for key, value in alone.per.items():
        np.testing.assert_array_equal(paired.per[key], value)
    path = alone.save(tmp_path / "r.json")
    back = Results.load(path)
    assert back.to_json() == alone.to_json() and json.loads(path.read_text())["num_avs"] == 2
    doc = json.loads(path.read_text())
    doc["scenarios"]["outcome"] = doc["scenarios"]["outcome"][:12]
    with pytest.raises(UserError, match="expected 24 values"):
        Results.from_json(json.dumps(doc))


def test_eval_refuses_an_archive_of_a_multi_av_suite_before_writing_anything(tmp_path, capsys):
    args = [
        "eval",
        "--suite",
        "duel",
        "--decider",
        "rule-fsm",
        "--out",
        str(tmp_path / "r.json"),
        "--archive",
        str(tmp_path / "run.mcap"),
        "--no-progress",
    ]
    assert main(args) == 2
    assert "archives record single-ego suites only" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_shards_of_a_multi_av_suite_merge_into_the_full_run(tmp_path):
    small = tmp_path / "duel-small.toml"
    small.write_text('name = "duel-small"\nversion = 1\ncount = 10\nseed = 5\nbase = "duel"\n')
    suite = load_suite(small)
    decider = load("always-overtake", suite.config)
    full = run_suite(suite, decider, progress=False)
    parts = [run_suite(suite, decider, shard=(i, 3), progress=False) for i in range(3)]
    assert merge(parts).without_timing() == full.without_timing()


def test_verify_reruns_a_multi_av_row_and_names_the_av_that_differs(tmp_path):
    root = tmp_path / "lb"
    (root / "submissions").mkdir(parents=True)
    shutil.copytree(REPO_LEADERBOARDS / "submissions" / "duel", root / "submissions" / "duel")
    rows = [p.stem for p in (root / "submissions" / "duel").glob("*.json")]
    for stem in set(rows) - {"rule-fsm", "always-overtake"}:
        (root / "submissions" / "duel" / f"{stem}.json").unlink()
    assert verify(root, sample=3, log=lambda _: None) == 2
    path = root / "submissions" / "duel" / "rule-fsm.json"
    r = Results.load(path)
    i = int(np.flatnonzero(r.per["outcome"][1000:] == SUCCESS)[0])  # an AV 1 success: make it a crash
    r.per["outcome"][1000 + i] = CRASH
    r.summary = summarize_multi(r.per, r.meta["seed"], 2)
    r.save(path)
    with pytest.raises(UserError, match=rf"scenario {i}, AV 1: outcome: recorded 2"):
        verify(root, only="duel/rule-fsm", log=lambda _: None)


def test_multi_agent_rows_leave_the_single_ego_files_and_the_score_alone(tmp_path):
    root = tmp_path / "lb"  # a slice of the shipped board: two single-ego suites, two multi-agent ones
    for part in (
        "reference",
        "seeds",
        "crossplay",
        "submissions/table1",
        "submissions/oncoming-2",
        "submissions/duel",
        "submissions/platoon",
    ):
        if (REPO_LEADERBOARDS / part).is_dir():
            shutil.copytree(REPO_LEADERBOARDS / part, root / part)
    for rel in [p.relative_to(root) for p in (root / "submissions").glob("*/*.json")]:
        if rel.stem not in ("rule-fsm", "fuzzy", "oracle", "dqn"):
            (root / rel).unlink()
    with_multi = generate(root)
    assert {"duel.md", "platoon.md", "crossplay-duel.md", "crossplay-duel.png"} <= set(with_multi)
    index = json.loads(with_multi["index.json"])
    assert set(index["multi_agent"]) == {"duel", "platoon"}
    assert not set(index["multi_agent"]) & set(index["suites"])
    for name in ("duel", "platoon"):
        shutil.rmtree(root / "submissions" / name)
    shutil.rmtree(root / "crossplay")
    alone = generate(root)
    assert "multi_agent" not in json.loads(alone["index.json"])
    assert json.loads(alone["index.json"])["headline"] == index["headline"]
    assert {k: v for k, v in alone.items() if k not in ("index.json", "README.md")} == {
        k: v for k, v in with_multi.items() if k in alone and k not in ("index.json", "README.md")
    }


def test_the_joint_oracle_is_an_upper_bound_apart_and_every_ranked_row_shows_its_gap(tmp_path):
    root = tmp_path / "lb"  # the shipped duel rows of two members and the privileged joint oracle
    (root / "submissions" / "duel").mkdir(parents=True)
    for stem in ("rule-fsm", "fuzzy", "joint-oracle"):
        shutil.copy(REPO_LEADERBOARDS / "submissions" / "duel" / f"{stem}.json", root / "submissions" / "duel")
    files = generate(root)
    duel = json.loads(files["index.json"])["multi_agent"]["duel"]
    assert [e["name"] for e in duel["upper_bounds"]] == ["joint-oracle"]
    assert sorted(e["name"] for e in duel["entries"]) == ["fuzzy", "rule-fsm"]  # never ranked with them
    bound = duel["upper_bounds"][0]["joint"]["all_succeed"]
    assert bound > max(e["joint"]["all_succeed"] for e in duel["entries"])
    for e in duel["entries"]:
        assert e["gap_to_bound_points"] == round(100 * (bound - e["joint"]["all_succeed"]), 1) > 0
    page = files["duel.md"].decode()
    ranked, bounds = page.split("## Upper bounds (privileged deciders, not ranked)")
    assert "joint-oracle" not in ranked.split("### Per AV index")[0]
    assert "| [joint-oracle](" in bounds and "gap to upper bound (points)" in ranked
    assert f"{100 * bound:.1f} % (joint-oracle)" in files["README.md"].decode()


def test_crossplay_regenerates_byte_identically_and_check_catches_edits(tmp_path, capsys):
    root = tmp_path / "lb"
    args = [
        "crossplay",
        "--suite",
        "duel",
        "--limit",
        "6",
        "--deciders",
        "rule-fsm,always-overtake",
        "--root",
        str(root),
    ]
    assert main(args) == 0
    doc = json.loads((root / "crossplay" / "duel.json").read_text())
    assert len(doc["pairs"]) == 4 and doc["scenarios"] == 6
    first = {p.name: p.read_bytes() for p in root.iterdir() if p.is_file()}
    assert {"crossplay-duel.md", "crossplay-duel.png", "index.json", "README.md"} <= set(first)
    assert generate(root) == first
    assert main(["leaderboard", "--root", str(root), "--check"]) == 0
    assert main(["crossplay", "--suite", "duel", "--check", "--root", str(root)]) == 0
    md = first["crossplay-duel.md"].decode()
    assert "| **always-overtake** |" in md and "[" in md.split("## AV-AV crash")[1]  # Wilson intervals
    pair = doc["pairs"][0]
    pair["all_succeed"][0] = (pair["all_succeed"][0] + 1) % 7
    (root / "crossplay" / "duel.json").write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    assert stale_files(root) == ["crossplay-duel.md", "crossplay-duel.png"]
    capsys.readouterr()
    assert main(["crossplay", "--suite", "duel", "--check", "--root", str(root)]) == 1
    assert "differs from a re-run" in capsys.readouterr().err
    assert main(["crossplay", "--suite", "table1", "--limit", "2", "--root", str(root)]) == 2
    assert "on multi-AV suites" in capsys.readouterr().err


def test_crossplay_changed_only_reruns_just_the_pairs_of_a_changed_decider(tmp_path, monkeypatch):
    """--changed-only copies the pairs of two unchanged deciders and re-runs the rest; the file is the
    one a full run writes. A changed weights hash, or another scenario count, means a re-run."""
    root = tmp_path / "lb"
    base = ["crossplay", "--suite", "duel", "--limit", "5", "--root", str(root)]
    assert main(base + ["--deciders", "rule-fsm,always-overtake,fuzzy"]) == 0
    full = (root / "crossplay" / "duel.json").read_bytes()
    ran = []
    real = crossplay.run_pairs
    monkeypatch.setattr(
        crossplay,
        "run_pairs",
        lambda suite, wanted, k, jobs=1, **on: ran.extend(wanted) or real(suite, wanted, k, jobs, **on),
    )
    doc = json.loads(full)
    doc["deciders"][[d["name"] for d in doc["deciders"]].index("fuzzy")]["weights_sha256"] = "0" * 64  # "retrained"
    (root / "crossplay" / "duel.json").write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n")
    assert main(base + ["--deciders", "rule-fsm,always-overtake,fuzzy", "--changed-only"]) == 0
    assert sorted(ran) == sorted(
        {
            (a, b)
            for a in ("rule-fsm", "always-overtake", "fuzzy")
            for b in ("rule-fsm", "always-overtake", "fuzzy")
            if "fuzzy" in (a, b)
        }
    )
    assert (root / "crossplay" / "duel.json").read_bytes() == full
    ran.clear()
    assert main(base[:4] + ["4"] + base[5:] + ["--deciders", "rule-fsm,always-overtake", "--changed-only"]) == 0
    assert len(ran) == 4  # another --limit: nothing is reusable


def test_crossplay_on_platoon_seats_b_on_every_other_av(tmp_path):
    """On a three-AV road A drives the ego and B both followers: B's counts are per AV (2 per road),
    and A = B is self-play (the same as every AV run by that member)."""
    from overtakezoo.benchmark.run.runner import run_suite

    suite = load_suite("platoon")
    doc = crossplay.measure(suite, ["rule-fsm", "always-follow"], scenarios=8)
    pairs = {(p["a"], p["b"]): p for p in doc["pairs"]}
    assert all(p["a_success"][1] == 8 and p["b_success"][1] == 16 for p in pairs.values())
    alone = run_suite(suite, zoo.load("rule-fsm", suite.config), limit=8, progress=False).summary
    assert pairs[("rule-fsm", "rule-fsm")]["all_succeed"] == [alone["joint"]["all_succeed"]["k"], 8]
    # always-follow never passes: as B it never succeeds, and its followers block nobody ahead.
    assert pairs[("rule-fsm", "always-follow")]["b_success"][0] == 0


def test_repo_crossplay_matrix_covers_the_zoo():
    doc = crossplay.load(REPO_LEADERBOARDS / "crossplay" / "duel.json")
    names = [d["name"] for d in doc["deciders"]]
    assert "oracle" not in names and {"rule-fsm", "fuzzy", "dqn", "double-dqn", "ppo", "bc", "cql"} <= set(names)
    assert len(doc["pairs"]) == len(names) ** 2


def test_against_fuzzy_counts_every_place_and_names_the_largest_shortfall():
    # joint success in %, rows A (the ego) x columns B (the other AVs)
    table = {
        ("fuzzy", "fuzzy"): 50,
        ("fuzzy", "x"): 40,
        ("fuzzy", "y"): 30,
        ("x", "fuzzy"): 60,
        ("x", "x"): 45,
        ("x", "y"): 30,
        ("y", "fuzzy"): 20,
        ("y", "x"): 35,
        ("y", "y"): 10,
    }
    pairs = {k: {"all_succeed": [v, 100]} for k, v in table.items()}
    lines = crossplay.against_reference(["fuzzy", "x", "y"], pairs)
    rows = {
        line.split(" | ")[0].strip("| "): line for line in lines if line.startswith("| x") or line.startswith("| y")
    }
    # x as ego: 60>=50, 45>=40, 30>=30; as partner: (fuzzy,x) 40>=50? no, (x,x) 45>=60? no, (y,x) 35>=20 -> 4 of 6
    assert "| 4 of 6 |" in rows["x"] and "partner of x: 45.0 % against 60.0 %" in rows["x"]
    # y as ego: 20<50, 35<40, 10<30; as partner: 30<50, 30<60, 10<20 -> 0 of 6, worst (y,fuzzy) 20 vs 50 (-30)
    assert "| 0 of 6 |" in rows["y"] and "ego beside fuzzy: 20.0 % against 50.0 %" in rows["y"]
    assert crossplay.against_reference(["x", "y"], pairs) == []


def test_repo_crossplay_pages_show_the_places_against_fuzzy():
    page = (REPO_LEADERBOARDS / "crossplay-duel.md").read_text()
    assert "## Against fuzzy, place by place" in page and "| ps-dqn | " in page
