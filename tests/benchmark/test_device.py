"""`--device` / `--backend`: the torch core (the GPU path, here on the CPU) gives the numpy core's
per-scenario results bit for bit, so a row measured on a GPU verifies on a CPU; a device that is not
there is one error line before anything runs."""

import json

import numpy as np
import pytest
from test_benchmark_cli import one_line_error

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.run.policy import load_zoo
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.backend import core_backend
from overtakezoo.envs.suites import load_suite

torch = pytest.importorskip("torch")


@pytest.mark.parametrize(
    "suite_name, decider_name, count",
    [
        ("table1", "rule-fsm", 300),
        ("table1-reactive", "dqn", 300),  # a learned member; reactive NPCs
        ("dense", "fuzzy", 200),  # more oncoming cars, NPC-NPC contacts
        ("table1", "oracle", 30),  # privileged: it clones and steps the (torch) core itself
        ("duel", "ps-dqn", 150),  # two AVs per road (self-play)
    ],
)
def test_the_torch_core_gives_the_numpy_results(suite_name, decider_name, count):
    suite = load_suite(suite_name)
    runs = {}
    for backend in ("numpy", "torch"):
        decider = load_zoo(decider_name, suite.config)
        runs[backend] = run_suite(suite, decider, limit=count, progress=False, backend=backend, device="cpu")
    ref, got = runs["numpy"], runs["torch"]
    assert set(got.per) == set(ref.per)
    for key, value in ref.per.items():
        np.testing.assert_array_equal(got.per[key], value, err_msg=key)
    assert got.summary == ref.summary
    assert ref.per["outcome"].size == count * suite.num_avs


def test_eval_device_flags_write_the_same_file(tmp_path, capsys):
    out = {}
    for backend in ("numpy", "torch"):
        path = tmp_path / f"{backend}.json"
        argv = ["eval", "--suite", "table1", "--decider", "fuzzy", "--shard", "3/20", "--no-progress"]
        assert main([*argv, "--backend", backend, "--out", str(path)]) == 0
        out[backend] = json.loads(path.read_text())
    capsys.readouterr()
    for data in out.values():
        data.pop("timing")
    assert out["torch"] == out["numpy"]


@pytest.mark.parametrize(
    "flags, needle",
    [
        (["--device", "tpu"], "--device 'tpu': expected cpu, cuda or cuda:N"),
        (["--device", "cuda", "--backend", "numpy"], "the numpy core runs on the CPU"),
        (["--device", "cuda:99"], "--device cuda:99"),
    ],
)
def test_a_device_that_is_not_there_is_one_line(tmp_path, capsys, flags, needle):
    out = tmp_path / "r.json"
    err = one_line_error(capsys, ["eval", "--suite", "table1", "--decider", "fuzzy", "--out", str(out), *flags])
    assert needle in err
    assert not out.exists()


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_without_a_gpu_says_so(capsys):
    with pytest.raises(ValueError, match="sees no CUDA device"):
        core_backend("cuda")
    err = one_line_error(capsys, ["eval", "--suite", "table1", "--decider", "fuzzy", "--device", "cuda"])
    assert "no CUDA device" in err


def test_only_ppo_numpy_trains_on_a_device(tmp_path, capsys):
    argv = ["train", "dqn", "--backend", "torch", "--steps", "10", "--eval-suite", "none", "--out", str(tmp_path / "r")]
    assert "only ppo-numpy trains on a device" in one_line_error(capsys, argv)
    argv = ["train", "ppo-numpy", "--backend", "torch", "--seeds", "0,1", "--out", str(tmp_path / "s")]
    assert "--seeds with --device" in one_line_error(capsys, argv)


def test_make_vec_on_the_torch_core_steps_like_numpy():
    """The Gymnasium batch with ``backend="torch"`` (``device="cuda"`` on a GPU): numpy arrays out, the
    same observations, ends and autoresets; rewards equal to float rounding."""
    from overtakezoo.envs import make_vec

    ref, dev = make_vec(64, suite="table1"), make_vec(64, suite="table1", backend="torch")
    np.testing.assert_array_equal(dev.reset(seed=3)[0], ref.reset(seed=3)[0])
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(150):
        act = rng.integers(0, 3, 64)
        (o1, r1, te1, tr1, _), (o2, r2, te2, tr2, _) = ref.step(act), dev.step(act)
        assert isinstance(o2, np.ndarray)
        np.testing.assert_array_equal(o2, o1)
        np.testing.assert_allclose(r2, r1, atol=1e-12)
        np.testing.assert_array_equal(te2, te1)
        np.testing.assert_array_equal(tr2, tr1)
        ends += int(te1.sum() + tr1.sum())
    assert ends > 64  # rows ended and restarted


def test_eval_draw_runs_fresh_scenarios_of_the_distribution(tmp_path, capsys):
    """`eval --draw N --draw-seed S`: the suite's distribution and settings, N scenarios of seed S (what
    a GPU makes cheap at a million); without a seed one from fresh randomness, printed."""
    from overtakezoo.benchmark.leaderboard.fresh import fresh_suite

    out = tmp_path / "draw.json"
    argv = ["eval", "--suite", "table1", "--decider", "fuzzy", "--no-progress", "--draw", "64", "--draw-seed", "5"]
    assert main([*argv, "--out", str(out)]) == 0
    assert "a fresh draw of table1: 64 scenarios, seed 5" in capsys.readouterr().err
    data = json.loads(out.read_text())
    assert data["suite"]["count"] == 64 and data["seed"] == 5 and data["range"] == [0, 64]
    want = run_suite(fresh_suite(load_suite("table1"), 5, 64), load_zoo("fuzzy"), progress=False)
    assert data["scenarios"]["outcome"] == want.per["outcome"].tolist()
    base = ["eval", "--suite", "table1", "--decider", "fuzzy", "--out", str(tmp_path / "c.json")]
    assert main([*base, "--draw", "3"]) == 0
    assert "seed " in capsys.readouterr().err
    assert "--draw-seed: only with --draw" in one_line_error(capsys, [*base, "--draw-seed", "3"])
    assert "--draw 0" in one_line_error(capsys, [*base, "--draw", "0"])
