"""The Gymnasium face: :class:`OvertakeEnv`, one ego over the core with ``N = 1``.

Registered by :func:`register_envs`, which ``import overtakezoo.envs`` runs (Gymnasium 1.x no
longer loads ``gymnasium.envs`` entry-point plugins, so the import is what registers;
``gymnasium.make("overtakezoo.envs:overtakezoo/Overtake-v1")`` imports it for you):

- ``"overtakezoo/Overtake-v1"`` (:data:`ENV_ID`): the training world, ``overtakezoo/table1-train-v2``'s
  kwargs (table1-train's settings and scenario distribution, each env step one decision held the
  zoo's 1 s, ``hold_steps=10``), so the id a guide names trains on what table1 evaluates: Stable-
  Baselines3's ``DQN("MlpPolicy", gym.make("overtakezoo/Overtake-v1"), seed=0)``, 200k steps,
  scores table1 success 90.2 %, crash 9.8 % (rule-fsm: 71 % / 29 %; the leaderboard's "Submit your
  policy" guide, ``tests/docs/test_guide_submit.py``). Its policy card is
  ``overtakezoo card model.zip --action-repeat 10 --suite table1-train``. A new version rather than a
  new meaning for v0 (Gymnasium's rule: changed dynamics, new version); its kwargs are pinned to
  table1-train v2 (``tests/envs/test_suite_envs.py``), so a new table1-train version means a new
  Overtake version;
- ``"overtakezoo/Overtake-v0"`` (:data:`ENV_ID_V0`): the env's defaults (table1-reactive's world,
  one core step, 0.1 s, per env step), kept as it always was for old code and for the faces'
  ``**config`` use. Trained as is, an agent learns to always follow (SB3 DQN's defaults, 200k steps:
  table1 success 0 %); ``gymnasium.make`` of it warns that it is out of date (upgrade to v1), as
  Gymnasium does for every id with a newer version. ``gymnasium.make("overtakezoo/Overtake")``
  without a version is v1;
- ``"overtakezoo/<suite>-v<version>"`` for every built-in suite (``overtakezoo/table1-v2``,
  ``overtakezoo/table1-train-v2``, ...; :func:`~overtakezoo.envs.suites.suite_env_ids`): the suite's
  settings and scenario distribution, each env step holding the action for the zoo's decision of
  1 s (``hold_steps=10`` at dt = 0.1 s, in the spec's kwargs), so an agent trains on what the suite
  evaluates. The single-ego suites are Gymnasium ids, every suite (the multi-AV ones too) a
  PettingZoo id.

Each Gymnasium id has a ``vector_entry_point``, so ``gymnasium.make_vec(id, num_envs=N)`` gives the
natively batched :class:`~.vector.OvertakeVectorEnv` with the same settings and hold.
"""

from __future__ import annotations

from typing import Any

import gymnasium
import numpy as np
from gymnasium import spaces

from overtakezoo.envs.config import MODE_NAMES, EnvConfig
from overtakezoo.envs.core import OvertakeCore
from overtakezoo.envs.faces._common import (
    as_config,
    check_action,
    env_hold,
    is_suite,
    row_info,
    single_ego,
    suite_config,
)
from overtakezoo.envs.faces.rendering import RendersFirstRow
from overtakezoo.envs.faces.spaces import ego_observation_space
from overtakezoo.envs.hold import hold
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios

ENV_ID = "overtakezoo/Overtake-v1"  # the training world: table1-train's kwargs, the zoo's 1 s hold
ENV_ID_V0 = "overtakezoo/Overtake-v0"  # the env's defaults, one core step per env step (out of date)
ENV_SUITE = "table1-train"  # the suite whose id's kwargs ENV_ID has


