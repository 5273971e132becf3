"""The search box and scenarios built from draw values (envs/draws.py)."""

import numpy as np
import pytest

from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.draws import build, draw_plan, layout, space_for
from overtakezoo.envs.suites import load_suite, suite_names


def recorded(dist, n, seed):
    """The values ``dist.sample(n, seed)`` draws, in its order."""
    rng = np.random.default_rng(seed)
    vals = {}
    for d in draw_plan(dist):
        lo, hi = getattr(dist, d.field)
        vals[d.key] = rng.uniform(lo, hi, size=(n,) if d.width is None else (n, d.width))
    return layout(dist, n, vals)


@pytest.mark.parametrize("name", [n for n in suite_names() if not n.endswith("-train")])
def test_build_from_the_draws_is_the_distributions_own_batch(name):
    # The plan lists sample()'s draws in order: building from the recorded values gives the same
    # scenarios, bit for bit, for every built-in suite (single- and multi-AV).
    dist = load_suite(name).distribution
    ref = dist.sample(40, 7)
    got = build(dist, recorded(dist, 40, 7))
    for key, a in ref.to_arrays().items():
        b = getattr(got, key)
        assert a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b), (name, key)


def test_table1_box_is_its_four_ranges():
    space = space_for(load_suite("table1").distribution)
    # Scripted NPCs never react and the first headway is never used: only what can change an episode.
    assert [d.label for d in space.dims] == ["lead_speed", "lead_gap", "oncoming_speed[0]", "oncoming_gap"]
    assert [(d.lo, d.hi) for d in space.dims] == [(1.0, 3.0), (8.0, 25.0), (1.0, 3.0), (20.0, 150.0)]
    sc = space.build(np.array([[0.0, 1.0, 0.5, 0.25]]))
    L = 4.54
    assert sc.npc_v[0, 0] == 1.0 and sc.npc_s[0, 0] == 25.0 + L
    assert sc.npc_v[0, 1] == 2.0 and sc.npc_s[0, 1] == L / 2 + 52.5 + L / 2


def test_counts_and_sensor_range_per_scenario():
    space = space_for(
        load_suite("oncoming-4").distribution, ["oncoming_count=1:4", "sensor_range=20:80", "oncoming_gap"]
    )
    assert [d.label for d in space.dims] == ["oncoming_gap", "oncoming_count", "sensor_range"]
    unit = np.random.default_rng(0).uniform(size=(64, 3))
    vals = space.values(unit)
    sc = space.build(unit)
    assert set(vals["oncoming_count"]) == {1, 2, 3, 4}
    assert np.array_equal(sc.npc_present.sum(axis=1), 1 + vals["oncoming_count"])  # padded to the widest
    assert np.array_equal(sc.sensor_range, vals["sensor_range"]) and sc.sensor_range.min() >= 20
    # Rows of each count are the distribution's own scenarios with that count.
    one = space.build(unit[:1])
    assert one.npc_present.sum() == 1 + vals["oncoming_count"][0]
    assert np.array_equal(space.canonical(space.canonical(unit)), space.canonical(unit))


@pytest.mark.parametrize(
    "params, needle",
    [
        (["lead_sped"], "--param lead_sped: unknown parameter for suite (searchable: "),
        (["ego_speed"], "--param ego_speed: suite: its range [4.16667, 4.16667] is a single value"),
        (["reaction_time"], "--param reaction_time: suite: it cannot change an episode here"),
        (["sensor_range"], "--param sensor_range: suite has one sensor_range (60.0); give a range"),
        (["lead_speed=3:1"], "expected finite LO < HI"),
        (["lead_speed=0:99"], "scenario.lead_speed: 99.0 is out of range [0.0, 40.0] m/s"),
        (["lead_speed=x"], "expected NAME or NAME=LO:HI"),
        (["oncoming_count=1.5:3"], "a count takes integers"),
        (["lead_gap", "lead_gap"], "given twice"),
    ],
)
def test_bad_parameters_are_one_user_error(params, needle):
    with pytest.raises(ConfigError) as exc:
        space_for(load_suite("table1").distribution, params, "suite")
    assert needle in str(exc.value)


def test_a_suite_without_ranges_has_no_box(tmp_path):
    from overtakezoo.envs import ScenarioDistribution

    dist = ScenarioDistribution.from_dict(
        {
            "lead_speed": [2.0, 2.0],
            "lead_gap": [10.0, 10.0],
            "oncoming_speed": [2.0, 2.0],
            "oncoming_gap": [50.0, 50.0],
            "oncoming_headway": [20.0, 20.0],
            "reaction_time": [0.5, 0.5],
        }
    )
    with pytest.raises(ConfigError, match="has no searchable range"):
        space_for(dist, None, "suite 'fixed'")
