"""The Gymnasium face: :class:`OvertakeEnv`, one ego over the core with ``N = 1``.

Registered as ``"overtakezoo/Overtake-v0"`` by :func:`register_envs`, which ``import
overtakezoo.envs`` runs (Gymnasium 1.x no longer loads ``gymnasium.envs`` entry-point plugins, so
the import is what registers; ``gymnasium.make("overtakezoo.envs:overtakezoo/Overtake-v0")`` imports
it for you). The same id is registered with PettingZoo's registry (parallel and AEC) and has a
``vector_entry_point``, so ``gymnasium.make_vec(id, num_envs=N)`` gives the natively batched
:class:`~.vector.OvertakeVectorEnv`.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from overtakezoo.envs.config import MODE_NAMES, EnvConfig
from overtakezoo.envs.core import OvertakeCore
from overtakezoo.envs.faces.rendering import RendersFirstRow
from overtakezoo.envs.hold import hold
from overtakezoo.envs.faces._common import as_config, check_action, row_info, single_ego
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios
from overtakezoo.envs.faces.spaces import ego_observation_space

ENV_ID = "overtakezoo/Overtake-v0"


class OvertakeEnv(RendersFirstRow, gymnasium.Env):
    """Single-ego overtaking: action 0 follow / 1 overtake / 2 abort; observation the core's vector.

    Each ``reset`` draws a scenario from the config's ``scenario`` distribution with the env's
    ``np_random`` (so ``reset(seed=s)`` is reproducible), or starts on
    ``options={"scenarios": <Scenarios of 1 row>}``. Episodes end by the core's outcomes
    (success / crash / off-road terminate; the scenario's time limit truncates).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(self, config: EnvConfig | dict[str, Any] | None = None, **overrides: Any) -> None:
        self.config = single_ego(as_config(config, **overrides), "OvertakeEnv")
        self.render_mode = self.config.render_mode
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        self.core = OvertakeCore(self.config, auto_reset=False)
        self.observation_space = ego_observation_space(self.config)  # finite bounds, see envs/faces/spaces.py
        self.action_space = spaces.Discrete(len(MODE_NAMES))
        self._renderer = None
        self._first_reset = True

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        if seed is None and self._first_reset:
            seed = self.config.seed
        self._first_reset = False
        super().reset(seed=seed)
        scen = (options or {}).get("scenarios")
        if scen is None:
            scen = self.distribution.sample(1, self.np_random)
        elif not isinstance(scen, Scenarios) or scen.num != 1:
            raise ValueError("options['scenarios'] must be a Scenarios batch of one row")
        obs = self._clip(self.core.reset(scen)[0])
        if self.render_mode == "human":
            self.render()
        return obs, row_info(self.core.info(), 0)

    def step(self, action: Any):
        if self.core.scen is None:
            raise RuntimeError("step() before reset(): call reset() first")
        if self.core.done[0]:
            # Gymnasium leaves stepping a finished episode undefined; ours would silently return
            # terminated=False on a frozen state, so say so instead.
            raise RuntimeError("step() after the episode ended (terminated or truncated): call reset() first")
        action = check_action(action, len(MODE_NAMES), "OvertakeEnv.step")
        # One env step holds the action for decision_interval core steps (rewards summed).
        res = hold(self.core, np.array([action], dtype=np.int64), self.config.decision_interval)
        if self.render_mode == "human":
            self.render()
        return (self._clip(res.obs[0]), float(res.reward[0]), bool(res.terminated[0]), bool(res.truncated[0]),
                row_info(res.info, 0))

    def _clip(self, obs: np.ndarray) -> np.ndarray:
        # A no-op for scenarios of the config's distribution; only a scenario given through
        # options["scenarios"] outside it can leave the Box (see envs/faces/spaces.py).
        return np.clip(obs, self.observation_space.low, self.observation_space.high)

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; pass render_mode='rgb_array' or 'human'")
            return None
        return self._render_first_row()


def register_envs() -> None:
    """Register ``overtakezoo/Overtake-v0`` with Gymnasium (single env + vector entry point) and
    with PettingZoo (parallel and AEC). Idempotent; run by ``import overtakezoo.envs``."""
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="overtakezoo.envs.faces.gym:OvertakeEnv",
                           vector_entry_point="overtakezoo.envs.faces.vector:make_vec")
    try:
        import pettingzoo
    except ImportError:  # pragma: no cover - pettingzoo is a dependency, but the gym face does not need it
        return
    if hasattr(pettingzoo, "register"):  # the registry exists from PettingZoo 1.27
        if ENV_ID not in pettingzoo.parallel_registry:
            pettingzoo.register("parallel", ENV_ID, entry_point="overtakezoo.envs.faces.pettingzoo:parallel_env")
        if ENV_ID not in pettingzoo.aec_registry:
            pettingzoo.register("aec", ENV_ID, entry_point="overtakezoo.envs.faces.pettingzoo:env")
