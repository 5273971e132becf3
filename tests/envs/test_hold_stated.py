"""One hold, stated (issue 36): every face of a suite holds what the suite's registered id holds,
``eval`` and ``submit`` say which hold they use and where it came from (and warn about a policy file
without a card), the training hold and the decision rate have one vocabulary, and the README's Python
example prints what its comment says."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium
import numpy as np
import pettingzoo
import pytest

import overtakezoo.envs  # noqa: F401  (registers the ids)
from conftest import suite_file
from overtakezoo import zoo
from overtakezoo.benchmark.cli import main
from overtakezoo.envs import OvertakeEnv, make_vec, parallel_env
from overtakezoo.envs import env as aec_env
from overtakezoo.envs.hold import hold_steps
from overtakezoo.envs.suites import SUITES_DIR, load_suite, suite_env_ids

ROOT = Path(__file__).resolve().parents[2]


# ------------------------------------------------------------------ 1. every face of a suite, one hold
def _table1_file(tmp_path: Path, dt: str = "0.1") -> Path:
    path = tmp_path / "mine.toml"
    text = (SUITES_DIR / "table1.toml").read_text()
    path.write_text(text.replace("dt = 0.1  ", f"dt = {dt}  ", 1))
    return path


def _gym_steps(env, seed=5, actions=(1, 1, 0)):
    out = [env.reset(seed=seed)[0]]
    for a in actions:
        obs, rew, term, trunc, info = env.step(a)
        out += [obs, rew, term, trunc, info["t"]]
        if term or trunc:
            break
    return out


def _vec_steps(vec, seed=5, actions=((1, 0, 1), (1, 1, 0))):
    out = [vec.reset(seed=seed)[0]]
    for a in actions:
        obs, rew, term, trunc, info = vec.step(np.array(a))
        out += [obs, rew, term, trunc, info["t"]]
    return out


def _par_steps(par, seed=5, steps=3):
    obs, _ = par.reset(seed=seed)
    out = [obs]
    for k in range(steps):
        if not par.agents:
            break
        obs, rew, term, trunc, info = par.step({a: (k + i) % 2 for i, a in enumerate(par.agents)})
        out += [obs, rew, term, trunc, {a: i["t"] for a, i in info.items()}]
    return out


def _aec_steps(aec, seed=5, turns=4):
    aec.reset(seed=seed)
    out = []
    for k in range(turns):
        obs, rew, term, trunc, info = aec.last()
        out += [aec.agent_selection, obs, rew, term, trunc, info["t"]]
        aec.step(None if term or trunc else k % 2)
    return out


def _same(a, b):
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        if isinstance(x, dict):
            assert x.keys() == y.keys()
            for k in x:
                np.testing.assert_array_equal(x[k], y[k])
        else:
            np.testing.assert_array_equal(x, y)


def test_every_face_of_a_suite_holds_what_its_registered_id_holds(tmp_path):
    """OvertakeEnv / make_vec / parallel_env / env made from a suite (by name, suite=, a loaded suite,
    a suite file) hold what gymnasium.make / make_vec / pettingzoo.make of the suite's id hold (the
    zoo's 1 s, computed in one place), and step alike for a fixed seed."""
    ids = {entry.name: (env_id, entry) for env_id, entry in suite_env_ids().items()}
    table1, path = load_suite("table1"), _table1_file(tmp_path)

    # the single Gymnasium env
    by_id = gymnasium.make(ids["table1"][0]).unwrapped
    ref = _gym_steps(by_id)
    for made in (
        OvertakeEnv("table1"),
        OvertakeEnv(suite="table1"),
        OvertakeEnv(table1),
        OvertakeEnv(suite=str(path)),
        gymnasium.make("overtakezoo/Overtake-v0", suite="table1").unwrapped,
    ):
        assert made.hold_steps == by_id.hold_steps == 10
        _same(_gym_steps(made), ref)
    # the vector env
    vec_id = gymnasium.make_vec(ids["table1"][0], num_envs=3)
    ref = _vec_steps(vec_id)
    for made in (make_vec(3, suite="table1"), make_vec(3, table1), make_vec(3, suite=str(path))):
        assert made.hold_steps == vec_id.hold_steps == 10
        _same(_vec_steps(made), ref)
    # PettingZoo, parallel and AEC
    duel = load_suite("duel")
    par_id = pettingzoo.make("parallel", ids["duel"][0])
    ref = _par_steps(par_id)
    for made in (parallel_env("duel"), parallel_env(suite="duel"), parallel_env(duel)):
        assert made.hold_steps == par_id.hold_steps == 10
        _same(_par_steps(made), ref)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        aec_id = pettingzoo.make("aec", ids["duel"][0])
        made = aec_env("duel")
        assert made.unwrapped.hold_steps == aec_id.unwrapped.hold_steps == 10
        _same(_aec_steps(made), _aec_steps(aec_id))
    # one formula: the ids' hold is the suite's, the zoo's 1 s at its dt
    from overtakezoo.envs.suites import zoo_hold

    for name in ("table1", "duel"):
        suite = load_suite(name)
        assert suite.hold_steps == ids[name][1].hold_steps == zoo_hold(suite.config.dt) == 10


