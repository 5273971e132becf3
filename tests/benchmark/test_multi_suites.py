"""Multi-AV scenario layouts and suites: the single-ego suites draw what they drew before, the new
keys are validated, and the duel / platoon / mixed-traffic suites hold the vehicles their files promise."""

import hashlib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.multi_metrics import run_joint_rates
from overtakezoo.benchmark.suite_groups import CORE, MULTI, load_training, mixtures
from overtakezoo.envs import ConfigError, ScenarioDistribution, make_scenario
from overtakezoo.envs.scenarios import OPPOSITE_LANE, Scenarios
from overtakezoo.envs.suites import load_suite

# sha256 of every core suite's (and training split's) scenario arrays, computed on the code before
# the multi-AV keys existed (commit 4262421): adding AVs must not move a single bit of them.
CORE_DIGESTS = {
    "table1": "103fe3d0762810e1967d3106c9bca76e6193b19358ee37f38c52affcd46b8776",
    "table1-reactive": "76b7d2d0d183fc2c500d8b4c8dcd3690253c1f105c4bb297a3eabef09d504c35",
    "oncoming-2": "481bd36c9b3c3ebb9df3f29bf977a4af85b61e91222384f8b32feed8926be711",
    "oncoming-4": "f22307f045d5c951ca606c393dc03c508c64ffea617327da684dfda9ddf7b92c",
    "oncoming-8": "83f61b4d28abae9554ee4eb49f033dcf3538f177e14c7a9fef3f5f5970681982",
    "dense": "21c276b38ab73f6fa00e098c7536cc3f88a037acfa4cb45181d24a148821456e",
    "urban-50": "13ae07f4931c9c473d619c583452751eeea1ace2aa506e57190463534c92dca7",
    "adversarial": "fb4ee73a499ff59cbedde3693d4b10cb156651c2d5e399084901d6dd7dac82bd",
    "occluded": "e6d1a218fae147c59893a0eb35e47673e4dea742773836278752ce09f22bbbeb",
    "table1-train": "e00da855f86284b84992ec7286eb97c69eb6939ffbac6ed125f6e8ce156f536e",
    "table1-reactive-train": "93a9f8b5a178127eb18c99a09cafb5ce5f083a22f0de667587819d6f1f5d28a6",
    "oncoming-2-train": "c1eec0e72ca7663ba34951fd135e0d6b3657461ffc40e008bd86c001e8a24b5a",
    "oncoming-4-train": "07ba30f759cc5d614178957ca1ba702adbb979377aa97693649054b51dc8767a",
    "oncoming-8-train": "60a3bf39c79dc568b7a78097ce066e6352f380e3c99f38fd070ff8ad41ec7b0c",
    "dense-train": "7f3c6a17d97730cf46e07b3b2dbe20274ed776a22d55d83fa595b91a10723723",
    "urban-50-train": "3ff5083b09e81774518cf89a9ef73333106659620be0d212bb7228807dc70892",
    "adversarial-train": "43c8d40c840cc0bad2a1b7799cc13d13e36a002e7640b742c1307d3ec72374de",
    "occluded-train": "9c91ad28927e922a3943518a31ffdca06fc9e41c3df46bb3c47b264cc41a6e37",
}
KMH = 1 / 3.6


def digest(sc: Scenarios) -> str:
    """sha256 over the single-ego arrays (names, dtypes, shapes and bytes)."""
    h = hashlib.sha256()
    for key, a in sorted(sc.to_arrays().items()):
        if not key.startswith("av_"):
            h.update(key.encode() + str(a.dtype).encode() + str(a.shape).encode() + a.tobytes())
    return h.hexdigest()


@pytest.mark.parametrize("name", sorted(CORE_DIGESTS))
def test_core_suites_draw_what_they_drew_before(name):
    sc = load_suite(name).scenarios()
    assert digest(sc) == CORE_DIGESTS[name]
    assert sc.num_avs == 1 and sc.av_s.shape == (sc.num, 0)


