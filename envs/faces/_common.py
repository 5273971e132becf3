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


def suite_config(config: Any = None, suite: Any = None) -> EnvConfig | dict[str, Any] | None:
    """The config of a loaded suite (anything with an :class:`EnvConfig` ``config``, passed as
    ``suite`` or as ``config``; a built-in suite's name or a suite file's path is loaded), else
    ``config`` unchanged."""
    if suite is None and (isinstance(config, str) or isinstance(getattr(config, "config", None), EnvConfig)):
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
        raise ConfigError(f"scenario: {face} drives one automated vehicle per road, this distribution has "
                          f"{dist.platoon_size + dist.oncoming_av} (platoon_size, oncoming_av); "
                          "use parallel_env, whose agents are the road's AVs")
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


def check_actions(actions: Any, num: int, who: str, n: int = len(MODE_NAMES)) -> np.ndarray:
    """A batch of ``num`` actions as int64, each an integer in ``range(n)``; else a ValueError naming
    the first bad entry ``who[i]``."""
    arr = np.asarray(actions)
    if arr.shape != (num,):
        raise ValueError(f"{who}: expected shape ({num},), got {arr.shape}")
    if arr.dtype.kind not in "iu":
        raise ValueError(f"{who}: expected integers in 0..{n - 1}, got dtype {arr.dtype}")
    bad = np.flatnonzero((arr < 0) | (arr >= n))
    if len(bad):
        raise ValueError(f"{who}[{bad[0]}]: action {arr[bad[0]].item()!r} is not an integer in 0..{n - 1}")
    return arr.astype(np.int64, copy=False)


def row_info(info: dict[str, np.ndarray], row: int) -> dict[str, Any]:
    """Per-row core info as plain Python values (the per-agent ``infos`` entry). An undefined
    value (``completion_time`` before a success, NaN in the core) becomes ``None`` so that two equal
    infos compare equal."""
    out = {}
    for key, values in info.items():
        if key[0] != "_":
            value = values.item(row)
            out[key] = None if value != value else value  # value != value: NaN
    out["outcome_name"] = OUTCOME_NAMES[out["outcome"]]
    return out


def env_hold(hold_steps: Any, config: EnvConfig) -> int:
    """Core steps one env step holds an action: ``hold_steps`` (a positive multiple of the config's
    ``decision_interval``), or ``decision_interval`` when None; else a :class:`ConfigError`."""
    interval = config.decision_interval
    if hold_steps is None:
        return interval
    if isinstance(hold_steps, (bool, np.bool_)) or not isinstance(hold_steps, (int, np.integer)) or hold_steps < 1:
        raise ConfigError(f"hold_steps: expected a positive integer (core steps per env step), got {hold_steps!r}")
    if hold_steps % interval:
        raise ConfigError(f"hold_steps: {hold_steps} is not a multiple of decision_interval {interval}")
    return int(hold_steps)
