"""Expected failures on every CLI path are one `error:` line and exit 2; SIGTERM and closed pipes end
cleanly; no command leaves a partial file or a temp file, or replaces a FIFO."""

import json
import math
import os
import signal
import stat
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_benchmark_cli import one_line_error, small_suite_file

from conftest import leftovers, read_fifo
from overtakezoo.benchmark.cli import main
from overtakezoo.envs import ConfigError, EnvConfig
from overtakezoo.envs.suites import SUITES_DIR

CLI = [sys.executable, "-c", "import sys; from overtakezoo.benchmark.cli import main; sys.exit(main())"]


def suite_with(tmp_path, scenario="", sim=""):
    path = tmp_path / "s.toml"
    path.write_text(f'name = "s"\nversion = 1\ncount = 3\nseed = 1\n[scenario]\n{scenario}\n[sim]\n{sim}\n')
    return path


@pytest.mark.parametrize(
    "scenario, sim, needle",
    [
        ("lead_gap = [8.0, inf]", "", "scenario.lead_gap: must be finite"),
        ("lead_gap = [nan, 9.0]", "", "scenario.lead_gap: must be finite"),
        ("time_limit = inf", "", "scenario.time_limit: must be finite"),
        ("goal = -inf", "", "scenario.goal: must be finite"),
        ("oncoming_reveal = [5.0, inf]", "", "scenario.oncoming_reveal: must be finite"),
        (
            "",
            "[sim.observation]\nvehicles_per_lane = 2.0",
            "sim.observation.vehicles_per_lane: expected an integer, got 2.0",
        ),
        ("", "[sim.planner]\nnum_rollouts = 4.0", "sim.planner.num_rollouts: expected an integer"),
        ("", "[sim.planner.modes.overtake]\nrollout_id = -1.0", "rollout_id: expected an integer"),
        ("", "decision_interval = 2.0", "sim.decision_interval: expected an integer"),
        # Issue 18: huge finite values, non-table [sim] sections and wrongly typed settings were accepted
        # (an endless run) or crashed with AttributeError; each is one line naming file, key and range.
        ("speed_limit = 1e300", "", "scenario.speed_limit: 1e+300 is out of range [0.5, 40.0] m/s"),
        ("lane_width = 1e-300", "", "scenario.lane_width: 1e-300 is out of range [2.0, 6.0] m"),
        ("goal = 1e12", "", "scenario.goal: 1000000000000.0 is out of range [1.0, 5000.0] m"),
        ("time_limit = 1e12", "", "scenario.time_limit: 1000000000000.0 is out of range [0.1, 3600.0] s"),
        ("lead_gap = [8.0, 1e9]", "", "scenario.lead_gap: 1000000000.0 is out of range [0.0, 5000.0] m"),
        ("oncoming_count = 65", "", "scenario.oncoming_count: 65 is out of range [0, 64]"),
        ("time_limit = 3600", "dt = 0.001", "scenario.time_limit: 3600 s at dt = 0.001 s is 3600000 steps"),
        ("", "npc = [1, 2]", "sim.npc: expected a table, got [1, 2]"),
        ("", "observation = 3", "sim.observation: expected a table, got 3"),
        ("", 'reward = "big"', "sim.reward: expected a table, got 'big'"),
        ("", 'seed = "abc"', "sim.seed: expected an integer, got 'abc'"),
        ("", "seed = -1", "sim.seed: -1 is out of range"),
        ("", 'npc_agents = "no"', "sim.npc_agents: expected true or false, got 'no'"),
        ("", "[sim.planner]\nmax_steer = 3.0", "sim.planner.max_steer: 3.0 is out of range [0.01, 1.2] rad"),
        ("lead_gapp = [1.0, 2.0]", "", "scenario.lead_gapp: unknown key (did you mean 'lead_gap'?)"),
    ],
)
def test_bad_suite_values_are_one_line(tmp_path, capsys, scenario, sim, needle):
    out = tmp_path / "r.json"
    path = suite_with(tmp_path, scenario, sim)
    err = one_line_error(
        capsys, ["eval", "--suite", str(path), "--decider", "always-follow", "--out", str(out), "--no-progress"]
    )
    assert err.startswith(f"error: {path}: ") and needle in err, err
    assert not out.exists()


