"""The numpy PPO (zoo/train/fastppo.py, `overtakezoo train ppo --hyperparams zoo/hyperparams/ppo-fast.toml`):
it learns table1-train from scratch in seconds, the same seed gives the same bits, it never imports torch."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from overtakezoo.envs import CRASH, SUCCESS
from overtakezoo.envs.suites import load_training
from overtakezoo.zoo.train import fastppo
from overtakezoo.zoo.train.contract import HYPERPARAMS, check_card, load_hyperparams
from overtakezoo.zoo.train.typed import HyperparameterError

FAST = HYPERPARAMS / "ppo-fast.toml"


def _train(tmp_path, name, steps, seed=0, **overrides):
    from overtakezoo.zoo.train import ppo

    return ppo.train(
        load_training("table1-train"),
        suite_name="table1-train",
        steps=steps,
        seed=seed,
        out=tmp_path / name,
        hyperparams=FAST,
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
    card = json.loads((tmp_path / "run" / "ppo.json").read_text())
    check_card(card)
    assert "torch" not in card["versions"] and card["training"]["selection"]["iteration"] in (8, 12, 16)
    assert "--hyperparams zoo/hyperparams/ppo-fast.toml" in card["reproduce"]
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
        f"rc = main(['train', 'ppo', '--hyperparams', {str(FAST)!r}, '--steps', '2048', '--eval-suite', 'none', "
        f"'--out', {str(tmp_path / 'run')!r}, '--no-progress']); "
        "assert rc == 0; assert 'torch' not in sys.modules, 'torch imported'"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "run" / "ppo.npz").is_file()


def test_bad_hyperparameters_are_one_error_naming_the_key(tmp_path):
    with pytest.raises(HyperparameterError, match="ppo.clip"):
        load_hyperparams(fastppo.FastPPOHyperparams, FAST, {"ppo": {"clip": -1}})
    with pytest.raises(HyperparameterError, match="ppo.lr"):
        load_hyperparams(fastppo.FastPPOHyperparams, FAST, {"ppo": {"lr": 0.1}})
    from overtakezoo.zoo.train.contract import TrainError

    with pytest.raises(TrainError, match="--resume"):
        from overtakezoo.zoo.train import ppo

        ppo.train(
            load_training("table1-train"),
            steps=2048,
            out=tmp_path / "r",
            hyperparams=FAST,
            resume=tmp_path / "x.pt",
            progress=False,
        )
    with pytest.raises(TrainError, match="single-AV"):
        ppo.train(load_training("multi-train"), steps=2048, out=tmp_path / "m", hyperparams=FAST, progress=False)