def vehicles(sc: Scenarios):
    """Every vehicle of every row as (N, V) arrays: lane, centre s, length, present; the ego first,
    then the other AVs, then the NPC slots."""
    lw = sc.lane_width[:, None]
    av_lane = np.rint(sc.av_d / lw).astype(int)
    lane = np.concatenate([np.rint(sc.ego_d / sc.lane_width)[:, None].astype(int), av_lane, sc.npc_lane], axis=1)
    s = np.concatenate([sc.ego_s[:, None], sc.av_s, sc.npc_s], axis=1)
    length = np.concatenate([np.repeat(sc.ego_length[:, None], sc.num_avs, axis=1), sc.npc_length], axis=1)
    present = np.concatenate([np.ones((sc.num, sc.num_avs), bool), sc.npc_present], axis=1)
    return lane, s, length, present


def min_start_gap(sc: Scenarios) -> float:
    """The smallest bumper gap between two present vehicles in the same lane, over all rows."""
    lane, s, length, present = vehicles(sc)
    gap = np.abs(s[:, :, None] - s[:, None, :]) - (length[:, :, None] + length[:, None, :]) / 2
    pair = (lane[:, :, None] == lane[:, None, :]) & present[:, :, None] & present[:, None, :]
    pair &= ~np.eye(s.shape[1], dtype=bool)
    return float(gap[pair].min()) if pair.any() else np.inf


def check_avs(sc: Scenarios, dist: ScenarioDistribution) -> None:
    """The layout ``dist`` promises: the platoon behind the ego, the oncoming AV behind its own lead."""
    P, O = dist.platoon_size, dist.oncoming_av
    assert sc.num_avs == P + O and sc.av_s.shape == sc.av_lead.shape == (sc.num, P - 1 + O)
    Le, L = dist.ego_length, dist.vehicle_length
    assert min_start_gap(sc) > 0
    if P > 1:
        plat = slice(0, P - 1)
        assert (sc.av_direction[:, plat] == 1).all() and (sc.av_d[:, plat] == 0).all()
        assert (sc.av_goal_s[:, plat] == sc.goal_s[:, None]).all() and (sc.av_lead[:, plat] == 0).all()
        chain = np.concatenate([sc.ego_s[:, None], sc.av_s[:, plat]], axis=1)
        gaps = -np.diff(chain, axis=1) - Le
        assert (gaps >= dist.platoon_gap[0]).all() and (gaps <= dist.platoon_gap[1]).all()
        assert (sc.av_v[:, plat] >= dist.ego_speed[0]).all() and (sc.av_v[:, plat] <= dist.speed_limit).all()
        # The shared lead (slot 0) is ahead of the whole platoon, the followers behind its tail.
        assert sc.npc_must_pass[:, 0].all() and (sc.npc_lane[:, 0] == 0).all()
        ego_lane_npcs = (sc.npc_lane == 0) & sc.npc_present
        ego_lane_npcs[:, 0] = False
        tail = sc.av_s[:, P - 2][:, None]
        assert (sc.npc_s[ego_lane_npcs] < np.broadcast_to(tail, sc.npc_s.shape)[ego_lane_npcs]).all()
    if O:
        k, slot = P - 1, sc.num_npcs - 1
        assert (sc.av_direction[:, k] == -1).all() and (sc.av_d[:, k] == sc.lane_width).all()
        assert (sc.av_lead[:, k] == slot).all()
        assert np.allclose(sc.av_s[:, k] - sc.av_goal_s[:, k], sc.goal_s - sc.ego_s)  # the ego's goal distance
        distance = sc.av_s[:, k] - Le / 2 - (sc.ego_s + Le / 2)
        assert (distance >= dist.oncoming_av_distance[0]).all() and (distance <= dist.oncoming_av_distance[1]).all()
        # Its lead: lane 1, ahead of it towards -s, between the two AVs, no vehicle in between.
        lead_s = sc.npc_s[:, slot]
        assert (sc.npc_lane[:, slot] == OPPOSITE_LANE).all() and not sc.npc_must_pass[:, slot].any()
        lead_gap = sc.av_s[:, k] - Le / 2 - (lead_s + L / 2)
        assert (lead_gap >= dist.oncoming_av_lead_gap[0]).all() and (lead_gap <= dist.oncoming_av_lead_gap[1]).all()
        assert (lead_s - L / 2 > sc.ego_s + Le / 2).all()
        lane1 = (sc.npc_lane == OPPOSITE_LANE) & sc.npc_present
        between = lane1 & (sc.npc_s > lead_s[:, None]) & (sc.npc_s < sc.av_s[:, k][:, None])
        assert not between.any()
        lo, hi = dist.oncoming_av_lead_speed
        assert (sc.npc_v[:, slot] >= lo).all() and (sc.npc_v[:, slot] <= hi).all()


