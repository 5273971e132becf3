"""Fresh draws (benchmark/leaderboard/fresh.py): a policy that memorised the public scenarios tops the
public suite, and the board flags it and keeps it off the top; one that memorised its recorded fresh
draw too is refused by verify's own draw; a recorded draw is re-derived like the public scenarios."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import last_error_line
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.leaderboard import fresh

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
from onnx import TensorProto, helper, numpy_helper  # noqa: E402

COUNT = 60  # scenarios of the tiny suite (the memoriser's keys grow with it)


# ------------------------------------------------------------------ the statistics
def test_z_score_is_zero_for_equal_rates_and_grows_with_the_gap():
    assert fresh.z_score(50, 100, 50, 100) == 0.0
    assert fresh.z_score(0, 100, 0, 500) == 0.0 and fresh.z_score(100, 100, 500, 500) == 0.0
    assert fresh.z_score(99, 100, 80, 100) < fresh.z_score(990, 1000, 400, 500)
    assert fresh.disagreement({"n": 1000, "success": 990, "crash": 10}, {"n": 500, "success": 400, "crash": 90})
    # an honest policy's two draws: 2.6 standard errors apart is chance, not a flag
    assert (
        fresh.disagreement({"n": 1000, "success": 900, "crash": 100}, {"n": 500, "success": 430, "crash": 70}) is None
    )


def test_outcomes_round_trip_as_one_digit_each():
    outcome = np.array([1, 2, 3, 4, 1, 1])
    assert fresh.encode(outcome) == "123411"
    assert np.array_equal(fresh.decode(fresh.encode(outcome)), outcome)


# ------------------------------------------------------------------ a memorising policy
class Logger:
    """A decider that records every (observation, decision) pair of the decider it wraps."""

    def __init__(self, inner):
        self.inner, self.obs, self.modes = inner, [], []

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def act(self, obs):
        modes = np.asarray(self.inner.act(obs))
        self.obs.append(np.asarray(obs, np.float32).copy())
        self.modes.append(modes.astype(np.int64).reshape(-1))
        return modes


def oracle_pairs(suite):
    from overtakezoo import zoo
    from overtakezoo.benchmark.run.runner import run_suite

    log = Logger(zoo.load("oracle", config=suite.config))
    run_suite(suite, log, progress=False)
    return np.concatenate(log.obs), np.concatenate(log.modes)


def memoriser(path: Path, keys: np.ndarray, modes: np.ndarray, otherwise: int = 1) -> Path:
    """An ONNX policy that looks its observation up among ``keys`` and answers the recorded mode, and
    ``otherwise`` (overtake) for an observation it never saw: it knows scenarios, not driving."""
    nodes = [
        helper.make_node("Unsqueeze", ["obs", "one"], ["o3"]),
        helper.make_node("Sub", ["o3", "keys"], ["diff"]),
        helper.make_node("Mul", ["diff", "diff"], ["sq"]),
        helper.make_node("ReduceSum", ["sq", "two"], ["dist"], keepdims=0),
        helper.make_node("ArgMin", ["dist"], ["nearest"], axis=1, keepdims=0),
        helper.make_node("ReduceMin", ["dist"], ["best"], axes=[1], keepdims=0),
        helper.make_node("Gather", ["modes", "nearest"], ["recalled"]),
        helper.make_node("Less", ["best", "eps"], ["known"]),
        helper.make_node("Where", ["known", "recalled", "otherwise"], ["mode"]),
    ]
    inits = [
        numpy_helper.from_array(np.array([1], np.int64), "one"),
        numpy_helper.from_array(np.array([2], np.int64), "two"),
        numpy_helper.from_array(keys.astype(np.float32), "keys"),
        numpy_helper.from_array(modes.astype(np.int64), "modes"),
        numpy_helper.from_array(np.array(1e-9, np.float32), "eps"),
        numpy_helper.from_array(np.array(otherwise, np.int64), "otherwise"),
    ]
    graph = helper.make_graph(
        nodes,
        "memoriser",
        [helper.make_tensor_value_info("obs", TensorProto.FLOAT, ["N", keys.shape[1]])],
        [helper.make_tensor_value_info("mode", TensorProto.INT64, ["N"])],
        initializer=inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    # the oracle's hold (it re-plans every 1 s), so the lookup meets the very observations it recorded
    helper.set_model_props(model, {"action_repeat": "10"})
    onnx.checker.check_model(model)
    onnx.save_model(model, str(path))
    return path


def _cli(*argv) -> None:
    assert main([str(a) for a in argv]) == 0


@pytest.fixture
def board(tiny_suite, tmp_path, capsys):
    """A leaderboard on a tiny oncoming-4 suite (where the oracle beats fuzzy and rule-fsm by 8-16
    points): fuzzy, rule-fsm and a policy that memorised the oracle's decisions on the public scenarios."""
    from overtakezoo.envs.suites import load_suite

    name = tiny_suite(COUNT, base="oncoming-4", time_limit=60.0)
    suite = load_suite(name)
    lb = tmp_path / "lb"
    for member in ("fuzzy", "rule-fsm"):
        _cli("eval", "--suite", name, "--decider", member, "--out", tmp_path / f"{member}.json", "--no-progress")
        _cli("submit", tmp_path / f"{member}.json", "--root", lb)
    policy = memoriser(tmp_path / "memoriser.onnx", *oracle_pairs(suite))
    _cli("eval", "--suite", name, "--policy", policy, "--out", tmp_path / "memoriser.json", "--no-progress")
    capsys.readouterr()
    _cli("submit", tmp_path / "memoriser.json", "--policy", policy, "--name", "memoriser", "--root", lb)
    said = capsys.readouterr().err
    return {"name": name, "suite": suite, "lb": lb, "said": said, "tmp": tmp_path}


