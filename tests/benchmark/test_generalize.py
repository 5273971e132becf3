"""Training over the core suites: train splits, the mixture core, speed-relative features."""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np
import pytest

from overtakezoo.benchmark.suite_groups import CORE, load_training, mixtures
from overtakezoo.envs import FOLLOW, OVERTAKE, EnvConfig, OvertakeCore, make_scenario, observation_layout
from overtakezoo.envs.hold import hold
from overtakezoo.envs.mixture import MixedCore, split_rows
from overtakezoo.envs.suites import SuiteError, load_suite
from overtakezoo.zoo.members.features import speed_relative


# ------------------------------------------------------------------ splits
@pytest.mark.parametrize("name", CORE)
def test_every_core_suite_has_a_disjoint_training_split(name):
    test, train = load_suite(name), load_suite(f"{name}-train")
    assert train.distribution == test.distribution and train.config == test.config
    assert train.seed != test.seed and train.hash != test.hash
    # No training scenario is a test scenario (the ego-lead gap is continuous: a repeat would show).
    a = test.scenarios().take(np.arange(200))
    b = train.scenarios().take(np.arange(200))
    assert not np.intersect1d(a.npc_s[:, 0], b.npc_s[:, 0]).size


def test_a_split_takes_its_tables_from_its_base_and_its_hash_covers_the_base(tmp_path, monkeypatch):
    from overtakezoo.envs import suites

    folder = tmp_path / "suites"
    folder.mkdir()
    base = (suites.SUITES_DIR / "oncoming-2.toml").read_bytes()
    (folder / "oncoming-2.toml").write_bytes(base)
    split = folder / "oncoming-2-train.toml"
    split.write_bytes((suites.SUITES_DIR / "oncoming-2-train.toml").read_bytes())
    monkeypatch.setattr(suites, "SUITES_DIR", folder)
    before = load_suite(split).hash
    (folder / "oncoming-2.toml").write_bytes(base.replace(b"count = 1000", b"count = 999"))
    assert load_suite(split).hash != before  # an edit of the base re-identifies the split
    split.write_text('name = "x-train"\nversion = 1\nbase = "nope"\ncount = 10\nseed = 1\n')
    with pytest.raises(SuiteError, match="base: 'nope' is not a built-in suite"):
        load_suite(split)


def test_a_variant_is_its_base_with_its_own_tables_merged_over_and_hashes_every_file(tmp_path, monkeypatch):
    # docs/suites.md: a new suite names a base and gives only what differs ([scenario] / [sim] keys,
    # merged key by key, nested tables too); its hash is sha256(own bytes + b"\0" + base bytes [+ b"\0"
    # + the base's base ...]), and a split of the variant is a split as any other.
    from overtakezoo.envs import suites

    folder = tmp_path / "suites"
    folder.mkdir()
    base_bytes = (suites.SUITES_DIR / "table1-reactive.toml").read_bytes()
    (folder / "table1-reactive.toml").write_bytes(base_bytes)
    monkeypatch.setattr(suites, "SUITES_DIR", folder)
    variant = folder / "late.toml"
    variant.write_bytes(
        b'name = "late"\nversion = 1\nbase = "table1-reactive"\ncount = 10\nseed = 7\n'
        b"[scenario]\nsensor_range = 30.0\noncoming_reveal = [12.0, 30.0]\n"
        b"[sim.planner]\nmax_steer = 0.5\n[sim.planner.modes.overtake]\nvelocity = 30.0\n"
    )
    base, late = load_suite(folder / "table1-reactive.toml"), load_suite(variant)
    expected_scenario = {**base.config.scenario, "sensor_range": 30.0, "oncoming_reveal": [12.0, 30.0]}
    assert late.config.scenario == expected_scenario
    assert late.distribution == dataclasses.replace(base.distribution, sensor_range=30.0, oncoming_reveal=(12.0, 30.0))
    overtake = dataclasses.replace(base.config.planner.modes["overtake"], velocity=30.0)
    planner = dataclasses.replace(
        base.config.planner, max_steer=0.5, modes={**base.config.planner.modes, "overtake": overtake}
    )
    assert late.config == dataclasses.replace(base.config, planner=planner, scenario=expected_scenario)
    assert (late.count, late.seed, late.name) == (10, 7, "late")  # its own keys, not the base's
    assert late.hash == hashlib.sha256(variant.read_bytes() + b"\0" + base_bytes).hexdigest()
    # The variant's own split: two bases deep, every file in its hash.
    split = folder / "late-train.toml"
    split.write_bytes(b'name = "late-train"\nversion = 1\nbase = "late"\ncount = 5\nseed = 8\n')
    train = load_suite(split)
    assert train.config == late.config and train.distribution == late.distribution
    chain = split.read_bytes() + b"\0" + variant.read_bytes() + b"\0" + base_bytes
    assert train.hash == hashlib.sha256(chain).hexdigest()
    (folder / "table1-reactive.toml").write_bytes(base_bytes.replace(b"count = 3000", b"count = 2999"))
    assert load_suite(split).hash != train.hash  # an edit of any file in the chain re-identifies it
    # A loop of bases is one error.
    (folder / "table1-reactive.toml").write_bytes(b'base = "late"\n' + base_bytes)
    with pytest.raises(SuiteError, match="base: late -> table1-reactive -> late is a loop"):
        load_suite(split)


