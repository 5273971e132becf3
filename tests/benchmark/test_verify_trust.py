"""Forged rows a pull request could add: every label is derived, CI's sample cannot be predicted,
new rows are verified in full, and two `submit` runs in one clone cannot lose each other's rows."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_submissions import REPO, one_line_error, shipped

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.changes import changed_rows
from overtakezoo.benchmark.leaderboard.submission import submissions_lock, submit
from overtakezoo.benchmark.leaderboard.verify import sample_indices, verify
from overtakezoo.benchmark.results.results import Results
from overtakezoo.envs.io import file_sha256

ROWS = ("always-follow", "always-overtake", "oracle", "rule-fsm")


@pytest.fixture
def root(tmp_path):
    """Shipped table1 rows copied into a leaderboard of its own."""
    root = tmp_path / "lb"
    (root / "submissions" / "table1").mkdir(parents=True)
    for name in ROWS:
        shutil.copy(REPO / "submissions" / "table1" / f"{name}.json", root / "submissions" / "table1")
    return root


def edit(path: Path, change) -> None:
    doc = json.loads(path.read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def test_relabelled_oracle_is_refused(root, capsys):
    path = root / "submissions" / "table1" / "oracle.json"
    edit(path, lambda d: d["decider"].update(privileged=False))
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "1"])
    assert "oracle.json: decider.privileged: recorded False, derived True" in err


def test_a_row_under_a_reserved_name_is_refused(root, capsys):
    src = root / "submissions" / "table1" / "always-follow.json"
    forged = root / "submissions" / "table1" / "ppo.json"
    shutil.copy(src, forged)
    edit(forged, lambda d: d["submission"].update(name="ppo"))  # always-follow's row, filed as ppo's
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "1"])
    assert "ppo.json: submission.policy.builtin: 'always-follow' filed as the row 'ppo'" in err

    # Every label swapped to ppo's (its version and weights): the labels pass, the numbers do not.
    ppo = json.loads((REPO / "submissions" / "table1" / "ppo.json").read_text())
    edit(
        forged, lambda d: (d["submission"].update(policy=ppo["submission"]["policy"]), d.update(decider=ppo["decider"]))
    )
    err = one_line_error(
        capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "20", "--only", "table1/ppo"]
    )
    assert "ppo.json: scenario " in err and "not produced by this policy" in err

    # An artifact row may not take a built-in's name in any case.
    art = dict(
        ppo, submission={"name": "PPO", "policy": {"artifact": "artifacts/" + "a" * 64 + ".onnx", "sha256": "a" * 64}}
    )
    forged.unlink()
    (root / "submissions" / "table1" / "PPO.json").write_text(json.dumps(art))
    (root / "submissions" / "artifacts").mkdir()
    (root / "submissions" / "artifacts" / ("a" * 64 + ".onnx")).write_bytes(b"x")
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "1"])
    assert "PPO.json: submission.name 'PPO': reserved for the built-in zoo member 'ppo'" in err


@pytest.mark.parametrize(
    "field, value",
    [
        (("package", "version"), "1 | ![t](https://x/t.png) | <b>x</b>"),
        (("git_commit",), "deadbeef; rm -rf"),
        (("timing", "started"), "<script>"),
        (("timing", "note"), "anything"),
        (("decider", "version"), "1 <b>"),
    ],
)
def test_provenance_fields_are_held_to_patterns(root, capsys, field, value):
    path = root / "submissions" / "table1" / "rule-fsm.json"

    def change(d):
        target = d
        for key in field[:-1]:
            target = target[key]
        target[field[-1]] = value

    edit(path, change)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--check"])
    assert "rule-fsm.json" in err and field[-1] in err


# ------------------------------------------------------------------ what CI verifies
def git(root: Path, *args: str) -> str:
    return subprocess.run(
        ["git", "-C", str(root), "-c", "user.name=t", "-c", "user.email=t@t", *args],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()


def test_new_and_changed_rows_are_verified_in_full(root, capsys):
    git(root, "init", "-q")
    git(root, "add", "-A")
    git(root, "commit", "-qm", "base")
    base = git(root, "rev-parse", "HEAD")
    assert changed_rows(root, base) == set()

    # A new row honest only at the scenario the old, predictable draw would have picked
    # (seed 0 and the row's path): its other scenarios claim success where the policy times out.
    rel = "submissions/table1/always-follow.json"
    path = root / rel
    r = Results.load(path)
    keep = int(sample_indices(3000, 1, 0, rel)[0])
    lie = np.arange(3000) != keep
    per = {k: v.copy() for k, v in r.per.items()}
    per["outcome"][lie] = 1
    per["completion_time"][lie] = 30.0
    from overtakezoo.benchmark.results.metrics import summarize

    forged = Results(r.meta, per, summarize(per, r.meta["seed"]), r.timing)
    forged.save(path)
    assert changed_rows(root, base) == {rel}
    capsys.readouterr()
    # The old rule (a fixed seed, no base) let it through; the CI rule verifies it in full.
    assert verify(root, sample=1, seed=0, log=lambda _: None) == len(ROWS)
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "1", "--base", base])
    assert f"{rel}: scenario " in err
    # The default draw is fresh randomness, printed so that a failure can be replayed.
    seeds = []
    for _ in range(2):
        verify(root, sample=1, log=seeds.append, only="table1/rule-fsm")
    assert all(s.startswith("verify seed ") for s in (seeds[0], seeds[2])) and seeds[0] != seeds[2]
    with pytest.raises(UserError, match="not a git revision"):
        changed_rows(root, "no-such-rev")


def test_a_new_stale_row_is_refused(root, capsys):
    git(root, "init", "-q")
    git(root, "add", "-A")
    git(root, "commit", "-qm", "base")
    edit(root / "submissions" / "table1" / "rule-fsm.json", lambda d: d.update(sim_version=1))
    err = one_line_error(capsys, ["leaderboard", "--root", str(root), "--verify", "--sample", "1", "--base", "HEAD"])
    assert "rule-fsm.json: stale" in err and "a new or changed row must measure the current benchmark" in err
    git(root, "commit", "-qam", "stale row")  # once on the base it is listed by name, never re-run
    lines: list[str] = []
    verify(root, sample=1, changed=changed_rows(root, "HEAD"), log=lines.append)
    assert (
        "stale submissions/table1/rule-fsm.json: listed by name only, not re-run (measured on simulator v1"
        f" (now v{Results.load(REPO / 'submissions/table1/dqn.json').meta['sim_version']}))" in lines
    )


@pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")
def test_untracked_rows_are_new_and_counted_as_rows(tiny, tmp_path, capsys, learned_dir, monkeypatch):
    # The board in a subfolder of its repository, as leaderboards/ in a checkout.
    monkeypatch.delenv("OVERTAKEZOO_VERIFY_BASE", raising=False)
    monkeypatch.delenv("GITHUB_BASE_REF", raising=False)
    repo = tmp_path / "repo"
    root = repo / "leaderboards"
    assert (
        main(
            ["eval", "--decider", "always-follow", "--suite", tiny, "--out", str(tmp_path / "af.json"), "--no-progress"]
        )
        == 0
    )
    assert main(["submit", str(tmp_path / "af.json"), "--root", str(root)]) == 0
    git(repo, "init", "-q")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "base")
    base = git(repo, "rev-parse", "HEAD")
    monkeypatch.setenv("OVERTAKEZOO_VERIFY_BASE", base)  # a pull request's target (no origin here)

    # A policy of our own, just submitted: three untracked files (the row, the weights, their card), one row.
    mine = tmp_path / "run" / "mine.npz"
    mine.parent.mkdir()
    shutil.copy(learned_dir / "dqn.npz", mine)
    shutil.copy(learned_dir / "dqn.json", mine.with_suffix(".json"))
    assert (
        main(["eval", "--policy", str(mine), "--suite", tiny, "--out", str(tmp_path / "r.json"), "--no-progress"]) == 0
    )
    assert (
        main(["submit", str(tmp_path / "r.json"), "--name", "my-dqn", "--policy", str(mine), "--root", str(root)]) == 0
    )
    assert len(git(repo, "ls-files", "--others").split()) == 3
    rel = f"submissions/{tiny}/my-dqn.json"
    for staged in (False, True):  # untracked, then added: the same one row, verified in full
        if staged:
            git(repo, "add", "-A")
        assert changed_rows(root, base) == {rel}
        capsys.readouterr()
        assert (
            main(["leaderboard", "--root", str(root), "--verify", "--sample", "1"]) == 0
        )  # base: the target, from the environment
        out = capsys.readouterr().out
        assert f"rows new or changed against {base[:12]} (untracked rows are new): 1 row(s), verified in full" in out
        assert (
            f"verified {rel}: 12 of 12 scenarios reproduce exactly; fresh draw: 12 of 12 reproduce, verify's own "
            "draw of 12 agrees (new or changed: every scenario)"
        ) in out
        assert (
            f"verified submissions/{tiny}/always-follow.json: 1 of 12 scenarios reproduce exactly; fresh draw: "
            "1 of 12 reproduce\n"
        ) in out
    # --only counts the rows it selects; a deleted row is on no board: nothing to verify.
    assert main(["leaderboard", "--root", str(root), "--verify", "--sample", "1", "--only", "*/always-*"]) == 0
    assert "(untracked rows are new): 0 row(s)" in capsys.readouterr().out
    git(repo, "commit", "-qm", "my-dqn")
    (root / "submissions" / tiny / "always-follow.json").unlink()
    assert changed_rows(root, "HEAD") == set()
    # A stored file changed: the row using it is the one row counted.
    card = root / "submissions" / "artifacts" / f"{file_sha256(mine)}.json"
    card.write_text(card.read_text() + " ")
    assert changed_rows(root, "HEAD") == {rel}


# ------------------------------------------------------------------ concurrent submits
def test_submits_in_one_clone_wait_for_each_other(tmp_path):
    root = tmp_path / "lb"
    rows = {name: shipped(name) for name in ("always-follow", "always-overtake")}
    done: list[str] = []
    with submissions_lock(root):  # another submit is filing: these must wait
        threads = [threading.Thread(target=lambda n=n: done.append(str(submit(rows[n], root)))) for n in rows]
        for t in threads:
            t.start()
        time.sleep(0.5)
        assert done == [] and not list((root / "submissions").glob("*/*.json"))
    for t in threads:
        t.join(60)
    assert sorted(Path(p).name for p in done) == ["always-follow.json", "always-overtake.json"]

    # Two submits of one name at once: one files it, the other finds its row and refuses.
    root2 = tmp_path / "lb2"
    errors: list[str] = []
    filed: list[str] = []

    def one():
        try:
            filed.append(str(submit(rows["always-follow"], root2)))
        except UserError as exc:
            errors.append(str(exc))

    with submissions_lock(root2):
        threads = [threading.Thread(target=one) for _ in range(2)]
        for t in threads:
            t.start()
        time.sleep(0.2)
    for t in threads:
        t.join(60)
    assert len(filed) == 1 and len(errors) == 1 and "already on the table1 leaderboard" in errors[0]
    assert Results.load(root2 / "submissions" / "table1" / "always-follow.json").decider["name"] == "always-follow"


def test_ci_in_a_fresh_clone_verifies_a_forged_row_in_full(tmp_path, capsys, monkeypatch):
    # As CI really runs: a fresh clone of the branch under test, no base in the environment. There
    # the merge base with origin/HEAD is HEAD itself, which used to mean "0 rows changed" and one
    # predictable scenario per row; now there is no base, and every row is re-run in full.
    for var in ("OVERTAKEZOO_VERIFY_BASE", "GITHUB_BASE_REF"):
        monkeypatch.delenv(var, raising=False)
    repo = tmp_path / "repo"
    lb = repo / "leaderboards"
    (lb / "submissions" / "table1").mkdir(parents=True)
    for name in ("always-follow", "rule-fsm"):
        shutil.copy(REPO / "submissions" / "table1" / f"{name}.json", lb / "submissions" / "table1")
    assert main(["leaderboard", "--root", str(lb)]) == 0
    git(repo, "init", "-q")
    git(repo, "add", "-A")
    git(repo, "commit", "-qm", "main")
    # The pull request: always-follow (it never overtakes, so it never succeeds) claims 13 successes,
    # its summary recomputed and the pages regenerated, so --check passes.
    rel = "submissions/table1/always-follow.json"
    r = Results.load(lb / rel)
    per = {k: v.copy() for k, v in r.per.items()}
    lie = np.flatnonzero(per["outcome"] != 1)[100:113]
    per["outcome"][lie], per["completion_time"][lie] = 1, 30.0
    from overtakezoo.benchmark.results.metrics import summarize

    Results(r.meta, per, summarize(per, r.meta["seed"]), r.timing).save(lb / rel)
    assert main(["leaderboard", "--root", str(lb)]) == 0
    git(repo, "commit", "-qam", "pr")
    clone = tmp_path / "ci"
    subprocess.run(["git", "clone", "-q", str(repo), str(clone)], check=True)
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(clone / "leaderboards"), "--check"]) == 0
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(clone / "leaderboards"), "--verify", "--sample", "1"]) == 2
    out, err = capsys.readouterr()
    assert "every row counts as changed and is verified in full" in out
    assert err.startswith(f"error: {rel}: scenario {lie[0]}") and "\n" not in err.strip(), err
