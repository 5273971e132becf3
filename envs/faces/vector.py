"""A natively batched Gymnasium ``VectorEnv``: ``num_envs`` scenarios in one core, one process.

One :class:`~.core.OvertakeCore` steps every row at once; a finished row is replaced by a fresh draw
from the config's ``scenario`` distribution, in one of Gymnasium's two autoreset modes
(``autoreset_mode=``):

- ``AutoresetMode.NEXT_STEP`` (the default, as Gymnasium's own vector envs): the step that ends an
  episode returns its last observation; the next step ignores that row's action, starts the new
  episode and returns its first observation with reward 0 and ``terminated = truncated = False``.
  Gymnasium's vector observation wrappers (``NormalizeObservation``, ``TransformObservation``,
  ``FlattenObservation``, ...) accept only this mode (or DISABLED).
- ``AutoresetMode.SAME_STEP``: the row is replaced in the step that ends it (no step is wasted); as
  Gymnasium's own vector envs do in that mode, ``infos`` then holds ``final_obs`` (an object array:
  the last observation of each finished row, ``None`` elsewhere) and ``final_info`` (the finished
  rows' episode info), each with its ``_final_obs`` / ``_final_info`` mask.

In both modes the other keys of ``infos`` are the per-row info of the current episodes, each with its
``_key`` mask.

The hold (``hold_steps``; by default the zoo's 1 s, 10 steps at dt = 0.1 s, for an env made
from a suite, as its id ``overtakezoo/<suite>-v<version>`` holds, and the config's
``decision_interval`` for one made from a raw config) applies per row: one env step holds
each row's action for ``hold_steps`` core steps (:func:`~overtakezoo.envs.hold.hold`, rewards summed
over the row's own steps). A row whose episode ends during the hold is frozen by the core from that
core step on and is reported at this env step (terminated / truncated, the observation of the step
that ended it); the autoreset mode then restarts it as above, so no held step ever runs in the next
episode.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space

from overtakezoo.envs.config import MODE_NAMES, EnvConfig
from overtakezoo.envs.faces._common import as_config, check_actions, env_hold, is_suite, single_ego, suite_config
from overtakezoo.envs.faces._compat import AutoresetMode  # gymnasium's own on 1.1+, a same-valued Enum on 1.0
from overtakezoo.envs.faces.spaces import ego_observation_space
from overtakezoo.envs.hold import hold
from overtakezoo.envs.host import make_core
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios


class OvertakeVectorEnv(VectorEnv):
    """``num_envs`` independent single-ego scenarios stepped as one batch (see module docstring)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        num_envs: int = 1,
        config: EnvConfig | dict[str, Any] | None = None,
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        *,
        suite: Any = None,
        hold_steps: int | None = None,
        device: str | None = None,
        backend: str | None = None,
        **overrides: Any,
    ) -> None:
        self._renderer = None  # first: close() runs on an instance whose __init__ raised, too
        if not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        modes = (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP)
        mode = next((m for m in modes if autoreset_mode in (m, m.value, m.name)), None)
        if mode is None:
            raise ValueError(f"autoreset_mode: expected AutoresetMode.NEXT_STEP or SAME_STEP, got {autoreset_mode!r}")
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.config = single_ego(as_config(suite_config(config, suite), **overrides), "OvertakeVectorEnv")
        self.hold_steps = env_hold(hold_steps, self.config, is_suite(config, suite))  # core steps per env step
        if self.config.render_mode not in (None, "rgb_array"):
            raise ValueError(f"OvertakeVectorEnv renders only 'rgb_array' (row 0), not {self.config.render_mode!r}")
        self.render_mode = self.config.render_mode
        self.num_envs = int(num_envs)
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        # The core freezes a finished row; this face restarts it, after the hold that ended it
        # (SAME_STEP) or at the next step (NEXT_STEP), so no held step runs in a new episode.
        # ``device`` / ``backend`` (envs/backend.py core_backend): the torch core, e.g. on a GPU, read
        # through HostCore, so the face's arrays stay numpy, as Gymnasium's API has them.
        self.core = make_core(self.config, device, backend, auto_reset=False)
        # finite bounds, see envs/faces/spaces.py
        self.single_observation_space: spaces.Box = ego_observation_space(self.config)
        self.single_action_space = spaces.Discrete(len(MODE_NAMES))
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._first_reset = True
        self._autoreset = np.zeros(self.num_envs, bool)  # NEXT_STEP: rows that restart on the next step

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
        # A private copy: restarting rows rewrites the batch's scenarios in place.
        obs = self.core.reset(Scenarios.from_arrays({k: v.copy() for k, v in scen.to_arrays().items()}))
        self._autoreset[:] = False
        return self._clip(obs), _with_masks(self.core.info())

    def step(self, actions: Any):
        if self.core.scen is None:
            raise RuntimeError("step() before reset(): call reset() first")
        actions = check_actions(actions, self.num_envs, "actions")
        # One env step holds each row's action for hold_steps core steps (rewards summed per row,
        # envs/hold.py); a row whose episode ends during the hold is frozen by the core from then on
        # and reported at this env step, with the observation of the step that ended it.
        last = None
        if self.hold_steps > 1:
            last = np.zeros((self.num_envs, self.core.obs_size), np.float32)

            def keep_last(modes: np.ndarray, step: Any) -> None:
                if step.finished.any():
                    last[step.finished] = step.obs[step.finished]

        res = hold(self.core, actions, self.hold_steps, on_step=None if last is None else keep_last)
        infos: dict[str, Any]  # (Gymnasium's: arrays, and on SAME_STEP the finished rows' final_info dict)
        finished, obs, infos = res.finished, res.obs, res.info
        if last is not None and finished.any():
            obs = np.where(finished[:, None], last, obs)
        if self.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP:
            # Rows that ended at the previous step were frozen (reward 0, not done): they start anew now.
            if self._autoreset.any():
                rows = np.flatnonzero(self._autoreset)
                obs = obs.copy()
                obs[rows] = self.core.restart(rows, self._draw(len(rows), self.core.rng))
                infos = self.core.info()  # the new episodes' (zeroed) stats in those rows
            self._autoreset = finished
            return self._clip(obs), res.reward, res.terminated, res.truncated, _with_masks(infos)
        if finished.any():  # SAME_STEP: the finished rows start anew in this step
            rows = np.flatnonzero(finished)
            final_obs = np.full(self.num_envs, None, dtype=object)
            ended = self._clip(obs)
            for i in rows:  # Gymnasium's layout: one array per finished row
                final_obs[i] = ended[i]
            obs = obs.copy()
            obs[rows] = self.core.restart(rows, self._draw(len(rows), self.core.rng))
            infos = _with_masks(self.core.info())  # the new episodes' (zeroed) stats
            infos["final_obs"], infos["_final_obs"] = final_obs, finished
            infos["final_info"] = _with_masks(res.info, finished)
            infos["_final_info"] = finished
        else:
            infos = _with_masks(infos)
        return self._clip(obs), res.reward, res.terminated, res.truncated, infos

    def _clip(self, obs: np.ndarray) -> np.ndarray:
        # A no-op for scenarios of the config's distribution; only scenarios given through
        # options["scenarios"] outside it can leave the Box (see envs/faces/spaces.py).
        space = self.single_observation_space
        return np.clip(obs, space.low, space.high)

    def render(self):
        """``(frame of row 0,)`` in ``rgb_array`` mode."""
        if self.render_mode is None:
            return None
        from overtakezoo.envs.faces.render import Renderer, frame_from_core

        if self._renderer is None:
            self._renderer = Renderer("rgb_array", fps=self.metadata["render_fps"])
        return (self._renderer.render(frame_from_core(self.core, 0)),)

    def close_extras(self, **kwargs: Any) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None