def test_integer_settings_take_integers_only():
    # Documented choice: an integer setting refuses 2.0 rather than rounding it; numpy integers are fine.
    with pytest.raises(ConfigError, match="vehicles_per_lane: expected an integer, got 2.0"):
        EnvConfig.from_dict({"observation": {"vehicles_per_lane": 2.0}})
    assert EnvConfig(decision_interval=np.int64(2), num_egos=np.int32(1)).decision_interval == 2


def test_unwritable_train_out_fails_before_training(tmp_path, capsys, monkeypatch):
    from overtakezoo.benchmark.run import training
    from overtakezoo.benchmark.suite_groups import load_training
    from overtakezoo.zoo.train import dqn

    def must_not_run(*args, **kwargs):
        raise AssertionError("training started although --out cannot be written")

    monkeypatch.setattr(training, "train", must_not_run)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for algo in ("dqn", "ppo"):
        err = one_line_error(capsys, ["train", algo, "--out", str(blocker / "run"), "--steps", "10"])
        assert err.startswith(f"error: cannot write {blocker / 'run'}")
    # The zoo's own entry point checks too (a Python caller gets the same error before training).
    from overtakezoo.envs.io import WriteError

    monkeypatch.undo()
    with pytest.raises(WriteError, match="cannot write"):
        dqn.train(load_training("table1-train"), steps=10, out=blocker / "run", progress=False)


@pytest.fixture(scope="module")
def archive(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("cli-archive")
    path = tmp / "run.mcap"
    assert (
        main(
            [
                "eval",
                "--suite",
                str(small_suite_file(tmp, count=3)),
                "--decider",
                "always-follow",
                "--out",
                str(tmp / "r.json"),
                "--archive",
                str(path),
                "--no-progress",
            ]
        )
        == 0
    )
    return path


def test_unwritable_out_on_every_command(tmp_path, tmp_path_factory, capsys, archive, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    bad = blocker / "sub"
    suite = str(small_suite_file(tmp_path, count=3))
    registry = tmp_path_factory.mktemp("registry") / "datasets.json"
    registry.write_text(
        json.dumps({"datasets": {"o/t/x-v0": {"url": "http://127.0.0.1:9/x.tar.gz", "size": 10, "sha256": "0" * 64}}})
    )
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(bad))
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(bad / "home"))
    monkeypatch.setenv("OVERTAKEZOO_REGISTRY", str(registry))
    runs = [
        ["eval", "--suite", suite, "--decider", "always-follow", "--out", f"{bad}/r.json"],
        [
            "eval",
            "--suite",
            suite,
            "--decider",
            "always-follow",
            "--out",
            str(tmp_path / "r.json"),
            "--archive",
            f"{bad}/a.mcap",
        ],
        ["decision-map", "--decider", "always-follow", "--resolution", "2", "--out", f"{bad}/m.png"],
        ["replay", str(archive), "--episode", "0", "--out", f"{bad}/e.gif"],
        ["replay", str(archive), "--episode", "0", "--out", f"{bad}/e.png"],
        ["submit", str(tmp_path / "r.json"), "--root", f"{bad}/lb"],  # a new root is created: here it cannot be
        ["dataset", "build", "--suite", suite, "--decider", "always-follow", "--name", "o/t/x-v0", "--count", "1"],
        ["dataset", "list"],
        ["dataset", "download", "o/t/x-v0", "--no-progress"],
        ["eval", "--suite", suite, "--decider", "always-follow", "--out", str(tmp_path)],  # a directory
    ]
    for argv in runs:
        assert "cannot write" in one_line_error(capsys, argv), argv
    # The leaderboard command reads its root, never creates it (submit --root may: a new leaderboard).
    assert one_line_error(capsys, ["leaderboard", "--root", f"{bad}/lb"]) == f"error: no such folder: {bad}/lb"
    t0 = time.perf_counter()  # perf fails before its (here 60 s of) measuring
    assert "cannot write" in one_line_error(
        capsys, ["perf", "--sizes", "1", "--seconds", "60", "--no-suites", "--out", f"{bad}/perf"]
    )
    assert time.perf_counter() - t0 < 30
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "small.toml"]


def test_eval_into_a_fifo_streams_and_keeps_the_fifo(tmp_path, capsys):
    fifo = tmp_path / "results.fifo"
    os.mkfifo(fifo)
    got = []
    t = read_fifo(fifo, got)
    assert (
        main(
            [
                "eval",
                "--suite",
                str(small_suite_file(tmp_path, count=3)),
                "--decider",
                "always-follow",
                "--out",
                str(fifo),
                "--no-progress",
            ]
        )
        == 0
    )
    t.join(30)
    assert json.loads(got[0])["decider"]["name"] == "always-follow"
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and leftovers(tmp_path) == []


