"""Conformance test for deciders, in the spirit of PettingZoo's ``pettingzoo.test`` utilities: run
:func:`check_decider` on your own decider before you submit it.

    from overtakezoo.zoo.testing import check_decider
    check_decider(MyDecider(config), config)

It drives the real simulator (observations of the environment's shape, each decision held as the
benchmark runner holds it) and raises ``AssertionError`` with a message naming the first rule broken:

- ``act`` on a batch (N, D) returns an (N,) integer array of modes in {0, 1, 2};
- ``act`` on one observation (D,) returns a Python ``int``, the same as that row of a batch;
- ``act`` on an empty batch (0, D) returns an empty (0,) integer array;
- ``reset(mask)`` (some rows) and ``reset()`` (all) are accepted and the batch form still works;
- the same scenarios give the same decisions after ``reset()`` (deterministic);
- ``name`` and ``version`` are strings and ``action_repeat`` is an int >= 1.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs import EnvConfig, OvertakeCore, ScenarioDistribution, observation_size
from overtakezoo.envs.hold import hold, hold_steps

MODES = (0, 1, 2)


def check_decider(
    decider: Any, config: EnvConfig | None = None, num: int = 8, decisions: int = 12, seed: int = 0
) -> None:
    """Raise ``AssertionError`` unless ``decider`` follows the decider protocol (module docstring)
    on ``num`` scenarios of ``config`` (default: the decider's own ``config``, else the default)
    for ``decisions`` decisions."""
    config = config or getattr(decider, "config", None) or EnvConfig()
    who = f"check_decider({getattr(decider, 'name', type(decider).__name__)!r})"
    _expect(hasattr(decider, "act") and callable(decider.act), f"{who}: no act(obs) method")
    _expect(callable(getattr(decider, "reset", None)), f"{who}: no reset(mask=None) method")
    _expect(
        isinstance(getattr(decider, "name", None), str) and decider.name,
        f"{who}: name must be a non-empty str, got {getattr(decider, 'name', None)!r}",
    )
    _expect(
        isinstance(getattr(decider, "version", None), str),
        f"{who}: version must be a str, got {getattr(decider, 'version', None)!r}",
    )
    repeat = getattr(decider, "action_repeat", 1)
    _expect(
        isinstance(repeat, (int, np.integer)) and not isinstance(repeat, bool) and repeat >= 1,
        f"{who}: action_repeat must be an int >= 1 (its decision rate: core steps each decision is held), "
        f"got {repeat!r}",
    )
    scenarios = ScenarioDistribution.from_dict(config.scenario).sample(num, seed)

    first = _rollout(decider, config, scenarios, decisions, who)
    again = _rollout(decider, config, scenarios, decisions, who)
    for k, (a, b) in enumerate(zip(first, again, strict=True)):
        _expect(
            np.array_equal(a, b),
            f"{who}: not deterministic: after reset() the same scenarios gave "
            f"different modes at decision {k} ({a.tolist()} vs {b.tolist()})",
        )

    # One observation (D,) -> a Python int, the same as row 0 of the batch at the first decision.
    _, obs = _start(decider, config, scenarios.take(slice(0, 1)))
    obs = obs[0]
    _expect(obs.shape == (observation_size(config),), f"{who}: internal: observation shape {obs.shape}")
    try:
        single = decider.act(obs)
    except Exception as exc:
        raise AssertionError(
            f"{who}: act(obs) with one observation of shape {obs.shape} raised {type(exc).__name__}: {exc}"
        ) from exc
    _expect(
        isinstance(single, int) and not isinstance(single, bool),
        f"{who}: act(obs) with one observation of shape {obs.shape} must return a Python int, got "
        f"{type(single).__name__} {np.shape(single)}",
    )
    _expect(single in MODES, f"{who}: act(obs) returned {single}, expected 0 (follow), 1 (overtake) or 2 (abort)")
    _expect(
        single == int(first[0][0]),
        f"{who}: act(obs[0]) = {single} but act(obs)[0] = {int(first[0][0])}: "
        "a row's decision must not depend on the other rows of the batch",
    )

    # An empty batch (0, D) -> an empty (0,) int array (a caller that passes only its live rows may have none).
    empty = _modes(decider, np.zeros((0, observation_size(config)), np.float32), who)
    _expect(empty.shape == (0,), f"{who}: act(obs) with an empty batch returned shape {empty.shape}, expected (0,)")

    # reset(mask) for finished rows, then the batch form still works on the same batch.
    _, obs = _start(decider, config, scenarios)
    _modes(decider, obs, who)
    mask = np.zeros(num, bool)
    mask[::2] = True
    for arg in (mask, None):
        try:
            decider.reset(arg)
        except Exception as exc:
            raise AssertionError(
                f"{who}: reset({'mask' if arg is not None else ''}) raised {type(exc).__name__}: {exc}"
            ) from exc
        _modes(decider, obs, who)


def _expect(ok: Any, message: str) -> None:
    if not ok:
        raise AssertionError(message)


def _start(decider: Any, config: EnvConfig, scenarios: Any) -> tuple[OvertakeCore, np.ndarray]:
    """A fresh core on ``scenarios`` and its first observation, the decider reset (and bound)."""
    core = OvertakeCore(config)
    obs = core.reset(scenarios)
    decider.reset()
    if getattr(decider, "privileged", False):
        decider.bind(core)
    return core, obs


def _modes(decider: Any, obs: np.ndarray, who: str) -> np.ndarray:
    try:
        modes = decider.act(obs)
    except Exception as exc:
        raise AssertionError(
            f"{who}: act(obs) with a batch of shape {obs.shape} raised {type(exc).__name__}: {exc}"
        ) from exc
    _expect(
        isinstance(modes, np.ndarray),
        f"{who}: act(obs) with a batch of shape {obs.shape} must return a numpy array, got {type(modes).__name__}",
    )
    _expect(
        modes.shape == (obs.shape[0],),
        f"{who}: act(obs) with a batch of shape {obs.shape} returned shape {modes.shape}, expected ({obs.shape[0]},)",
    )
    _expect(np.issubdtype(modes.dtype, np.integer), f"{who}: act(obs) returned dtype {modes.dtype}, expected integers")
    bad = modes[~np.isin(modes, MODES)]
    _expect(
        bad.size == 0,
        f"{who}: act(obs) returned mode {bad[:1].tolist()}, expected 0 (follow), 1 (overtake) or 2 (abort)",
    )
    return modes


def _rollout(decider: Any, config: EnvConfig, scenarios: Any, decisions: int, who: str) -> list[np.ndarray]:
    """The modes of ``decisions`` decisions on ``scenarios``, each held as the runner holds it."""
    core, obs = _start(decider, config, scenarios)
    steps = hold_steps(config.decision_interval, getattr(decider, "action_repeat", 1))
    out = []
    for _ in range(decisions):
        if core.done.all():
            break
        modes = _modes(decider, obs, who)
        out.append(modes.copy())
        obs = hold(core, modes, steps).obs
    return out
