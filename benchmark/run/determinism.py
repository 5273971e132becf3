"""A stored policy decides each observation on its own, the same on every call; else it is refused.

``leaderboard --verify`` re-runs a row on a sample of its scenarios: other batches (sizes, row orders,
other rows beside them) than the run that recorded it. A policy whose decision for an observation
depends on the rest of its batch (a mean over the batch axis), or on the calls before (a random op,
seeded or not: its generator moves on with every call), gives the recorded numbers on the full run
and then fails a later sample, blocking every verification after it. So before a policy is filed
(``submit``) and whenever ``leaderboard --verify`` re-runs an artifact row:

- :func:`check_onnx_ops`: an ONNX graph (its subgraphs and local functions included) holds no random
  op: ``RandomNormal``, ``RandomNormalLike``, ``RandomUniform``, ``RandomUniformLike``,
  ``Multinomial``, ``Bernoulli``, any op of another domain named like one (or like a dropout),
  and no ``Dropout`` that may run in training mode (a ``training_mode`` input that is not the
  constant false; before opset 7, ``is_test`` not 1);
- :func:`check_deterministic`: the policy, acting in its sandbox, gives the same decisions for a
  fixed set of observations (the suite's first scenarios at their start and mid-episode) all at
  once, in chunks of 3, one by one, in a fixed shuffled order, and all at once again.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError

# The random ops of the ONNX standard (onnx.ai/onnx/operators): each draws new values on every call.
RANDOM_OPS = ("RandomNormal", "RandomNormalLike", "RandomUniform", "RandomUniformLike", "Multinomial", "Bernoulli")
_RANDOM_WORDS = (
    "random",
    "multinomial",
    "bernoulli",
    "dropout",
)  # in an op of another domain (com.microsoft's BiasDropout)
_STANDARD = ("", "ai.onnx")
PROBE_SCENARIOS = 16  # the suite's first scenarios whose observations are probed
PROBE_CHUNK = 3


def random_ops(model: bytes) -> list[str]:
    """The random ops of an ONNX model, each as ``"RandomUniform (node 'noise')"`` (graph order;
    subgraphs and the model's local functions included)."""
    import onnx

    from overtakezoo.benchmark.run.artifacts import subgraphs

    m = onnx.load_model_from_string(model)
    opset = next((o.version for o in m.opset_import if o.domain in _STANDARD), 0)
    found: list[str] = []
    bodies: list[tuple[Any, set[str], dict[str, Any]]] = [
        (m.graph.node, {i.name for i in m.graph.input}, _constants(m.graph.initializer, m.graph.node))
    ]
    bodies += [(f.node, set(f.input), _constants((), f.node)) for f in m.functions]
    while bodies:
        nodes, inputs, consts = bodies.pop(0)
        for node in nodes:
            label = f"{node.op_type} (node {node.name!r})" if node.name else node.op_type
            if node.domain in _STANDARD:
                if node.op_type in RANDOM_OPS or (
                    node.op_type == "Dropout" and _may_train(node, opset, inputs, consts)
                ):
                    found.append(label)
            elif any(w in node.op_type.lower() for w in _RANDOM_WORDS):
                found.append(f"{node.domain}.{label}")
            for g in subgraphs(node):  # If / Loop / Scan bodies see the outer graph's names
                bodies.append(
                    (g.node, inputs | {i.name for i in g.input}, {**consts, **_constants(g.initializer, g.node)})
                )
    return found


def _constants(initializers: Any, nodes: Any) -> dict[str, Any]:
    """The values of a graph's initializers and ``Constant`` nodes (by output name)."""
    from onnx import numpy_helper

    out: dict[str, Any] = {}
    for t in initializers:
        out[t.name] = t
    for node in nodes:
        if node.op_type == "Constant" and node.domain in _STANDARD and node.output:
            value = next((a.t for a in node.attribute if a.name == "value"), None)
            if value is not None:
                out[node.output[0]] = value
    return {k: _array(v, numpy_helper) for k, v in out.items()}


def _array(tensor: Any, numpy_helper: Any) -> np.ndarray | None:
    try:
        return numpy_helper.to_array(tensor)
    except Exception:  # noqa: BLE001 (external or malformed data: not a known constant)
        return None


def _may_train(node: Any, opset: int, inputs: set[str], consts: dict[str, Any]) -> bool:
    """Whether a standard Dropout node may drop at random: before opset 7 unless ``is_test`` is 1;
    from opset 12 when its ``training_mode`` input is given and is not the constant false (a graph
    input may be fed true)."""
    if 0 < opset < 7:
        return next((a.i for a in node.attribute if a.name == "is_test"), 0) != 1
    if len(node.input) < 3 or not node.input[2]:
        return False
    name = node.input[2]
    value = consts.get(name)
    return name in inputs or value is None or bool(np.any(value))


def check_onnx_ops(model: bytes, who: str) -> None:
    """:class:`UserError` naming the first random op of an ONNX model (:func:`random_ops`)."""
    try:
        found = random_ops(model)
    except ImportError:
        raise UserError(
            f"{who}: checking an ONNX policy for random ops needs onnx (pip install 'overtakezoo[onnx]')"
        ) from None
    except Exception as exc:  # noqa: BLE001 (a protobuf decode error, of any class)
        line = (str(exc).splitlines() or [type(exc).__name__])[0][:200]
        raise UserError(f"{who}: not a readable ONNX model: {line}") from None
    if found:
        more = f" (and {len(found) - 1} more)" if len(found) > 1 else ""
        raise UserError(
            f"{who}: the ONNX graph uses the random op {found[0]}{more}: a policy on the leaderboard "
            "must decide the same on every run; remove it (export in eval mode, without sampling)"
        )


def probe_observations(suite: Any, k: int = PROBE_SCENARIOS) -> np.ndarray:
    """Observations of the suite's first ``k`` scenarios (every AV's): at their start, after 3 s of
    mixed modes, and 5 s of overtaking later (float32, a fixed set for a given suite file)."""
    from overtakezoo.envs import OvertakeCore
    from overtakezoo.envs.hold import hold, hold_steps

    cfg = suite.config
    core = OvertakeCore(cfg)
    obs = [core.reset(suite.scenarios().take(slice(0, min(k, suite.count))))]
    n, step = obs[0].shape[0], hold_steps(cfg.decision_interval)
    for modes, seconds in ((np.arange(n) % 3, 3), (np.ones(n, np.int64), 5)):
        obs.append(hold(core, modes, max(1, int(round(seconds / cfg.dt / step))) * step).obs)
    return np.ascontiguousarray(np.concatenate(obs), np.float32)


def check_deterministic(
    act: Callable[[np.ndarray], np.ndarray], suite: Any, who: str, obs: np.ndarray | None = None
) -> None:
    """:class:`UserError` when ``act`` (observations -> modes, the sandboxed policy) decides the
    probe observations differently by batch size, row order or call, or fails on some of those
    calls only (``obs``: :func:`probe_observations` of ``suite``, when already drawn). A policy that
    fails on the whole batch is left to the run, which names the scenario and step."""
    from overtakezoo.benchmark.run.sandbox import PolicyFailure

    obs = probe_observations(suite) if obs is None else obs
    try:
        ref = np.asarray(act(obs))
    except PolicyFailure:
        return
    try:
        _compare_calls(act, obs, ref, who)
    except PolicyFailure as exc:
        raise UserError(
            f"{who}: not deterministic: decides the observations of the suite's first scenarios all at "
            f"once but fails on them in other batches: {exc}"
        ) from None


def _compare_calls(act: Callable[[np.ndarray], np.ndarray], obs: np.ndarray, ref: np.ndarray, who: str) -> None:
    n = obs.shape[0]
    perm = np.random.default_rng(0).permutation(n)  # a fixed shuffle
    inverse = np.argsort(perm)
    tries = [
        ("in chunks of 3", lambda: np.concatenate([act(obs[i : i + PROBE_CHUNK]) for i in range(0, n, PROBE_CHUNK)])),
        ("one at a time", lambda: np.concatenate([act(obs[i : i + 1]) for i in range(n)])),
        ("in another row order", lambda: np.asarray(act(obs[perm]))[inverse]),
        ("all at once, called again", lambda: np.asarray(act(obs))),
    ]
    for how, run in tries:
        got = run()
        bad = np.flatnonzero(got != ref)
        if bad.size:
            i = int(bad[0])
            raise UserError(
                f"{who}: not deterministic: observation {i} of {n} (of the suite's first scenarios) is "
                f"decided {int(ref[i])} when all {n} are decided at once and {int(got[i])} {how} "
                f"({bad.size} of {n} differ): a policy must decide each observation on its own, the same "
                "on every call, or its row fails later verifications (batch statistics, random ops)"
            )
