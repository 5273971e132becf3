"""The PettingZoo face of the core: ``parallel_env(**config)`` and its AEC version ``env(**config)``.

A thin adapter over one :class:`~.core.OvertakeCore` with ``N = num_egos`` rows and
``auto_reset=False`` (a finished row is held; its agent leaves ``agents``).

Agents:

- ``ego_0 .. ego_{E-1}``: one per row. The egos drive in *parallel, independent* scenarios (rows
  never interact), each drawn from the config's ``scenario`` distribution; ``reset(seed=s)`` draws
  the batch ``ScenarioDistribution.sample(E, s)``, so ego ``i`` gets the same scenario as row ``i``
  of a suite with that seed. They are meant to share one policy (same spaces, same reward).
  Action ``Discrete(3)``: 0 follow, 1 overtake, 2 abort. Observation: the core's vector
  (``observation_layout``), a ``Box`` of finite bounds derived from the config (envs/spaces.py).
- with ``npc_agents=True`` also ``npc_0 .. npc_{M-1}``: the NPC slots of ``ego_0``'s scenario
  (slot 0 is NPC1, the lead; then the oncoming vehicles; then the followers). Action
  ``Discrete(4)``: an acceleration from :data:`NPC_ACCELERATIONS` (m/s^2; the core clips it to the
  IDM limits), applied instead of IDM. Observation (:data:`NPC_OBS_SIZE` floats): own speed, own
  lane, distance to the ego along the NPC's own direction of travel (positive: ego ahead), the
  closing speed to the ego, the ego's lateral offset from the NPC's lane centre, presence.
  Reward: adversarial, zero-sum with ``ego_0`` (each NPC receives ``-reward(ego_0)``), so an
  NPC population is a stress test of the ego policy. NPC agents end when ``ego_0``'s episode ends.

``reset(options={"scenarios": Scenarios})`` starts on given scenarios (E rows) instead of a draw.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from .config import MODE_NAMES, ConfigError, EnvConfig
from .core import OUTCOME_NAMES, OvertakeCore
from .face_render import RendersFirstRow
from .hold import hold
from .scenarios import OPPOSITE_LANE, ScenarioDistribution, Scenarios
from .spaces import ego_observation_space, npc_observation_space, npc_start_extent

NPC_ACCELERATIONS = np.array([-4.0, -2.0, 0.0, 1.0])  # m/s^2, the NPC agents' discrete choices
NPC_OBS_SIZE = 6


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


def single_ego(config: EnvConfig, face: str) -> EnvConfig:
    """The Gymnasium faces drive one ego per scenario and no NPC agents: say so instead of ignoring."""
    if config.num_egos != 1:
        raise ConfigError(f"num_egos: {face} has one ego per scenario (got {config.num_egos}); "
                          "use parallel_env(num_egos=...) or make_vec(num_envs=...)")
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


class OvertakeParallelEnv(RendersFirstRow, ParallelEnv):
    """Egos (and optionally NPCs) as agents over one batched core; see the module docstring."""

    metadata = {"name": "overtake_v0", "render_modes": ["rgb_array", "human"], "render_fps": 10,
                "is_parallelizable": True}

    def __init__(self, config: EnvConfig | dict[str, Any] | None = None, **overrides: Any) -> None:
        self.config = as_config(config, **overrides)
        self.render_mode = self.config.render_mode
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        self.core = OvertakeCore(self.config, auto_reset=False)
        self.num_egos = self.config.num_egos
        self.num_npcs = self.distribution.sample(1, 0).num_npcs  # slots per scenario of this distribution
        self._egos = [f"ego_{i}" for i in range(self.num_egos)]
        self._npcs = [f"npc_{j}" for j in range(self.num_npcs)] if self.config.npc_agents else []
        self.possible_agents = self._egos + self._npcs
        self.agents: list[str] = []
        # Finite bounds (envs/spaces.py); observations are clipped to them, a no-op for scenarios
        # of the config's distribution.
        ego_obs = ego_observation_space(self.config)
        npc_obs = npc_observation_space(self.config, npc_start_extent(self.distribution))
        ego_act, npc_act = spaces.Discrete(len(MODE_NAMES)), spaces.Discrete(len(NPC_ACCELERATIONS))
        # Plain dicts (not lru_cache on the method, which would pin every env in a global cache):
        # each call returns the same space object, so seeding a space sticks.
        self.observation_spaces = {a: ego_obs if a in self._egos else npc_obs for a in self.possible_agents}
        self.action_spaces = {a: ego_act if a in self._egos else npc_act for a in self.possible_agents}
        self._rng: np.random.Generator | None = None
        self._renderer = None

    def observation_space(self, agent: str) -> spaces.Space:
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Space:
        return self.action_spaces[agent]

    # ---------------------------------------------------------------- reset
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        elif self._rng is None:
            self._rng = np.random.default_rng(self.config.seed)
        scen = (options or {}).get("scenarios")
        if scen is None:
            scen = self.distribution.sample(self.num_egos, self._rng)
        elif not isinstance(scen, Scenarios) or scen.num != self.num_egos:
            raise ValueError(f"options['scenarios'] must be a Scenarios batch of num_egos={self.num_egos} rows")
        elif self._npcs and scen.num_npcs > self.num_npcs:
            raise ValueError(f"options['scenarios'] has {scen.num_npcs} NPC slots; "
                             f"this env has {self.num_npcs} NPC agents")
        obs = self._clip_egos(self.core.reset(scen))
        self.agents = list(self._egos)
        if self._npcs:
            self.agents += [self._npcs[j] for j in np.flatnonzero(scen.npc_present[0])]
        info = self.core.info()
        observations = {a: obs[i] for i, a in enumerate(self._egos)}
        infos = {a: row_info(info, i) for i, a in enumerate(self._egos)}
        if self._npcs:
            npc_obs = self._npc_observations()
            for a in self.agents[self.num_egos:]:
                j = int(a[4:])
                observations[a] = npc_obs[j]
                infos[a] = {"slot": j, "lane": int(scen.npc_lane[0, j])}
        if self.render_mode == "human":
            self.render()
        return observations, infos

    # ----------------------------------------------------------------- step
    def step(self, actions: dict[str, Any]):
        live = self.agents
        if not live:
            raise RuntimeError("step() called with no live agents: call reset() first")
        unknown = [a for a in actions if a not in self.observation_spaces]
        if unknown:
            raise KeyError(f"action for unknown agent {unknown[0]!r} (agents: {', '.join(self.possible_agents)})")
        modes = self.core.mode.copy()  # finished rows are frozen by the core whatever we pass
        for i, a in enumerate(self._egos):
            if a in actions and actions[a] is not None:
                modes[i] = check_action(actions[a], len(MODE_NAMES), a)
            elif not self.core.done[i]:
                raise KeyError(f"no action for live agent {a!r}")
        live_npcs = [a for a in live if a.startswith("npc_")] if self._npcs else []
        npc_accel = None
        if live_npcs:  # NaN = IDM (NPCs of the other rows, and NPCs given no action)
            npc_accel = np.full((self.num_egos, self.core.scen.num_npcs), np.nan)
            for a in live_npcs:
                if actions.get(a) is not None:
                    npc_accel[0, int(a[4:])] = NPC_ACCELERATIONS[check_action(actions[a], len(NPC_ACCELERATIONS), a)]
        # One env step holds the actions for decision_interval core steps (rewards summed).
        res = hold(self.core, modes, self.config.decision_interval, npc_accel)

        obs, rew, term, trunc, infos = {}, {}, {}, {}, {}
        ego_obs = self._clip_egos(res.obs)
        for a in live:
            if a.startswith("ego_"):
                i = int(a[4:])
                obs[a], rew[a] = ego_obs[i], float(res.reward[i])
                term[a], trunc[a] = bool(res.terminated[i]), bool(res.truncated[i])
                infos[a] = row_info(res.info, i)
        if live_npcs:
            npc_obs = self._npc_observations()
            r0, t0, u0 = -float(res.reward[0]), bool(res.terminated[0]), bool(res.truncated[0])
            outcome = OUTCOME_NAMES[int(res.info["outcome"][0])]
            for a in live_npcs:
                j = int(a[4:])
                obs[a], rew[a], term[a], trunc[a] = npc_obs[j], r0, t0, u0
                infos[a] = {"slot": j, "lane": int(self.core.scen.npc_lane[0, j]), "ego_outcome": outcome}
        self.agents = [a for a in live if not (term[a] or trunc[a])]
        if self.render_mode == "human":
            self.render()
        return obs, rew, term, trunc, infos

    def _npc_observations(self) -> np.ndarray:
        """(M, NPC_OBS_SIZE) float32 for the NPC slots of row 0 (ego_0's scenario)."""
        c, sc = self.core, self.core.scen
        lane = sc.npc_lane[0]
        direction = np.where(lane == OPPOSITE_LANE, -1.0, 1.0)
        v = c.npc_v[0]
        ego_vx = c.v[0] * np.cos(c.psi[0])
        oc = self.config.observation
        gap = direction * (c.x[0] - c.npc_s[0])  # ego ahead of the NPC along its travel: > 0
        closing = v - direction * ego_vx  # rate at which that distance shrinks
        lateral = (c.y[0] - lane * sc.lane_width[0]) / sc.lane_width[0]
        obs = np.stack([v / oc.speed_scale, lane.astype(float), gap / oc.position_scale,
                        closing / oc.speed_scale, lateral, sc.npc_present[0].astype(float)],
                       axis=1).astype(np.float32)
        space = self.observation_spaces[self._npcs[0]]
        return np.clip(obs, space.low, space.high)  # a no-op but for scenarios outside the distribution

    def _clip_egos(self, obs: np.ndarray) -> np.ndarray:
        # A no-op for scenarios of the config's distribution; only scenarios given through
        # options["scenarios"] outside it can leave the Box (see envs/spaces.py).
        space = self.observation_spaces[self._egos[0]]
        return np.clip(obs, space.low, space.high)

    # --------------------------------------------------------------- render
    def render(self):
        """Top view of ``ego_0``'s scenario (see :mod:`.render`)."""
        if self.render_mode is None:
            return None
        if self.core.scen is None:
            raise RuntimeError("render() before reset()")
        return self._render_first_row()


def parallel_env(config: EnvConfig | dict[str, Any] | None = None, **overrides: Any) -> OvertakeParallelEnv:
    """The PettingZoo ``ParallelEnv``; keyword arguments are :class:`EnvConfig` keys."""
    return OvertakeParallelEnv(config, **overrides)


def env(config: EnvConfig | dict[str, Any] | None = None, **overrides: Any):
    """The AEC version (PettingZoo's own conversion, with its bounds and order checks)."""
    aec = parallel_to_aec_wrapper(parallel_env(config, **overrides))
    aec = wrappers.AssertOutOfBoundsWrapper(aec)
    return wrappers.OrderEnforcingWrapper(aec)