def _with_masks(info: dict[str, np.ndarray], mask: np.ndarray | None = None) -> dict[str, Any]:
    """Gymnasium's vector info layout: every key ``k`` paired with a boolean ``_k`` (rows that have it)."""
    out: dict[str, np.ndarray] = {}
    for key, value in info.items():
        out[key] = value
        out[f"_{key}"] = np.ones(value.shape[0], bool) if mask is None else mask
    return out


def make_vec(
    num_envs: int = 1,
    config: EnvConfig | dict[str, Any] | None = None,
    autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
    *,
    suite: Any = None,
    hold_steps: int | None = None,
    device: str | None = None,
    backend: str | None = None,
    **overrides: Any,
) -> OvertakeVectorEnv:
    """``num_envs`` scenarios as one natively batched ``gymnasium.vector.VectorEnv`` (NEXT_STEP
    autoreset unless ``autoreset_mode`` says SAME_STEP); ``suite`` a suite's name, file path or
    loaded suite (its settings and distribution); ``hold_steps`` core steps per env step: an explicit
    value wins, else the zoo's 1 s (10 at dt = 0.1 s) for a suite, as
    ``gymnasium.make_vec("overtakezoo/<suite>-v<version>")`` holds, and the config's
    ``decision_interval`` for a raw config; ``device`` (cuda, cuda:N) / ``backend`` (torch) run the
    torch core there (the same results; observations still numpy); other keyword arguments are
    :class:`EnvConfig` keys."""
    return OvertakeVectorEnv(
        num_envs,
        config,
        autoreset_mode,
        suite=suite,
        hold_steps=hold_steps,
        device=device,
        backend=backend,
        **overrides,
    )