@pytest.mark.parametrize("name", MULTI)
def test_multi_suites_hold_what_their_files_promise(name):
    test, train = load_suite(name), load_suite(f"{name}-train")
    assert train.distribution == test.distribution and train.config == test.config
    assert train.seed == test.seed - 10000 and train.count == test.count == 1000
    for suite in (test, train):
        sc = suite.scenarios()
        check_avs(sc, suite.distribution)
        assert np.isfinite(sc.av_s).all() and np.isfinite(sc.npc_s).all()
    # Disjoint draws: no scenario of the training split is a test scenario.
    a, b = test.scenarios(), train.scenarios()
    assert not np.isin(a.npc_s[:, 0], b.npc_s[:, 0]).any()


def test_multi_suites_layouts():
    duel, platoon, mixed = (load_suite(n).scenarios() for n in MULTI)
    assert duel.num_avs == 2 and duel.num_npcs == 2  # each AV's lead
    assert (duel.npc_behaviour == 2).all()  # scripted: only the AVs react
    assert platoon.num_avs == 3 and platoon.num_npcs == 3 and (platoon.npc_lane[:, 1:] == OPPOSITE_LANE).all()
    assert mixed.num_avs == 2 and mixed.num_npcs == 6 and (mixed.npc_behaviour == 0).all()
    assert not set(MULTI) & set(CORE)
    assert [s.name for s in load_training("multi-train")] == [f"{n}-train" for n in MULTI]
    assert mixtures()["multi-train"] == tuple(f"{n}-train" for n in MULTI)


def test_adding_avs_leaves_the_single_ego_draws_alone():
    base = ScenarioDistribution(oncoming_count=2, follower_count=2)
    plain = base.sample(200, 5)
    with_oav = ScenarioDistribution(
        oncoming_count=2,
        follower_count=2,
        oncoming_av=1,
        oncoming_av_distance=(40.0, 100.0),
        oncoming_gap=(120.0, 150.0),
    )
    sc = with_oav.sample(200, 5)
    # The first slots are the single-ego draws (the oncoming gap differs, so compare the rest).
    for key in ("npc_v", "npc_reaction", "npc_lane", "npc_behaviour"):
        assert (getattr(sc, key)[:, : plain.num_npcs] == getattr(plain, key)).all(), key
    assert (sc.npc_s[:, [0, 3, 4]] == plain.npc_s[:, [0, 3, 4]]).all()
    platoon = ScenarioDistribution(oncoming_count=2, follower_count=2, platoon_size=3).sample(200, 5)
    assert (platoon.npc_s[:, :3] == plain.npc_s[:, :3]).all() and (platoon.npc_v == plain.npc_v).all()
    assert (platoon.npc_s[:, 3:] == plain.npc_s[:, 3:] - (plain.ego_s - platoon.av_s[:, 1])[:, None]).all()


