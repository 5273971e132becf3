"""`overtakezoo train ... --seeds`: one run per seed, on Ray or one after the other, the same bits."""

import hashlib
import importlib.util
import json

import pytest

from overtakezoo.benchmark.cli import main

ARGS = ["--steps", "3000", "--eval-suite", "none", "--no-progress", "--set", "learning_starts=500"]


def _shas(base, seeds, name="dqn"):
    return {
        s: {
            f: hashlib.sha256((base.with_name(f"{base.name}-s{s}") / f).read_bytes()).hexdigest()
            for f in (f"{name}.npz", f"{name}.pt")
        }
        for s in seeds
    }


@pytest.fixture(scope="module")
def sequential(tmp_path_factory):
    """A sweep of seeds 0 and 1 one after the other: its folder and what it printed."""
    import contextlib
    import io

    out, text = tmp_path_factory.mktemp("seq") / "dqn", io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(["train", "dqn", "--seeds", "0,1", "--engine", "sequential", "--out", str(out), *ARGS]) == 0
    return out, text.getvalue()


def test_a_sequential_sweep_writes_one_run_per_seed(sequential):
    out, text = sequential
    cards = [json.loads((out.with_name(f"dqn-s{s}") / "dqn.json").read_text()) for s in (0, 1)]
    assert [c["seed"] for c in cards] == [0, 1]
    shas = _shas(out, (0, 1))
    assert shas[0] != shas[1]  # different seeds, different networks
    assert text.count("trained dqn") == 2 and "dqn-s1" in text


@pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="needs ray (pip install -e '.[ray]')")
def test_a_ray_sweep_gives_the_same_files_as_the_sequential_one(sequential, tmp_path):
    par = tmp_path / "ray" / "dqn"
    assert main(["train", "dqn", "--seeds", "0,1", "--engine", "ray", "--out", str(par), *ARGS]) == 0
    assert _shas(sequential[0], (0, 1)) == _shas(par, (0, 1))


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--seeds", "0,x"], "expected integers"),
        (["--seeds", "0,0"], "distinct seeds"),
        (["--seeds", "0,1", "--seed", "3"], "without --seed"),
    ],
)
def test_bad_sweeps_are_one_error_line(tmp_path, capsys, argv, message):
    assert main(["train", "dqn", "--out", str(tmp_path / "d"), *argv, *ARGS]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and message in err and err.count("\n") == 1
