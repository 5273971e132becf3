"""DQN / Double DQN: the target formulas, the numpy export, weight checks, the pretrained deciders, a
short training run."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch

from conftest import needs_shipped_weights
from overtakezoo import zoo
from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs import (
    ABORT,
    FOLLOW,
    OVERTAKE,
    EnvConfig,
    OvertakeCore,
    ScenarioDistribution,
    make_scenario,
    observation_size,
)
from overtakezoo.envs.hold import hold, hold_steps
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.members.features import FEATURES_VERSION, speed_relative
from overtakezoo.zoo.members.learned import MLPDecider, WeightsError, action_mask, load_pretrained
from overtakezoo.zoo.train.contract import hyperparams_file, load_hyperparams
from overtakezoo.zoo.train.dqn import DQNHyperparams, train
from overtakezoo.zoo.train.qlearning import QNetwork, td_targets


class _Table(torch.nn.Module):
    """A 'network' returning fixed Q rows, to check target formulas by hand."""

    def __init__(self, q: list[list[float]]) -> None:
        super().__init__()
        self.q = torch.tensor(q)

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.q[: obs.shape[0]]


def test_double_dqn_target_differs_from_dqn_as_the_formula_says():
    online = _Table([[1.0, 5.0, 0.0], [2.0, 1.0, 0.0]])
    target = _Table([[3.0, 0.5, 9.0], [4.0, 7.0, 0.0]])
    reward = torch.tensor([1.0, -1.0])
    done = torch.tensor([0.0, 0.0])
    next_obs = torch.zeros(2, 4)
    gamma = 0.9
    dqn = td_targets(online, target, reward, next_obs, done, gamma, double=False)
    ddqn = td_targets(online, target, reward, next_obs, done, gamma, double=True)
    # DQN: max of the target net. Double: the target net's value at the online net's argmax.
    assert torch.allclose(dqn, torch.tensor([1 + 0.9 * 9.0, -1 + 0.9 * 7.0]))
    assert torch.allclose(ddqn, torch.tensor([1 + 0.9 * 0.5, -1 + 0.9 * 4.0]))
    # A mask removes the masked mode from both the max and the online argmax.
    mask = torch.tensor([[True, True, False], [True, True, False]])
    assert torch.allclose(
        td_targets(online, target, reward, next_obs, done, gamma, False, mask),
        torch.tensor([1 + 0.9 * 3.0, -1 + 0.9 * 7.0]),
    )
    # Terminal rows do not bootstrap.
    assert torch.allclose(td_targets(online, target, reward, next_obs, torch.tensor([1.0, 1.0]), gamma, True), reward)


def test_action_mask_allows_abort_only_while_overtaking_and_follow_only_in_lane():
    cfg = EnvConfig()
    core = OvertakeCore(cfg)
    obs = core.reset(ScenarioDistribution().sample(3, 0))
    assert not action_mask(obs, cfg)[:, ABORT].any()  # every row starts in follow
    core.step(np.array([OVERTAKE, FOLLOW, ABORT]))
    obs = core.observe()
    np.testing.assert_array_equal(action_mask(obs, cfg)[:, ABORT], [True, False, True])
    assert action_mask(obs, cfg)[:, FOLLOW].all()  # still inside the ego lane
    out = obs.copy()
    out[:, 2] = 0.8  # out in the opposite lane: only finishing or aborting, no cut-in
    np.testing.assert_array_equal(action_mask(out, cfg)[:, FOLLOW], [False, True, False])
    # The speed-relative features keep the columns the mask reads: the same mask on either.
    np.testing.assert_array_equal(action_mask(speed_relative(out, cfg), cfg), action_mask(out, cfg))
    # An abort under way outside the lane is carried through: no overtake until back in lane.
    np.testing.assert_array_equal(action_mask(out, cfg)[:, OVERTAKE], [True, True, False])
    assert action_mask(out, cfg, version=2)[:, OVERTAKE].all()
    assert action_mask(obs, cfg)[:, OVERTAKE].all()


def _copy_member(source, tmp_path, name="dqn"):
    for ext in (".npz", ".json"):
        shutil.copy(source / f"{name}{ext}", tmp_path / f"{name}{ext}")
    return tmp_path


def test_the_numpy_export_computes_what_the_torch_network_computes():
    from overtakezoo.zoo.train.export import convert

    torch.manual_seed(0)
    net = QNetwork(observation_size(EnvConfig()), [32, 16], dueling=True)
    buf = __import__("io").BytesIO()
    torch.save(net.state_dict(), buf)
    card = {"name": "dqn", "architecture": {"dueling": True}, "weights_file": "dqn.pt"}
    out, npz, numpy_net = convert(card, buf.getvalue(), "dqn")
    x = np.random.default_rng(0).normal(size=(256, numpy_net.in_features))
    with torch.no_grad():
        ref = net.double()(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(numpy_net(x), ref, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(numpy_net(x).argmax(1), ref.argmax(1))
    assert convert(card, buf.getvalue(), "dqn")[1] == npz  # content-deterministic bytes
    assert out["weights_file"] == "dqn.npz" and out["trained_weights_file"] == "dqn.pt"
    assert out["weights_sha256"] == __import__("hashlib").sha256(npz).hexdigest()


@needs_shipped_weights
@pytest.mark.parametrize("name", ["dqn", "double-dqn"])
def test_pretrained_loads_and_acts(name):
    dec = zoo.load(name)
    assert dec.name == name and len(dec.weights_sha256) == 64
    assert name in zoo.names()
    assert "table1" in dec.card()
    core = OvertakeCore(EnvConfig())
    obs = core.reset(ScenarioDistribution().sample(64, 1))
    dec.reset()
    modes = dec.act(obs)
    assert modes.shape == (64,) and modes.dtype == np.int64 and set(modes.tolist()) <= {FOLLOW, OVERTAKE}


@needs_shipped_weights
@pytest.mark.parametrize("name", ["dqn", "double-dqn"])
def test_pretrained_overtakes_a_clear_road_and_waits_for_close_oncoming_traffic(name):
    from overtakezoo.envs import SUCCESS, Scenarios

    dec = zoo.load(name)
    clear = make_scenario(lead=(10.0, 1.5), oncoming=[])
    blocked = make_scenario(lead=(10.0, 1.5), oncoming=[(25.0, 3.0)])
    core = OvertakeCore(EnvConfig())
    obs = core.reset(Scenarios.concat([clear, blocked]))
    dec.reset()
    lateral = []  # the ego's offset while the oncoming car has not passed it yet

    def watch(modes, res):
        if core.npc_s[1, 1] > core.x[1]:
            lateral.append(core.y[1])

    while not core.done.all():  # each decision held as the runner holds it
        obs = hold(core, dec.act(obs), hold_steps(1, dec.action_repeat), on_step=watch).obs
    lateral_while_oncoming_ahead = max(lateral, default=0.0)
    np.testing.assert_array_equal(core.outcome, [SUCCESS, SUCCESS])
    assert lateral_while_oncoming_ahead < 0.5  # stayed in its lane until the oncoming car passed
    assert core.t[0] < core.t[1]  # waiting costs time


def test_load_refuses_truncated_and_modified_weights(tmp_path, learned_dir):
    d = _copy_member(learned_dir, tmp_path)
    data = (d / "dqn.npz").read_bytes()
    (d / "dqn.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(WeightsError, match="sha256"):
        load_pretrained("dqn", directory=d)
    assert issubclass(WeightsError, ValueError)
    (d / "dqn.npz").write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    with pytest.raises(WeightsError, match="truncated or modified"):
        load_pretrained("dqn", directory=d)
    (d / "dqn.npz").write_bytes(data)
    assert (
        load_pretrained("dqn", directory=d).weights_sha256 == json.loads((d / "dqn.json").read_text())["weights_sha256"]
    )
    (d / "dqn.json").unlink()
    with pytest.raises(WeightsError, match="not found"):
        load_pretrained("dqn", directory=d)


def test_decider_is_stateless_and_declares_its_hold_for_the_runner(learned_dir):
    cfg = EnvConfig()
    dec = MLPDecider(QNetwork(observation_size(cfg), [8]).to_numpy(), "dqn", cfg, {"action_repeat": 3})
    assert dec.action_repeat == 3 and zoo.load("dqn", directory=learned_dir).action_repeat == 10  # the card's
    core = OvertakeCore(cfg)
    obs = core.reset(ScenarioDistribution().sample(4, 2))
    first = dec.act(obs)
    np.testing.assert_array_equal(dec.act(obs), first)  # no countdown: same input, same modes
    assert [dec.act(o) for o in obs] == first.tolist()  # one observation (D,) -> int


def _rates(net_or_card, algo, suite):
    """(success rate, crash rate) on table1's first 200 scenarios."""
    from overtakezoo.benchmark.run.training import evaluate

    hp, _ = load_hyperparams(DQNHyperparams, hyperparams_file(algo))
    dec = MLPDecider(
        net_or_card.to_numpy(),
        algo,
        suite.config,
        {"action_repeat": hp.action_repeat, "action_mask": True, "features": FEATURES_VERSION},
    )
    summary = evaluate(dec, suite, limit=200)[0]
    return summary["success_rate"], summary["crash_rate"]