def test_a_raw_config_keeps_decision_interval_and_an_explicit_hold_wins(tmp_path):
    table1, duel = load_suite("table1"), load_suite("duel")
    # a raw config (EnvConfig, dict, keywords): its decision_interval
    assert OvertakeEnv(table1.config).hold_steps == make_vec(2, table1.config).hold_steps == 1
    assert parallel_env(duel.config).hold_steps == parallel_env(duel.config.to_dict()).hold_steps == 1
    assert OvertakeEnv(decision_interval=2).hold_steps == 2
    # an explicit hold_steps wins, both ways
    assert parallel_env("duel", hold_steps=1).hold_steps == 1
    assert pettingzoo.make("parallel", "overtakezoo/duel-v1", hold_steps=20).hold_steps == 20
    assert OvertakeEnv("table1", hold_steps=30).hold_steps == 30
    # the zoo's 1 s at the env's own dt and interval: a suite file at dt = 0.05 holds 20 steps
    fine = _table1_file(tmp_path, "0.05")
    assert load_suite(fine).hold_steps == OvertakeEnv(suite=str(fine)).hold_steps == 20
    assert parallel_env("duel", decision_interval=4).hold_steps == hold_steps(4, 10) == 8


# ------------------------------------------------------------------ 2. eval and submit say the hold
@pytest.fixture
def tiny(tiny_suite):
    return tiny_suite(6)


def _eval(capsys, tiny, tmp_path, *decider):
    out = tmp_path / f"r{len(list(tmp_path.glob('r*.json')))}.json"
    assert main(["eval", "--suite", tiny, *decider, "--out", str(out), "--no-progress"]) == 0
    got = capsys.readouterr()
    assert "hold:" not in got.out and got.out.startswith(f"suite {tiny} v")  # stdout: the results, unchanged
    return got.err, out


def test_eval_and_submit_say_a_zoo_deciders_hold(capsys, tiny, tmp_path):
    err, _ = _eval(capsys, tiny, tmp_path, "--decider", "dqn")
    card = json.loads((ROOT / "zoo" / "pretrained" / "dqn.json").read_text())
    assert card["decide_every"] == 1 and card["action_repeat"] == 10
    assert (
        "hold: 1 core step per decision (from dqn's model card: decide_every 1, its decision rate when "
        "deployed; trained at a hold of 10)"
    ) in err.splitlines(), err
    err, results = _eval(capsys, tiny, tmp_path, "--decider", "rule-fsm")
    assert "hold: 1 core step per decision (the default: rule-fsm declares no action_repeat" in err, err
    assert "warning" not in err
    err, _ = _eval(capsys, tiny, tmp_path, "--decider", "oracle")
    assert "hold: 10 core steps per decision (from oracle's own action_repeat)" in err, err
    # submit of a zoo member's results says it too (stderr; stdout as before)
    assert main(["submit", str(results), "--root", str(tmp_path / "lb")]) == 0
    got = capsys.readouterr()
    assert "hold: 1 core step per decision (the default: rule-fsm" in got.err and "hold:" not in got.out


def test_a_model_card_beside_weights_is_named(tmp_path):
    from overtakezoo.benchmark.run.policy import hold_lines, load_policy

    config = load_suite("table1").config
    dec = load_policy(str(ROOT / "zoo" / "pretrained" / "dqn.npz"), config)
    try:
        assert hold_lines(dec, config) == [
            "hold: 1 core step per decision (from the model card dqn.json: decide_every 1, trained at a hold of 10)"
        ]
    finally:
        dec.inner.close()


