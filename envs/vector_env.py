"""A natively batched Gymnasium ``VectorEnv``: ``num_envs`` scenarios in one core, one process.

One :class:`~.core.OvertakeCore` with ``auto_reset=True`` steps every row at once; a finished row is
replaced in the same step by a fresh draw from the config's ``scenario`` distribution
(``AutoresetMode.SAME_STEP``). As Gymnasium's own vector envs do in that mode, ``infos`` then holds
``final_obs`` (an object array: the last observation of each finished row, ``None`` elsewhere) and
``final_info`` (the finished rows' episode info), each with its ``_final_obs`` / ``_final_info``
mask; the other keys are the per-row info of the (possibly new) episodes, each with its ``_key`` mask.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from .config import MODE_NAMES, ConfigError, EnvConfig
from .core import OvertakeCore
from .pettingzoo_env import as_config, single_ego
from .scenarios import ScenarioDistribution, Scenarios


class OvertakeVectorEnv(VectorEnv):
    """``num_envs`` independent single-ego scenarios stepped as one batch (see module docstring)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, num_envs: int = 1, config: EnvConfig | dict[str, Any] | None = None, **overrides: Any) -> None:
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.config = single_ego(as_config(config, **overrides), "OvertakeVectorEnv")
        if self.config.decision_interval != 1:
            # Auto-reset replaces a row the moment it ends, so repeating an action across that
            # boundary would drive the new episode blind; the held-row faces support it.
            raise ConfigError("decision_interval: OvertakeVectorEnv steps every control cycle (1); got "
                              f"{self.config.decision_interval} (OvertakeEnv and parallel_env repeat actions)")
        if self.config.render_mode not in (None, "rgb_array"):
            raise ValueError(f"OvertakeVectorEnv renders only 'rgb_array' (row 0), not {self.config.render_mode!r}")
        self.render_mode = self.config.render_mode
        self.num_envs = int(num_envs)
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        self.core = OvertakeCore(self.config, auto_reset=True, source=self._draw)
        self.single_observation_space = spaces.Box(-np.inf, np.inf, (self.core.obs_size,), np.float32)
        self.single_action_space = spaces.Discrete(len(MODE_NAMES))
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._first_reset = True
        self._renderer = None

    def _draw(self, n: int, rng: np.random.Generator) -> Scenarios:
        return self.distribution.sample(n, rng)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start every row on a fresh draw (or on ``options={"scenarios": <Scenarios of num_envs rows>}``).
        Refills after this use the same generator, so a seeded run is reproducible end to end."""
        if seed is None and self._first_reset:
            seed = self.config.seed
        if seed is not None and not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int or None (one generator drives every row), got {seed!r}")
        self._first_reset = False
        super().reset(seed=seed)
        self.core.rng = self.np_random
        scen = (options or {}).get("scenarios")
        if scen is None:
            scen = self._draw(self.num_envs, self.np_random)
        elif not isinstance(scen, Scenarios) or scen.num != self.num_envs:
            raise ValueError(f"options['scenarios'] must be a Scenarios batch of num_envs={self.num_envs} rows")
        obs = self.core.reset(scen)
        return obs, _with_masks(self.core.info())

    def step(self, actions: Any):
        res = self.core.step(np.asarray(actions, dtype=np.int64))
        finished = res.info.pop("_finished")
        if finished.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for i in np.flatnonzero(finished):  # Gymnasium's layout: one array per finished row
                final_obs[i] = res.final_obs[i]
            infos = _with_masks(self.core.info())  # the new episodes' (zeroed) stats
            infos["final_obs"], infos["_final_obs"] = final_obs, finished
            infos["final_info"] = _with_masks(res.info, finished)
            infos["_final_info"] = finished
        else:
            infos = _with_masks(res.info)
        return res.obs, res.reward, res.terminated, res.truncated, infos

    def render(self):
        """``(frame of row 0,)`` in ``rgb_array`` mode."""
        if self.render_mode is None:
            return None
        from .render import Renderer, frame_from_core

        if self._renderer is None:
            self._renderer = Renderer("rgb_array", fps=self.metadata["render_fps"])
        return (self._renderer.render(frame_from_core(self.core, 0)),)

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _with_masks(info: dict[str, np.ndarray], mask: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Gymnasium's vector info layout: every key ``k`` paired with a boolean ``_k`` (rows that have it)."""
    out: dict[str, np.ndarray] = {}
    for key, value in info.items():
        if key.startswith("_"):
            continue
        out[key] = value
        out[f"_{key}"] = np.ones(value.shape[0], bool) if mask is None else mask
    return out


def make_vec(num_envs: int = 1, config: EnvConfig | dict[str, Any] | None = None,
             **overrides: Any) -> OvertakeVectorEnv:
    """``num_envs`` scenarios as one natively batched ``gymnasium.vector.VectorEnv``; keyword
    arguments are :class:`EnvConfig` keys."""
    return OvertakeVectorEnv(num_envs, config, **overrides)
