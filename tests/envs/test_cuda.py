"""The GPU path on a GPU (skipped where torch sees none; run by scripts/gpu-check.sh): the torch core
on CUDA gives the numpy core's per-scenario results, its step never waits for the device, the step
captured in a CUDA graph (and fused by torch.compile) steps like the core, and the device trainer
learns table1-train on every seed."""

import numpy as np
import pytest

from overtakezoo.envs import OvertakeCore, ScenarioDistribution

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


@pytest.mark.parametrize(
    "suite_name, decider_name, count",
    [("table1", "rule-fsm", 3000), ("table1-reactive", "dqn", 1000), ("dense", "fuzzy", 1000), ("duel", "ps-dqn", 500)],
)
def test_a_row_measured_on_the_gpu_is_the_cpu_row(suite_name, decider_name, count):
    from overtakezoo.benchmark.run.policy import load_zoo
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import load_suite

    suite = load_suite(suite_name)
    runs = {
        backend: run_suite(
            suite, load_zoo(decider_name, suite.config), limit=count, progress=False, backend=backend, device=device
        )
        for backend, device in (("numpy", "cpu"), ("torch", "cuda"))
    }
    for key, value in runs["numpy"].per.items():
        np.testing.assert_array_equal(runs["torch"].per[key], value, err_msg=key)


def _cores(n, dtype=torch.float64):
    dist = ScenarioDistribution(oncoming_count=2, follower_count=1, time_limit=6.0)
    bank = dist.sample(4 * n + 3, 3)
    ref = OvertakeCore(auto_reset=True, bank=bank)
    dev = OvertakeCore(auto_reset=True, bank=bank, backend="torch", device="cuda", dtype=dtype)
    ref.reset_from_bank(n), dev.reset_from_bank(n)
    return ref, dev


def test_the_cuda_step_never_waits_for_the_device():
    ref, dev = _cores(2048)
    assert dev.xp.sync_free
    modes = torch.ones(2048, dtype=torch.int64, device="cuda")
    torch.cuda.set_sync_debug_mode("error")  # any host read of a device value inside a step raises
    try:
        for _ in range(50):
            dev.step(modes)
    finally:
        torch.cuda.set_sync_debug_mode("default")
    for _ in range(50):
        ref.step(np.ones(2048, int))
    np.testing.assert_allclose(dev.x.cpu().numpy(), ref.x, atol=1e-9)
    np.testing.assert_array_equal(dev.outcome.cpu().numpy(), ref.outcome)


@pytest.mark.parametrize("compile", [False, True])
def test_the_captured_step_is_the_step(compile):
    from overtakezoo.envs.graph import StaticStep

    ref, dev = _cores(1024)
    modes = torch.ones(1024, dtype=torch.int64, device="cuda")
    static = StaticStep(dev, modes, compile=compile)
    static.capture()
    for _ in range(3 + compile + 1):  # warm-up, compiling, the side-stream step (a capture runs nothing)
        ref.step(np.ones(1024, int))
    for t in range(300):
        m = (np.arange(1024) + t) % 3
        modes.copy_(torch.as_tensor(m))
        got, want = static.step(), ref.step(m)
        np.testing.assert_allclose(got.obs.cpu().numpy(), want.obs, atol=1e-5)
        np.testing.assert_array_equal(got.terminated.cpu().numpy(), want.terminated)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_device_trainer_learns_on_the_gpu(tmp_path, seed):
    from overtakezoo.benchmark.suite_groups import load_training
    from overtakezoo.envs import CRASH, SUCCESS
    from overtakezoo.envs.hold import run_to_end
    from overtakezoo.zoo.train import fastppo

    suites = load_training("table1-train")
    trained = fastppo.train(suites, suite_name="table1-train", seed=seed, out=tmp_path, progress=False, device="cuda")
    held = suites[0].scenarios().take(np.arange(600, 1000))
    decider = trained.decider(suites[0].config)
    core = OvertakeCore(suites[0].config)
    run_to_end(core, core.reset(held), lambda o, _: decider.act_batch(o), 10)
    assert np.mean(core.outcome == SUCCESS) >= 0.85 and np.mean(core.outcome == CRASH) <= 0.05
