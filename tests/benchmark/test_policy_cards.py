"""Policy cards (the decision hold and the observation contract) travel with a policy file in every
format, through eval, decision-map, submit and verify; rsl-rl's own exports (TorchScript (N, 1),
ONNX with a fixed batch of 1 and external data) evaluate; every bad card is one `error:` line."""

from __future__ import annotations

import json
import os
import types
import warnings

import numpy as np
import pytest

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import Results
from overtakezoo.benchmark.run.artifacts import CARD_KEY, CardError, card_file, parse_card, write_card
from overtakezoo.benchmark.run.policy import load_policy
from overtakezoo.envs import EnvConfig, observation_layout, observation_size, suites

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings(
    "ignore:`torch.jit:DeprecationWarning", "ignore::DeprecationWarning", "ignore::UserWarning", "ignore::FutureWarning"
)

D = observation_size(EnvConfig())


@pytest.fixture(autouse=True)
def one_thread(one_torch_thread):
    yield


@pytest.fixture
def tiny(tiny_suite):
    """A built-in suite of 8 short scenarios (submit needs a built-in suite)."""
    return tiny_suite(8)


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


def evaluate(capsys, suite, spec, out):
    assert main(["eval", "--suite", suite, "--policy", str(spec), "--out", str(out), "--no-progress"]) == 0, (
        capsys.readouterr().err
    )
    capsys.readouterr()
    return Results.load(out)


def _mlp(seed=0):
    torch.manual_seed(seed)
    return torch.nn.Sequential(torch.nn.Linear(D, 16), torch.nn.Tanh(), torch.nn.Linear(16, 3)).eval()


def _sb3_zip(path):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from overtakezoo.envs import OvertakeEnv  # the env's defaults: only its spaces matter (tiny replaces the suites)

    PPO("MlpPolicy", OvertakeEnv(), seed=0, n_steps=64, device="cpu").save(path)
    return path.with_name(path.name + ".zip") if path.suffix != ".zip" else path


# ------------------------------------------------------------------ the card itself
@pytest.mark.parametrize(
    "raw, says",
    [
        ('{"action_repeat": 10, "frame_skip": 2}', "unknown key 'frame_skip'"),
        ('{"action_repeat": "10"}', "action_repeat: '10' is not of type 'integer'"),
        ('{"action_repeat": 10.0}', "action_repeat: 10.0 is not an integer"),
        ('{"action_repeat": 0}', "action_repeat: 0 is less than the minimum of 1"),
        ('{"action_repeat": 1001}', "action_repeat: 1001 is greater than the maximum of 1000"),
        ('{"action_repeat": true}', "action_repeat: True is not of type 'integer'"),
        ('{"action_repeat": NaN}', "NaN is not a JSON number"),
        ('{"action_repeat": 1, "action_repeat": 2}', "key 'action_repeat' given twice"),
        ('{"observation_size": 34}', "'action_repeat' is a required property"),
        ("[1]", "expected a JSON object"),
        ('{"action_repeat": ', "not JSON"),
        ("[" * 60000, "not JSON"),
        ('{"action_repeat": 1, "name": "' + "x" * 70000 + '"}', "at most 65536"),
        ('{"action_repeat": 1, "observation_layout": {"ego": [6, 0]}}', "observation_layout.ego"),
        ('{"action_repeat": 1, "name": "../../etc"}', "name: "),
    ],
    ids=lambda v: str(v)[:24] if isinstance(v, str) else None,
)
def test_bad_cards_are_one_line(raw, says):
    with pytest.raises(CardError) as exc:
        parse_card(raw, "c.json")
    assert says in str(exc.value) and "\n" not in str(exc.value) and str(exc.value).startswith("c.json: ")
    assert len(str(exc.value)) < 400


def test_a_bad_card_beside_a_policy_is_one_error_line(tmp_path, tiny, capsys):
    ts = tmp_path / "ts.pt"
    torch.jit.save(torch.jit.script(_mlp()), ts)
    for raw, says in (
        ('{"action_repeat": 10, "code": "import os"}', "unknown key 'code'"),
        ('{"action_repeat": 2000}', "greater than the maximum"),
        (
            json.dumps({"action_repeat": 10, "observation_size": D + 4, "suite": "urban"}),
            f"observation_size is {D + 4} (trained on urban), this suite's observations have {D}",
        ),
        (
            json.dumps({"action_repeat": 10, "observation_size": D, "observation_layout": {"ego": [0, 5]}}),
            "observation_layout.ego is [0, 5]",
        ),
    ):
        card_file(ts).write_text(raw)
        for command in (
            ["eval", "--suite", tiny, "--out", str(tmp_path / "r.json"), "--no-progress"],
            ["decision-map", "--suite", tiny, "--resolution", "3", "--out", str(tmp_path / "m.png")],
        ):
            assert says in one_line_error(capsys, command + ["--policy", str(ts)])
    assert one_line_error(capsys, ["card", str(ts), "--action-repeat", "0"]).endswith(
        "action_repeat: 0 is less than the minimum of 1"
    )
    assert "no such policy file" in one_line_error(capsys, ["card", str(tmp_path / "nope.zip"), "--action-repeat", "2"])


