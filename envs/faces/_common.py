"""What every face shares: reading a config or a suite, the single-ego check, action checks and per-row info."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from overtakezoo.envs.config import MODE_NAMES, ConfigError, EnvConfig
from overtakezoo.envs.core import OUTCOME_NAMES
from overtakezoo.envs.scenarios import ScenarioDistribution


def as_config(config: EnvConfig | dict[str, Any] | None = None, **overrides: Any) -> EnvConfig:
    """One validated :class:`EnvConfig` from a config object or dict plus keyword overrides
    (unknown keys raise :class:`ConfigError` naming the key)."""
    if isinstance(config, EnvConfig):
        if not overrides:
            return config
        config = dataclasses.asdict(config)
    if config is not None and not isinstance(config, dict):
        raise ConfigError(f"config: expected an EnvConfig or a dict, got {type(config).__name__}")
    return EnvConfig.from_dict(config, **overrides)


def is_suite(config: Any = None, suite: Any = None) -> bool:
    """Whether a face is made from a suite (``suite=``, a suite's name or path, or a loaded suite
    passed as ``config``) rather than from a raw config: :func:`env_hold`'s default differs."""
    return suite is not None or isinstance(config, str) or isinstance(getattr(config, "config", None), EnvConfig)


def suite_config(config: Any = None, suite: Any = None) -> EnvConfig | dict[str, Any] | None:
    """The config of a loaded suite (anything with an :class:`EnvConfig` ``config``, passed as
    ``suite`` or as ``config``; a built-in suite's name or a suite file's path is loaded), else
    ``config`` unchanged."""
    if suite is None and is_suite(config):
        config, suite = None, config
    if suite is None:
        return config
    if config is not None:
        raise ConfigError("suite: pass either a config or a suite, not both (override keys as keywords)")
    if isinstance(suite, str):
        from overtakezoo.envs.suites import load_suite

        suite = load_suite(suite)
    if not isinstance(getattr(suite, "config", None), EnvConfig):
        raise ConfigError(f"suite: expected a loaded suite (with an EnvConfig .config), got {type(suite).__name__}")
    return suite.config


def single_ego(config: EnvConfig, face: str) -> EnvConfig:
    """The Gymnasium faces drive one AV per scenario and no NPC agents: say so instead of ignoring."""
    dist = ScenarioDistribution.from_dict(config.scenario)
    if dist.platoon_size > 1 or dist.oncoming_av:
        raise ConfigError(
            f"scenario: {face} drives one automated vehicle per road, this distribution has "
            f"{dist.platoon_size + dist.oncoming_av} (platoon_size, oncoming_av); "
            "use parallel_env, whose agents are the road's AVs"
        )
    if config.npc_agents:
        raise ConfigError(f"npc_agents: {face} has no NPC agents; use parallel_env(npc_agents=True)")
    return config


def check_action(action: Any, n: int, who: str) -> int:
    """``action`` as an int in ``range(n)``; a ValueError naming ``who`` (the agent) for anything else:
    a float, a bool, a negative or too large index (NumPy would wrap -1 round to the last choice)."""
    value = action.item() if isinstance(action, np.ndarray) and action.ndim == 0 else action
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 0 <= value < n:
        shown = action.item() if isinstance(action, np.generic) else action
        raise ValueError(f"{who}: action {shown!r} is not an integer in 0..{n - 1}")
    return int(value)


def check_actions(actions: Any, num: int, who: str, n: int = len(MODE_NAMES), whole_floats: bool = False) -> np.ndarray:
    """A batch of ``num`` actions as int64, each an integer in ``range(n)``; else a ValueError naming
    the first bad entry ``who[i]``, in the words of :func:`check_action`. Floats are refused (as the
    single-action faces refuse ``1.0``) unless ``whole_floats``: a face whose trainer samples the index
    as a float (rsl-rl's action column) takes ``1.0``, never ``1.7``, NaN or an infinity."""
    arr = np.asarray(actions)
    if arr.shape != (num,):
        raise ValueError(f"{who}: expected shape ({num},), got {arr.shape}")
    kind = arr.dtype.kind
    if kind in "iu":
        ok = (arr >= 0) & (arr < n)
    elif kind == "f":
        ok = (arr >= 0) & (arr < n) & (arr == np.floor(arr))  # NaN fails every comparison
        if not whole_floats and num and ok.all():  # refused: name the first entry that is no index, else the first
            ok[0] = False
    else:
        raise ValueError(f"{who}: expected integers in 0..{n - 1}, got dtype {arr.dtype}")
    if not ok.all():
        i = int(np.argmin(ok))
        shown = str(arr[i]) if kind == "f" else repr(arr[i].item())  # str: 1.7 for a float32 1.7, not 1.70000005
        raise ValueError(f"{who}[{i}]: action {shown} is not an integer in 0..{n - 1}")
    return arr.astype(np.int64, copy=False)


def row_info(info: dict[str, np.ndarray], row: int) -> dict[str, Any]:
    """Per-row core info as plain Python values (the per-agent ``infos`` entry). An undefined
    value (``completion_time`` before a success, NaN in the core) becomes ``None`` so that two equal
    infos compare equal."""
    out: dict[str, Any] = {}
    for key, values in info.items():
        if key[0] != "_":
            value = values.item(row)
            out[key] = None if value != value else value  # value != value: NaN
    out["outcome_name"] = OUTCOME_NAMES[out["outcome"]]
    return out


def env_hold(hold_steps: Any, config: EnvConfig, from_suite: bool = False) -> int:
    """Core steps one env step holds an action: ``hold_steps`` (a positive multiple of the config's
    ``decision_interval``) when given; else, for a face made from a suite (``from_suite``,
    :func:`is_suite`), the zoo's 1 s at the config's dt, what the suite's registered id holds
    (:func:`~overtakezoo.envs.suites.zoo_hold`: 10 at dt = 0.1 s), and for a face made from a raw
    config its ``decision_interval``. Anything else is a :class:`ConfigError`."""
    interval = config.decision_interval
    if hold_steps is None:
        if from_suite:
            from overtakezoo.envs.suites import zoo_hold

            return zoo_hold(config.dt, interval)
        return interval
    if isinstance(hold_steps, (bool, np.bool_)) or not isinstance(hold_steps, (int, np.integer)) or hold_steps < 1:
        raise ConfigError(f"hold_steps: expected a positive integer (core steps per env step), got {hold_steps!r}")
    if hold_steps % interval:
        raise ConfigError(f"hold_steps: {hold_steps} is not a multiple of decision_interval {interval}")
    return int(hold_steps)
