"""``overtakezoo seeds`` (benchmark/leaderboard/seeds.py): every training seed of a learned member run on its
training splits and the test suites, written as the seeds file the leaderboard's headline reads; --ship
publishes the chosen seed with its selection in the card."""

from __future__ import annotations

import json

import pytest

from conftest import PRETRAINED, last_error_line, shipped_as_runs, suite_file
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.leaderboard import headline


@pytest.fixture
def runs(tmp_path):
    """Three runs of dqn (the shipped weights under seeds 0, 1 and 2), as `overtakezoo train` leaves them."""
    return shipped_as_runs(tmp_path)


def test_the_command_writes_a_seeds_file_the_headline_accepts_and_ships_the_chosen_seed(tmp_path, tiny_suite, runs):
    test_suite = tiny_suite(6)
    split = suite_file(tmp_path / "tiny-train.toml", 6, base="occluded")
    root = tmp_path / "leaderboards"
    root.mkdir()
    argv = ["seeds", "dqn", *map(str, runs), "--suites", test_suite, "--train-suite", str(split), "--root", str(root)]
    assert main(argv) == 0
    path = root / "seeds" / "dqn.json"
    text = path.read_text()
    doc = json.loads(text)
    assert text == json.dumps(doc, indent=1, sort_keys=True) + "\n"  # the format the board keeps
    assert doc["member"] == "dqn" and doc["train_suite"] == str(split) and doc["shipped_seed"] in (0, 1, 2)
    assert [e["seed"] for e in doc["seeds"]] == [0, 1, 2]
    for entry in doc["seeds"]:
        assert set(entry["suites"]) == {"tiny-train", "tiny"} and entry["suites"]["tiny"]["n"] == 6
        assert (tmp_path / entry["run"] / "seed-eval.json").is_file()  # each run's evaluations, cached
    assert doc["seeds"][0]["suites"] == doc["seeds"][1]["suites"]  # the same weights score the same

    seeds = headline.load_seeds(root)  # the shipped seed's weights are the zoo's: accepted
    assert seeds["dqn"] == doc
    assert f"| dqn | {doc['shipped_seed']} |" in headline.seed_lines(seeds, "tiny")

    # Again from the runs' caches, and shipped into a folder of our own: the same file, and a card
    # that carries the selection.
    shipped = tmp_path / "pretrained"
    shipped.mkdir()
    assert main([*argv, "--ship", "--pretrained", str(shipped)]) == 0
    assert path.read_text() == text
    card = json.loads((shipped / "dqn.json").read_text())
    assert card["selection_rule"] == doc["selection_rule"] and set(card["seed_results"]) == {"0", "1", "2"}
    assert card["results"]["tiny"]["count"] == 6
    assert (shipped / "dqn.npz").read_bytes() == (PRETRAINED / "dqn.npz").read_bytes()


def test_bad_seeds_calls_are_one_error_line(tmp_path, capsys):
    root = tmp_path / "leaderboards"
    root.mkdir()
    assert "run directories" in last_error_line(capsys, ["seeds", "dqn", "--root", str(root)])
    missing = str(tmp_path / "nowhere")
    assert "no such run directory" in last_error_line(capsys, ["seeds", "dqn", missing, "--root", str(root)])
    err = last_error_line(capsys, ["seeds", "dqn", "--compare-only", "--compare", "ppo", "--root", str(root)])
    assert "no seeds file" in err


def test_the_shipped_seed_exports_as_a_run_that_scores_as_the_zoo_member(tmp_path, tiny_suite, capsys):
    """Retraining the seeds whose weights were never kept: the shipped seed, written out as a run
    directory, is the zoo member (same weights, same deployment, same counts) under its own seed."""
    from overtakezoo.benchmark.leaderboard import seeds
    from overtakezoo.envs.suites import load_suite

    run = tmp_path / "ppo-s2"
    assert main(["seeds", "ppo", "--export-shipped", str(run)]) == 0
    card = json.loads((PRETRAINED / "ppo.json").read_text())
    assert f"shipped seed {card['seed']} written" in capsys.readouterr().out
    suite = load_suite(tiny_suite(6))
    entry = seeds.evaluate_run("ppo", run, {"tiny": suite})
    assert entry["seed"] == card["seed"] and entry["weights_sha256"] == card["trained_weights_sha256"]
    from overtakezoo.benchmark.run.policy import load_policy

    assert entry["suites"]["tiny"] == {
        "suite_version": suite.version,
        "suite_sha256": suite.hash,
        **seeds.evaluate(suite, load_policy("ppo", suite.config)),
    }
    # never over a run that is there, nor for a member without trained weights
    assert "not an empty directory" in last_error_line(capsys, ["seeds", "ppo", "--export-shipped", str(run)])
    err = last_error_line(capsys, ["seeds", "rule-fsm", "--export-shipped", str(tmp_path / "r")])
    assert "not a learned zoo member" in err and not (tmp_path / "r").exists()
