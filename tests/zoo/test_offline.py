"""Offline RL (bc, cql): real short training runs on a real Minari dataset recorded from rule-fsm,
numpy-only acting (no torch in a fresh process), verified weights, typed hyperparameter files."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("minari")

from overtakezoo import zoo  # noqa: E402
from overtakezoo.benchmark.cli import main  # noqa: E402
from overtakezoo.benchmark.datasets import store as datasets  # noqa: E402
from overtakezoo.benchmark.run import training  # noqa: E402
from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, OvertakeCore, ScenarioDistribution  # noqa: E402
from overtakezoo.zoo.members.learned import WeightsError, action_mask, load_pretrained  # noqa: E402
from overtakezoo.zoo.testing import check_decider  # noqa: E402
from overtakezoo.zoo.train.contract import check_card, load_hyperparams  # noqa: E402
from overtakezoo.zoo.train.offline import transitions  # noqa: E402

NAME = "overtakezoo/table1/offline-test-v0"


@pytest.fixture(scope="module")
def home(tmp_path_factory):
    """One dataset for the module: the first 40 table1-train scenarios, rule-fsm, epsilon 0.1."""
    root = tmp_path_factory.mktemp("offline")
    mp = pytest.MonkeyPatch()
    mp.setenv("OVERTAKEZOO_HOME", str(root / "home"))
    mp.delenv("MINARI_DATASETS_PATH", raising=False)
    assert (
        main(
            [
                "dataset",
                "build",
                "--suite",
                "table1-train",
                "--decider",
                "rule-fsm",
                "--count",
                "40",
                "--epsilon",
                "0.1",
                "--name",
                NAME,
            ]
        )
        == 0
    )
    yield root
    mp.undo()


@pytest.fixture(scope="module")
def bc_run(home):
    out = home / "bc"
    card = training.train("bc", dataset=NAME, steps=600, out=out, eval_suite=None, progress=False).card
    return card, out


def test_transitions_are_the_recorded_steps(home):
    ds = datasets.load(NAME)
    data = transitions(ds)
    episodes = list(ds.iterate_episodes())
    assert len(data) == ds.total_steps == sum(len(e.actions) for e in episodes)
    assert data.done.sum() == len(episodes)  # every episode ends once (termination or time limit)
    # next_obs of a step is the obs of the following step inside an episode
    inside = data.done == 0
    assert np.array_equal(data.next_obs[:-1][inside[:-1]], data.obs[1:][inside[:-1]])
    assert np.array_equal(data.action, np.concatenate([e.actions for e in episodes]))


def test_bc_imitates_rule_fsm_and_acts_without_torch(home, bc_run):
    card, out = bc_run
    # 10 % of the recorded modes are uniform noise: at most ~93 % of them can be matched
    acc = card["training"]["heldout_accuracy"]
    assert acc > 0.8, card["training"]
    assert card["action_repeat"] == 1 and card["features"] == "speed-relative-v1"
    assert card["dataset"]["name"] == NAME and len(card["dataset"]["content_sha256"]) == 64
    assert card["reproduce"].startswith(f"overtakezoo train bc --dataset {NAME}")
    assert card["dataset"]["content_sha256"] == datasets.content_sha256(datasets.load(NAME))
    check_card(card)
    assert json.loads((out / "bc.json").read_text()) == card and not (out / "bc.pt").exists()

    # the decider from the written files, in a fresh process: torch never imported
    code = (
        "import sys, numpy as np\n"
        "from overtakezoo.zoo.members.learned import load_pretrained\n"
        "from overtakezoo.envs import EnvConfig, OvertakeCore, ScenarioDistribution\n"
        f"d = load_pretrained('bc', directory={str(out)!r})\n"
        "core = OvertakeCore(EnvConfig()); obs = core.reset(ScenarioDistribution().sample(16, 0))\n"
        "print(d.act(obs).tolist()); assert 'torch' not in sys.modules, 'torch imported'\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    decider = load_pretrained("bc", directory=out)
    check_decider(decider, EnvConfig())


def test_bc_matches_rule_fsm_decisions_on_its_own_states(home, bc_run):
    """Drive rule-fsm (no noise) on scenarios it was not trained on; bc, asked on the same
    observations, picks rule-fsm's mode on most of them."""
    _, out = bc_run
    bc, rule = load_pretrained("bc", directory=out), zoo.load("rule-fsm")
    core = OvertakeCore(EnvConfig())
    obs = core.reset(ScenarioDistribution().sample(64, 7))
    agree = total = 0
    for _ in range(150):
        modes = rule.act(obs)
        running = ~core.done
        agree += int((bc.act(obs) == modes)[running].sum())
        total += int(running.sum())
        obs = core.step(modes).obs
    assert agree / total > 0.8, agree / total