class OvertakeEnv(RendersFirstRow, gymnasium.Env):
    """Single-ego overtaking: action 0 follow / 1 overtake / 2 abort; observation the core's vector.

    Each ``reset`` draws a scenario from the config's ``scenario`` distribution with the env's
    ``np_random`` (so ``reset(seed=s)`` is reproducible), or starts on
    ``options={"scenarios": <Scenarios of 1 row>}``. Episodes end by the core's outcomes
    (success / crash / off-road terminate; the scenario's time limit truncates).

    ``suite``: a built-in suite's name (``"table1-train"``), a suite file's path or a loaded suite
    (also accepted as ``config``): its simulator settings and scenario distribution instead of
    ``config`` (keyword arguments still override EnvConfig keys). ``hold_steps``: core steps one env
    step holds the action (rewards summed, :func:`~overtakezoo.envs.hold.hold`), a multiple of
    ``decision_interval``. An explicit value wins; otherwise an env made from a suite holds the
    zoo's 1 s (10 steps at dt = 0.1 s, :func:`~overtakezoo.envs.suites.zoo_hold`), the same hold
    as the suite's registered id, so ``OvertakeEnv(suite="table1")`` and
    ``gymnasium.make("overtakezoo/table1-v2")`` step alike; an env made from a raw config (an
    :class:`EnvConfig`, a dict, keywords, none) holds its ``decision_interval`` (1 by default).
    """

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 10}

    def __init__(
        self,
        config: EnvConfig | dict[str, Any] | None = None,
        *,
        suite: Any = None,
        hold_steps: int | None = None,
        **overrides: Any,
    ) -> None:
        self.config = single_ego(as_config(suite_config(config, suite), **overrides), "OvertakeEnv")
        self.hold_steps = env_hold(hold_steps, self.config, is_suite(config, suite))  # core steps per env step
        self.render_mode = self.config.render_mode
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        self.core = OvertakeCore(self.config, auto_reset=False)
        # finite bounds, see envs/faces/spaces.py
        self.observation_space: spaces.Box = ego_observation_space(self.config)
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
        # One env step holds the action for hold_steps core steps (rewards summed).
        res = hold(self.core, np.array([action], dtype=np.int64), self.hold_steps)
        if self.render_mode == "human":
            self.render()
        return (
            self._clip(res.obs[0]),
            float(res.reward[0]),
            bool(res.terminated[0]),
            bool(res.truncated[0]),
            row_info(res.info, 0),
        )

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
    """Register ``overtakezoo/Overtake-v1``, ``overtakezoo/Overtake-v0`` and every built-in suite's id
    (module docstring) with Gymnasium (single env + vector entry point; the single-ego suites) and with
    PettingZoo (parallel and AEC; every suite). A multi-AV suite's id is registered with Gymnasium
    too, but only to refuse: ``gymnasium.make`` / ``make_vec`` of it raise a ``NameNotFound`` that
    shows the PettingZoo call (:func:`~.pettingzoo.gymnasium_refusal`). Idempotent; run by
    ``import overtakezoo.envs``."""
    from overtakezoo.envs.suites import suite_env_ids

    suites = {
        env_id: ({"suite": s.name, "hold_steps": s.hold_steps}, s.multi_av) for env_id, s in suite_env_ids().items()
    }
    train = next(kw for env_id, (kw, _) in suites.items() if kw["suite"] == ENV_SUITE)
    ids = {ENV_ID: (dict(train), False), ENV_ID_V0: ({}, False), **suites}
    for env_id, (kwargs, multi_av) in ids.items():
        if env_id in gymnasium.registry:
            continue
        if multi_av:
            refusal = "overtakezoo.envs.faces.pettingzoo:gymnasium_refusal"
            gymnasium.register(id=env_id, entry_point=refusal, vector_entry_point=refusal, kwargs=kwargs)
        else:
            gymnasium.register(
                id=env_id,
                entry_point="overtakezoo.envs.faces.gym:OvertakeEnv",
                vector_entry_point="overtakezoo.envs.faces.vector:make_vec",
                kwargs=kwargs,
            )
    try:
        import pettingzoo
    except ImportError:  # pragma: no cover - pettingzoo is a dependency, but the gym face does not need it
        return
    if hasattr(pettingzoo, "register"):  # the registry exists from PettingZoo 1.27
        for env_id, (kwargs, _) in ids.items():
            if env_id not in pettingzoo.parallel_registry:
                pettingzoo.register(
                    "parallel", env_id, entry_point="overtakezoo.envs.faces.pettingzoo:parallel_env", kwargs=kwargs
                )
            if env_id not in pettingzoo.aec_registry:
                pettingzoo.register("aec", env_id, entry_point="overtakezoo.envs.faces.pettingzoo:env", kwargs=kwargs)