# ------------------------------------------------------------------ the hold travels: SB3, TorchScript, ONNX
def test_sb3_zip_card_gives_the_hold_through_eval_submit_and_verify(tmp_path, tiny, capsys):
    model = _sb3_zip(tmp_path / "model")
    assert load_policy(str(model)).action_repeat == 1  # no card: one core step per decision, as before
    # The helper (SB3's model.save("model") writes model.zip): the card goes beside, model.card.json.
    assert write_card(tmp_path / "model", action_repeat=10, suite=tiny) == tmp_path / "model.card.json"
    card = json.loads((tmp_path / "model.card.json").read_text())
    assert card == {
        "card_version": 1,
        "action_repeat": 10,
        "suite": "tiny",
        "observation_size": D,
        "observation_layout": {k: [s.start, s.stop] for k, s in observation_layout(EnvConfig()).items()},
    }
    dec = load_policy(str(model), suites.load_suite(tiny).config)
    assert dec.action_repeat == 10
    dec.inner.close()
    r10 = evaluate(capsys, tiny, model, tmp_path / "r10.json")
    assert (
        main(
            [
                "decision-map",
                "--policy",
                str(model),
                "--suite",
                tiny,
                "--resolution",
                "3",
                "--out",
                str(tmp_path / "map.png"),
            ]
        )
        == 0
    )
    # submit stores the hold in the converted npz's card; verify re-runs with it.
    root = tmp_path / "lb"
    assert (
        main(["submit", str(tmp_path / "r10.json"), "--name", "my-sb3", "--policy", str(model), "--root", str(root)])
        == 0
    )
    policy = Results.load(root / "submissions" / tiny / "my-sb3.json").meta["submission"]["policy"]
    stored = json.loads((root / "submissions" / "artifacts" / f"{policy['sha256']}.json").read_text())
    assert stored["action_repeat"] == 10 and stored["policy_card"] == card
    capsys.readouterr()
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    assert "verified submissions/tiny/my-sb3.json: 8 of 8 scenarios reproduce" in capsys.readouterr().out
    from overtakezoo.benchmark.leaderboard.rows import load_submissions
    from overtakezoo.benchmark.leaderboard.verify import row_policy

    row = load_submissions(root, tiny)[tiny][0]
    dec = row_policy(row, root, suites.load_suite(tiny).config)
    assert dec.action_repeat == 10
    dec.inner.close()
    # The card changed after the evaluation (another hold): the stored form no longer gives the numbers.
    write_card(model, action_repeat=1)
    r1 = evaluate(capsys, tiny, model, tmp_path / "r1.json")
    assert not all(np.array_equal(r1.per[k], r10.per[k], equal_nan=True) for k in r10.per)  # the hold matters
    write_card(model, action_repeat=10)
    assert "not produced by this policy" in one_line_error(
        capsys, ["submit", str(tmp_path / "r1.json"), "--name", "other", "--policy", str(model), "--root", str(root)]
    )


def test_torchscript_card_beside_goes_into_the_stored_onnx(tmp_path, tiny, capsys):
    pytest.importorskip("onnx")
    ts = tmp_path / "ts.pt"
    torch.jit.save(torch.jit.script(_mlp()), ts)
    assert main(["card", str(ts), "--action-repeat", "5", "--name", "my-ts", "--version", "3"]) == 0
    assert "ts.card.json" in capsys.readouterr().out
    res = evaluate(capsys, tiny, ts, tmp_path / "r.json")
    assert res.decider["name"].startswith("my-ts-") and res.decider["version"] == "3"
    dec = load_policy(str(ts))
    assert dec.action_repeat == 5
    dec.inner.close()
    root = tmp_path / "lb"
    assert main(["submit", str(tmp_path / "r.json"), "--name", "my-ts", "--policy", str(ts), "--root", str(root)]) == 0
    import onnx

    policy = Results.load(root / "submissions" / tiny / "my-ts.json").meta["submission"]["policy"]
    model = onnx.load(str(root / "submissions" / policy["artifact"]))
    props = {p.key: p.value for p in model.metadata_props}
    assert json.loads(props[CARD_KEY])["action_repeat"] == 5 and props["action_repeat"] == "5"
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0


