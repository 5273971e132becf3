"""`--device` / `--backend` on `leaderboard --verify`, `submit` and `crossplay`: the torch core (the GPU
path, here on the CPU) gives the numpy core's results, so each command prints and stores the same
bytes either way, still refuses a forgery, and a device that is not there is one error line before
anything runs (test_device.py holds `eval` to the same)."""

import json
import shutil

import pytest
from test_benchmark_cli import one_line_error

from overtakezoo.benchmark.cli import main
from overtakezoo.benchmark.results.metrics import summarize
from overtakezoo.benchmark.results.results import Results

torch = pytest.importorskip("torch")

TORCH = ["--backend", "torch", "--device", "cpu"]  # the GPU code path, on the CPU
no_gpu = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")


@pytest.fixture
def cores(monkeypatch):
    """The core each runner call ran on ("numpy" or "torch"), in order: proof that the flags reached it."""
    from overtakezoo.benchmark.run import runner

    seen, real = [], runner.core_backend

    def spy(device=None, backend=None):
        on = real(device, backend)
        seen.append(on["backend"])
        return on

    monkeypatch.setattr(runner, "core_backend", spy)
    return seen


def _ran_on(cores, backend):
    assert cores and set(cores) == {backend}, cores
    cores.clear()


def _eval(tmp_path, suite, decider, capsys):
    out = tmp_path / f"{decider}.results.json"
    argv = ["eval", "--suite", suite, "--decider", decider, "--out", str(out), "--no-progress"]
    assert main(argv) == 0
    capsys.readouterr()
    return out


# ------------------------------------------------------------------ leaderboard --verify
@pytest.fixture
def board(tiny, tmp_path, capsys):
    """A leaderboard of two built-in rows (rule-fsm, fuzzy) on the 12-scenario suite, filed on numpy."""
    root = tmp_path / "lb"
    for decider in ("rule-fsm", "fuzzy"):
        assert main(["submit", str(_eval(tmp_path, tiny, decider, capsys)), "--root", str(root)]) == 0
    capsys.readouterr()
    return root


def test_verify_on_the_torch_core_prints_the_same_lines_and_refuses_a_forgery(board, tiny, capsys, cores):
    argv = ["leaderboard", "--root", str(board), "--verify", "--seed", "3"]
    out = {}
    for backend, flags in (("numpy", []), ("torch", TORCH)):
        assert main([*argv, *flags]) == 0
        out[backend] = capsys.readouterr().out
        _ran_on(cores, backend)
    assert out["torch"] == out["numpy"]
    assert f"verified submissions/{tiny}/rule-fsm.json: 12 of 12 scenarios reproduce exactly" in out["torch"]
    assert "verified 2 row(s)" in out["torch"]

    # A consistent forgery (an outcome edited, the summary recomputed) is named the same on both cores.
    path = board / "submissions" / tiny / "fuzzy.json"
    r = Results.load(path)
    r.per["outcome"][5] = 1 if r.per["outcome"][5] != 1 else 2
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(path)
    errors = {backend: one_line_error(capsys, [*argv, *flags]) for backend, flags in (("numpy", []), ("torch", TORCH))}
    assert errors["torch"] == errors["numpy"]
    assert f"submissions/{tiny}/fuzzy.json: scenario 5: outcome: recorded" in errors["torch"]
    assert "torch" in cores


def test_verify_hands_the_core_to_its_worker_processes(board, tiny, capsys, cores, monkeypatch):
    """With --jobs > 1 each suite is verified in a worker: the device travels in its arguments (here the
    pool runs its work in this process, which sees the test's suite registry)."""
    import concurrent.futures

    class InProcess(concurrent.futures.ThreadPoolExecutor):
        def __init__(self, workers, mp_context=None):
            super().__init__(workers)

    monkeypatch.setattr(concurrent.futures, "ProcessPoolExecutor", InProcess)
    (board / "submissions" / "zz-empty").mkdir()  # a second suite folder: two suites, so the pool is used
    argv = ["leaderboard", "--root", str(board), "--verify", "--seed", "3", "--jobs", "2"]
    assert main([*argv, *TORCH]) == 0
    assert "verified 2 row(s)" in capsys.readouterr().out
    _ran_on(cores, "torch")


def test_device_flags_go_with_verify(board, capsys):
    base = ["leaderboard", "--root", str(board)]
    for flags in (["--device", "cuda"], ["--backend", "torch"], TORCH):
        assert "--device and --backend go with --verify" in one_line_error(capsys, [*base, *flags])
    assert main([*base, "--device", "cpu"]) == 0  # the default, said out loud: no refusal
    assert main([*base, "--check", "--backend", "numpy"]) == 0
    capsys.readouterr()


@no_gpu
def test_verify_on_cuda_without_a_gpu_is_one_line(board, capsys, cores):
    err = one_line_error(capsys, ["leaderboard", "--root", str(board), "--verify", "--device", "cuda"])
    assert "no CUDA device" in err
    assert not cores  # refused before anything ran


