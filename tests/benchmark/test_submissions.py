"""Verified submissions: rows re-run exactly, edits and swapped artifacts are refused, names are guarded."""

import json
import shutil
import time
from pathlib import Path

import numpy as np
import pytest
from test_benchmark_results import fake_results
from test_benchmark_runner import small_suite

from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.changes import default_base
from overtakezoo.benchmark.leaderboard.generate import generate
from overtakezoo.benchmark.leaderboard.rows import load_submissions
from overtakezoo.benchmark.leaderboard.submission import submit
from overtakezoo.benchmark.leaderboard.verify import sample_indices
from overtakezoo.benchmark.results.metrics import summarize
from overtakezoo.benchmark.results.results import PER_SCENARIO, Results
from overtakezoo.benchmark.run.runner import run_indices, run_suite
from overtakezoo.envs import FOLLOW, OVERTAKE, SIM_VERSION, EnvConfig, observation_size
from overtakezoo.envs.io import file_sha256

REPO = Path(__file__).resolve().parents[2] / "leaderboards"


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


def shipped(name, suite="table1"):
    """A shipped row as it was measured (the submission block stripped)."""
    r = Results.load(REPO / "submissions" / suite / f"{name}.json")
    return Results({**r.meta, "submission": None}, r.per, r.summary, r.timing)


@pytest.fixture
def root(tmp_path):
    """A leaderboard holding the shipped table1 rows of always-overtake and rule-fsm."""
    root = tmp_path / "lb"
    for name in ("always-overtake", "rule-fsm"):
        submit(shipped(name), root)
    return root


# ------------------------------------------------------------------ subsets
@pytest.mark.parametrize("decider", ["rule-fsm", "dqn", "oracle"])
def test_a_subset_run_equals_the_same_scenarios_of_the_full_run(tmp_path, decider, learned_dir):
    suite = small_suite(tmp_path, count=24)
    kw = {"directory": learned_dir} if decider == "dqn" else {}  # dqn: random weights, the shipped format
    full = run_suite(suite, zoo.load(decider, suite.config, **kw), progress=False).per
    idx = np.array([21, 2, 17, 17, 23, 0])  # any order, repeats allowed
    sub = run_indices(suite, zoo.load(decider, suite.config, **kw), idx, chunk_size=4)
    for key in PER_SCENARIO:
        np.testing.assert_array_equal(sub[key], full[key][idx], err_msg=key)


def test_sample_indices_are_seeded_sorted_and_per_row():
    a = sample_indices(3000, 5, 0, "submissions/table1/a.json")
    assert np.array_equal(a, sample_indices(3000, 5, 0, "submissions/table1/a.json"))
    assert np.all(np.diff(a) > 0) and a.size == 5
    assert not np.array_equal(a, sample_indices(3000, 5, 0, "submissions/table1/b.json"))
    assert not np.array_equal(a, sample_indices(3000, 5, 1, "submissions/table1/a.json"))
    assert np.array_equal(sample_indices(10, None, 0, "x"), np.arange(10))


# ------------------------------------------------------------------ the shipped leaderboard
@pytest.mark.board
def test_every_shipped_row_reproduces_as_ci_runs(capsys):
    # CI's verify step: `overtakezoo leaderboard --verify --sample 1 --jobs 2`, the base resolved as in
    # CI. In CI's fresh clone of the branch under test there is no base, so every row of the board is
    # re-run in full; against a real base (a pull-request job), the rows it changed in full and one
    # scenario of each other row, drawn from fresh randomness.
    rows = len(list(REPO.glob("submissions/*/*.json")))
    assert rows == sum(len(v) for v in load_submissions(REPO).values())  # every row file is a current row
    base = default_base(REPO)
    t0 = time.perf_counter()
    assert main(["leaderboard", "--root", str(REPO), "--verify", "--sample", "1", "--jobs", "2"]) == 0
    out = capsys.readouterr().out
    assert f"verified {rows} row(s): every re-run reproduces" in out
    assert ("every row counts as changed" in out) == (base is None)
    for matrix in sorted(REPO.glob("crossplay/*.json")):  # and the cross-play matrices, 12 pairs each
        assert f"verified crossplay/{matrix.name}: 12 of " in out
    with capsys.disabled():
        print(
            f"\nverified {rows} rows ({'all in full: no base' if base is None else f'against {base[:12]}'}) "
            f"in {time.perf_counter() - t0:.1f} s"
        )