def test_the_core_mixture_is_every_core_suites_split():
    assert [s.name for s in load_training("core-train")] == [f"{n}-train" for n in CORE]
    assert mixtures()["core-train"] == tuple(f"{n}-train" for n in CORE)
    assert [s.name for s in load_training("table1-train+urban-50-train")] == ["table1-train", "urban-50-train"]
    with pytest.raises(SuiteError, match="unknown suite"):
        load_training("table1-train+nope")


# ------------------------------------------------------------------ mixture core
def test_split_rows_is_even_and_refuses_empty_parts():
    assert split_rows(10, 3) == [4, 3, 3] and sum(split_rows(128, 9)) == 128
    with pytest.raises(ValueError):
        split_rows(2, 3)


def test_a_mixture_steps_each_suite_as_its_own_core_would():
    suites = [load_suite("table1-train"), load_suite("urban-50-train")]
    pools = [s.scenarios() for s in suites]
    sources = [lambda n, rng, p=p: p.take(rng.integers(0, p.num, n)) for p in pools]
    mix = MixedCore([s.config for s in suites], sources, [3, 2], seed=7)
    # The same scenarios on cores of their own (no episode ends within the 1 s held below).
    alone = []
    for core, src in zip(mix.cores, sources, strict=True):
        twin = OvertakeCore(core.cfg, auto_reset=True, source=src, seed=0)
        twin.reset(core.scen)
        alone.append(twin)
    assert mix.num == 5 and mix.observe().shape == (5, alone[0].obs_size)
    modes = np.array([OVERTAKE, FOLLOW, OVERTAKE, OVERTAKE, FOLLOW])
    held = hold(mix, modes, 10)
    ref = [hold(core, modes[s], 10) for core, s in zip(alone, (slice(0, 3), slice(3, 5)), strict=True)]
    np.testing.assert_array_equal(held.obs, np.concatenate([r.obs for r in ref]))
    np.testing.assert_array_equal(held.reward, np.concatenate([r.reward for r in ref]))
    # The urban rows keep their own speed limit: each core kept its suite's scenarios.
    limit = observation_layout(EnvConfig())["ego"].start + 4
    assert held.obs[3:, limit].min() > 2 * held.obs[:3, limit].max()


def test_a_mixture_refills_finished_rows_from_their_own_suite():
    suites = [load_suite("table1-train"), load_suite("urban-50-train")]
    pools = [s.scenarios() for s in suites]
    sources = [lambda n, rng, p=p: p.take(rng.integers(0, p.num, n)) for p in pools]
    mix = MixedCore([s.config for s in suites], sources, [4, 4], seed=1)
    limit = observation_layout(EnvConfig())["ego"].start + 4
    finished = np.zeros(8, bool)
    for _ in range(80):  # always overtaking: episodes end (crash or success) and rows refill
        res = hold(mix, np.full(8, OVERTAKE), 10)
        finished |= res.finished
        np.testing.assert_allclose(res.obs[:4, limit], suites[0].distribution.speed_limit / 5.0, rtol=1e-6)
        np.testing.assert_allclose(res.obs[4:, limit], suites[1].distribution.speed_limit / 5.0, rtol=1e-6)
    assert finished[:4].any() and finished[4:].any()


# ------------------------------------------------------------------ features
@pytest.mark.parametrize("k", [2.0, 10.0 / 3.0])
def test_features_do_not_change_when_speeds_and_distances_scale_together(k):
    """A scenario driven k times faster over k times the distances reads the same (but the speed
    limit feature, which tells the regimes apart)."""

    def first_obs(scale):
        sc = make_scenario(
            lead=(15.0 * scale, 2.0 * scale),
            oncoming=[(50.0 * scale, 2.5 * scale)],
            ego_speed=4.0 * scale,
            speed_limit=4.2 * scale,
            goal=100.0 * scale,
            sensor_range=60.0 * scale,
            ego_length=4.54 * scale,
            vehicle_length=4.54 * scale,
            lead_behaviour="scripted",
            oncoming_behaviour="scripted",
        )
        cfg = EnvConfig()
        return cfg, OvertakeCore(cfg).reset(sc)

    cfg, slow = first_obs(1.0)
    _, fast = first_obs(k)
    assert not np.allclose(slow, fast)  # the raw observation moves with the speeds
    f_slow, f_fast = speed_relative(slow, cfg), speed_relative(fast, cfg)
    limit = observation_layout(cfg)["ego"].start + 4
    keep = np.arange(f_slow.shape[1]) != limit
    np.testing.assert_allclose(f_slow[:, keep], f_fast[:, keep], rtol=1e-5, atol=1e-6)
    assert f_fast[0, limit] - f_slow[0, limit] == pytest.approx(np.log(k))
