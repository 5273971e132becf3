"""PPO through rsl-rl: the VecEnv face, the categorical distribution, a tiny runner, the pretrained decider."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("rsl_rl")

from tensordict import TensorDict  # noqa: E402

from conftest import needs_shipped_weights, suite_file  # noqa: E402
from overtakezoo.benchmark.suite_groups import load_training  # noqa: E402
from overtakezoo.envs import EnvConfig, ScenarioDistribution, observation_size  # noqa: E402
from overtakezoo.envs.faces.rsl_rl import OvertakeRslRlEnv  # noqa: E402
from overtakezoo.zoo import load  # noqa: E402
from overtakezoo.zoo.members.learned import PRETRAINED, MLPDecider, WeightsError, load_pretrained, sha256_bytes  # noqa: E402
from overtakezoo.zoo.train import ppo  # noqa: E402
from overtakezoo.zoo.train.categorical import CategoricalDistribution  # noqa: E402
from overtakezoo.zoo.train.contract import check_card, hyperparams_file, load_hyperparams  # noqa: E402


@pytest.fixture(scope="module")
def pool():
    return ScenarioDistribution().sample(64, seed=3)


def test_vecenv_shapes_and_types(pool):
    from rsl_rl.env import VecEnv

    env = OvertakeRslRlEnv(8, EnvConfig(), pool, seed=0)
    assert isinstance(env, VecEnv) and env.num_envs == 8 and env.num_actions == 1
    assert env.cfg is not None and env.max_episode_length == 600
    d = observation_size(env.cfg)
    obs = env.get_observations()
    assert isinstance(obs, TensorDict) and obs["policy"].shape == (8, d) and obs["policy"].dtype == torch.float32
    finished = 0
    for _ in range(400):  # overtake into the oncoming traffic: episodes end (crash or success) and refill
        obs, rew, dones, extras = env.step(torch.ones(8, 1))
        assert obs["policy"].shape == (8, d) and rew.shape == (8,) and dones.shape == (8,)
        assert extras["time_outs"].shape == (8,)
        if "log" in extras:
            finished += 1
            assert set(extras["log"]) >= {"Episode/success", "Episode/crash", "Episode/crash_opposite_lane"}
            assert torch.all(extras["time_outs"] <= dones.float())
    assert finished > 0 and env.episode_counts["episodes"] >= 8
    c = env.episode_counts
    assert c["success"] + c["crash"] + c["timeout"] + c["offroad"] == c["episodes"]
    assert c["crash_ego_lane"] + c["crash_opposite_lane"] == c["crash"]
    assert torch.all(env.episode_length_buf < 400)


def test_vecenv_action_repeat_holds_decisions(pool):
    env = OvertakeRslRlEnv(8, EnvConfig(), pool, seed=0, action_repeat=10, bootstrap_timeouts=False)
    assert env.max_episode_length == 60
    for _ in range(40):  # 40 decisions = 400 core steps
        obs, rew, dones, extras = env.step(torch.ones(8, 1))
        assert torch.all(extras["time_outs"] == 0)
    assert env.episode_counts["episodes"] >= 8
    with pytest.raises(ValueError):
        OvertakeRslRlEnv(2, EnvConfig(), pool, action_repeat=0)


def test_categorical_matches_torch():
    torch.manual_seed(0)
    dist = CategoricalDistribution(1, num_categories=3)
    logits = torch.randn(16, 3)
    dist.update(logits)
    ref = torch.distributions.Categorical(logits=logits)
    a = dist.sample()
    assert a.shape == (16, 1) and a.dtype == torch.float32 and set(a.unique().tolist()) <= {0.0, 1.0, 2.0}
    assert torch.allclose(dist.log_prob(a), ref.log_prob(a[:, 0].long()))
    assert torch.allclose(dist.entropy, ref.entropy())
    assert torch.equal(dist.deterministic_output(logits)[:, 0], logits.argmax(-1).float())
    assert torch.equal(dist.as_deterministic_output_module()(logits), dist.deterministic_output(logits))
    assert dist.input_dim == 3 and dist.mean.shape == (16, 1) and dist.std.shape == (16, 1)
    other = torch.randn(16, 3)
    kl = dist.kl_divergence(dist.params, (other,))
    assert torch.allclose(
        kl, torch.distributions.kl_divergence(ref, torch.distributions.Categorical(logits=other)), atol=1e-6
    )
    with pytest.raises(ValueError):
        CategoricalDistribution(2)


def test_tiny_runner_learns_exports_and_acts(pool, tmp_path):
    torch.manual_seed(0)
    hp, _ = load_hyperparams(ppo.PPOHyperparams, hyperparams_file("ppo"), {"runner": {"num_steps_per_env": 8}})
    env = OvertakeRslRlEnv(16, EnvConfig(), pool, seed=0)
    runner = ppo.make_runner(env, hp)
    assert type(runner.alg.get_policy().distribution) is CategoricalDistribution
    before = [p.detach().clone() for p in runner.alg.get_policy().parameters()]
    runner.learn(2)
    after = list(runner.alg.get_policy().parameters())
    assert any(not torch.equal(b, a) for b, a in zip(before, after, strict=True))
    policy = runner.get_inference_policy("cpu")
    actions = policy(env.get_observations())
    assert actions.shape == (16, 1) and set(actions.unique().tolist()) <= {0.0, 1.0, 2.0}
    runner.export_policy_to_jit(str(tmp_path))
    jit = torch.jit.load(str(tmp_path / "policy.pt"))
    assert torch.equal(jit(env.get_observations()["policy"]), actions)
    # The numpy decider exported from the saved blob acts like the runner's policy.
    from overtakezoo.zoo.train.export import convert

    blob = ppo.weights_blob(policy, env.core.obs_size, hp.actor)
    card, _, net = convert({"name": "ppo", "weights_sha256": sha256_bytes(blob)}, blob, "ppo")
    assert card["architecture"]["activation"] == "elu" and card["trained_weights_sha256"] == sha256_bytes(blob)
    dec = MLPDecider(net, "ppo", EnvConfig(), card)
    obs = env.get_observations()["policy"].numpy()
    assert np.array_equal(dec.act(obs), actions[:, 0].long().numpy())


@needs_shipped_weights
def test_pretrained_ppo_loads_and_acts(pool):
    dec = load("ppo")
    assert dec.name == "ppo" and len(dec.weights_sha256) == 64
    assert "table1" in dec.card()
    from overtakezoo.envs import OvertakeCore

    core = OvertakeCore(EnvConfig())
    modes = dec.act(core.reset(pool))
    assert modes.shape == (64,) and modes.dtype == np.int64 and set(modes.tolist()) <= {0, 1, 2}


def test_truncated_weights_are_refused(tmp_path):
    for name in ("ppo.npz", "ppo.json"):
        shutil.copy(PRETRAINED / name, tmp_path / name)
    data = (tmp_path / "ppo.npz").read_bytes()
    (tmp_path / "ppo.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match="truncated or modified"):
        load_pretrained("ppo", directory=tmp_path)
    assert issubclass(WeightsError, ValueError)
    # A card whose hash matches a file that is not PPO weights: refused in one line too.
    (tmp_path / "ppo.npz").write_bytes(b"not an npz file")
    card = json.loads((tmp_path / "ppo.json").read_text())
    card["weights_sha256"] = sha256_bytes(b"not an npz file")
    (tmp_path / "ppo.json").write_text(json.dumps(card))
    with pytest.raises(WeightsError, match="cannot load"):
        load_pretrained("ppo", directory=tmp_path)


def _tiny_ppo_toml(tmp_path):
    """The real hyperparameter file, shrunk: 16 scenarios x 8 decisions per iteration."""
    text = hyperparams_file("ppo").read_text()
    for old, new in (
        ("num_envs = 256", "num_envs = 16"),
        ("num_steps_per_env = 32", "num_steps_per_env = 8"),
        ("select_every = 20", "select_every = 1"),
        ("select_scenarios = 500", "select_scenarios = 16"),
        ("checkpoint_every = 50", "checkpoint_every = 1"),
    ):
        assert old in text
        text = text.replace(old, new)
    hp = tmp_path / "ppo.toml"
    hp.write_text(text)
    return hp


def test_train_writes_card_and_resumes(tmp_path):
    hp = _tiny_ppo_toml(tmp_path)
    out = tmp_path / "run"
    suites = load_training("table1-train")
    trained = ppo.train(suites, steps=2 * 16 * 8, seed=1, out=out, hyperparams=hp, progress=False)
    assert (out / "ppo.pt").read_bytes() == trained.weights and (out / "checkpoints" / "ppo_00002.pt").exists()
    ppo.train(
        suites,
        steps=3 * 16 * 8,
        seed=1,
        out=out,
        hyperparams=hp,
        progress=False,
        resume=out / "checkpoints" / "ppo_00002.pt",
    )
    rows = (out / "train_log.csv").read_text().splitlines()
    assert rows[0].startswith("iteration,") and [r.split(",")[0] for r in rows[1:]] == ["1", "2", "3"]
    card = json.loads((out / "ppo.json").read_text())
    check_card(card)
    assert card["training"]["iterations"] == 3 and card["steps"] == 3 * 16 * 8 and card["action_repeat"] == 10
    assert card["train_suite"]["name"] == "table1-train" and card["training"]["selection"]["iteration"] in (1, 2, 3)
    assert card["trained_weights_sha256"] == sha256_bytes((out / "ppo.pt").read_bytes())
    assert card["hyperparameters"]["train"]["select_every"] == 1 and card["hyperparameters"]["file"] == "ppo.toml"
    assert card["versions"]["rsl-rl-lib"].startswith("5.5") and card["action_mask"] is False
    dec = load_pretrained("ppo", directory=out)  # the .npz the trainer exported, numpy only
    assert dec.weights_sha256 == card["weights_sha256"] == sha256_bytes((out / "ppo.npz").read_bytes())


def test_train_command_writes_a_results_file_for_ppo_as_for_every_trainer(tmp_path, capsys):
    from overtakezoo.benchmark.cli import main
    from overtakezoo.benchmark.results.results import Results

    suite = suite_file(tmp_path / "tiny.toml", 6, time_limit=20.0)  # table1's first scenarios, shortened
    out = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "ppo",
                "--hyperparams",
                str(_tiny_ppo_toml(tmp_path)),
                "--steps",
                str(16 * 8),
                "--out",
                str(out),
                "--eval-suite",
                str(suite),
                "--no-progress",
            ]
        )
        == 0
    )
    assert "trained ppo" in capsys.readouterr().out
    card = json.loads((out / "ppo.json").read_text())
    results = Results.load(out / "ppo-tiny.results.json")  # the runner's file, ready for `overtakezoo submit`
    assert results.decider["name"] == "ppo" and results.decider["weights_sha256"] == card["weights_sha256"]
    assert card["results"]["tiny"]["count"] == 6 == len(results.per["outcome"])
    assert card["results"]["tiny"]["suite_sha256"] == results.suite["hash"]
