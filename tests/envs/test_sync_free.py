"""The sync-free step (the GPU path, checked here on the CPU): no value is read back to the host
inside a step, auto-reset restarts rows from a scenario bank by masked writes, and the results are
the numpy core's (bit for bit where numpy runs the same bank path)."""

import numpy as np
import pytest

from overtakezoo.envs import FOLLOW, OvertakeCore, ScenarioDistribution

torch = pytest.importorskip("torch")
from torch.overrides import TorchFunctionMode  # noqa: E402

# Every way a tensor's value reaches the host (on a GPU each one waits for the device).
HOST_READS = {"__bool__", "item", "tolist", "nonzero", "__int__", "__float__", "__index__", "numpy", "argwhere"}


class HostReads(TorchFunctionMode):
    """Counts the torch calls that read a tensor's value on the host."""

    def __init__(self):
        super().__init__()
        self.seen = {}

    def __torch_function__(self, func, types, args=(), kwargs=None):
        name = getattr(func, "__name__", str(func))
        if name in HOST_READS:
            self.seen[name] = self.seen.get(name, 0) + 1
        return func(*args, **(kwargs or {}))


class InOrder:
    """A scenario source that hands out ``bank``'s scenarios in order, cycling: what the bank does."""

    def __init__(self, bank):
        self.bank, self.next = bank, 0

    def __call__(self, k, rng):
        idx = (self.next + np.arange(k)) % self.bank.num
        self.next = (self.next + k) % self.bank.num
        return self.bank.take(idx)


@pytest.mark.parametrize("lead", ["idm", "speedup"])
def test_bank_auto_reset_is_sync_free_and_matches_numpy(lead):
    dist = ScenarioDistribution(oncoming_count=2, follower_count=1, lead_behaviour=lead, time_limit=6.0)
    bank, batch = dist.sample(97, 3), dist.sample(64, 4)
    ref = OvertakeCore(auto_reset=True, source=InOrder(bank), seed=0)  # the host path
    same = OvertakeCore(auto_reset=True, bank=bank)  # the bank path on numpy
    dev = OvertakeCore(auto_reset=True, bank=bank, backend="torch", device="cpu", sync_free=True)
    for core in (ref, same, dev):
        core.reset(batch)
    rng = np.random.default_rng(0)
    ended = 0
    for _ in range(300):
        modes = rng.integers(0, 3, batch.num)  # every mode and every switch, so aborts and crashes happen
        r_ref, r_same = ref.step(modes), same.step(modes)
        with HostReads() as reads:
            r_dev = dev.step(torch.as_tensor(modes))
        assert reads.seen == {}, reads.seen
        ended += int(r_ref.finished.sum())
        for key in ("obs", "reward", "terminated", "truncated"):
            np.testing.assert_array_equal(getattr(r_same, key), getattr(r_ref, key), err_msg=key)
        done = r_ref.finished  # (the bank path hands out final_obs every step; the host path only when rows end)
        if done.any():
            np.testing.assert_array_equal(r_same.final_obs[done], r_ref.final_obs[done])
            np.testing.assert_allclose(r_dev.final_obs.numpy()[done], r_ref.final_obs[done], atol=1e-5)
        for key, value in r_ref.info.items():
            np.testing.assert_array_equal(r_same.info[key], value, err_msg=key)
            np.testing.assert_allclose(r_dev.info[key].numpy(), value, atol=1e-9, err_msg=key)
        np.testing.assert_allclose(r_dev.obs.numpy(), r_ref.obs, atol=1e-5)
        np.testing.assert_array_equal(r_dev.terminated.numpy(), r_ref.terminated)
    assert ended > 3 * batch.num  # rows restarted many times, cycling through the bank
    np.testing.assert_array_equal(dev.bank_row.numpy(), same.bank_row)