# One-step targets learn slower and less surely at this length (seed 2 passed nothing on two of three
# kernel settings), so that variant runs with the slow tests; 3-step returns are dqn.toml's.
@pytest.mark.parametrize("n_step", [pytest.param(1, marks=pytest.mark.slow), 3])
def test_short_training_beats_an_untrained_network(tmp_path, n_step):
    torch.manual_seed(0)
    hp, _ = load_hyperparams(DQNHyperparams, hyperparams_file("dqn"))
    untrained = QNetwork(observation_size(EnvConfig()), hp.hidden, hp.dueling)
    scen = load_suite("table1")
    s0, c0 = _rates(untrained, "dqn", scen)
    # ~25 s of CPU. The untrained net never passes (0 % success, 0 % crash). Short runs are chaotic:
    # the bits of the trained net depend on the CPU's float kernels, and at 60k steps one CPU's
    # 3-step run passed 90.5 % of table1's first 200 while the same seed on another passed none. At
    # 100k steps, measured on an AVX-512 Xeon over seeds 0-2 and torch kernels (ATEN_CPU_CAPABILITY
    # default / avx2 / avx512): 3-step returns 83.5-93 % success, 7-16.5 % crashes; one-step targets
    # 0-87 %, 0-12 % (seed 0: 34.5-47.5 %). So this checks that learning started -- safe passes
    # appear, crashes stay below rule-fsm's 29 % -- with room for any CPU, not how far it gets.
    trained = train(
        load_training("table1-train"),
        member="dqn",
        steps=100_000,
        seed=0,
        out=tmp_path,
        progress=False,
        overrides={
            "eps_fraction": 0.5,
            "learning_starts": 2000,
            "checkpoint_every": 50000,
            "log_every": 10000,
            "n_step": n_step,
        },
    )
    s1, c1 = _rates(trained.module, "dqn", scen)
    assert s1 >= 0.1 and c1 <= 0.25 and s1 - 2 * c1 > s0 - 2 * c0 + 0.1, ((s0, c0), (s1, c1))
    assert ("3-step returns" in trained.card["algorithm"]) == (n_step == 3)
    assert trained.card["hyperparameters"]["n_step"] == n_step
    log = (tmp_path / "log.csv").read_text().splitlines()
    assert log[0].startswith("steps,episodes,success_rate,crash_rate,loss,epsilon")
    assert (tmp_path / "checkpoint.pt").is_file() and (tmp_path / "dqn.json").is_file()


