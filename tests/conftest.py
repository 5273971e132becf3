"""Shared test setup: one fixed Hypothesis profile for every run (CI and local).

Derandomized (the examples follow from each test's source, not from a random seed) with no example
database, so ``python -m pytest`` on a fresh clone tries the same inputs every time: a fuzz test
either always passes or always fails. ``print_blob`` prints a failing example's reproduction blob.
Tests may still set their own ``max_examples`` with ``@settings``; the rest comes from here.
"""

from hypothesis import HealthCheck, settings

settings.register_profile(
    "overtakezoo",
    derandomize=True,
    database=None,
    max_examples=100,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow],
)
settings.load_profile("overtakezoo")


# ----------------------------------------------------------------------------- learned members
import json  # noqa: E402
import threading  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from overtakezoo import zoo  # noqa: E402
from overtakezoo.envs import suites as suites_module  # noqa: E402

LEARNED = tuple(zoo.names("learned"))  # the registry's list: dqn, double-dqn, ps-dqn, ppo, bc, cql
PRETRAINED = Path(__file__).resolve().parents[1] / "zoo" / "pretrained"


def write_random_member(directory: Path, name: str, seed: int = 0, hidden: tuple[int, ...] = (16, 16)) -> Path:
    """A learned member with seeded random weights, in the shipped format (``<name>.npz`` + card),
    for the current observation size: protocol tests that do not depend on trained weights."""
    from overtakezoo.envs import EnvConfig, observation_size
    from overtakezoo.zoo.members.features import FEATURES_VERSION
    from overtakezoo.zoo.members.mlp import NumpyMLP, npz_bytes
    from overtakezoo.zoo.train.export import exported_card

    rng = np.random.default_rng(seed)
    ppo = name == "ppo"
    widths = [observation_size(EnvConfig()), *hidden, 3 if ppo else 4]
    layers = tuple(
        (rng.normal(0, 1 / np.sqrt(i), (o, i)), rng.normal(0, 0.1, o)) for i, o in zip(widths, widths[1:], strict=False)
    )
    net = NumpyMLP(layers, "elu" if ppo else "relu", dueling=not ppo)
    card = {
        "name": name,
        "version": "1",
        "features": FEATURES_VERSION,
        "action_repeat": 10,
        "action_mask": not ppo,
        "action_mask_version": 3,
        "seed": seed,
        "steps": 0,
        "architecture": {"obs_dim": widths[0], "hidden": list(hidden)},
        "weights_file": f"{name}.pt",
        "weights_sha256": "0" * 64,
    }  # as a trainer's card, before export
    npz = npz_bytes(net.arrays())
    directory.mkdir(parents=True, exist_ok=True)
    (directory / f"{name}.npz").write_bytes(npz)
    (directory / f"{name}.json").write_text(json.dumps(exported_card(card, net, npz, name), indent=1))
    return directory / f"{name}.json"


@pytest.fixture(scope="session")
def learned_dir(tmp_path_factory) -> Path:
    """A directory with random-weight dqn, double-dqn and ppo members (``zoo.load(name, directory=...)``)."""
    d = tmp_path_factory.mktemp("learned")
    for i, name in enumerate(LEARNED):
        write_random_member(d, name, seed=i)
    return d


def shipped_as_runs(directory: Path, member: str = "dqn", seeds: tuple[int, ...] = (0, 1, 2)) -> list[Path]:
    """The shipped ``member``'s weights as one `overtakezoo train` output per seed (``<member>-s<seed>``),
    its card naming the seed: what `overtakezoo seeds` reads."""
    from overtakezoo.benchmark.leaderboard.seeds import export_shipped

    runs = []
    for seed in seeds:
        run = directory / f"{member}-s{seed}"
        export_shipped(member, run)
        card = json.loads((run / f"{member}.json").read_text())
        (run / f"{member}.json").write_text(json.dumps({**card, "seed": seed}))
        runs.append(run)
    return runs


def shipped_weights_current(name: str) -> bool:
    """Whether the shipped ``zoo/pretrained/<name>`` takes the current observation (weights trained
    before observation v2 take 32 features; retrained ones ship at integration)."""
    from overtakezoo.envs import EnvConfig, observation_size

    card = json.loads((PRETRAINED / f"{name}.json").read_text())
    return card["architecture"]["obs_dim"] == observation_size(EnvConfig())


