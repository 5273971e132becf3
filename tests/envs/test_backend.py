"""The torch backend runs the same model as numpy: equal results to float rounding."""

import numpy as np
import pytest

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, OvertakeCore, ScenarioDistribution

torch = pytest.importorskip("torch")


@pytest.mark.parametrize("n, lead", [(300, "idm"), (4, "speedup")])  # 4 rows: numpy's small-batch paths
def test_torch_backend_matches_numpy_step_for_step(n, lead):
    scenarios = ScenarioDistribution(oncoming_count=2, follower_count=1, lead_behaviour=lead).sample(n, 5)

    def policy(x, y):  # switches through all three modes
        return np.where(x < 20, FOLLOW, np.where(y > 3.0, ABORT, OVERTAKE))

    ref = OvertakeCore()
    tor = OvertakeCore(backend="torch", device="cpu")
    obs_ref, obs_tor = ref.reset(scenarios), tor.reset(scenarios)
    np.testing.assert_allclose(obs_tor.numpy(), obs_ref, atol=1e-6)
    for _ in range(250):
        r_ref = ref.step(policy(ref.x, ref.y))
        r_tor = tor.step(policy(tor.x.numpy(), tor.y.numpy()))
        if ref.done.all():
            break
    assert isinstance(tor.x, torch.Tensor)
    np.testing.assert_allclose(tor.x.numpy(), ref.x, atol=1e-9)
    np.testing.assert_allclose(tor.npc_s.numpy(), ref.npc_s, atol=1e-9)
    np.testing.assert_allclose(r_tor.obs.numpy(), r_ref.obs, atol=1e-5)
    np.testing.assert_array_equal(tor.outcome.numpy(), ref.outcome)
    np.testing.assert_array_equal(tor.crash_npc.numpy(), ref.crash_npc)


def test_torch_backend_auto_resets_rows():
    dist = ScenarioDistribution(time_limit=2.0)
    core = OvertakeCore(
        auto_reset=True, source=lambda n, rng: dist.sample(n, rng), seed=0, backend="torch", device="cpu"
    )
    core.reset(dist.sample(16, 1))
    ended = 0
    for _ in range(45):
        res = core.step(np.ones(16, int))
        ended += int(res.truncated.sum()) + int(res.terminated.sum())
    assert ended >= 16 and float(core.t.max()) < 2.0