def test_privileged_rows_are_upper_bounds_not_ranked():
    md = (REPO / "table1.md").read_text()
    ranked, rest = md.split("## Upper bounds")
    assert "[oracle]" not in ranked and "[oracle](submissions/table1/oracle.json)" in rest.split("###")[0]
    index = json.loads((REPO / "index.json").read_text())
    for s in index["suites"].values():
        assert [e["name"] for e in s["upper_bounds"]] == ["oracle"]
        assert all(not e["privileged"] for e in s["entries"])
    for s in index["multi_agent"].values():  # the joint oracle bounds every multi-agent suite, with a gap per row
        assert [e["name"] for e in s["upper_bounds"]] == ["joint-oracle"]
        assert all(not e["privileged"] and e["gap_to_bound_points"] is not None for e in s["entries"])


# ------------------------------------------------------------------ refusals
def test_edited_per_scenario_outcome_is_refused_naming_the_scenario(root, capsys):
    path = root / "submissions" / "table1" / "always-overtake.json"
    idx = sample_indices(3000, 3, 0, "submissions/table1/always-overtake.json")
    r = Results.load(path)
    i = int(idx[1])
    r.per["outcome"][i] = 1 if r.per["outcome"][i] != 1 else 2  # consistent file: the summary follows the edit
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(path)
    assert main(["leaderboard", "--root", str(root), "--verify", "--sample", "3", "--only", "table1/rule-fsm"]) == 0
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "3", "--seed", "0"])
    assert f"submissions/table1/always-overtake.json: scenario {i}: outcome: recorded" in err

    # A float edited in the fourth decimal is caught too, and named.
    r = Results.load(path)
    r.per["outcome"] = shipped("always-overtake").per["outcome"]
    r.per["episode_time"][idx[0]] += 1e-4
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(path)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "3", "--seed", "0"])
    assert f"scenario {idx[0]}: episode_time: recorded" in err


def test_parallel_verify_runs_every_row_once_reports_in_name_order_and_refuses_an_edited_oracle_row(tmp_path, capsys):
    # --jobs 2 verifies each suite's privileged rows apart from its others, longest first (verify.py):
    # every row is still verified exactly once, reported in suite order, and a failure still names it.
    root = tmp_path / "lb"
    for suite, name in (("table1", "oracle"), ("table1", "rule-fsm"), ("oncoming-2", "always-follow")):
        submit(shipped(name, suite), root)
    argv = ["leaderboard", "--root", str(root), "--verify", "--sample", "2", "--seed", "0", "--jobs", "2"]
    assert main(argv) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("verified submissions/")]
    assert [line.split(":")[0] for line in lines] == [
        "verified submissions/oncoming-2/always-follow.json",
        "verified submissions/table1/oracle.json",
        "verified submissions/table1/rule-fsm.json",
    ]
    path = root / "submissions" / "table1" / "oracle.json"
    i = int(sample_indices(3000, 2, 0, "submissions/table1/oracle.json")[0])
    r = Results.load(path)
    r.per["outcome"][i] = 1 if r.per["outcome"][i] != 1 else 2
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(path)
    assert f"submissions/table1/oracle.json: scenario {i}: outcome: recorded" in one_line_error(capsys, argv)


# ------------------------------------------------------------------ a policy file, end to end through the CLI
def scripted_policy(path, seed, favour):
    """A TorchScript MLP (N, D) float32 -> 3 logits with seeded weights, leaning towards mode ``favour``."""
    torch = pytest.importorskip("torch")
    torch.manual_seed(seed)
    net = torch.nn.Sequential(
        torch.nn.Linear(observation_size(EnvConfig()), 16), torch.nn.Tanh(), torch.nn.Linear(16, 3)
    )
    with torch.no_grad():
        net[2].bias.copy_(torch.nn.functional.one_hot(torch.tensor(favour), 3) * 4.0)
    torch.jit.save(torch.jit.script(net.eval()), str(path))
    return path


@pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
def test_artifact_row_reproduces_and_a_swapped_artifact_is_refused(tiny, tmp_path, capsys):
    a = scripted_policy(tmp_path / "tiny.pt", 0, OVERTAKE)
    b = scripted_policy(tmp_path / "other.pt", 1, FOLLOW)  # same shapes, other weights, other outcomes
    root = tmp_path / "lb"
    for policy, out in ((a, "ra.json"), (b, "rb.json")):
        assert (
            main(["eval", "--policy", str(policy), "--suite", tiny, "--out", str(tmp_path / out), "--no-progress"]) == 0
        )
    ra, rb = Results.load(tmp_path / "ra.json"), Results.load(tmp_path / "rb.json")
    assert not np.array_equal(ra.per["outcome"], rb.per["outcome"])
    capsys.readouterr()

    # Results of policy A filed with policy B: refused at submit time (the results record A's sha256).
    assert "submit the file that was evaluated" in one_line_error(
        capsys, ["submit", str(tmp_path / "ra.json"), "--name", "my-policy", "--policy", str(b), "--root", str(root)]
    )
    assert (
        main(["submit", str(tmp_path / "ra.json"), "--name", "my-policy", "--policy", str(a), "--root", str(root)]) == 0
    )
    filed = Results.load(root / "submissions" / tiny / "my-policy.json")
    policy = filed.meta["submission"]["policy"]
    sha = policy["sha256"]
    # TorchScript is code: what is stored is its ONNX export (made in the sandbox), and the row's
    # decider block describes that file; the submitted file is recorded as the source.
    artifact = root / "submissions" / "artifacts" / f"{sha}.onnx"
    assert policy["artifact"] == f"artifacts/{sha}.onnx" and artifact.read_bytes()[:1] == b"\x08"
    assert policy["source"] == {"kind": "torchscript", "sha256": file_sha256(a)}
    assert filed.decider == {
        "name": "my-policy",
        "version": "1",
        "weights_sha256": sha,
        "privileged": False,
        "policy": {"kind": "onnx", "file": f"{sha}.onnx", "sha256": sha},
    }
    assert filed.per["outcome"].tolist() == ra.per["outcome"].tolist()
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert "verified submissions/tiny/my-policy.json: 12 of 12 scenarios reproduce exactly" in capsys.readouterr().out

    # The stored policy swapped for another one: a sha256 mismatch, named.
    good = artifact.read_bytes()
    artifact.write_bytes(good[:-3] + b"\x00\x00\x00")
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert f"my-policy.json: submission.policy.artifact: artifacts/{sha}.onnx has sha256" in err and sha[:12] in err
    artifact.write_bytes(good)

    # A consistent forgery: A's outcomes claimed for B (the results' weights sha256 edited to B's):
    # submit re-runs the stored form of B on every scenario and refuses, naming the first that differs.
    forged = Results(
        {**ra.meta, "decider": {**ra.decider, "weights_sha256": rb.decider["weights_sha256"]}},
        ra.per,
        ra.summary,
        ra.timing,
    )
    forged.save(tmp_path / "forged.json")
    first = int(np.flatnonzero(ra.per["outcome"] != rb.per["outcome"])[0])
    err = one_line_error(
        capsys, ["submit", str(tmp_path / "forged.json"), "--name", "forged", "--policy", str(b), "--root", str(root)]
    )
    assert "forged.json: scenario " in err and "not produced by this policy" in err
    assert int(err.split("scenario ")[1].split(":")[0]) <= first
    assert not (root / "submissions" / tiny / "forged.json").exists()
    assert main(["leaderboard", "--root", str(root), "--verify", "--only", "*/my-policy"]) == 0


@pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
def test_train_output_is_submitted_with_its_model_card(tiny, tmp_path, capsys, learned_dir):
    """`overtakezoo train` writes weights plus their model card: the pair is stored (artifacts/<sha256>.npz
    + artifacts/<sha256>.json), the row records both sha256s and re-runs; a swapped card is refused."""
    mine = tmp_path / "run" / "mine.npz"
    mine.parent.mkdir()
    shutil.copy(learned_dir / "dqn.npz", mine)
    shutil.copy(learned_dir / "dqn.json", mine.with_suffix(".json"))
    root, results = tmp_path / "lb", tmp_path / "r.json"
    assert main(["eval", "--policy", str(mine), "--suite", tiny, "--out", str(results), "--no-progress"]) == 0
    assert main(["submit", str(results), "--name", "my-dqn", "--policy", str(mine), "--root", str(root)]) == 0
    filed = Results.load(root / "submissions" / tiny / "my-dqn.json")
    policy = filed.meta["submission"]["policy"]
    sha = policy["sha256"]
    assert sha == file_sha256(mine) and filed.decider["policy"]["kind"] == "overtakezoo-dqn"
    store = root / "submissions" / "artifacts"
    assert sorted(p.name for p in store.iterdir()) == [f"{sha}.json", f"{sha}.npz"]
    assert json.loads((store / f"{sha}.json").read_text()) == json.loads(mine.with_suffix(".json").read_text())
    assert policy["card_sha256"] == file_sha256(store / f"{sha}.json")
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert "verified submissions/tiny/my-dqn.json: 12 of 12" in capsys.readouterr().out
    # The same weights with another card would overwrite the card the row uses: refused.
    noted = tmp_path / "noted.npz"
    shutil.copy(mine, noted)
    noted.with_suffix(".json").write_text(json.dumps({**json.loads(mine.with_suffix(".json").read_text()), "n": 1}))
    assert "another model card for these weights" in one_line_error(
        capsys, ["submit", str(results), "--name", "noted", "--policy", str(noted), "--root", str(root)]
    )

    # The card is part of the policy (architecture, action repeat): an edited one is refused, named.
    card = json.loads((store / f"{sha}.json").read_text())
    (store / f"{sha}.json").write_text(json.dumps({**card, "action_repeat": 1}))
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify"])
    assert f"my-dqn.json: submission.policy.artifact: artifacts/{sha}.json has sha256" in err
    (store / f"{sha}.json").unlink()
    assert f"artifacts/{sha}.json is missing" in one_line_error(capsys, ["leaderboard", "--root", str(root)])

    # Replaced by another policy: the pair is pruned together.
    other = scripted_policy(tmp_path / "other.pt", 1, FOLLOW)
    assert main(["eval", "--policy", str(other), "--suite", tiny, "--out", str(results), "--no-progress"]) == 0
    assert (
        main(["submit", str(results), "--name", "my-dqn", "--policy", str(other), "--replace", "--root", str(root)])
        == 0
    )
    (onnx,) = store.iterdir()
    assert onnx.suffix == ".onnx" and onnx.stem == file_sha256(onnx)


def _results_file(tmp_path, name):
    path = tmp_path / f"{name}.results.json"
    shipped(name).save(path)
    return path


def test_builtin_names_are_reserved(root, tmp_path, capsys):
    mine = tmp_path / "ppo.zip"
    mine.write_bytes(b"my own ppo")
    own = fake_results()
    own.meta["decider"] = {**own.meta["decider"], "name": "ppo", "weights_sha256": "0" * 64}
    path = tmp_path / "ppo.json"
    own.save(path)
    # A self-trained "ppo" is not the zoo's ppo: refused, with or without its file.
    assert "the zoo has v1" in one_line_error(capsys, ["submit", str(path), "--root", str(root)])
    assert "reserved" in one_line_error(capsys, ["submit", str(path), "--policy", str(mine), "--root", str(root)])
    assert "reserved" in one_line_error(
        capsys, ["submit", str(path), "--policy", str(mine), "--name", "PPO", "--root", str(root)]
    )
    assert "not a file" in one_line_error(
        capsys, ["submit", str(path), "--policy", "pkg.mod:factory", "--name", "mine", "--root", str(root)]
    )
    # The weights the results recorded must be the file's.
    assert "submit the file that was evaluated" in one_line_error(
        capsys, ["submit", str(path), "--policy", str(mine), "--name", "my-ppo", "--root", str(root)]
    )
    # A decider that is not built in needs its policy file; a built-in keeps its own name.
    own.meta["decider"] = {**own.meta["decider"], "name": "stub", "weights_sha256": None}
    own.save(path)
    assert "--policy FILE" in one_line_error(capsys, ["submit", str(path), "--root", str(root)])
    assert "its own name" in one_line_error(
        capsys, ["submit", str(_results_file(tmp_path, "rule-fsm")), "--name", "rules", "--root", str(root)]
    )
    assert sorted(p.name for p in (root / "submissions" / "table1").iterdir()) == [
        "always-overtake.json",
        "rule-fsm.json",
    ]
    assert not (root / "submissions" / "artifacts").exists()