def test_onnx_card_inside_with_external_data_from_another_cwd(tmp_path, tiny, capsys, monkeypatch):
    """torch 2.13's default exporter writes policy.onnx.data beside the model: `card` writes into the
    model without touching it, eval runs from any cwd, submit stores one self-contained file."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    net = _mlp(1)
    d = tmp_path / "export"
    d.mkdir()
    torch.onnx.export(
        net,
        (torch.zeros(2, D),),
        str(d / "policy.onnx"),
        input_names=["obs"],
        output_names=["q"],
        dynamic_shapes=({0: torch.export.Dim("n")},),
        external_data=True,
    )
    assert (d / "policy.onnx.data").is_file()
    assert main(["card", str(d / "policy.onnx"), "--action-repeat", "10", "--suite", tiny]) == 0
    assert not card_file(d / "policy.onnx").exists() and (d / "policy.onnx.data").is_file()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    rel = os.path.relpath(d / "policy.onnx")
    res = evaluate(capsys, tiny, rel, tmp_path / "r.json")
    dec = load_policy(rel)
    assert dec.action_repeat == 10
    obs = np.random.default_rng(3).normal(size=(9, D)).astype(np.float32)
    with torch.no_grad():
        np.testing.assert_array_equal(dec.act(obs), net(torch.from_numpy(obs)).argmax(1).numpy())
    dec.inner.close()
    root = tmp_path / "lb"
    assert main(["submit", str(tmp_path / "r.json"), "--name", "my-onnx", "--policy", rel, "--root", str(root)]) == 0
    policy = Results.load(root / "submissions" / tiny / "my-onnx.json").meta["submission"]["policy"]
    stored = root / "submissions" / policy["artifact"]
    assert sorted(p.name for p in stored.parent.iterdir()) == [stored.name]  # one self-contained file
    model = onnx.load(str(stored), load_external_data=False)
    from onnx.external_data_helper import uses_external_data

    assert not any(uses_external_data(t) for t in model.graph.initializer)
    assert json.loads({p.key: p.value for p in model.metadata_props}[CARD_KEY])["action_repeat"] == 10
    assert res.decider["policy"]["sha256"] == policy["sha256"]
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0
    # The data file outside the model's directory is never read: one line naming the fix.
    (d / "policy.onnx.data").unlink()
    capsys.readouterr()  # (submit's hold line on stderr)
    assert "save_as_external_data=False" in one_line_error(
        capsys, ["eval", "--suite", tiny, "--policy", rel, "--no-progress"]
    )


def test_onnx_card_beside_or_conflicting_is_one_line(tmp_path, tiny, capsys):
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    path = tmp_path / "m.onnx"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            _mlp(),
            (torch.zeros(1, D),),
            str(path),
            input_names=["obs"],
            output_names=["q"],
            dynamic_axes={"obs": {0: "n"}, "q": {0: "n"}},
            dynamo=False,
        )
    card_file(path).write_text('{"action_repeat": 10}')
    assert "travels inside it" in one_line_error(capsys, ["eval", "--suite", tiny, "--policy", str(path)])
    card_file(path).unlink()
    model = onnx.load(str(path))
    for key, value in (("action_repeat", "3"), (CARD_KEY, '{"action_repeat": 10}')):
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.save(model, str(path))
    assert "action_repeat '3' differs" in one_line_error(capsys, ["eval", "--suite", tiny, "--policy", str(path)])
    model = onnx.load(str(path))
    del model.metadata_props[:]
    entry = model.metadata_props.add()
    entry.key, entry.value = CARD_KEY, '{"action_repeat": 10, "exec": 1}'
    onnx.save(model, str(path))
    assert "unknown key 'exec'" in one_line_error(capsys, ["eval", "--suite", tiny, "--policy", str(path)])
    # The sandbox reads the card itself too (a stored ONNX file, or no onnx package here).
    from overtakezoo.benchmark.run.artifacts import Artifact
    from overtakezoo.benchmark.run.policy import boxed

    with pytest.raises(UserError, match="unknown key 'exec'"):
        boxed(Artifact("onnx", path.read_bytes()), EnvConfig(), "stored")


# ------------------------------------------------------------------ rsl-rl's own exporters
def _rsl_runner(distribution=True, seed=0):
    """A minimal OnPolicyRunner: its exporters only read ``alg.get_policy()`` (the actor)."""
    pytest.importorskip("rsl_rl")
    from rsl_rl.runners import OnPolicyRunner

    from overtakezoo.zoo.train.ppo import build_actor

    torch.manual_seed(seed)
    cfg = {"class_name": "MLPModel", "hidden_dims": [16], "activation": "elu"}
    if distribution:
        cfg["distribution_cfg"] = {
            "class_name": "overtakezoo.zoo.train.categorical:CategoricalDistribution",
            "num_categories": 3,
        }
    actor = build_actor(D, cfg).eval()
    runner = OnPolicyRunner.__new__(OnPolicyRunner)
    runner.alg = types.SimpleNamespace(get_policy=lambda: actor)
    return OnPolicyRunner, runner, actor


def test_rsl_rl_exports_evaluate(tmp_path, tiny, capsys):
    pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    cls, runner, actor = _rsl_runner()
    out = tmp_path / "exported"
    cls.export_policy_to_jit(runner, str(out))  # (N, 1) float column of the argmax
    cls.export_policy_to_onnx(runner, str(out))  # batch fixed to 1; torch 2.13: policy.onnx.data beside
    obs = np.random.default_rng(4).normal(size=(11, D)).astype(np.float32)
    with torch.no_grad():
        want = actor.mlp(torch.from_numpy(obs)).argmax(1).numpy()
    assert len(set(want.tolist())) > 1
    results = []
    for name in ("policy.pt", "policy.onnx"):
        dec = load_policy(str(out / name))
        np.testing.assert_array_equal(dec.act(obs), want)
        assert dec.act(obs[:1]).tolist() == want[:1].tolist()
        dec.inner.close()
        results.append(evaluate(capsys, tiny, out / name, tmp_path / f"{name}.json"))
    for key in results[0].per:
        np.testing.assert_array_equal(results[0].per[key], results[1].per[key])
    # The fixed-batch ONNX file is submitted as it is (self-contained) and verifies.
    root = tmp_path / "lb"
    assert (
        main(
            [
                "submit",
                str(tmp_path / "policy.onnx.json"),
                "--name",
                "rsl",
                "--policy",
                str(out / "policy.onnx"),
                "--root",
                str(root),
            ]
        )
        == 0
    )
    assert main(["leaderboard", "--root", str(root), "--verify"]) == 0


def test_rsl_rl_continuous_column_is_one_line(tmp_path, tiny, capsys):
    cls, runner, actor = _rsl_runner(distribution=False)
    cls.export_policy_to_jit(runner, str(tmp_path))
    err = one_line_error(capsys, ["eval", "--suite", tiny, "--policy", str(tmp_path / "policy.pt"), "--no-progress"])
    assert "expected 0, 1 or 2" in err
    # An exact integer column (a policy that always overtakes) is taken as modes.
    with torch.no_grad():
        actor.mlp[-1].weight.zero_()
        actor.mlp[-1].bias.fill_(1.0)
    cls.export_policy_to_jit(runner, str(tmp_path))
    dec = load_policy(str(tmp_path / "policy.pt"))
    assert dec.act(np.zeros((4, D), np.float32)).tolist() == [1, 1, 1, 1]
    dec.inner.close()


def test_sb3_ppo_and_a2c_zips_act_as_they_predict(tmp_path):
    """SB3 2.x stores PPO's and A2C's policy as common.policies.ActorCriticPolicy."""
    pytest.importorskip("stable_baselines3")
    import gymnasium
    from stable_baselines3 import A2C, PPO

    import overtakezoo.envs  # noqa: F401

    obs = np.random.default_rng(5).normal(size=(6, D)).astype(np.float32)
    for algo, kwargs in ((PPO, {"n_steps": 64}), (A2C, {})):
        model = algo("MlpPolicy", gymnasium.make("overtakezoo/Overtake-v1"), seed=1, device="cpu", **kwargs)
        model.save(tmp_path / algo.__name__)
        dec = load_policy(str(tmp_path / f"{algo.__name__}.zip"))
        assert dec.policy["kind"] == "sb3"
        np.testing.assert_array_equal(dec.act(obs), model.predict(obs, deterministic=True)[0])
        dec.inner.close()