def test_resume_continues_from_a_checkpoint(tmp_path):
    ov = {"num_envs": 64, "learning_starts": 300, "checkpoint_every": 1500, "log_every": 500}
    suites = load_training("table1-train")
    first = train(suites, member="double-dqn", steps=1500, seed=1, out=tmp_path, progress=False, overrides=ov).card
    card = train(
        suites,
        member="double-dqn",
        steps=3000,
        seed=1,
        out=tmp_path,
        resume=tmp_path / "checkpoint.pt",
        progress=False,
        overrides=ov,
    ).card
    assert first["steps"] < 3000 <= card["steps"]
    done, before = card["training"], first["training"]
    assert done["gradient_updates"] > before["gradient_updates"] and done["episodes"] >= before["episodes"]
    rows = (tmp_path / "log.csv").read_text().splitlines()
    steps = [int(r.split(",")[0]) for r in rows[1:]]
    assert len(steps) >= 5 and steps == sorted(steps)  # one log, continued


@pytest.mark.slow
def test_training_from_scratch_reaches_the_paper_figure(tmp_path):
    from overtakezoo.benchmark.run import training

    card = training.train("dqn", suite="core-train", out=tmp_path, progress=False).card  # the shipped recipe
    assert card["results"]["table1"]["success_rate"] >= 0.922  # the paper's DQN figure
    assert card["wall_time_s"] < 900