# Tests of the shipped weights' behaviour: skipped while the shipped weights predate observation v2.
needs_shipped_weights = pytest.mark.skipif(
    not all(shipped_weights_current(n) for n in LEARNED),
    reason="the shipped weights take 32 features, the observation has 33: retrained weights ship at integration",
)


@pytest.fixture(autouse=True)
def seeded_fresh_draws(monkeypatch):
    """The seeds `submit` and `verify` take from fresh randomness (a row's fresh draw, the sample, verify's
    own draw) come from a seeded generator in tests: each still differs from the last, and a test
    replays bit for bit."""
    from overtakezoo.benchmark.leaderboard import changes, verify

    rng = np.random.default_rng(20261204)
    draw = lambda: int(rng.integers(0, 2**63 - 1))  # noqa: E731
    monkeypatch.setattr(changes, "fresh_seed", draw)
    monkeypatch.setattr(verify, "fresh_seed", draw)


BUILTIN_SUITES = suites_module.SUITES_DIR  # (tiny_suite points the registry elsewhere; the texts stay these)


def suite_text(base: str = "table1", **settings: Any) -> str:
    """A built-in suite file's text with top-level settings replaced, as TOML values: ``name="tiny"``,
    ``count=6``, ``time_limit=20.0``, ``decision_interval=5``, ``lead_gap=[8.0, 30.0]`` (each key must be
    in the file once). The one way tests shorten a suite."""
    import re

    text = (BUILTIN_SUITES / f"{base}.toml").read_text()
    for key, value in settings.items():
        text, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {json.dumps(value)}", text)
        assert n == 1, f"{base}.toml: {key} set {n} times"
    return text


def suite_file(path: Path, count: int, base: str = "table1", **settings: Any) -> Path:
    """``base``'s first ``count`` scenarios as a suite file at ``path`` (a user's own suite, given by
    path), named after the file."""
    path.write_text(suite_text(base, name=path.stem, count=count, **settings))
    return path


@pytest.fixture
def tiny_suite(tmp_path, monkeypatch):
    """``tiny_suite(count)``: the name of a built-in suite of ``count`` short table1 scenarios (the
    suite registry points at tmp_path: a leaderboard row needs a built-in suite); eval, submit, the
    policy loader and verify are the real ones. ``base`` names another suite to shorten, and
    ``time_limit`` (default 20 s: no scenario can succeed) the episodes' length."""
    from overtakezoo.envs import suites

    def make(count: int, base: str = "table1", time_limit: float = 20.0) -> str:
        builtin = tmp_path / "suites"
        builtin.mkdir(exist_ok=True)
        (builtin / "tiny.toml").write_text(suite_text(base, name="tiny", count=count, time_limit=time_limit))
        monkeypatch.setattr(suites, "SUITES_DIR", builtin)
        return "tiny"

    return make


@pytest.fixture
def tiny(tiny_suite):
    """A built-in suite of 12 short scenarios (submit needs a built-in suite)."""
    return tiny_suite(12)


@pytest.fixture
def one_torch_thread():
    """Small networks run fastest on one thread (and the machine is shared); restored afterwards."""
    torch = pytest.importorskip("torch")
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def last_error_line(capsys, argv):
    """The one ``error:`` line a refused command prints, last (after any lines saying the hold)."""
    from overtakezoo.benchmark.cli import main

    capsys.readouterr()
    assert main(argv) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1 and lines[-1] == errors[0], lines
    return errors[0]


@pytest.fixture
def home(tmp_path, monkeypatch):
    """A private dataset cache dir and an empty registry (tests of datasets)."""
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.setenv("OVERTAKEZOO_REGISTRY", str(tmp_path / "registry.json"))
    (tmp_path / "registry.json").write_text(json.dumps({"datasets": {}}))
    return tmp_path


# ------------------------------------------------------------------ file-safety helpers (envs/io.py)
def leftovers(folder):
    """Temp files the writers would leave beside their targets."""
    return sorted(p.name for p in folder.iterdir() if ".tmp-" in p.name or ".old-" in p.name)


def read_fifo(path, into):
    """Read a FIFO to its end in a thread (a FIFO's writer blocks until a reader opens it)."""

    def run():
        with open(path, "rb") as f:
            into.append(f.read())

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t
