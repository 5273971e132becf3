"""Results files: schema validation names the field, tampering is caught, the loader never crashes."""

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import PER_SCENARIO, SAFETY_PER_SCENARIO, Results
from overtakezoo.envs.suites import load_suite


class Stub:
    name, version, privileged, weights_sha256 = "stub", "1", False, None


def fake_results(n=3000, seed=0, suite="table1", safety=True):
    """Results with random per-scenario arrays (no simulation: fast), with the safety arrays a run
    records (a leaderboard row needs every one) unless ``safety`` is off (`eval --no-safety`)."""
    rng = np.random.default_rng(seed)
    outcome = rng.choice([1, 2, 3], n, p=[0.6, 0.3, 0.1])
    crash_npc = np.where(outcome == 2, rng.integers(0, 2, n), -1)
    per = {k: rng.uniform(0, 5, n) for k, (dtype, _) in PER_SCENARIO.items() if dtype is np.float64}
    per.update(
        outcome=outcome,
        crash_npc=crash_npc,
        crash_lane=np.where(outcome == 2, crash_npc, -1),
        aborts=rng.integers(0, 3, n),
        switches=rng.integers(0, 4, n),
    )
    per["completion_time"] = np.where(outcome == 1, per["completion_time"] + 25, np.nan)
    per["min_ttc"][::7] = np.inf
    if safety:  # drawn after the others: those arrays are what they were before the safety metrics
        per.update(
            {
                k: np.where(rng.random(n) < 0.5, rng.uniform(0, 1, n), np.nan)
                for k, (dtype, _) in SAFETY_PER_SCENARIO.items()
                if dtype is np.float64
            }
        )
        per.update({k: rng.integers(-1, 2, n) for k, (dtype, _) in SAFETY_PER_SCENARIO.items() if dtype is np.int8})
    return Results.create(
        load_suite(suite),
        Stub(),
        per,
        start=0,
        stop=n,
        shard=None,
        timing={"wall_time_s": 1.0, "started": "2026-01-01T00:00:00+00:00", "steps": 1},
    )


@pytest.fixture(scope="module")
def good():
    return fake_results().to_json()


def _mutated(text, fn):
    doc = json.loads(text)
    fn(doc)
    return json.dumps(doc)


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d["suite"].update(hash="xyz"), "suite.hash"),
        (lambda d: d["decider"].pop("version"), "decider"),
        (lambda d: d.update(seed=-1), "seed"),
        (lambda d: d["scenarios"].update(outcome=[9] * 3000), "scenarios.outcome.0"),
        (lambda d: d["scenarios"]["aborts"].pop(), "scenarios.aborts"),
        (lambda d: d["summary"]["success_rate"].update(value=0.99), "summary"),
        (lambda d: d.update(extra=1), "(top level)"),
        (lambda d: d.update(range=[0, 5000]), "range"),
    ],
)
def test_schema_and_consistency_errors_name_the_field(good, mutate, field):
    with pytest.raises(UserError) as exc:
        Results.from_json(_mutated(good, mutate), "f.json")
    assert str(exc.value).startswith(f"f.json: {field}")


def test_round_trip_and_non_finite_values(good):
    r = Results.from_json(good)
    assert r.to_json() == good
    assert np.isinf(r.per["min_ttc"][0]) and np.isnan(r.per["completion_time"][r.per["outcome"] != 1]).all()
    with pytest.raises(UserError, match="not a valid JSON"):
        Results.from_json(good.replace('"seed": ', '"seed": NaN, "x": ', 1))


_GOOD = None


def _good_doc():
    global _GOOD
    if _GOOD is None:
        _GOOD = json.loads(fake_results(n=40, seed=1, suite="table1").to_json().replace('"count": 3000', '"count": 40'))
    return json.loads(json.dumps(_GOOD))


_json = st.recursive(
    st.none() | st.booleans() | st.integers(-(10**20), 10**20) | st.floats(allow_nan=False) | st.text(max_size=8),
    lambda c: st.lists(c, max_size=4) | st.dictionaries(st.text(max_size=6), c, max_size=4),
    max_leaves=12,
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.one_of(
        st.binary(max_size=100),
        _json.map(json.dumps),
        # A valid file with one key somewhere replaced by a random JSON value.
        st.tuples(
            st.sampled_from(["suite", "decider", "scenarios", "summary", "range", "shard", "seed", "timing"]),
            st.text(max_size=10),
            _json,
        ).map(lambda t: (t[0], t[1], t[2])),
    )
)
def test_fuzz_results_loader_raises_only_user_errors(data):
    if isinstance(data, tuple):
        key, sub, value = data
        doc = _good_doc()
        if isinstance(doc[key], dict) and doc[key]:
            keys = sorted(doc[key])
            doc[key][keys[len(sub) % len(keys)]] = value
        else:
            doc[key] = value
        data = json.dumps(doc)
    try:
        Results.from_json(data, "fuzz.json")
    except UserError as exc:
        assert str(exc).startswith("fuzz.json: ") and "\n" not in str(exc)
