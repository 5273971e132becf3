"""Training with several automated vehicles per road (ps-dqn): every AV row shares the Q-network,
waiting AVs store no transition, the hold treats them as finished, the single-ego trainer is
unchanged, and the shipped ps-dqn drives multi-AV roads."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from conftest import needs_shipped_weights
from overtakezoo import zoo
from overtakezoo.benchmark.suite_groups import load_training
from overtakezoo.envs import OvertakeCore
from overtakezoo.envs.hold import hold
from overtakezoo.envs.mixture import MixedCore
from overtakezoo.envs.suites import load_suite
from overtakezoo.zoo.train.contract import hyperparams_file, load_hyperparams
from overtakezoo.zoo.train.dqn import DQNHyperparams, Trainer, row_split, train


def _digest(net) -> str:
    h = hashlib.sha256()
    for key, value in net.state_dict().items():
        h.update(key.encode())
        h.update(value.detach().contiguous().numpy().tobytes())
    return h.hexdigest()


def test_single_ego_training_takes_the_plain_path():
    # The multi-AV machinery (waiting-row filter, row split) must leave single-ego training as it was:
    # no row ever waits, every row's decision is stored in order, the rows split evenly. Checked as
    # properties, not as a pinned digest of trained weights: those bits depend on the CPU's float
    # kernels (an AVX-512 Xeon and an AMD EPYC train different bits from the same code and seed).
    hp, _ = load_hyperparams(
        DQNHyperparams, hyperparams_file("dqn"), {"num_envs": 64, "learning_starts": 300, "steps": 1500, "n_step": 1}
    )
    trainer = Trainer("dqn", hp, load_training("core-train"), seed=3)
    trainer._start_core()
    assert not trainer.multi_av and sum(r["rows"] for r in trainer.row_counts().values()) == 64
    assert row_split(64, [1] * 9, 0.5) == row_split(64, [1] * 9, None)  # the multi share is inert
    decisions = 0
    while trainer.transitions < hp.steps:
        before, obs = trainer.buffer.size, trainer.obs.copy()
        trainer._env_step()
        np.testing.assert_array_equal(trainer.buffer.obs[before : trainer.buffer.size], obs)  # all, in order
        decisions += len(obs)
    assert trainer.transitions == decisions == trainer.buffer.size


def test_single_ego_training_is_deterministic_and_keeps_its_card():
    # ~3 s of CPU. Same seed twice on this machine: the same weights, bit for bit.
    def run():
        return train(
            load_training("core-train"),
            member="dqn",
            suite_name="core-train",
            steps=1500,
            seed=3,
            progress=False,
            overrides={"num_envs": 64, "learning_starts": 300, "n_step": 1},
        )

    first, second = run(), run()
    assert _digest(first.module) == _digest(second.module)
    card = first.card
    assert (card["steps"], card["training"]["gradient_updates"]) == (1536, 200)  # the schedule, not the floats
    assert card["training"]["episodes"] == second.card["training"]["episodes"] > 0
    assert "train_rows" not in card["training"]
    assert card["algorithm"] == "DQN (Mnih et al. 2015) with a dueling head (Wang et al. 2016)"


@pytest.mark.parametrize("n_step", [1, 3])
def test_waiting_avs_never_enter_the_buffer(n_step):
    hp, _ = load_hyperparams(
        DQNHyperparams,
        hyperparams_file("ps-dqn"),
        {"num_envs": 24, "learning_starts": 10**9, "steps": 2500, "n_step": n_step},
    )
    trainer = Trainer("ps-dqn", hp, load_training("duel-train+platoon-train"), seed=0)
    trainer._start_core()
    assert trainer.row_counts() == {"duel-train": {"roads": 6, "rows": 12}, "platoon-train": {"roads": 4, "rows": 12}}
    waited, decided = 0, set()
    while trainer.transitions < hp.steps:
        before, obs = trainer.buffer.size, trainer.obs.copy()
        waiting = np.asarray(trainer.core.done).copy()  # done AVs whose road still runs
        trainer._env_step()
        stored = slice(before, trainer.buffer.size)
        if n_step == 1:  # exactly the rows that were not waiting, in order, and nothing else
            np.testing.assert_array_equal(trainer.buffer.obs[stored], obs[~waiting])
        decided.update(o.tobytes() for o in obs[~waiting])
        waited += int(waiting.sum())
    assert waited > 50  # AVs of a road finish at different times: the filter was exercised
    # n-step: every stored transition starts at a decision of a running AV; the rest are pending.
    assert all(o.tobytes() in decided for o in trainer.buffer.obs[: trainer.buffer.size])
    pending = 0 if trainer.nstep is None else int((trainer.nstep.age > 0).sum())
    assert trainer.transitions == trainer.buffer.size + pending  # one transition per decision, no more


def test_the_hold_gives_a_waiting_av_no_reward_and_no_steps():
    suite = load_suite("platoon")
    core = OvertakeCore(
        suite.config, auto_reset=True, seed=0, source=lambda n, rng: suite.scenarios().take(rng.integers(0, 50, n))
    )
    core.reset(suite.scenarios().take(slice(0, 8)))
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(60):
        res = hold(core, rng.integers(0, 2, core.num), 10)
        assert not (res.waiting & res.finished).any()  # a waiting AV cannot finish again
        assert (res.reward[res.waiting] == 0).all() and (res.live_steps[res.waiting] == 0).all()
        seen += int(res.waiting.sum())
    assert seen > 0


def test_a_mixture_holds_multi_av_suites_as_roads_of_several_rows():
    assert row_split(128, [1] * 9 + [2, 3, 2], 0.5) == [8, 7, 7, 7, 7, 7, 7, 7, 7, 22, 21, 21]
    assert row_split(128, [1] * 9, 0.5) == row_split(128, [1] * 9, None)  # no multi-AV suite: even split
    suites = load_training("table1-train+duel-train")
    pools = [s.scenarios() for s in suites]
    mix = MixedCore(
        [s.config for s in suites], [lambda n, rng, p=p: p.take(rng.integers(0, 100, n)) for p in pools], [3, 2], seed=0
    )
    assert mix.num == 3 + 2 * 2 and mix.observe().shape[0] == mix.num
    assert mix.step(np.zeros(mix.num, np.int64)).obs.shape[0] == mix.num


@needs_shipped_weights
@pytest.mark.parametrize("suite_name", ["duel", "platoon"])
def test_shipped_ps_dqn_loads_by_name_and_drives_every_av(suite_name):
    suite = load_suite(suite_name)
    dec = zoo.load("ps-dqn", suite.config)
    assert dec.name == "ps-dqn" and "core-train+multi-train" in str(dec.card())
    core = OvertakeCore(suite.config)
    obs = core.reset(suite.scenarios().take(slice(0, 20)))
    modes = dec.act(obs)
    assert modes.shape == (core.num,) and set(modes.tolist()) <= {0, 1, 2}