@pytest.mark.filterwarnings("ignore::DeprecationWarning", "ignore::UserWarning", "ignore::FutureWarning")
def test_eval_and_submit_say_a_policy_files_hold_and_warn_without_a_card(capsys, tiny, tmp_path, one_torch_thread):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from overtakezoo.benchmark.run.artifacts import write_card

    PPO("MlpPolicy", OvertakeEnv(hold_steps=10), seed=0, n_steps=64, device="cpu").save(tmp_path / "model")
    model = tmp_path / "model.zip"
    # no card: held one core step, and said so, with a warning and the command that writes the card
    err, _ = _eval(capsys, tiny, tmp_path, "--policy", str(model))
    lines = err.splitlines()
    assert "hold: 1 core step per decision (the default: model.zip has no policy card)" in lines, err
    warning = next(line for line in lines if line.startswith("warning: "))
    assert "has no policy card" in warning and f"overtakezoo card {model} --action-repeat 10 --suite {tiny}" in warning
    # with its card: held what the card says, and where that came from; no warning
    write_card(model, action_repeat=10, suite=tiny)
    err, results = _eval(capsys, tiny, tmp_path, "--policy", str(model))
    assert "hold: 10 core steps per decision (from the policy card model.card.json)" in err.splitlines(), err
    assert "warning" not in err
    assert (
        main(["submit", str(results), "--name", "my-sb3", "--policy", str(model), "--root", str(tmp_path / "lb")]) == 0
    )
    got = capsys.readouterr()
    assert "hold: 10 core steps per decision (from the policy card model.card.json)" in got.err.splitlines(), got.err
    assert "hold:" not in got.out


def test_eval_prints_the_hold_on_stderr_only(tmp_path):
    suite = suite_file(tmp_path / "small.toml", 4)
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "overtakezoo.benchmark.cli",
            "eval",
            "--suite",
            str(suite),
            "--decider",
            "always-follow",
            "--out",
            str(tmp_path / "r.json"),
            "--no-progress",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert p.returncode == 0, p.stderr
    assert p.stderr.splitlines()[0].startswith("hold: 1 core step per decision ("), p.stderr
    assert p.stdout.startswith("suite small v2") and "hold:" not in p.stdout


# ------------------------------------------------------------------ 3. one vocabulary
def test_decision_rate_and_training_hold_are_named_apart():
    """A learned member's action_repeat is its decision rate (card decide_every), not its training
    hold (card action_repeat): the docstrings and help say so, none says it comes 'from training'."""
    from overtakezoo.zoo.members.learned import deployed_repeat

    dqn = zoo.load("dqn")
    assert dqn.action_repeat == dqn.model_card["decide_every"] == 1 != dqn.model_card["action_repeat"]
    assert "decision rate" in zoo.Decider.__doc__ and "training hold" in zoo.Decider.__doc__
    assert "decide_every" in zoo.Decider.__doc__ and "from training" not in zoo.Decider.__doc__
    assert "decision rate" in deployed_repeat.__doc__
    for rel in (
        "zoo/base.py",
        "zoo/members/learned.py",
        "benchmark/run/policy.py",
        "envs/hold.py",
        *(f"benchmark/commands/{p.name}" for p in (ROOT / "benchmark" / "commands").glob("*.py")),
        *(f"envs/faces/{p.name}" for p in (ROOT / "envs" / "faces").glob("*.py")),
    ):
        assert "from training" not in (ROOT / rel).read_text(), rel
    from overtakezoo.benchmark.commands import card

    assert "its training hold" in Path(card.__file__).read_text()


# ------------------------------------------------------------------ 4. the README's Python example
def _readme_python_example() -> str:
    from doc_blocks import blocks

    return next(b.body for b in blocks(ROOT / "README.md") if b.lang == "python")


def test_readmes_python_example_prints_the_hold_its_comment_says(capsys):
    code = _readme_python_example()
    said = re.search(r"^steps = hold_steps\(.*#\s*(\d+) core steps? per decision", code, re.M)
    assert said, "the README's Python example: its steps = hold_steps(...) line says '# N core step(s) per decision'"
    small = code.replace(".sample(3000,", ".sample(40,")
    assert small != code
    namespace: dict = {}
    exec(compile(small + "\nprint('steps', steps)\n", "README.md (Python)", "exec"), namespace)
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == f"steps {said.group(1)}"
    counts = [int(v) for v in out[-2].strip("[]").split()]  # the bincount: running, success, ...
    assert sum(counts) == 40 and counts[0] == 0