# ------------------------------------------------------------------ submit
@pytest.fixture
def fixed_fresh_seed(monkeypatch):
    """One fresh-draw seed for every submit, so rows filed on either core can be compared byte for byte."""
    from overtakezoo.benchmark.leaderboard import changes

    monkeypatch.setattr(changes, "fresh_seed", lambda: 424242)


def _submit_both(capsys, cores, tmp_path, argv, name, suite):
    rows = {}
    for backend, flags in (("numpy", []), ("torch", TORCH)):
        root = tmp_path / f"lb-{backend}"
        assert main([*argv, "--root", str(root), *flags]) == 0, capsys.readouterr().err
        capsys.readouterr()
        _ran_on(cores, backend)
        rows[backend] = (root / "submissions" / suite / f"{name}.json").read_bytes()
    return rows


def test_submit_a_builtin_row_on_the_torch_core_files_the_same_bytes(tiny, tmp_path, capsys, cores, fixed_fresh_seed):
    results = _eval(tmp_path, tiny, "rule-fsm", capsys)
    cores.clear()
    rows = _submit_both(capsys, cores, tmp_path, ["submit", str(results)], "rule-fsm", tiny)
    assert rows["torch"] == rows["numpy"]
    assert json.loads(rows["torch"])["submission"]["fresh"]["seed"] == 424242


def test_submit_a_policy_file_on_the_torch_core_files_the_same_bytes_and_refuses_a_forgery(
    tiny, tmp_path, capsys, cores, fixed_fresh_seed, learned_dir
):
    """A policy file is re-run on every scenario (and its fresh draw) in the sandbox, on the core the
    flags pick: the same row either way; results it did not produce are refused on either core."""
    mine = tmp_path / "run" / "mine.npz"
    mine.parent.mkdir()
    shutil.copy(learned_dir / "dqn.npz", mine)
    shutil.copy(learned_dir / "dqn.json", mine.with_suffix(".json"))
    results = tmp_path / "mine.results.json"
    assert main(["eval", "--policy", str(mine), "--suite", tiny, "--out", str(results), "--no-progress"]) == 0
    cores.clear()
    argv = ["submit", str(results), "--name", "my-dqn", "--policy", str(mine)]
    rows = _submit_both(capsys, cores, tmp_path, argv, "my-dqn", tiny)
    assert rows["torch"] == rows["numpy"]

    r = Results.load(results)
    r.per["outcome"][4] = 1 if r.per["outcome"][4] != 1 else 2
    r.summary = summarize(r.per, r.meta["seed"])
    r.save(tmp_path / "forged.json")
    argv = ["submit", str(tmp_path / "forged.json"), "--name", "forged", "--policy", str(mine)]
    errors = {
        backend: one_line_error(capsys, [*argv, "--root", str(tmp_path / "lb-forged"), *flags])
        for backend, flags in (("numpy", []), ("torch", TORCH))
    }
    assert errors["torch"] == errors["numpy"]
    assert "scenario 4: outcome: recorded" in errors["torch"] and "not produced by this policy" in errors["torch"]
    assert "torch" in cores
    assert not (tmp_path / "lb-forged" / "submissions" / tiny / "forged.json").exists()


@no_gpu
def test_submit_on_cuda_without_a_gpu_is_one_line(tiny, tmp_path, capsys, cores):
    results = _eval(tmp_path, tiny, "rule-fsm", capsys)
    cores.clear()
    root = tmp_path / "lb"
    err = one_line_error(capsys, ["submit", str(results), "--root", str(root), "--device", "cuda"])
    assert "no CUDA device" in err
    assert not cores and not root.exists()  # refused before anything ran or was written


# ------------------------------------------------------------------ crossplay
def test_crossplay_on_the_torch_core_writes_the_same_matrix_that_verifies(tmp_path, capsys, cores):
    """The same matrix bytes on either core; `leaderboard --verify` re-runs it on the torch core too."""
    data = {}
    for backend, flags in (("numpy", []), ("torch", TORCH)):
        root = tmp_path / backend
        argv = ["crossplay", "--suite", "duel", "--limit", "2", "--deciders", "rule-fsm,always-overtake"]
        assert main([*argv, "--root", str(root), *flags]) == 0
        _ran_on(cores, backend)
        data[backend] = (root / "crossplay" / "duel.json").read_bytes()
    assert data["torch"] == data["numpy"]
    capsys.readouterr()
    root = str(tmp_path / "numpy")
    assert main(["crossplay", "--suite", "duel", "--check", "--root", root, *TORCH]) == 0
    _ran_on(cores, "torch")
    assert main(["leaderboard", "--root", root, "--verify", "--seed", "3", "--only", "crossplay/duel", *TORCH]) == 0
    assert "verified crossplay/duel.json: 4 of 4 pairs reproduce exactly" in capsys.readouterr().out
    _ran_on(cores, "torch")


@no_gpu
def test_crossplay_on_cuda_without_a_gpu_is_one_line(tmp_path, capsys, cores):
    root = tmp_path / "lb"
    argv = ["crossplay", "--suite", "duel", "--limit", "2", "--deciders", "rule-fsm", "--root", str(root)]
    assert "no CUDA device" in one_line_error(capsys, [*argv, "--device", "cuda"])
    assert not cores and not root.exists()