def test_sampling_is_deterministic():
    dist = load_suite("mixed-traffic").distribution
    a, b, c = dist.sample(64, 11), dist.sample(64, 11), dist.sample(64, 12)
    for key, x in a.to_arrays().items():
        y = b.to_arrays()[key]
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), key
    assert not np.array_equal(a.av_s, c.av_s)
    assert a.av_direction.dtype == np.int8 and a.av_lead.dtype == np.int16
    # Concatenation and slicing keep the AVs (the runner shards and stacks batches).
    both = Scenarios.concat([a, c])
    assert both.num_avs == 2 and (both.take(slice(64, None)).av_s == c.av_s).all()


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("platoon_size", 0, "1 .the ego alone. to 16"),
        ("platoon_size", 17, "1 .the ego alone. to 16"),
        ("platoon_size", 2.0, "integer"),
        ("oncoming_av", 2, "0 or 1"),
        ("oncoming_av", True, "integer"),
        ("platoon_gap", [0.0, 5.0], "must be > 0"),
        ("platoon_gap", [5.0], r"\[low, high\]"),
        ("oncoming_av_lead_gap", [-1.0, 5.0], "must be > 0"),
        ("oncoming_av_lead_speed", [-1.0, 2.0], ">= 0"),
        ("oncoming_av_distance", [10.0, 5.0], "above high"),
        ("oncoming_av_distance", [float("inf"), float("inf")], "finite"),
    ],
)
def test_bad_av_keys_are_config_errors_naming_the_key(key, value, message):
    with pytest.raises(ConfigError, match=rf"scenario\.{key}: .*{message}"):
        ScenarioDistribution.from_dict({key: value})


def test_av_layouts_that_would_overlap_are_refused():
    # The oncoming AV's lead must start ahead of the ego: distance above lead gap + a car length.
    with pytest.raises(ConfigError, match=r"scenario\.oncoming_av_distance: .*29\.54 m"):
        ScenarioDistribution.from_dict({"oncoming_av": 1, "oncoming_av_distance": [20.0, 100.0]})
    # Oncoming NPCs share lane 1 with the oncoming AV: they must start behind it.
    with pytest.raises(ConfigError, match=r"scenario\.oncoming_gap: .*behind"):
        ScenarioDistribution.from_dict({"oncoming_av": 1, "oncoming_av_distance": [40.0, 100.0]})
    ok = ScenarioDistribution.from_dict({"oncoming_av": 1, "oncoming_count": 0, "oncoming_av_distance": [40.0, 100.0]})
    assert ok.sample(3, 0).num_avs == 2
    # Unused AV keys are not held against a single-ego distribution.
    assert ScenarioDistribution.from_dict({"oncoming_av_distance": [20.0, 100.0]}).sample(2, 0).num_avs == 1


@given(
    platoon=st.integers(1, 4),
    oav=st.integers(0, 1),
    followers=st.integers(0, 3),
    oncoming=st.integers(0, 3),
    gap=st.floats(0.5, 30.0),
    distance=st.floats(30.0, 200.0),
    seed=st.integers(0, 2**32 - 1),
)
def test_no_two_vehicles_start_in_contact(platoon, oav, followers, oncoming, gap, distance, seed):
    keys = dict(
        platoon_size=platoon,
        oncoming_av=oav,
        follower_count=followers,
        oncoming_count=oncoming,
        platoon_gap=(gap, gap * 1.5),
        oncoming_av_distance=(distance, distance + 20.0),
        oncoming_gap=(distance + 30.0, distance + 90.0) if oav else (20.0, 150.0),
        lead_gap=(0.5, 25.0),
        follower_gap=(0.5, 20.0),
    )
    dist = ScenarioDistribution.from_dict({k: list(v) if isinstance(v, tuple) else v for k, v in keys.items()})
    check_avs(dist.sample(32, seed), dist)