def test_a_memorising_policy_tops_the_public_suite_and_is_flagged_off_the_top(board, capsys):
    lb, name = board["lb"], board["name"]
    assert "flagged:" in board["said"], board["said"]  # submit says so at once
    rows = {p.stem: json.loads(p.read_text()) for p in (lb / "submissions" / name).glob("*.json")}
    public = {n: r["summary"]["success_rate"]["value"] for n, r in rows.items()}
    assert public["memoriser"] > max(public["fuzzy"], public["rule-fsm"]), public  # the public suite: on top

    _cli("leaderboard", "--root", lb)
    entry = json.loads((lb / "index.json").read_text())["suites"][name]
    assert [e["name"] for e in entry["entries"]] == sorted(["fuzzy", "rule-fsm"], key=lambda n: -public[n])
    assert [e["name"] for e in entry["flagged"]] == ["memoriser"]
    memo = entry["flagged"][0]
    mine = rows["memoriser"]["summary"]
    # it knew scenarios, not driving (60 of each, seeded: public 81.7 % success / 0 % crash, fresh 38.3 / 61.7 %)
    assert memo["fresh"]["success_rate"] < mine["success_rate"]["value"] - 0.15
    assert memo["fresh"]["crash_rate"] > mine["crash_rate"]["value"] + 0.15
    page = (lb / f"{name}.md").read_text()
    ranked, flagged = page.split("## Flagged: not ranked")
    assert "memoriser" not in ranked.split("## Upper bounds")[0] and "memoriser" in flagged
    # an honest row is re-derived in full, the memoriser too (it is flagged, not forged)
    capsys.readouterr()
    _cli("leaderboard", "--root", lb, "--verify")
    out = capsys.readouterr().out
    assert "verify seed" in out and out.count("verify's own draw of") == 3, out


def test_a_policy_that_memorised_its_recorded_draw_too_is_refused_by_verify(board, capsys):
    """The recorded fresh draw is the submitter's to forge (a row is data in a pull request): memorise the
    public scenarios *and* a draw of the author's choosing, record that draw. It re-derives exactly and
    the row is not flagged; verify's own draw, from a seed nobody knew, refuses it."""
    from overtakezoo.benchmark.run.policy import load_policy

    lb, name, suite, tmp = board["lb"], board["name"], board["suite"], board["tmp"]
    chosen = 4242
    keys, modes = oracle_pairs(suite)
    keys2, modes2 = oracle_pairs(fresh.fresh_suite(suite, chosen, fresh.fresh_count(suite)))
    policy = memoriser(tmp / "cheat.onnx", np.concatenate([keys, keys2]), np.concatenate([modes, modes2]))
    _cli("eval", "--suite", name, "--policy", policy, "--out", tmp / "cheat.json", "--no-progress")
    _cli("submit", tmp / "cheat.json", "--policy", policy, "--name", "cheat", "--root", lb)
    row_path = lb / "submissions" / name / "cheat.json"
    row = json.loads(row_path.read_text())
    outcome = fresh.run_fresh(suite, load_policy(str(policy), suite.config), chosen)
    row["submission"]["fresh"] = fresh.block(chosen, fresh.fresh_count(suite), outcome)
    row_path.write_text(json.dumps(row, indent=1, sort_keys=True) + "\n")

    _cli("leaderboard", "--root", lb)
    entry = json.loads((lb / "index.json").read_text())["suites"][name]
    assert entry["entries"][0]["name"] == "cheat"  # the forged draw agrees with the public suite: it would rank
    line = last_error_line(capsys, ["leaderboard", "--root", str(lb), "--verify", "--only", f"{name}/cheat"])
    assert "cheat.json: submission.fresh: verify's own draw" in line and "never saw" in line, line


def test_a_recorded_draw_is_re_derived_and_may_not_be_a_public_seed(board, capsys):
    lb, name, suite = board["lb"], board["name"], board["suite"]
    row_path = lb / "submissions" / name / "fuzzy.json"
    row = json.loads(row_path.read_text())
    outcomes = row["submission"]["fresh"]["outcomes"]
    i = next(i for i, c in enumerate(outcomes) if c != "1")
    row["submission"]["fresh"]["outcomes"] = outcomes[:i] + "1" + outcomes[i + 1 :]  # a crash turned success
    row_path.write_text(json.dumps(row, indent=1, sort_keys=True) + "\n")
    line = last_error_line(capsys, ["leaderboard", "--root", str(lb), "--verify", "--only", f"{name}/fuzzy"])
    assert f"fuzzy.json: submission.fresh (seed {row['submission']['fresh']['seed']}): scenario {i}" in line, line

    row["submission"]["fresh"] = {**row["submission"]["fresh"], "seed": suite.seed}  # the public draw itself
    row_path.write_text(json.dumps(row, indent=1, sort_keys=True) + "\n")
    line = last_error_line(capsys, ["leaderboard", "--root", str(lb), "--verify", "--only", f"{name}/fuzzy"])
    assert "submission.fresh.seed" in line and "not a fresh draw" in line, line

    del row["submission"]["fresh"]
    row_path.write_text(json.dumps(row, indent=1, sort_keys=True) + "\n")
    line = last_error_line(capsys, ["leaderboard", "--root", str(lb), "--verify", "--only", f"{name}/fuzzy"])
    assert "submission.fresh: missing" in line, line
    _cli("leaderboard", "--root", lb)  # and the board lists it apart, unranked
    entry = json.loads((lb / "index.json").read_text())["suites"][name]
    assert "no fresh draw" in {e["name"]: e["why"] for e in entry["flagged"]}["fuzzy"]
