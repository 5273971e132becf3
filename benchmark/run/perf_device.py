"""The device rows of the performance report: ``overtakezoo perf --device cuda --out docs/perf-gpu``.

The batched core on the torch backend, sync-free, auto-resetting from a scenario bank on the device
(envs/core.py), beside the numpy core measured in the same run: env-steps/s at each N in float64 (the
per-scenario results of the CPU) and float32, and on a GPU the step captured in a CUDA graph
(envs/graph.py). Also what a step costs in launches: the aten operations one step dispatches
(counted on any device) and, on a GPU, the kernel launches the host makes per step (the CUDA runtime
calls in torch's profiler: one graph launch per step once captured). Each figure names its machine,
device, driver and torch version in the report's header.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from overtakezoo.benchmark.run.perf import Report, core_rates, windows
from overtakezoo.envs import OVERTAKE, EnvConfig, OvertakeCore, ScenarioDistribution

BANK = 65_536  # scenarios in the device bank (the batch cycles through them)
NUMPY_MAX_N = 65_536  # larger numpy batches only measure the machine's memory bandwidth, slowly
LAUNCH_CALLS = ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel", "cuLaunchKernelEx", "cudaGraphLaunch")


def device_meta(device: str) -> dict[str, Any]:
    """What the device rows ran on: torch, and the GPU, its driver and CUDA where there is one."""
    import torch

    meta: dict[str, Any] = {"device": device, "torch": torch.__version__}
    if device.startswith("cuda"):
        props = torch.cuda.get_device_properties(torch.device(device))
        meta.update(
            gpu=props.name,
            gpu_memory_gib=round(props.total_memory / 2**30, 1),
            cuda=torch.version.cuda,
            driver=_driver_version(),
        )
    return meta


def _driver_version() -> str | None:
    import subprocess

    try:
        out = subprocess.run(
            ["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=30,
        )
        return out.stdout.strip().splitlines()[0] if out.returncode == 0 and out.stdout.strip() else None
    except (OSError, subprocess.TimeoutExpired, IndexError):
        return None


def device_core(n: int, device: str, dtype: Any, seed: int = 0) -> tuple[OvertakeCore, Any]:
    """A sync-free torch core of N roads on ``device`` (auto-reset from a bank of min(N, BANK) of the
    env's default scenarios), reset; and its modes tensor (every row overtaking, as ``core-N``)."""
    import torch

    dist = ScenarioDistribution()
    bank = dist.sample(min(n, BANK), seed)
    core = OvertakeCore(
        EnvConfig(), auto_reset=True, bank=bank, backend="torch", device=device, dtype=dtype, sync_free=True
    )
    core.reset_from_bank(n)
    return core, torch.full((n,), OVERTAKE, dtype=torch.int64, device=device)


def _stepper(core: OvertakeCore, modes: Any, graph: bool, compile: bool = False) -> Callable[[], Any]:
    from overtakezoo.envs.graph import StaticStep

    static = StaticStep(core, modes, compile=compile)
    if graph:
        static.capture()
    return static.step


def device_rates(
    n: int, device: str, dtype: Any, seconds: float, repeats: int, graph: bool = False, compile: bool = False
) -> list[float]:
    """Env-steps/s of the device core at N (the device synchronised at each window's end)."""
    import torch

    core, modes = device_core(n, device, dtype)
    step = _stepper(core, modes, graph, compile)
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)

    def ten() -> int:
        for _ in range(10):
            step()
        sync()
        return 10 * n

    return windows(ten, seconds, repeats)


def ops_per_step(n: int, device: str, dtype: Any) -> int:
    """aten operations one sync-free step dispatches (each is about one kernel on a GPU)."""
    from torch.utils._python_dispatch import TorchDispatchMode

    class Count(TorchDispatchMode):
        ops = 0

        def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[no-untyped-def]
            Count.ops += 1
            return func(*args, **(kwargs or {}))

    core, modes = device_core(n, device, dtype)
    step = _stepper(core, modes, graph=False)
    with Count():
        step()
    return Count.ops


def launches_per_step(n: int, device: str, dtype: Any, graph: bool, compile: bool = False, steps: int = 10) -> float:
    """Kernel (or graph) launches the host makes per step on a GPU, from torch's profiler."""
    import torch
    from torch.profiler import ProfilerActivity, profile

    core, modes = device_core(n, device, dtype)
    step = _stepper(core, modes, graph, compile)
    torch.cuda.synchronize()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        for _ in range(steps):
            step()
        torch.cuda.synchronize()
    calls = sum(1 for e in prof.events() if e.name in LAUNCH_CALLS)
    return calls / steps


def add_device_rows(
    r: Report, meta: dict[str, Any], sizes: list[int], seconds: float, repeats: int, device: str, compile: bool = False
) -> None:
    """The device rows (module docstring) at each N of ``sizes``, with the numpy core's beside them;
    ``compile``: also the float32 step fused by torch.compile (and on a GPU, that captured in a graph)."""
    import torch

    meta["device"] = device_meta(device)
    cuda = device.startswith("cuda")
    dt = EnvConfig().dt
    label = meta["device"].get("gpu", "CPU") + f" ({device})"
    for n in sizes:
        if n <= NUMPY_MAX_N:
            r.add(
                f"core-{n}", f"numpy core on the CPU, N = {n}", "env-steps/s", core_rates(n, seconds, repeats), dt, n=n
            )
        for name, dtype in (("f64", torch.float64), ("f32", torch.float32)):
            r.add(
                f"core-torch-{name}-{n}",
                f"torch core, {name.replace('f', 'float')}, sync-free, bank auto-reset, {label}, N = {n}",
                "env-steps/s",
                device_rates(n, device, dtype, seconds, repeats),
                dt,
                n=n,
                **_peak_memory(cuda, device),
            )
            if cuda:
                r.add(
                    f"core-torch-{name}-graph-{n}",
                    f"the same step captured in a CUDA graph, {name.replace('f', 'float')}, {label}, N = {n}",
                    "env-steps/s",
                    device_rates(n, device, dtype, seconds, repeats, graph=True),
                    dt,
                    n=n,
                    **_peak_memory(cuda, device),
                )
        if compile:
            r.add(
                f"core-torch-f32-compiled-{n}",
                f"the float32 step fused by torch.compile{' and captured in a CUDA graph' if cuda else ''}, "
                f"{label}, N = {n}",
                "env-steps/s",
                device_rates(n, device, torch.float32, seconds, repeats, graph=cuda, compile=True),
                dt,
                n=n,
                **_peak_memory(cuda, device),
            )
    n = min(sizes)
    r.add(
        "ops-per-step",
        f"aten operations dispatched by one sync-free step (torch core, float32, N = {n})",
        "ops",
        [ops_per_step(n, device, torch.float32)],
    )
    if cuda:
        for graph, fused in ((False, False), (False, True), (True, True)):
            if fused and not compile:
                continue
            what = "compiled" if fused and not graph else "compiled, CUDA graph" if graph else "eager"
            r.add(
                "launches-per-step" + ("-compiled" if fused else "") + ("-graph" if graph else ""),
                f"host kernel launches per step, float32, N = {n} ({what})",
                "launches",
                [launches_per_step(n, device, torch.float32, graph, fused)],
                digits=1,
            )


def _peak_memory(cuda: bool, device: str) -> dict[str, Any]:
    if not cuda:
        return {}
    import torch

    peak = torch.cuda.max_memory_allocated(torch.device(device))
    torch.cuda.reset_peak_memory_stats(torch.device(device))
    torch.cuda.empty_cache()
    return {"peak_gpu_memory_gib": round(peak / 2**30, 2)}
