"""Ray-sharded runs merge into exactly the single-process results (skipped without Ray)."""

import re

import pytest

from overtakezoo import zoo
from overtakezoo.benchmark.run.distributed import run_suite_ray
from overtakezoo.benchmark.run.runner import run_suite
from overtakezoo.envs.suites import load_suite

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


@pytest.mark.parametrize("core", [None, {"backend": "torch", "device": "cpu"}])  # torch: a GPU worker's path
def test_ray_sharded_run_equals_the_single_process_run(tmp_path, local_ray, core):
    if core:
        pytest.importorskip("torch")
    text = load_suite("table1").path.read_text()
    small = tmp_path / "table1-small.toml"
    small.write_text(re.sub(r"(?m)^count = \d+", "count = 90", text))
    suite = load_suite(small)
    sharded = run_suite_ray(suite, "rule-fsm", shards=3, core=core)
    single = run_suite(suite, zoo.load("rule-fsm", config=suite.config), progress=False)
    assert sharded.without_timing() == single.without_timing()
    assert sharded.timing["shards"] == 3
