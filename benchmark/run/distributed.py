"""Fan a suite's shards over a Ray cluster and merge them into one results file.

The merged file equals the single-process run apart from ``timing``: every shard runs the same
deterministic code on its own contiguous slice, and :func:`~.results.merge` checks that the shards
agree on suite, decider and package before concatenating them.

Point it at a real cluster with ``overtakezoo eval --suite table1 --decider dqn --ray ray://HEAD:10001``
(or ``--ray auto`` on a cluster node); without an address a local Ray instance is started. Every
worker needs OvertakeZoo installed (same version); the suite file travels with the task, so a
user's own suite file needs no shared filesystem.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import Results, merge
from overtakezoo.envs.suites import Suite


def _run_shard(
    suite_bytes: bytes, suite_path: str, decider_name: str, shard: tuple[int, int], core: dict[str, Any] | None = None
) -> str:
    """One shard on a Ray worker; returns the results as JSON text. ``decider_name`` is any policy
    spec (``benchmark/run/policy.py``): a registry name, a file or package.module:factory; ``core``:
    the core's backend and device (a GPU task's device is the GPU Ray gave it)."""
    from overtakezoo.benchmark.run.policy import load_policy
    from overtakezoo.benchmark.run.runner import run_suite
    from overtakezoo.envs.suites import parse_suite

    suite = parse_suite(suite_bytes, Path(suite_path))
    decider = load_policy(decider_name, suite.config)
    return run_suite(suite, decider, shard=shard, progress=False, **(core or {})).to_json()


def run_suite_ray(
    suite: Suite,
    decider_name: str,
    shards: int,
    address: str | None = None,
    num_cpus: int | None = None,
    core: dict[str, Any] | None = None,
) -> Results:
    """Run ``suite`` as ``shards`` Ray tasks and merge them. ``address`` None starts a local Ray.
    ``core`` (``backend``, ``device``): on a CUDA device each task asks Ray for one GPU."""
    try:
        import ray
    except ImportError:
        raise UserError("--ray needs Ray: pip install -e '.[ray]'") from None
    if shards < 1 or shards > suite.count:
        raise UserError(f"--shards {shards}: must be between 1 and the suite's {suite.count} scenarios")
    started_here = not ray.is_initialized()
    if started_here:
        try:
            ray.init(
                address=address,
                num_cpus=num_cpus if address is None else None,
                include_dashboard=False,
                log_to_driver=False,
                configure_logging=False,
            )
        except (ConnectionError, ValueError, RuntimeError) as exc:
            raise UserError(f"cannot reach Ray at {address or 'a local instance'}: {exc}") from None
    try:
        on_gpu = str((core or {}).get("device") or "").startswith("cuda")
        task = ray.remote(num_gpus=1)(_run_shard) if on_gpu else ray.remote(_run_shard)
        data = suite.path.read_bytes()
        refs = [task.remote(data, str(suite.path), decider_name, (i, shards), core) for i in range(shards)]
        parts = [Results.from_json(text, where=f"shard {i}") for i, text in enumerate(ray.get(refs))]
    finally:
        if started_here:
            ray.shutdown()
    return merge(parts)


def parse_address(value: Any) -> str | None:
    """``--ray`` with no value means a local instance."""
    return None if value in (None, "", "local") else str(value)
