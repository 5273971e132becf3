"""The numpy PPO (zoo/train/fastppo.py, `overtakezoo train ppo-numpy`, zoo/hyperparams/ppo-numpy.toml):
it learns table1-train from scratch in seconds, the same seed gives the same bits, it never imports torch;
it is a trainer of its own, never posing as the ppo member, and its runs evaluate like any run."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs import CRASH, SUCCESS
from overtakezoo.zoo.train import fastppo
from overtakezoo.zoo.train.contract import HYPERPARAMS, check_card, load_hyperparams, run_files
from overtakezoo.zoo.train.typed import HyperparameterError

FAST = HYPERPARAMS / "ppo-numpy.toml"


def _train(tmp_path, name, steps, seed=0, **overrides):
    return fastppo.train(
        load_training("table1-train"),
        suite_name="table1-train",
        steps=steps,
        seed=seed,
        out=tmp_path / name,
        overrides=overrides or None,
        progress=False,
    )


def test_backward_matches_finite_differences():
    rng = np.random.default_rng(0)
    net = fastppo.MLP([5, 7, 6, 3], rng, 1.0)
    net.params = [p.astype(np.float64) for p in net.params]  # (float64 for the check)
    x, w = rng.standard_normal((4, 5)), rng.standard_normal((4, 3))
    out, acts = net.forward(x)
    grads = net.backward(acts, w)  # d sum(w * out) / d params
    for p, g in zip(net.params, grads, strict=True):
        for idx in [(0,) * p.ndim, tuple(s - 1 for s in p.shape)]:
            keep = p[idx]
            p[idx] = keep + 1e-6
            up = (net.forward(x)[0] * w).sum()
            p[idx] = keep - 1e-6
            down = (net.forward(x)[0] * w).sum()
            p[idx] = keep
            assert g[idx] == pytest.approx((up - down) / 2e-6, rel=1e-5, abs=1e-8)


def test_sample_follows_the_probabilities():
    rng = np.random.default_rng(0)
    logp = np.log(np.tile([[0.7, 0.2, 0.1]], (100_000, 1)))
    freq = np.bincount(fastppo.sample(logp, rng), minlength=3) / 100_000
    assert np.allclose(freq, [0.7, 0.2, 0.1], atol=0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_learns_table1_train_from_scratch(tmp_path, seed):
    """16 iterations (32k decisions, ~3 CPU s), every seed: the shipped greedy policy passes most
    of 400 table1-train scenarios it was not selected on and crashes in few."""
    trained = _train(tmp_path, "run", 16 * 2048, seed=seed)
    suite = load_training("table1-train")[0]
    held = suite.scenarios().take(np.arange(600, 1000))  # (selection scored the first 256)
    from overtakezoo.envs import OvertakeCore
    from overtakezoo.envs.hold import run_to_end

    decider = trained.decider(suite.config)
    core = OvertakeCore(suite.config)
    run_to_end(core, core.reset(held), lambda o, _: decider.act_batch(o), 10)
    success, crash = np.mean(core.outcome == SUCCESS), np.mean(core.outcome == CRASH)
    print(f"seed {seed}: success {success:.3f} crash {crash:.3f}")
    assert success >= 0.85 and crash <= 0.05, (success, crash)
    card = json.loads((tmp_path / "run" / "ppo-numpy.json").read_text())
    check_card(card)
    assert "torch" not in card["versions"] and card["training"]["selection"]["iteration"] in (8, 12, 16)
    assert card["name"] == "ppo-numpy" and card["weights_file"] == "ppo-numpy.npz"
    assert card["reproduce"] == f"overtakezoo train ppo-numpy --suite table1-train --steps 32768 --seed {seed}"
    assert card["hyperparameters"]["file"] == "ppo-numpy.toml"
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == sorted(run_files("fastppo", "ppo-numpy"))
    assert (tmp_path / "run" / "train_log.csv").read_text().count("\n") == 17  # header + 16 iterations


def test_same_seed_same_bits_other_seed_other_bits(tmp_path):
    a = _train(tmp_path, "a", 2 * 2048, seed=3, train={"select_from": 1, "select_every": 1})
    b = _train(tmp_path, "b", 2 * 2048, seed=3, train={"select_from": 1, "select_every": 1})
    c = _train(tmp_path, "c", 2 * 2048, seed=4, train={"select_from": 1, "select_every": 1})
    assert a.npz == b.npz and a.card["weights_sha256"] == b.card["weights_sha256"]
    assert a.npz != c.npz


def test_trains_without_importing_torch(tmp_path):
    code = (
        "import sys; from overtakezoo.benchmark.cli import main; "
        f"rc = main(['train', 'ppo-numpy', '--steps', '2048', '--eval-suite', 'none', "
        f"'--out', {str(tmp_path / 'run')!r}, '--no-progress']); "
        "assert rc == 0; assert 'torch' not in sys.modules, 'torch imported'"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "run" / "ppo-numpy.npz").is_file() and not (tmp_path / "run" / "ppo.npz").exists()


def test_bad_hyperparameters_are_one_error_naming_the_key(tmp_path):
    with pytest.raises(HyperparameterError, match="ppo.clip"):
        load_hyperparams(fastppo.FastPPOHyperparams, FAST, {"ppo": {"clip": -1}})
    with pytest.raises(HyperparameterError, match="ppo.lr"):
        load_hyperparams(fastppo.FastPPOHyperparams, FAST, {"ppo": {"lr": 0.1}})
    from overtakezoo.zoo.train.contract import TrainError

    with pytest.raises(TrainError, match="--resume"):
        fastppo.train(load_training("table1-train"), steps=2048, out=tmp_path / "r", resume=tmp_path / "x.pt")
    with pytest.raises(TrainError, match="single-AV"):
        fastppo.train(load_training("multi-train"), steps=2048, out=tmp_path / "m", progress=False)


def test_one_ppo_trainer_per_name_each_file_for_its_own_command(tmp_path, capsys):
    """`train ppo` is always rsl-rl's; the numpy PPO is `train ppo-numpy`. A hyperparameter file of
    the other trainer is one `error:` line naming the command that reads it, never a switch."""
    from overtakezoo.benchmark.cli import main
    from overtakezoo.zoo.train.contract import hyperparams_file

    old = tmp_path / "ppo-fast.toml"  # a file from before: the numpy PPO chosen by a key of the ppo member's
    old.write_text('trainer = "numpy"\n' + FAST.read_text())
    for argv, right in (
        (["train", "ppo", "--hyperparams", str(FAST)], f"`overtakezoo train ppo-numpy --hyperparams {FAST}`"),
        (["train", "ppo", "--hyperparams", str(old)], f"`overtakezoo train ppo-numpy --hyperparams {old}`"),
        (["train", "ppo-numpy", "--hyperparams", str(hyperparams_file("ppo"))], "`overtakezoo train ppo --hyperparams"),
        (["train", "ppo-numpy", "--hyperparams", str(old)], "`overtakezoo train ppo-numpy`; delete the line"),
    ):
        assert main([*argv, "--steps", "2048", "--out", str(tmp_path / "run"), "--no-progress"]) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.startswith("error: ") and err.count("\n") == 1 and right in err, err
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())  # nothing trained


def test_a_run_evaluates_as_before_under_its_own_name(tmp_path):
    """What `train ppo-numpy` writes is evaluated by `eval --policy` (the .npz, its card or the run
    directory) and loaded by the learned loader, under its own name."""
    from overtakezoo.benchmark.cli import main
    from overtakezoo.zoo.members.learned import load_pretrained

    run = tmp_path / "run"
    argv = ["train", "ppo-numpy", "--steps", "2048", "--eval-suite", "none", "--out", str(run), "--no-progress"]
    assert main(argv) == 0
    card = json.loads((run / "ppo-numpy.json").read_text())
    suite = load_training("table1-train")[0]
    dec = load_pretrained("ppo-numpy", suite.config, directory=run)
    assert dec.name == "ppo-numpy" and dec.weights_sha256 == card["weights_sha256"] and dec.action_repeat == 10
    from conftest import suite_file
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    tiny = suite_file(tmp_path / "tiny.toml", 4)
    run_suite(load_suite(str(tiny)), dec, progress=False).save(tmp_path / "loaded.json")
    want = json.loads((tmp_path / "loaded.json").read_text())["scenarios"]
    for spec in (run / "ppo-numpy.npz", run / "ppo-numpy.json", run):
        res = tmp_path / "res.json"
        assert main(["eval", "--suite", str(tiny), "--policy", str(spec), "--out", str(res), "--no-progress"]) == 0
        doc = json.loads(res.read_text())
        assert doc["decider"]["name"] == f"ppo-numpy-{card['weights_sha256'][:8]}"
        assert doc["decider"]["policy"]["kind"] == "overtakezoo-ppo" and doc["scenarios"] == want
