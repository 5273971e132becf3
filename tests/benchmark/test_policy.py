"""`eval --policy SPEC` / `decision-map --policy SPEC`: module:factory, TorchScript, ONNX, a
Stable-Baselines3 .zip and the weights `overtakezoo train` writes, each end to end through the CLI;
corrupted weights and missing extras are one `error:` line."""

from __future__ import annotations

import json
import shutil
import sys
import warnings

import numpy as np
import pytest

from conftest import suite_file
from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.run.policy import load_policy
from overtakezoo.envs import EnvConfig, observation_size
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.testing import check_decider

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore:`torch.jit:DeprecationWarning")

D = observation_size(EnvConfig())


@pytest.fixture
def suite(tmp_path):
    """table1's first scenarios, shortened: a few seconds of simulation per policy."""
    return suite_file(tmp_path / "tiny.toml", 6, time_limit=20.0)


@pytest.fixture(autouse=True)
def one_thread(one_torch_thread):
    yield


def evaluate(capsys, suite, spec, out):
    assert main(["eval", "--suite", str(suite), "--policy", str(spec), "--out", str(out), "--no-progress"]) == 0, (
        capsys.readouterr().err
    )
    capsys.readouterr()
    return json.loads(out.read_text())


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


def _mlp():
    torch.manual_seed(0)
    return torch.nn.Sequential(torch.nn.Linear(D, 16), torch.nn.ReLU(), torch.nn.Linear(16, 3)).eval()


def _modes(net, obs):
    with torch.no_grad():
        return net(torch.as_tensor(obs, dtype=torch.float32)).argmax(1).numpy()


# ----------------------------------------------------------------------------- Stable-Baselines3
def test_sb3_dqn_trained_on_the_gym_env_evaluates_through_the_cli(tmp_path, suite, capsys):
    pytest.importorskip("stable_baselines3")
    import gymnasium
    from stable_baselines3 import DQN

    import overtakezoo.envs  # noqa: F401 (registers overtakezoo/Overtake-v1)

    model = DQN(
        "MlpPolicy",
        gymnasium.make("overtakezoo/Overtake-v1"),
        seed=0,
        learning_starts=100,
        train_freq=8,
        verbose=0,
        device="cpu",
    )
    model.learn(600)  # a couple of seconds: the point is the route, not the skill
    model.save(tmp_path / "model.zip")
    doc = evaluate(capsys, suite, tmp_path / "model.zip", tmp_path / "r.json")
    sha = __import__("hashlib").sha256((tmp_path / "model.zip").read_bytes()).hexdigest()
    assert doc["decider"]["policy"] == {"kind": "sb3", "file": "model.zip", "sha256": sha}
    assert doc["decider"]["name"] == f"model-{sha[:8]}" and doc["decider"]["weights_sha256"] == sha
    assert len(doc["scenarios"]["outcome"]) == 6
    # The decider gives what the model predicts, one observation or a batch.
    dec = load_policy(str(tmp_path / "model.zip"), load_suite(suite).config)
    obs = np.random.default_rng(0).normal(size=(5, D)).astype(np.float32)
    np.testing.assert_array_equal(dec.act(obs), model.predict(obs, deterministic=True)[0])
    assert dec.act(obs[0]) == int(model.predict(obs[0], deterministic=True)[0])
    check_decider(dec)


# ----------------------------------------------------------------------------- TorchScript / ONNX
def test_torchscript_file_evaluates_and_draws_a_decision_map(tmp_path, suite, capsys):
    net = _mlp()
    torch.jit.save(torch.jit.script(net), tmp_path / "ts.pt")
    doc = evaluate(capsys, suite, tmp_path / "ts.pt", tmp_path / "r.json")
    assert doc["decider"]["policy"]["kind"] == "torchscript"
    dec = load_policy(str(tmp_path / "ts.pt"))
    obs = np.random.default_rng(1).normal(size=(7, D)).astype(np.float32)
    np.testing.assert_array_equal(dec.act(obs), _modes(net, obs))
    check_decider(dec)
    assert (
        main(
            [
                "decision-map",
                "--policy",
                str(tmp_path / "ts.pt"),
                "--suite",
                str(suite),
                "--resolution",
                "4",
                "--out",
                str(tmp_path / "map.png"),
            ]
        )
        == 0
    )
    assert (tmp_path / "map.png").read_bytes()[:4] == b"\x89PNG"


def test_onnx_file_evaluates(tmp_path, suite, capsys):
    pytest.importorskip("onnxruntime")
    pytest.importorskip("onnx")
    net = _mlp()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net,
            (torch.zeros(1, D),),
            str(tmp_path / "m.onnx"),
            input_names=["obs"],
            output_names=["q"],
            dynamic_axes={"obs": {0: "n"}, "q": {0: "n"}},
            dynamo=False,
        )
    doc = evaluate(capsys, suite, tmp_path / "m.onnx", tmp_path / "r.json")
    assert doc["decider"]["policy"]["kind"] == "onnx"
    dec = load_policy(str(tmp_path / "m.onnx"))
    obs = np.random.default_rng(2).normal(size=(7, D)).astype(np.float32)
    np.testing.assert_array_equal(dec.act(obs), _modes(net, obs))
    # The same network as TorchScript gives the same per-scenario results.
    torch.jit.save(torch.jit.script(net), tmp_path / "ts.pt")
    assert evaluate(capsys, suite, tmp_path / "ts.pt", tmp_path / "r2.json")["scenarios"] == doc["scenarios"]


def test_a_missing_extra_is_one_line_naming_it(tmp_path, suite, capsys, monkeypatch):
    (tmp_path / "m.onnx").write_bytes(b"not really")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)  # import fails as if not installed
    err = one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "m.onnx")])
    assert "overtakezoo[onnx]" in err
    monkeypatch.setitem(sys.modules, "torch", None)  # an SB3 zip's policy.pth needs torch (not SB3) to be read
    import zipfile

    with zipfile.ZipFile(tmp_path / "model.zip", "w") as z:
        z.writestr("data", json.dumps({"policy_class": {"__module__": "stable_baselines3.dqn.policies"}}))
        z.writestr("policy.pth", b"")
    assert "overtakezoo[sb3]" in one_line_error(
        capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "model.zip")]
    )


# ----------------------------------------------------------------------------- module:factory
FACTORY = """
import numpy as np
from overtakezoo.zoo import load

def rule(config):
    return load("rule-fsm", config)

class Batch:
    name = "lefty"
    def act(self, obs):
        return np.ones(len(obs), np.int64)

def plain(config):
    return Batch()

def broken(config):
    raise RuntimeError("no weights here")
"""


def test_module_factory(tmp_path, suite, capsys, monkeypatch):
    (tmp_path / "my_policies.py").write_text(FACTORY)
    monkeypatch.syspath_prepend(str(tmp_path))
    doc = evaluate(capsys, suite, "my_policies:rule", tmp_path / "r.json")
    assert doc["decider"]["name"] == "rule-fsm"
    assert doc["decider"]["policy"] == {"kind": "module", "spec": "my_policies:rule"}
    zoo_doc = evaluate(capsys, suite, "rule-fsm", tmp_path / "z.json")  # a registry name is a spec too
    assert "policy" not in zoo_doc["decider"] and zoo_doc["scenarios"] == doc["scenarios"]
    plain = load_policy("my_policies:plain")
    assert plain.name == "lefty" and plain.act(np.zeros(D, np.float32)) == 1
    check_decider(plain)
    assert "no weights here" in one_line_error(
        capsys, ["eval", "--suite", str(suite), "--policy", "my_policies:broken"]
    )
    assert "cannot import" in one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", "nope_mod:x"])
    assert "no callable" in one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", "my_policies:zzz"])


# ----------------------------------------------------------------------------- overtakezoo train output
@pytest.mark.parametrize("name", ["dqn", "ppo"])
def test_weights_in_the_train_format_evaluate_like_the_zoo_member(
    tmp_path, suite, capsys, learned_dir, monkeypatch, name
):
    from overtakezoo.zoo.members import learned
    from overtakezoo.zoo.members.learned import read_card

    for ext in (".npz", ".json"):  # `overtakezoo train` writes <algo>.npz beside the card <algo>.json
        shutil.copy(learned_dir / f"{name}{ext}", tmp_path / f"{name}{ext}")
    monkeypatch.setattr(learned, "PRETRAINED", learned_dir)  # the zoo member with the same weights
    doc = evaluate(capsys, suite, tmp_path / f"{name}.npz", tmp_path / "p.json")
    zoo_doc = evaluate(capsys, suite, name, tmp_path / "z.json")
    assert doc["scenarios"] == zoo_doc["scenarios"]  # same weights, same hold: same results
    assert doc["decider"]["weights_sha256"] == read_card(tmp_path / f"{name}.json", name)["weights_sha256"]
    assert doc["decider"]["policy"]["kind"] == f"overtakezoo-{name}" and doc["decider"]["name"] != name
    for spec in (tmp_path / f"{name}.json", tmp_path):  # the card, or the directory holding the pair
        assert evaluate(capsys, suite, spec, tmp_path / "c.json")["scenarios"] == doc["scenarios"]


def test_train_dqn_output_evaluates_with_one_command(tmp_path, suite, capsys):
    out = tmp_path / "runs" / "dqn"
    assert (
        main(
            [
                "train",
                "dqn",
                "--steps",
                "1000",
                "--seed",
                "0",
                "--out",
                str(out),
                "--eval-suite",
                "none",
                "--no-progress",
            ]
        )
        == 0
    )
    capsys.readouterr()
    doc = evaluate(capsys, suite, out / "dqn.pt", tmp_path / "r.json")  # torch weights, converted on load
    assert doc["decider"]["policy"]["kind"] == "overtakezoo-dqn"
    for spec in (out / "dqn.npz", out / "dqn.json", out):  # the export the trainer wrote: numpy only
        assert evaluate(capsys, suite, spec, tmp_path / "n.json")["scenarios"] == doc["scenarios"]


# ----------------------------------------------------------------------------- corrupted weights
def test_corrupted_policy_file_is_one_line(tmp_path, suite, capsys):
    net = _mlp()
    torch.jit.save(torch.jit.script(net), tmp_path / "ts.pt")
    data = (tmp_path / "ts.pt").read_bytes()
    (tmp_path / "bad.pt").write_bytes(data[: len(data) // 3])
    for argv in (["eval", "--suite", str(suite)], ["decision-map", "--suite", str(suite)]):
        one_line_error(capsys, argv + ["--policy", str(tmp_path / "bad.pt"), "--out", str(tmp_path / "o")])
    assert not (tmp_path / "o").exists()
    (tmp_path / "wide.onnx").write_bytes(b"\x08\x07garbage")
    one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "wide.onnx")])
    assert "no such file" in one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", "missing.pt"])
    # Weights with a model card whose sha256 no longer matches.
    pre = __import__("overtakezoo.zoo.members.learned", fromlist=["PRETRAINED"]).PRETRAINED
    shutil.copy(pre / "dqn.json", tmp_path / "dqn.json")
    (tmp_path / "dqn.npz").write_bytes((pre / "dqn.npz").read_bytes()[:-10])
    assert "sha256" in one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "dqn.npz")])
    (tmp_path / "dqn.pt").write_bytes(b"not the trained weights")
    assert "sha256" in one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "dqn.pt")])


def test_a_policy_for_other_observations_is_refused_at_load(tmp_path, suite, capsys):
    torch.manual_seed(0)
    torch.jit.save(torch.jit.script(torch.nn.Linear(D + 3, 3)), tmp_path / "wide.pt")
    err = one_line_error(capsys, ["eval", "--suite", str(suite), "--policy", str(tmp_path / "wide.pt")])
    assert f"(N, {D})" in err


@pytest.mark.parametrize("command", ["eval", "decision-map"])
def test_tampered_pretrained_weights_through_decider_are_one_line(tmp_path, suite, capsys, monkeypatch, command):
    from overtakezoo.zoo.members import learned

    for ext in (".npz", ".json"):
        shutil.copy(learned.PRETRAINED / f"dqn{ext}", tmp_path / f"dqn{ext}")
    data = (tmp_path / "dqn.npz").read_bytes()
    (tmp_path / "dqn.npz").write_bytes(data[: len(data) // 2])
    monkeypatch.setattr(learned, "PRETRAINED", tmp_path)
    err = one_line_error(capsys, [command, "--suite", str(suite), "--decider", "dqn", "--out", str(tmp_path / "o")])
    assert "truncated or modified" in err and not (tmp_path / "o").exists()


def test_load_policy_errors_are_user_errors():
    with pytest.raises(UserError, match="unknown decider"):
        load_policy("no-such-decider")
    assert load_policy("always-follow").act(np.zeros(D)) == 0