def test_sync_free_evaluation_matches_numpy():
    """Without auto-reset (how eval runs), the sync-free step freezes finished rows like numpy's."""
    scenarios = ScenarioDistribution(oncoming_count=3, follower_count=1).sample(200, 7)
    ref, dev = OvertakeCore(), OvertakeCore(backend="torch", device="cpu", sync_free=True)
    ref.reset(scenarios), dev.reset(scenarios)
    modes = np.where(np.arange(200) % 3 == 0, FOLLOW, 1)
    for _ in range(700):
        ref.step(modes)
        with HostReads() as reads:
            dev.step(torch.as_tensor(modes))
        assert reads.seen == {}
        if ref.done.all():
            break
    assert ref.done.all()
    np.testing.assert_array_equal(dev.outcome.numpy(), ref.outcome)
    np.testing.assert_array_equal(dev.crash_npc.numpy(), ref.crash_npc)
    np.testing.assert_allclose(dev.x.numpy(), ref.x, atol=1e-9)


def test_bank_needs_auto_reset_and_single_av_scenarios():
    bank = ScenarioDistribution().sample(4, 0)
    with pytest.raises(ValueError, match="auto_reset=True"):
        OvertakeCore(bank=bank)
    with pytest.raises(ValueError, match="no source"):
        OvertakeCore(auto_reset=True, bank=bank, source=lambda k, g: bank)


def test_static_step_keeps_every_state_buffer_and_steps_like_the_core():
    """What a CUDA graph replays: the step with its results copied back into the same tensors."""
    from overtakezoo.envs.graph import StaticStep

    dist = ScenarioDistribution(oncoming_count=2, follower_count=1, time_limit=6.0)
    bank, batch = dist.sample(97, 3), dist.sample(64, 4)
    ref = OvertakeCore(auto_reset=True, bank=bank)
    dev = OvertakeCore(auto_reset=True, bank=bank, backend="torch", device="cpu", sync_free=True)
    ref.reset(batch), dev.reset(batch)
    modes = torch.ones(batch.num, dtype=torch.int64)
    for _ in range(3):  # StaticStep's warm-up steps
        ref.step(np.ones(batch.num, int))
    static = StaticStep(dev, modes)
    buffers = {name: id(value) for name, value in vars(dev).items() if isinstance(value, torch.Tensor)}
    for t in range(300):
        m = (np.arange(batch.num) + t) % 3
        modes.copy_(torch.as_tensor(m))
        got, want = static.step(), ref.step(m)
        np.testing.assert_allclose(got.obs.numpy(), want.obs, atol=1e-5)
        np.testing.assert_array_equal(got.terminated.numpy(), want.terminated)
    assert {name: id(getattr(dev, name)) for name in buffers} == buffers
    np.testing.assert_allclose(dev.x.numpy(), ref.x, atol=1e-9)
    with pytest.raises(ValueError, match="sync-free torch core"):
        StaticStep(ref, modes)


@pytest.mark.slow  # (compiling the step takes about half a minute)
def test_the_compiled_step_is_the_eager_step():
    """torch.compile traces the whole step as one graph (fullgraph: no data-dependent branch) and it
    computes what the numpy core does."""
    from overtakezoo.envs.graph import StaticStep

    dist = ScenarioDistribution(oncoming_count=2, follower_count=1, time_limit=6.0)
    bank, batch = dist.sample(97, 3), dist.sample(64, 4)
    ref = OvertakeCore(auto_reset=True, bank=bank)
    dev = OvertakeCore(auto_reset=True, bank=bank, backend="torch", device="cpu", sync_free=True)
    ref.reset(batch), dev.reset(batch)
    modes = torch.ones(batch.num, dtype=torch.int64)
    for _ in range(4):  # StaticStep's three warm-up steps and the compiling one
        ref.step(np.ones(batch.num, int))
    static = StaticStep(dev, modes, compile=True)
    for t in range(200):
        m = (np.arange(batch.num) + t) % 3
        modes.copy_(torch.as_tensor(m))
        got, want = static.step(), ref.step(m)
        np.testing.assert_allclose(got.obs.numpy(), want.obs, atol=1e-5)
        np.testing.assert_array_equal(got.terminated.numpy(), want.terminated)
    np.testing.assert_array_equal(dev.outcome.numpy(), ref.outcome)