def test_a_hand_built_duel():
    sc = make_scenario(lead=(10.0, 1.0), oncoming_av=(120.0, 15 * KMH, 10.0, 1.5), oncoming_behaviour="scripted")
    Le = L = 4.54
    assert sc.num_avs == 2 and sc.num_npcs == 2
    assert sc.av_direction.tolist() == [[-1]] and sc.av_lead.tolist() == [[1]]
    assert sc.av_s[0, 0] == pytest.approx(Le / 2 + 120.0 + Le / 2)  # its front 120 m ahead of the ego's
    assert sc.av_goal_s[0, 0] == pytest.approx(sc.av_s[0, 0] - 100.0)
    assert sc.av_d[0, 0] == sc.lane_width[0] and sc.av_v[0, 0] == pytest.approx(15 * KMH)
    assert sc.npc_s[0, 1] == pytest.approx(Le / 2 + 120.0 - 10.0 - L / 2)
    assert sc.npc_lane[0].tolist() == [0, 1] and sc.npc_behaviour[0, 1] == 2 and sc.npc_v[0, 1] == 1.5
    assert sc.npc_must_pass[0].tolist() == [True, False]
    platoon = make_scenario(lead=(10.0, 2.0), platoon=[(8.0, 4.0), (9.0, 4.0)], followers=[(5.0, 3.0)])
    assert platoon.av_s.tolist() == [[-(8.0 + Le), -(17.0 + 2 * Le)]] and platoon.av_lead.tolist() == [[0, 0]]
    assert platoon.npc_s[0, 1] == pytest.approx(-(17.0 + 2 * Le) - Le / 2 - 5.0 - L / 2)
    assert min_start_gap(platoon) > 0
    assert make_scenario(lead=None, platoon=[(8.0, 4.0)]).av_lead.tolist() == [[-1]]  # nothing to pass


@pytest.mark.parametrize("name", MULTI)
def test_multi_suites_step_on_the_core(name):
    """Every AV of every road runs to an end: following never crashes nor succeeds (the leads are
    slow), overtaking blindly crashes somewhere (the suites are not free)."""
    suite = load_suite(name)
    follow = run_joint_rates(suite, "always-follow", 16)
    assert len(follow["per_av"]) == suite.scenarios().num_avs
    assert all(av == {"success": 0.0, "crash": 0.0, "timeout": 1.0} for av in follow["per_av"])
    rush = run_joint_rates(suite, "always-overtake", 32)
    assert rush["any_crash"] > 0 and rush["all_succeed"] < 1


def test_eval_refuses_a_privileged_decider_on_a_multi_av_suite_with_one_error_line(tmp_path, capsys):
    out = tmp_path / "duel.json"
    assert main(["eval", "--suite", "duel", "--decider", "oracle", "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: suite 'duel' has 2 automated vehicles") and "\n" not in err
    assert "privileged" in err
    assert not out.exists() and not list(tmp_path.iterdir())


def test_the_multi_train_mixture_steps_one_row_per_av():
    from overtakezoo.envs.mixture import MixedCore

    suites = load_training("multi-train")
    sources = [(lambda d: lambda n, rng: d.sample(n, rng))(s.distribution) for s in suites]
    mix = MixedCore([s.config for s in suites], sources, [3, 2, 2], seed=0)
    rows = 3 * 2 + 2 * 3 + 2 * 2  # duel, platoon, mixed-traffic: 2, 3, 2 AVs per road
    assert mix.num == rows and mix.observe().shape[0] == rows
    for _ in range(5):
        res = mix.step(np.ones(rows, np.int64))
    assert res.obs.shape[0] == rows and res.reward.shape == (rows,) and mix.done.shape == (rows,)


@pytest.mark.parametrize("name", MULTI)
def test_every_av_observation_lies_in_the_observation_space(name):
    from overtakezoo.envs import OvertakeCore
    from overtakezoo.envs.faces.spaces import ego_observation_space
    from overtakezoo.envs.hold import hold

    suite = load_suite(name)
    box = ego_observation_space(suite.config)
    core = OvertakeCore(suite.config)
    obs = core.reset(suite.scenarios().take(slice(0, 64)))
    modes = np.random.default_rng(0).integers(0, 3, size=(40, obs.shape[0]))
    for step_modes in modes:  # 40 decisions of 10 steps: most of an episode
        assert ((obs >= box.low) & (obs <= box.high)).all()
        obs = hold(core, step_modes, 10).obs
