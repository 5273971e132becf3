"""The registry (zoo/base.py) is the one list of members: each has a kind, and what the kind says
is what loading gives; the trainers, the train command and the leaderboard ask it."""

from __future__ import annotations

import importlib

import pytest

from overtakezoo import zoo
from overtakezoo.zoo.members.learned import MLPDecider
from overtakezoo.zoo.members.shield import Shielded
from overtakezoo.zoo.train.contract import hyperparams_file


@pytest.mark.parametrize("name", zoo.known_names())
def test_each_member_is_what_its_kind_says(name):
    m = zoo.member(name)
    assert m.name == name and m.kind in zoo.KINDS
    d = zoo.load(name)
    assert d.name == name and bool(d.privileged) == (
        m.kind == "privileged" or (m.kind == "wrapper" and zoo.member(m.wraps).kind == "privileged")
    )
    assert isinstance(d, MLPDecider) == (m.kind == "learned")
    assert isinstance(d, Shielded) == (m.kind == "wrapper")
    if m.kind == "wrapper":
        assert name == f"{m.wraps}+shield" and zoo.member(m.wraps).shieldable
    if m.kind == "learned":
        assert m.trainer and m.shieldable and d.weights_sha256


@pytest.mark.parametrize("name", zoo.names("learned"))
def test_each_learned_member_has_its_trainer_and_hyperparameters(name):
    pytest.importorskip("torch")
    if name == "ppo":
        pytest.importorskip("rsl_rl")
    module = importlib.import_module(f"overtakezoo.zoo.train.{zoo.member(name).trainer}")
    assert module.LEARNS_FROM in ("suites", "dataset") and callable(module.train)
    assert hyperparams_file(name).is_file()


def test_the_lists_elsewhere_ask_the_registry():
    from overtakezoo.benchmark.leaderboard import generate as leaderboard

    assert leaderboard.LEARNED == set(zoo.names("learned")) and "ps-dqn" in leaderboard.LEARNED
    assert zoo.names("wrapper") == sorted(f"{n}+shield" for n in zoo.names() if zoo.member(n).shieldable)
    assert set(zoo.names()) == set(zoo.names("rule")) | set(zoo.names("learned")) | set(zoo.names("privileged"))
    with pytest.raises(zoo.UnknownDecider, match="unknown decider 'nope'"):
        zoo.member("nope")


def test_a_registered_decider_gets_a_kind():
    zoo.register("test-constant", lambda config=None: zoo.ConstantDecider(0, "test-constant", config))
    try:
        assert zoo.member("test-constant").kind == "rule" and "test-constant" in zoo.names("rule")
        assert zoo.load("test-constant").name == "test-constant"
        with pytest.raises(ValueError, match="kind 'magic'"):
            zoo.register("test-magic", lambda config=None: None, kind="magic")
    finally:
        from overtakezoo.zoo import base

        base._MEMBERS.pop("test-constant"), base._REGISTRY.pop("test-constant")
