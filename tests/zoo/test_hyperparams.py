"""Typed hyperparameters (zoo/train/typed.py): a misspelt key, a wrong type or an out-of-range value in a
hyperparameter file or a --set override is one `error:` line naming the file and the key, before
any training starts."""

from __future__ import annotations

import dataclasses

import pytest

from overtakezoo.benchmark.cli import main
from overtakezoo.zoo.train.contract import hyperparams_file, load_hyperparams, parse_overrides
from overtakezoo.zoo.train.dqn import DQNHyperparams
from overtakezoo.zoo.train.typed import HyperparameterError, as_dict, build, param

DQN_TOML = hyperparams_file("dqn").read_text()


def one_line_error(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


def train_dqn_with(tmp_path, capsys, old, new, extra=()):
    assert old in DQN_TOML
    path = tmp_path / "bad.toml"
    path.write_text(DQN_TOML.replace(old, new))
    out = tmp_path / "run"
    err = one_line_error(
        capsys, ["train", "dqn", "--hyperparams", str(path), "--out", str(out), "--no-progress", *extra]
    )
    assert not (out / "dqn.pt").exists() and not (out / "log.csv").exists()  # refused before training
    return err, str(path)


@pytest.mark.parametrize(
    "old, new, needle",
    [
        ("gamma = 0.99", "gama = 0.99", "gama: unknown key (did you mean 'gamma'?)"),
        ("stats_window = 1000", "stats_window = 1000\ntime_penality = 0.1", "time_penality: unknown key"),
        ("gamma = 0.99", "gamma = 1.5", "gamma: 1.5 is out of range [0.0, 1.0]"),
        ("batch_size = 256", "batch_size = 256.5", "batch_size: expected an integer, got 256.5"),
        ("hidden = [128, 128]", 'hidden = "big"', "hidden: expected an array, got 'big'"),
        ("hidden = [128, 128]", "hidden = [128, 0]", "hidden[1]: 0 is out of range"),
        ("dueling = true", "dueling = 1", "dueling: expected true or false, got 1"),
        ("lr = 5e-4\n", "", "lr: missing (required)"),
    ],
)
def test_bad_dqn_hyperparameters_are_one_line_naming_file_and_key(tmp_path, capsys, old, new, needle):
    err, path = train_dqn_with(tmp_path, capsys, old, new)
    assert needle in err and path in err, err


def test_a_reward_in_the_hyperparameters_is_refused_with_the_reason(tmp_path, capsys):
    err, _ = train_dqn_with(tmp_path, capsys, "stats_window = 1000", "stats_window = 1000\ntime_penalty = 0.1")
    assert "'time_penalty' is not a training setting" in err


def test_set_overrides_go_through_the_same_checks(tmp_path, capsys):
    out = str(tmp_path / "run")
    err = one_line_error(capsys, ["train", "dqn", "--set", "gama=0.9", "--out", out])
    assert "gama: unknown key (did you mean 'gamma'?)" in err
    err = one_line_error(capsys, ["train", "dqn", "--set", "eps_end=2", "--out", out])
    assert "eps_end: 2 is out of range" in err
    assert "expected KEY=VALUE" in one_line_error(capsys, ["train", "dqn", "--set", "gamma", "--out", out])
    assert parse_overrides(["hidden=[64, 64]", "train.steps=10", "schedule=fixed"]) == {
        "hidden": [64, 64],
        "train": {"steps": 10},
        "schedule": "fixed",
    }


@pytest.mark.parametrize(
    "section, old, new, needle",
    [
        (
            "train",
            "select_every = 20",
            "select_evry = 20",
            "train.select_evry: unknown key (did you mean 'select_every'?)",
        ),
        ("env", "num_envs = 256", "num_envs = 0", "env.num_envs: 0 is out of range"),
        ("runner", "save_interval = 50", "save_intervall = 50", "runner.save_intervall: unknown key"),
        ("algorithm", "lam = 0.95", "lamda = 0.95", "algorithm.lamda: unknown key (did you mean 'lam'?)"),
        (
            "actor",
            'activation = "elu"\nobs_normalization = false\n\n[actor.distribution_cfg]',
            'activaton = "elu"\nobs_normalization = false\n\n[actor.distribution_cfg]',
            "actor.activaton: unknown key",
        ),
    ],
)
def test_bad_ppo_hyperparameters_are_one_line_naming_section_and_key(tmp_path, capsys, section, old, new, needle):
    pytest.importorskip("rsl_rl")
    text = hyperparams_file("ppo").read_text()
    assert old in text, old
    path = tmp_path / "ppo.toml"
    path.write_text(text.replace(old, new, 1))
    out = tmp_path / "run"
    err = one_line_error(capsys, ["train", "ppo", "--hyperparams", str(path), "--out", str(out), "--no-progress"])
    assert needle in err and str(path) in err, err
    assert not (out / "ppo.pt").exists()


def test_shipped_hyperparameter_files_load_and_round_trip():
    for algo in ("dqn", "double-dqn", "ps-dqn", "ps-dqn-multi"):
        hp, name = load_hyperparams(DQNHyperparams, hyperparams_file(algo))
        assert name == f"{algo}.toml" and hp.double == (algo == "double-dqn") and hp.hidden == (128, 128)
        assert build(DQNHyperparams, as_dict(hp), "card") == hp
    # ps-dqn-multi is ps-dqn's recipe on other roads: the same hyperparameters, key for key.
    assert (
        load_hyperparams(DQNHyperparams, hyperparams_file("ps-dqn-multi"))[0]
        == (load_hyperparams(DQNHyperparams, hyperparams_file("ps-dqn"))[0])
    )


def test_schema_helper_for_other_trainers():
    @dataclasses.dataclass(frozen=True)
    class Tiny:
        epochs: int = param(lo=1)
        beta: float = param(0.5, 0.0, 1.0)
        kind: str = param("bc", choices=("bc", "cql"))

    assert build(Tiny, {"epochs": 3}, "here") == Tiny(epochs=3, beta=0.5, kind="bc")
    with pytest.raises(HyperparameterError, match=r"^offline.toml: kind: 'x' is not one of 'bc', 'cql'$"):
        build(Tiny, {"epochs": 3, "kind": "x"}, "offline.toml")
    with pytest.raises(HyperparameterError, match="epochs: missing"):
        build(Tiny, {}, "offline.toml")


def test_a_cards_reproduce_line_carries_the_overrides_it_was_trained_with():
    # A run trained with --set must not reproduce as if it had the file's values (the shipped ppo's
    # card says train.overtake_bias=0 since ppo.toml's default changed).
    import shlex

    from overtakezoo.zoo.train.contract import (
        hyperparams_file,
        load_hyperparams,
        model_card,
        parse_overrides,
        set_flags,
    )
    from overtakezoo.zoo.train.dqn import DQNHyperparams

    given = {"num_envs": 64, "hidden": [64, 64], "lr": 1e-5, "steps": 10, "action_repeat": 5}
    hp, name = load_hyperparams(DQNHyperparams, hyperparams_file("dqn"), given)
    flags = set_flags(hp, name)
    again, _ = load_hyperparams(
        DQNHyperparams, hyperparams_file("dqn"), {**parse_overrides(shlex.split(" ".join(flags))), "steps": 10}
    )
    assert again == hp and not any(f.startswith("steps=") for f in flags)
    plain, _ = load_hyperparams(DQNHyperparams, hyperparams_file("dqn"))
    assert set_flags(plain, name) == []
    card = model_card(
        "dqn",
        algorithm="x",
        architecture={"kind": "q-network"},
        hp=hp,
        hp_file=name,
        action_repeat=5,
        action_mask=True,
        source={},
        steps=10,
        steps_unit="decisions",
        seed=0,
        wall_time_s=0.0,
        training={},
        reproduce="overtakezoo train dqn --suite s --steps 10 --seed 0",
        torch=False,
    )
    assert card["reproduce"] == "overtakezoo train dqn --suite s --steps 10 --seed 0 " + " ".join(
        f"--set {f}" for f in flags
    )


def test_a_file_with_a_base_resolves_to_the_flat_file_it_replaces(tmp_path, monkeypatch):
    # double-dqn.toml and ps-dqn.toml are dqn.toml (`base = "dqn"`) and the keys they change: each
    # loads exactly as the flat file with those keys edited in (what they were before, as_dict and all).
    for algo, edits in (
        ("double-dqn", (("double = false", "double = true"), ("steps = 500000", "steps = 1000000"))),
        ("ps-dqn", (("double = false", "double = false\nmulti_av_share = 0.5"),)),
    ):
        text = DQN_TOML
        for old, new in edits:
            assert old in text
            text = text.replace(old, new)
        flat = tmp_path / f"{algo}-flat.toml"
        flat.write_text(text)
        hp, name = load_hyperparams(DQNHyperparams, hyperparams_file(algo))
        want, _ = load_hyperparams(DQNHyperparams, flat)
        assert name == f"{algo}.toml" and hp == want and as_dict(hp) == as_dict(want)
    # Tables merge key by key (as a suite's [sim] over its base's): only [train] steps changes here.
    from overtakezoo.zoo.train.fastppo import FastPPOHyperparams

    short = tmp_path / "short.toml"
    short.write_text('base = "ppo-numpy"\n[train]\nsteps = 4096\n')
    hp, _ = load_hyperparams(FastPPOHyperparams, short)
    base, _ = load_hyperparams(FastPPOHyperparams, hyperparams_file("ppo-numpy"))
    assert hp == dataclasses.replace(base, train=dataclasses.replace(base.train, steps=4096))
    # --set goes over the resolved file; the base must be a file of zoo/hyperparams; no loops.
    hp, _ = load_hyperparams(DQNHyperparams, hyperparams_file("double-dqn"), {"double": False, "steps": 500000})
    assert hp == load_hyperparams(DQNHyperparams, hyperparams_file("dqn"))[0]
    short.write_text('base = "nope"\n')
    with pytest.raises(HyperparameterError, match=r"short.toml: base: 'nope' is not a hyperparameter file"):
        load_hyperparams(DQNHyperparams, short)
    from overtakezoo.zoo.train import contract

    monkeypatch.setattr(contract, "HYPERPARAMS", tmp_path)
    (tmp_path / "a.toml").write_text('base = "b"\n')
    (tmp_path / "b.toml").write_text('base = "a"\n')
    with pytest.raises(HyperparameterError, match="base: b -> a -> b is a loop"):
        load_hyperparams(DQNHyperparams, tmp_path / "a.toml")