def test_cql_trains_acts_and_refuses_tampered_weights(home):
    out = home / "cql"
    assert (
        main(
            [
                "train",
                "cql",
                "--dataset",
                NAME,
                "--steps",
                "300",
                "--out",
                str(out),
                "--eval-suite",
                "none",
                "--no-progress",
            ]
        )
        == 0
    )
    card = json.loads((out / "cql.json").read_text())
    assert card["hyperparameters"]["alpha"] == 0.1 and card["training"]["gradient_steps"] == 300
    d = load_pretrained("cql", directory=out)
    check_decider(d, EnvConfig())
    core = OvertakeCore(EnvConfig())
    obs = core.reset(ScenarioDistribution().sample(32, 3))
    q = d.scores(obs)
    assert q.shape == (32, 3) and np.isfinite(q).all()
    # the same seed gives the same weights (bytes), a different seed different ones
    again = training.train("cql", dataset=NAME, steps=300, eval_suite=None, progress=False).card
    other = training.train("cql", dataset=NAME, steps=300, seed=1, eval_suite=None, progress=False).card
    assert again["weights_sha256"] == card["weights_sha256"] != other["weights_sha256"]

    data = bytearray((out / "cql.npz").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (out / "cql.npz").write_bytes(bytes(data))
    with pytest.raises(WeightsError, match="does not match"):
        load_pretrained("cql", directory=out)


def test_acting_respects_the_action_mask(home, bc_run):
    _, out = bc_run
    d = load_pretrained("bc", directory=out)
    cfg = EnvConfig()
    core = OvertakeCore(cfg)
    obs = core.reset(ScenarioDistribution().sample(256, 11)).astype(np.float64)
    rng = np.random.default_rng(0)
    from overtakezoo.envs import observation_layout

    lay = observation_layout(cfg)
    obs[:, lay["mode"]] = np.eye(3)[rng.integers(0, 3, len(obs))]  # every current mode
    obs[:, lay["ego"].start + 2] = rng.uniform(-0.2, 1.2, len(obs))  # in lane and out of it
    modes = d.act(obs)
    allowed = action_mask(obs, cfg)
    assert allowed[np.arange(len(obs)), modes].all()
    assert {FOLLOW, OVERTAKE, ABORT} >= set(modes.tolist())


def test_hyperparameter_files_are_typed(tmp_path, home):
    from overtakezoo.zoo.train.bc import BCHyperparams
    from overtakezoo.zoo.train.cql import CQLHyperparams

    for cls, text, match in [
        (CQLHyperparams, "gama = 0.9\n", "gama: unknown key"),
        (CQLHyperparams, "gamma = 1.5\n", "gamma: 1.5 is out of range"),
        (BCHyperparams, "steps = 2.0\n", "steps: expected an integer"),
        (BCHyperparams, "hidden = [64, 0]\n", r"hidden\[1\]: 0 is out of range"),
        (BCHyperparams, "action_mask = 1\n", "action_mask: expected true or false"),
    ]:
        path = tmp_path / "hp.toml"
        path.write_text(text)
        with pytest.raises(ValueError, match=match):
            load_hyperparams(cls, path)
    (tmp_path / "hp.toml").write_text("time_penalty = 0.1\n")  # offline trainers learn the env's reward too
    with pytest.raises(ValueError, match="not a training setting"):
        load_hyperparams(BCHyperparams, tmp_path / "hp.toml")
    (tmp_path / "hp.toml").write_text("time_penality = 0.1\n")
    assert (
        main(
            ["train", "bc", "--dataset", NAME, "--hyperparams", str(tmp_path / "hp.toml"), "--out", str(tmp_path / "o")]
        )
        == 2
    )
    assert main(["train", "bc", "--out", str(tmp_path / "o")]) == 2  # no --dataset
    assert main(["train", "cql", "--dataset", "overtakezoo/table1/missing-v0", "--out", str(tmp_path / "o")]) == 2
    assert not (tmp_path / "o" / "bc.npz").exists()


def test_pretrained_members_load_and_say_what_data_they_learned_from():
    for name in ("bc", "cql"):
        d = zoo.load(name)
        assert d.action_repeat == 1 and d.weights_sha256
        assert d.model_card["dataset"]["name"].startswith("overtakezoo/")
        assert "table1" in d.model_card["results"]
        assert "reproduce" in d.card()