def test_resubmitting_needs_replace(root, tmp_path, capsys):
    row = root / "submissions" / "table1" / "rule-fsm.json"
    before = row.read_bytes()
    results = _results_file(tmp_path, "rule-fsm")
    assert "--replace" in one_line_error(capsys, ["submit", str(results), "--root", str(root)])
    assert row.read_bytes() == before
    assert main(["submit", str(results), "--replace", "--root", str(root)]) == 0
    old, new = json.loads(before), json.loads(row.read_bytes())
    assert new["submission"].pop("fresh")["seed"] != old["submission"].pop("fresh")["seed"]  # a draw nobody knew
    assert new == old  # the same row, filed again


@pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
def test_replace_prunes_the_old_artifact(tiny, tmp_path, capsys):
    root, path = tmp_path / "lb", tmp_path / "mine.json"
    for i in range(2):
        policy = scripted_policy(tmp_path / f"mine-{i}.pt", i, OVERTAKE if i else FOLLOW)
        assert main(["eval", "--policy", str(policy), "--suite", tiny, "--out", str(path), "--no-progress"]) == 0
        argv = ["submit", str(path), "--name", "mine", "--policy", str(policy), "--root", str(root)]
        assert main(argv + (["--replace"] if i else [])) == 0
        if not i:
            capsys.readouterr()  # (eval's and submit's hold lines on stderr)
            assert "--replace" in one_line_error(capsys, argv)
    (stored,) = (root / "submissions" / "artifacts").iterdir()  # the first one's artifact was pruned
    filed = Results.load(root / "submissions" / tiny / "mine.json")
    assert stored.name == f"{filed.decider['weights_sha256']}.onnx"
    assert filed.meta["submission"]["policy"]["source"]["sha256"] == file_sha256(tmp_path / "mine-1.pt")


def test_stale_rows_are_shown_apart_and_skipped_by_verify(root, capsys):
    path = root / "submissions" / "table1" / "rule-fsm.json"
    doc = json.loads(path.read_text())
    doc["sim_version"] = SIM_VERSION + 1
    path.write_text(json.dumps(doc))
    md = generate(root)["table1.md"].decode()
    ranked, stale = md.split("## Stale submissions")
    assert "[rule-fsm]" not in ranked
    assert (
        f"[rule-fsm](submissions/table1/rule-fsm.json): measured on simulator v{SIM_VERSION + 1} "
        f"(now v{SIM_VERSION})" in stale
    )
    index = json.loads(generate(root)["index.json"])
    assert index["suites"]["table1"]["stale"][0]["file"] == "submissions/table1/rule-fsm.json"
    assert main(["leaderboard", "--root", str(root), "--verify", "--sample", "1"]) == 0
    out = capsys.readouterr().out
    assert "stale submissions/table1/rule-fsm.json: listed by name only" in out and "verified 1 row(s)" in out

    # A results file without a simulator version (an older OvertakeZoo) is stale as well, and refused.
    doc.pop("sim_version")
    path.write_text(json.dumps(doc))
    assert "simulator of unknown version" in generate(root)["table1.md"].decode()
    assert "re-run the evaluation" in one_line_error(capsys, ["submit", str(path), "--replace", "--root", str(root)])


def test_verify_flags_need_verify(capsys):
    assert "--verify" in one_line_error(capsys, ["leaderboard", "--sample", "3", "--root", str(REPO)])
    assert "no current row" in one_line_error(
        capsys, ["leaderboard", "--verify", "--only", "nope/*", "--root", str(REPO)]
    )


# ------------------------------------------------------------------ the results loader (defect: "seed": 0.0)
@pytest.mark.parametrize("key, value", [("seed", 0.0), ("range", [0.0, 40]), ("sim_version", 1.0)])
def test_integer_fields_given_as_floats_are_user_errors(tmp_path, capsys, key, value):
    doc = json.loads(fake_results(n=40, seed=1).to_json().replace('"count": 3000', '"count": 40'))
    doc[key] = value  # the exact input hypothesis found: "seed": 0.0 made compare/submit/leaderboard raise TypeError
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(UserError, match=f"^r.json: {key}.*is not of type 'integer'"):
        Results.from_json(path.read_text(), "r.json")
    for argv in (["compare", str(path), str(path)], ["submit", str(path), "--root", str(tmp_path / "lb")]):
        assert f"{key}" in one_line_error(capsys, argv)
    (tmp_path / "lb" / "submissions" / "table1").mkdir(parents=True)
    shutil.copy(path, tmp_path / "lb" / "submissions" / "table1" / "stub.json")
    assert key in one_line_error(capsys, ["leaderboard", "--root", str(tmp_path / "lb")])
