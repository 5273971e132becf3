"""The leaderboard's promise across machines: a row recorded on one CPU verifies on another.

The shipped rows were recorded on AMD EPYC machines; CI and users run on whatever x86-64 CPU they
get (an AVX-512 Xeon among them). What can differ between two CPUs is which float kernels run:
NumPy's SIMD dispatch (float64 sin/cos/arctan/expm1/tanh take other code paths with and without
AVX-512) and OpenBLAS's kernels (the learned members' matrix products). This re-runs shipped rows
with every NumPy dispatch target switched off (the baseline x86-64 code only) and OpenBLAS on its
Haswell (AVX2) kernels, and requires every per-scenario value to equal the recorded one.

The guarantee, as tested: the zoo's members act through NumPy in float64 on the float64 core, and
their per-scenario results do not depend on these kernels. An ONNX row runs through onnxruntime in
float32, whose kernels are chosen by the CPU itself; a decision there could flip on a near-tie of two
mode scores, and `leaderboard --verify` would then name the scenario.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def other_kernels() -> dict[str, str]:
    """Environment that moves NumPy to its baseline code (every dispatched SIMD target off) and
    OpenBLAS to its AVX2 kernels; torch (not used by `eval` or `verify`) to its scalar kernels."""
    try:
        from numpy._core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__
    except ImportError:  # NumPy 1.x
        from numpy.core._multiarray_umath import __cpu_baseline__, __cpu_dispatch__
    dispatched = [f for f in __cpu_dispatch__ if f not in __cpu_baseline__]
    return {
        **os.environ,
        "NPY_DISABLE_CPU_FEATURES": " ".join(dispatched),
        "OPENBLAS_CORETYPE": "Haswell",
        "ATEN_CPU_CAPABILITY": "default",
        "ONEDNN_MAX_CPU_ISA": "AVX2",
    }


PROBE = """
import json, threadpoolctl
try:
    from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
except ImportError:
    from numpy.core._multiarray_umath import __cpu_dispatch__, __cpu_features__
blas = [i.get("architecture") for i in threadpoolctl.threadpool_info() if i["user_api"] == "blas"]
print(json.dumps({"found": [f for f in __cpu_dispatch__ if __cpu_features__.get(f)], "blas": blas}))
"""


def test_other_kernels_are_really_in_force():
    import json

    seen = json.loads(
        subprocess.run(
            [sys.executable, "-c", PROBE], env=other_kernels(), capture_output=True, text=True, check=True
        ).stdout
    )
    assert seen == {"found": [], "blas": ["Haswell"]}


def test_shipped_rows_verify_under_other_cpu_kernels():
    # Every member's row on dense (the learned members' matrix products, the planner's trig on the
    # busiest suite), 5 scenarios each, under the other kernels. Measured once on the whole board
    # (225 rows, --sample 2 --seed 11) and on 18 suite x member runs of 500 scenarios: no value moved.
    cmd = [
        sys.executable,
        "-m",
        "overtakezoo.benchmark.cli",
        "leaderboard",
        "--verify",
        "--only",
        "dense/*",
        "--sample",
        "5",
        "--seed",
        "1204",
        "--base",
        "HEAD",
        "--root",
        str(REPO / "leaderboards"),
    ]
    res = subprocess.run(cmd, env=other_kernels(), capture_output=True, text=True, cwd=REPO, timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-2000:]
    verified = [line for line in res.stdout.splitlines() if line.startswith("verified submissions/dense/")]
    assert len(verified) == len(list((REPO / "leaderboards" / "submissions" / "dense").glob("*.json"))) > 10