def test_closed_stdout_pipe_ends_quietly(archive):
    # `overtakezoo replay run.mcap --list | head`: the reader is gone before the first line.
    p = subprocess.Popen(CLI + ["replay", str(archive), "--list"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    p.stdout.close()
    err = p.stderr.read().decode()
    assert p.wait(60) == 1 and err == "", err


def test_sigterm_during_eval_leaves_no_file(tmp_path):
    suite = small_suite_file(tmp_path, count=20000)  # long enough to be stopped mid-run
    out = tmp_path / "out" / "r.json"
    p = subprocess.Popen(
        CLI
        + [
            "eval",
            "--suite",
            str(suite),
            "--decider",
            "always-follow",
            "--out",
            str(out),
            "--no-progress",
            "--chunk-size",
            "500",
        ],
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 60
    while not out.parent.exists() and time.monotonic() < deadline:  # made by the --out check, before the run
        time.sleep(0.05)
    time.sleep(0.3)
    p.send_signal(signal.SIGTERM)
    err = p.stderr.read().decode()
    assert p.wait(60) == 143 and err.strip() == "terminated", err
    assert not out.exists() and leftovers(out.parent) == []


_SLOW_WRITER = """
import signal, sys, time
from overtakezoo.benchmark.cli import _on_sigterm
from overtakezoo.envs.io import atomic_output
signal.signal(signal.SIGTERM, _on_sigterm)  # what the CLI installs
with atomic_output(sys.argv[1]) as f:
    f.write(b"x" * 100000)
    f.flush()
    print("writing", flush=True)
    time.sleep(60)
"""


def test_sigterm_while_a_file_is_half_written(tmp_path):
    target = tmp_path / "big.bin"
    target.write_bytes(b"old")
    p = subprocess.Popen(
        [sys.executable, "-c", _SLOW_WRITER, str(target)], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert p.stdout.readline() == b"writing\n"
    assert len(leftovers(tmp_path)) == 1  # the temp file being written
    p.send_signal(signal.SIGTERM)
    p.wait(60)
    assert target.read_bytes() == b"old" and leftovers(tmp_path) == []


# ---------------------------------------------------------------------------------------- fuzzing
_SCENARIO_KEYS = [
    "speed_limit",
    "lane_width",
    "goal",
    "road_extra",
    "sensor_range",
    "time_limit",
    "ego_speed",
    "lead_speed",
    "lead_gap",
    "lead_behaviour",
    "lead_boost",
    "oncoming_count",
    "oncoming_speed",
    "oncoming_gap",
    "oncoming_headway",
    "oncoming_reveal",
    "follower_count",
    "follower_gap",
    "reaction_time",
    "ego_length",
    "vehicle_width",
]
_SIM_KEYS = [
    "dt",
    "decision_interval",
    "num_egos",
    "npc_agents",
    "seed",
    "planner.num_rollouts",
    "planner.horizon_time",
    "planner.enable_prediction",
    "planner.modes.follow.rollout_number",
    "planner.modes.overtake.rollout_id",
    "planner.modes.abort.velocity",
    "npc.min_gap",
    "reward.crash",
    "observation.vehicles_per_lane",
    "observation.speed_scale",
    "render_mode",
]
# Edge values first (inf, NaN, integral floats, huge numbers), then anything.
_scalar = st.one_of(
    st.sampled_from([math.inf, -math.inf, math.nan, 2.0, 0.0, -1.0, 1e300, 1, 0, 3, 2**63, True, '"idm"', '""']),
    st.floats(0, 100),
    st.integers(-10, 40),
    st.floats(),
    st.integers(-(2**70), 2**70),
)
_value = st.one_of(_scalar, st.lists(_scalar, min_size=2, max_size=2), st.lists(_scalar, max_size=3))


def _toml(v):
    if isinstance(v, list):
        return "[" + ", ".join(_toml(x) for x in v) + "]"
    if isinstance(v, bool):
        return "true" if v else "false"
    return v if isinstance(v, str) else repr(v)  # repr: inf, -inf, nan and 1e+300 are TOML too


def _suite_text(scenario, sim):
    lines = ['name = "fuzz"', "version = 1", "count = 3", "seed = 1", "[scenario]"]
    lines += [f"{k} = {_toml(v)}" for k, v in scenario.items()]
    tables = {}
    for key, v in sim.items():
        table, _, leaf = key.rpartition(".")
        tables.setdefault(table, []).append(f"{leaf} = {_toml(v)}")
    for table, rows in sorted(tables.items()):
        lines += [f"[sim{'.' + table if table else ''}]"] + rows
    return "\n".join(lines) + "\n"


@settings(max_examples=150)
@given(
    st.dictionaries(st.sampled_from(_SCENARIO_KEYS), _value, max_size=3),
    st.dictionaries(st.sampled_from(_SIM_KEYS), _value, max_size=3),
)
def test_fuzz_suite_values_load_run_or_fail_with_user_errors(scenario, sim):
    from overtakezoo.envs import OvertakeCore
    from overtakezoo.envs.suites import SuiteError, parse_suite

    try:
        suite = parse_suite(_suite_text(scenario, sim).encode(), SUITES_DIR / "fuzz.toml")
    except SuiteError as exc:
        assert str(exc).startswith(str(SUITES_DIR / "fuzz.toml")) and "\n" not in str(exc)
        return
    # A suite that loads must also sample and step: no error may wait until the run.
    scenarios = suite.scenarios()
    assert np.isfinite(scenarios.time_limit).all()
    core = OvertakeCore(suite.config)
    core.reset(scenarios)
    for mode in (0, 1, 1):
        core.step(np.full(scenarios.num * suite.config.num_egos, mode)[: core.num])


@settings(max_examples=25)
@given(
    shard=st.one_of(st.none(), st.text(max_size=6), st.sampled_from(["0/1", "1/2", "2/2", "0/9"])),
    chunk=st.integers(-3, 5),
    decider=st.sampled_from(["always-follow", "nope", "", "always-follow\0"]),
    out=st.sampled_from(["r.json", "", ".", "x/../r.json", "a\0b.json", "sub/"]),
    suite=st.sampled_from(["small", "nope", "", "small.toml\0"]),
)
def test_fuzz_eval_arguments_are_one_line_errors(tmp_path_factory, shard, chunk, decider, out, suite):
    import contextlib
    import io

    tmp = tmp_path_factory.mktemp("fuzz-eval")
    small = small_suite_file(tmp, count=2).with_name("small.toml")
    suite_arg = str(small) + suite[5:] if suite.startswith("small") else suite
    argv = [
        "eval",
        "--suite",
        suite_arg,
        "--decider",
        decider,
        "--out",
        str(tmp / out),
        "--no-progress",
        "--chunk-size",
        str(chunk),
    ] + (["--shard", shard] if shard is not None else [])
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse's own usage errors
            code = exc.code
    if code != 0:
        assert code == 2 and err.getvalue().count("\n") <= 3 and "Traceback" not in err.getvalue(), err.getvalue()


# Issue 18: count = 1000000 with 64 oncoming and 64 followers ended in a MemoryError traceback.
def test_a_suite_too_big_for_memory_is_refused_before_drawing(tmp_path, capsys, monkeypatch):
    from overtakezoo.envs import ScenarioDistribution, suites

    drawn = []
    sample = ScenarioDistribution.sample
    monkeypatch.setattr(ScenarioDistribution, "sample", lambda self, n, seed: drawn.append(n) or sample(self, n, seed))
    monkeypatch.setattr(suites, "available_memory", lambda: 8 * 2**30)  # a laptop, whatever this machine has
    big = tmp_path / "big.toml"
    big.write_text(
        'name = "big"\nversion = 1\ncount = 1000000\nseed = 1\n[scenario]\noncoming_count = 64\nfollower_count = 64\n'
    )
    out = tmp_path / "r.json"
    err = one_line_error(
        capsys, ["eval", "--suite", str(big), "--decider", "always-follow", "--out", str(out), "--no-progress"]
    )
    assert err.startswith(f"error: {big}: count: 1000000 scenarios of 129 NPCs need about "), err
    assert "only 8.0 GiB is available" in err and not out.exists()
    assert max(drawn) == 1  # only the one-scenario probe of the estimate was drawn
    # The same machine runs a small suite, and every shipped suite fits in it.
    small = suite_with(tmp_path, "oncoming_count = 2")
    assert main(["eval", "--suite", str(small), "--decider", "always-follow", "--out", str(out), "--no-progress"]) == 0
    for name in suites.suite_names():
        suites.check_memory(suites.load_suite(name))