def test_train_command_writes_log_weights_and_card(tmp_path, capsys):
    from overtakezoo.benchmark.cli import main

    out = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "dqn",
                "--steps",
                "3000",
                "--seed",
                "2",
                "--out",
                str(out),
                "--eval-suite",
                "none",
                "--no-progress",
            ]
        )
        == 0
    )
    card = json.loads((out / "dqn.json").read_text())
    assert card["steps"] >= 3000 and card["seed"] == 2 and card["train_suite"]["name"] == "table1-train"
    sha = __import__("hashlib").sha256
    assert card["trained_weights_sha256"] == sha((out / "dqn.pt").read_bytes()).hexdigest()
    assert card["weights_sha256"] == sha((out / "dqn.npz").read_bytes()).hexdigest()
    assert card["weights_file"] == "dqn.npz" and card["hyperparameters"]["file"] == "dqn.toml"
    assert "trained dqn" in capsys.readouterr().out
    assert main(["train", "dqn", "--resume", str(tmp_path / "missing.pt"), "--out", str(out)]) == 2
    assert "no checkpoint" in capsys.readouterr().err


def test_model_selection_ships_the_best_greedy_network_and_survives_resume(tmp_path):
    """With select_every the network that ships is the best scored one: its recorded score is what
    the shipped decider (numpy, masked, loaded from the run's files) scores on the same training
    scenarios, and no scored network, the last one included, scored higher."""
    from overtakezoo.zoo.members.learned import from_card
    from overtakezoo.zoo.train.selection import greedy_score, selection_sets

    suites = load_training("table1-train")
    ov = {
        "num_envs": 64,
        "learning_starts": 1000,
        "checkpoint_every": 6000,
        "log_every": 2000,
        "eps_fraction": 0.5,
        "select_every": 3000,
        "select_from": 3000,
        "select_scenarios": 64,
    }
    first = train(suites, member="dqn", steps=6000, seed=0, out=tmp_path, progress=False, overrides=ov)
    done = train(
        suites,
        member="dqn",
        steps=12000,
        seed=0,
        out=tmp_path,
        resume=tmp_path / "checkpoint.pt",
        progress=False,
        overrides=ov,
    )
    sel, sel_first = done.card["training"]["selection"], first.card["training"]["selection"]
    assert sel["scenarios"] == 64 and sel["every"] == 3000 and sel["score"] >= sel_first["score"]
    assert 3000 <= sel["transitions"] <= done.card["steps"]
    assert [t for t, _ in sel["scores"]][:2] == [t for t, _ in sel_first["scores"]] and len(sel["scores"]) == 4
    assert max(x for _, x in sel["scores"]) == sel["score"]
    sets = selection_sets(suites, [s.scenarios() for s in suites], 64)
    shipped = from_card("dqn", json.loads((tmp_path / "dqn.json").read_text()), tmp_path / "dqn.npz", suites[0].config)

    def act(obs, config):
        shipped.config = config
        return shipped.act_batch(obs)

    last = torch.load(tmp_path / "checkpoint.pt", weights_only=True)
    best = last["best"]["score"]  # the card rounds it to 4 decimals
    assert greedy_score(act, sets, shipped.action_repeat) == pytest.approx(best, abs=1e-9)
    assert best == pytest.approx(sel["score"], abs=5e-5) and last["counters"][0] == done.card["steps"]
    hp, _ = load_hyperparams(DQNHyperparams, hyperparams_file("dqn"))
    net = QNetwork(observation_size(suites[0].config), hp.hidden, hp.dueling)
    net.load_state_dict(last["net"])
    last_net = net.to_numpy()

    def act_last(obs, config):
        return np.where(action_mask(obs, config), last_net(speed_relative(obs, config)), -np.inf).argmax(axis=1)

    assert greedy_score(act_last, sets, shipped.action_repeat) <= best + 1e-12


