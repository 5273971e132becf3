"""The rsl-rl ``VecEnv`` face of the core: a thin adapter for ``rsl_rl.runners.OnPolicyRunner``.

One :class:`OvertakeCore` with ``auto_reset=True`` steps ``num_envs`` scenarios; finished rows are
refilled from ``source`` (or pass ``core``, e.g. a :class:`~.mixture.MixedCore` over several
suites). ``transform`` (obs -> obs) maps what the policy sees, e.g. a decider's input features. The
action is one column holding the mode index as a float (what a categorical action distribution
samples): a whole number in 0..2, anything else (1.7, -1, NaN) is refused with the ValueError every
face raises, never rounded; observations are a TensorDict with one group,
``"policy"``, which the runner's ``obs_groups`` route to both actor and critic. With
``action_repeat`` = k one env step holds the decision for k core steps (:func:`.hold.hold`,
rewards summed): the *training hold* a model card records as its ``action_repeat``. The face is
built from a config (or a core), not a suite, so it keeps its own default of 1 core step; the
faces made from a suite (``make_vec(suite=...)``, ``parallel_env("duel")``, the registered ids)
hold the zoo's 1 s instead, ``zoo_hold(cfg.dt, cfg.decision_interval)`` = 10 at dt = 0.1 s
(:func:`overtakezoo.envs.suites.zoo_hold`): pass that as ``action_repeat`` to train at the zoo's hold.

rsl-rl and torch are optional dependencies (the ``train`` extra); nothing else in ``envs`` needs
them, so this module is imported explicitly, never from ``overtakezoo.envs``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")  # rsl_rl imports GitPython, which wants a git binary
from rsl_rl.env import VecEnv  # noqa: E402

from overtakezoo.envs.config import EnvConfig  # noqa: E402
from overtakezoo.envs.core import CRASH, OFFROAD, SUCCESS, TIMEOUT, OvertakeCore  # noqa: E402
from overtakezoo.envs.faces._common import check_actions  # noqa: E402
from overtakezoo.envs.hold import hold  # noqa: E402
from overtakezoo.envs.scenarios import OPPOSITE_LANE, ScenarioDistribution, Scenarios  # noqa: E402

Source = Callable[[int, np.random.Generator], Scenarios]


def pool_source(pool: Scenarios) -> Source:
    """A scenario source drawing rows uniformly (with replacement) from a fixed pool, e.g. a suite."""
    if pool.num == 0:
        raise ValueError("scenario pool is empty")

    def draw(n: int, rng: np.random.Generator) -> Scenarios:
        return pool.take(rng.integers(0, pool.num, n))

    return draw


class OvertakeRslRlEnv(VecEnv):
    """``num_envs`` scenarios stepped as one batch; ``source`` is a pool of scenarios or a
    ``source(n, rng) -> Scenarios`` callable that refills finished rows."""

    def __init__(
        self,
        num_envs: int,
        config: EnvConfig | None = None,
        source: Scenarios | Source | None = None,
        seed: int | None = None,
        device: str | torch.device = "cpu",
        bootstrap_timeouts: bool = True,
        action_repeat: int = 1,
        core: Any = None,
        transform: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.cfg = config or (core.cfg if core is not None else EnvConfig())  # the runner's logger reads env.cfg
        self.transform = transform or (lambda obs: obs)
        # True: a time limit is a truncation and PPO bootstraps its value (extras["time_outs"]); False:
        # running out of time is a terminal failure of the task (the limit is part of the suite).
        self.bootstrap_timeouts = bootstrap_timeouts
        if action_repeat < 1:
            raise ValueError(f"action_repeat must be >= 1, got {action_repeat}")
        self.action_repeat = action_repeat  # the training hold: core steps one env step holds a decision
        self.num_envs = num_envs
        self.num_actions = 1
        self.device = torch.device(device)
        if core is None:
            if source is None:
                source = ScenarioDistribution.from_dict(self.cfg.scenario).sample(1000, seed=seed)
            source = pool_source(source) if isinstance(source, Scenarios) else source
            core = OvertakeCore(self.cfg, auto_reset=True, source=source, seed=seed)
            core.reset(source(num_envs, core.rng))
        elif core.num != num_envs or not core.auto_reset:
            raise ValueError(f"core: expected an auto-reset core of {num_envs} rows")
        self.core = core
        self._obs = self.transform(core.observe())
        # Longest episode any row can have; the runner only uses it for random initial lengths.
        cores = getattr(core, "cores", [core])
        limit = max(float(np.max(c.scen.time_limit)) for c in cores)
        self.max_episode_length = int(math.ceil(limit / self.cfg.dt / action_repeat))
        self.episode_length_buf = torch.zeros(num_envs, dtype=torch.long, device=self.device)
        self.episode_counts: dict[str, int] = {"episodes": 0}  # running totals, e.g. for a progress bar

    def _tensordict(self, obs: np.ndarray) -> TensorDict:
        return TensorDict(
            {"policy": torch.as_tensor(obs, dtype=torch.float32, device=self.device)},
            batch_size=[self.num_envs],
            device=self.device,
        )

    def get_observations(self) -> TensorDict:
        return self._tensordict(self._obs)

    def _modes(self, actions: torch.Tensor) -> np.ndarray:
        """The action column as mode indices; a ValueError like every face's (:func:`check_actions`)
        for anything but a whole number in 0..2 (rsl-rl samples the index as a float: 1.0 is mode 1;
        1.7, -1, 5 or NaN is refused, never rounded or clamped into a mode)."""
        n, tensor = self.num_envs, isinstance(actions, torch.Tensor)
        shape = tuple(actions.shape) if tensor else np.shape(actions)
        if shape not in ((n, 1), (n,)):
            raise ValueError(f"actions: expected shape ({n}, 1), got {shape}")
        if tensor:
            t = actions.detach().reshape(n).to("cpu")
            col = (t.float() if t.dtype == torch.bfloat16 else t).numpy()  # numpy has no bfloat16
        else:
            col = np.reshape(actions, n)
        return check_actions(col, n, "actions", whole_floats=True)

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        modes = self._modes(actions)
        # A row whose episode ended during the hold has been refilled: it follows (the reset mode)
        # until the next decision; those few steps' rewards belong to no decision and are dropped.
        res = hold(self.core, modes, self.action_repeat)
        reward, finished, truncated = res.reward, res.finished, res.truncated
        self._obs = self.transform(res.obs)
        dev = self.device
        self.episode_length_buf += 1
        self.episode_length_buf[torch.as_tensor(finished, device=dev)] = 0
        time_outs = truncated if self.bootstrap_timeouts else np.zeros_like(truncated)
        extras: dict = {"time_outs": torch.as_tensor(time_outs, dtype=torch.float32, device=dev)}
        if finished.any():
            assert res.final_info is not None  # (set on an auto-reset core when rows finished)
            # Per finished episode indicators: the runner's logger averages them over an iteration.
            out, lane = res.final_info["outcome"][finished], res.final_info["crash_lane"][finished]
            crash = out == CRASH
            rates = {
                "success": out == SUCCESS,
                "crash": crash,
                "crash_ego_lane": crash & (lane != OPPOSITE_LANE),
                "crash_opposite_lane": crash & (lane == OPPOSITE_LANE),
                "timeout": out == TIMEOUT,
                "offroad": out == OFFROAD,
            }
            self.episode_counts["episodes"] += int(finished.sum())
            for k, v in rates.items():
                self.episode_counts[k] = self.episode_counts.get(k, 0) + int(v.sum())
            extras["log"] = {
                f"Episode/{k}": torch.as_tensor(v, dtype=torch.float32, device=dev) for k, v in rates.items()
            }
        rewards = torch.as_tensor(reward, dtype=torch.float32, device=dev)
        dones = torch.as_tensor(finished, dtype=torch.long, device=dev)
        return self._tensordict(self._obs), rewards, dones, extras