def _nstep_reference(rewards, finished, done, n, gamma):
    """Per row, by hand: every decision t's k-step return, k = n or up to the episode's end."""
    out = []
    T, R = rewards.shape
    for r in range(R):
        for t in range(T):
            ret, k = 0.0, 0
            while k < n and t + k < T:
                ret += gamma**k * rewards[t + k, r]
                k += 1
                if finished[t + k - 1, r]:
                    break
            # Only transitions that the stream completed: n decisions, or the episode's end.
            if k == n or finished[t + k - 1, r]:
                out.append((r, t, ret, k, float(done[t + k - 1, r]), t + k - 1))
    return sorted(out)


@pytest.mark.parametrize("n", [1, 2, 3, 5])
def test_n_step_returns_match_a_by_hand_sum_over_episode_ends(n):
    from overtakezoo.zoo.train.qlearning import NStepReturns

    rng = np.random.default_rng(n)
    T, R, gamma = 40, 4, 0.9
    rewards = rng.normal(size=(T, R)).astype(np.float32)
    finished = rng.random((T, R)) < 0.15
    done = finished & (rng.random((T, R)) < 0.7)  # the rest: a time limit that bootstraps
    acc = NStepReturns(n, gamma, R, 2)
    got = []
    for t in range(T):
        # obs carries (row, decision) so each emitted transition says where it started; next_obs where it ended.
        obs = np.stack([np.arange(R), np.full(R, t)], 1).astype(np.float32)
        out = acc.push(obs, np.full(R, t % 3), rewards[t], obs, done[t], finished[t])
        for o, ret, k, d, nxt in zip(
            out["obs"], out["reward"], out["steps"], out["done"], out["next_obs"], strict=True
        ):
            got.append((int(o[0]), int(o[1]), float(ret), int(k), float(d), int(nxt[1])))
    want = _nstep_reference(rewards.astype(np.float64), finished, done, n, gamma)
    got = sorted(got)
    assert [g[:2] + g[3:] for g in got] == [w[:2] + w[3:] for w in want]  # which transitions, k, done, s'
    np.testing.assert_allclose([g[2] for g in got], [w[2] for w in want], rtol=1e-6)  # float32 returns


def test_n_step_returns_skip_rows_that_make_no_decision():
    """A waiting AV (done, its road still running) adds nothing and ages nothing."""
    from overtakezoo.zoo.train.qlearning import NStepReturns

    acc = NStepReturns(3, 0.5, 2, 1)
    obs, one = np.zeros((2, 1), np.float32), np.ones(2, np.float32)
    no = np.zeros(2, bool)
    acc.push(obs, np.zeros(2, int), one, obs, no, np.array([False, True]))  # row 1 ends: a 1-step transition
    out = acc.push(obs, np.zeros(2, int), one, obs, no, no, valid=np.array([True, False]))
    assert len(out["reward"]) == 0
    out = acc.push(obs, np.zeros(2, int), one, obs, no, no, valid=np.array([True, False]))
    assert out["steps"].tolist() == [3.0] and out["reward"].tolist() == [1.75]  # row 0 only: 1 + 0.5 + 0.25
