"""The PettingZoo face of the core: ``parallel_env(...)`` and its AEC version ``env(...)``.

One env is one *road*: a thin adapter over an :class:`~.core.OvertakeCore` holding one scenario
(``N = 1``, ``auto_reset=False``) whose automated vehicles (AVs) are the agents, so the agents share
the road and meet: each sees the others in its observation slots, and two AVs can crash into each
other.

Building: ``parallel_env(config, **overrides)`` with an :class:`EnvConfig` or a dict (keyword
arguments are EnvConfig keys), or ``parallel_env(suite)`` / ``parallel_env(suite=suite)`` with a
loaded suite (``overtakezoo.envs.suites.load_suite("duel")``, or the name ``"duel"``, or a suite
file's path: its simulator settings and scenario distribution). ``hold_steps`` is how many core
steps one env step holds the actions (:func:`~overtakezoo.envs.hold.hold`): an explicit value
wins; otherwise an env made from a suite holds the zoo's 1 s (10 steps at dt = 0.1 s,
:func:`~overtakezoo.envs.suites.zoo_hold`), as the suite's registered id does, so
``parallel_env("duel")`` and ``pettingzoo.make("parallel", "overtakezoo/duel-v1")`` are the same env;
an env made from a raw config (an :class:`EnvConfig`, a dict, ``suite.config``) holds its
``decision_interval`` (1 by default). Each ``reset(seed=s)`` draws
the road from the distribution with the env's generator (``ScenarioDistribution.sample(1, rng)``;
without a seed, the next draw of the generator, first seeded by the config's ``seed``), or starts on
``options={"scenarios": <Scenarios of one row>}``.

Agents:

- ``av_0 .. av_{E-1}``: the road's AVs (E from the distribution: ``platoon_size`` AVs in lane 0, then
  the ``oncoming_av``; ``av_0`` is the scenario's ego). A single-ego config has one agent ``av_0``
  (formerly ``ego_0``; an action for ``ego_<i>`` raises a KeyError saying so). Every AV has the same
  spaces, so one policy can drive them all (parameter sharing): action ``Discrete(3)`` (0 follow,
  1 overtake, 2 abort), observation the core's vector for that AV, in its own frame
  (``observation_layout``; a ``Box`` of finite bounds from the config, envs/faces/spaces.py). Reward: the
  core's, per AV. ``infos[av]`` is the core's per-row info plus ``outcome_name`` and ``crashed_into``
  (``"av_1"``, ``"npc_0"``, or None: whom the AV crashed into; an AV-AV crash names each other).
- with ``npc_agents=True`` also ``npc_<slot>`` for each NPC slot present on the road (slot 0 is the
  lead, then the oncoming vehicles, the followers, and the oncoming AV's lead). Action
  ``Discrete(4)``: an acceleration from :data:`NPC_ACCELERATIONS` (m/s^2; the core clips it to the
  IDM limits), applied instead of IDM. Observation (:data:`NPC_OBS_SIZE` floats) relative to the
  nearest AV still driving: own speed, own lane, distance to that AV along the NPC's direction of
  travel (positive: AV ahead), the closing speed, the AV's lateral offset from the NPC's lane centre,
  presence. Reward: adversarial, zero-sum with the AVs as a team (each NPC receives minus the sum of
  the AVs' rewards). NPC agents end when the road ends.

Finished agents: an AV whose episode ends (terminated: success / crash / off-road; truncated: time
limit) leaves ``agents`` (PettingZoo's semantics); the core freezes it where it stopped (a crashed AV
stays on the road as an obstacle). The episode ends when every AV is done; ``step({})`` after that
returns empty dicts (as PettingZoo's ``aec_to_parallel`` does), any other action raises.

Parameter sharing (SuperSuit): ``pettingzoo_env_to_vec_env_v1`` needs a fixed agent set, so wrap with
``supersuit.black_death_v3`` first (a finished AV then receives zero observations and zero rewards
until the road ends; ``npc_agents`` must stay off: their spaces differ from the AVs'). SuperSuit
3.11.0's ``black_death_v3`` ends the episode one step after the last AV finishes (its done test is
``terminations & truncations``, fixed by SuperSuit PR #265); that extra step is the ``step({})``
above, zero reward for every AV.

Batching for training: a PettingZoo env is one road; several roads per env would not be
PettingZoo-shaped. The recommended route is SuperSuit's vector of envs::

    vec = supersuit.pettingzoo_env_to_vec_env_v1(supersuit.black_death_v3(parallel_env(suite)))
    vec = supersuit.concat_vec_envs_v1(vec, num_vec_envs=k, base_class="gymnasium")  # k * E rows

(a Gymnasium ``VectorEnv`` that resets each road when it ends; ``num_cpus`` for processes). For
Stable-Baselines3 use :func:`sb3_vec_env` (``overtakezoo.envs.sb3_vec_env(parallel_env(suite),
num_roads=k)``, extra ``marl``): SuperSuit 3.11's own ``base_class="stable_baselines3"`` wrapper
fails in ``PPO(..., seed=0)`` (``'ConcatVecEnv' object has no attribute 'seed'``); this one seeds.
Trainers that want speed step :class:`~.core.OvertakeCore`
directly: ``reset`` on N roads gives ``E * N`` AV rows (AV ``e`` of road ``n`` in row ``e * N + n``)
stepped as one array, with ``auto_reset=True`` refilling each road when its last AV is done.
"""

from __future__ import annotations

import functools
from typing import Any

import numpy as np
from gymnasium import error as gymnasium_error
from gymnasium import spaces
from pettingzoo import ParallelEnv
from pettingzoo.utils import wrappers
from pettingzoo.utils.conversions import parallel_to_aec_wrapper

from overtakezoo.envs.config import MODE_NAMES
from overtakezoo.envs.core import OUTCOME_NAMES, OvertakeCore
from overtakezoo.envs.faces._common import as_config, check_action, env_hold, is_suite, row_info, suite_config
from overtakezoo.envs.faces.rendering import RendersFirstRow
from overtakezoo.envs.faces.spaces import ego_observation_space, npc_observation_space, npc_start_extent
from overtakezoo.envs.hold import hold
from overtakezoo.envs.scenarios import OPPOSITE_LANE, ScenarioDistribution, Scenarios

NPC_ACCELERATIONS = np.array([-4.0, -2.0, 0.0, 1.0])  # m/s^2, the NPC agents' discrete choices


NPC_OBS_SIZE = 6


def av_info(info: dict[str, np.ndarray], row: int) -> dict[str, Any]:
    """:func:`row_info` of AV ``row`` plus ``crashed_into``: the agent name of whom it hit, or None."""
    out = row_info(info, row)
    other = out.get("crash_av", -1)
    out["crashed_into"] = f"av_{other}" if other >= 0 else f"npc_{out['crash_npc']}" if out["crash_npc"] >= 0 else None
    return out


class OvertakeParallelEnv(RendersFirstRow, ParallelEnv):
    """The automated vehicles of one road (and optionally its NPCs) as agents; see the module docstring."""

    metadata = {
        "name": "overtake_v1",
        "render_modes": ["rgb_array", "human"],
        "render_fps": 10,
        "is_parallelizable": True,
    }

    def __init__(
        self, config: Any = None, *, suite: Any = None, hold_steps: int | None = None, **overrides: Any
    ) -> None:
        self.config = as_config(suite_config(config, suite), **overrides)
        self.hold_steps = env_hold(hold_steps, self.config, is_suite(config, suite))  # core steps per env step
        self.render_mode = self.config.render_mode
        self.distribution = ScenarioDistribution.from_dict(self.config.scenario)
        self.core = OvertakeCore(self.config, auto_reset=False)
        probe = self.distribution.sample(1, 0)  # the road's layout: AVs and NPC slots
        self.num_avs, self.num_npcs = probe.num_avs, probe.num_npcs
        self._avs = [f"av_{e}" for e in range(self.num_avs)]
        self._npcs = [f"npc_{j}" for j in range(self.num_npcs)] if self.config.npc_agents else []
        self.possible_agents = self._avs + self._npcs
        self.agents: list[str] = []
        # Finite bounds (envs/faces/spaces.py); observations are clipped to them, a no-op for scenarios
        # of the config's distribution. With several AVs an NPC's nearest AV may be any of them.
        av_obs = ego_observation_space(self.config)
        extent = npc_start_extent(self.distribution) * (2 if self.num_avs > 1 else 1)
        npc_obs = npc_observation_space(self.config, extent)
        av_act, npc_act = spaces.Discrete(len(MODE_NAMES)), spaces.Discrete(len(NPC_ACCELERATIONS))
        # Plain dicts (not lru_cache on the method, which would pin every env in a global cache):
        # each call returns the same space object, so seeding a space sticks.
        self.observation_spaces = {a: av_obs if a in self._avs else npc_obs for a in self.possible_agents}
        self.action_spaces = {a: av_act if a in self._avs else npc_act for a in self.possible_agents}
        self._rng: np.random.Generator | None = None
        self._renderer = None
        self._truncated = np.zeros(self.num_avs, bool)  # how each AV's episode ended (for the NPCs)

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
            scen = self.distribution.sample(1, self._rng)
        elif not isinstance(scen, Scenarios) or scen.num != 1:
            raise ValueError("options['scenarios'] must be a Scenarios batch of one road (one row)")
        elif scen.num_avs != self.num_avs:
            raise ValueError(
                f"options['scenarios'] has {scen.num_avs} automated vehicles; this env's agents are "
                f"{', '.join(self._avs)} (build the env from a distribution with that many)"
            )
        elif self._npcs and scen.num_npcs > self.num_npcs:
            raise ValueError(
                f"options['scenarios'] has {scen.num_npcs} NPC slots; this env has {self.num_npcs} NPC agents"
            )
        obs = self._clip_avs(self.core.reset(scen))
        self._truncated[:] = False
        self.agents = list(self._avs)
        if self._npcs:
            self.agents += [self._npcs[j] for j in np.flatnonzero(scen.npc_present[0])]
        info = self.core.info()
        observations = {a: obs[e] for e, a in enumerate(self._avs)}
        infos = {a: av_info(info, e) for e, a in enumerate(self._avs)}
        if self._npcs:
            npc_obs = self._npc_observations()
            for a in self.agents[self.num_avs :]:
                j = int(a[4:])
                observations[a] = npc_obs[j]
                infos[a] = {"slot": j, "lane": int(scen.npc_lane[0, j])}
        if self.render_mode == "human":
            self.render()
        return observations, infos

    # ----------------------------------------------------------------- step
    def step(self, actions: dict[str, Any]):
        if self.core.scen is None:
            raise RuntimeError("step() before reset(): call reset() first")
        unknown = [a for a in actions if a not in self.observation_spaces]
        if unknown:
            hint = (
                "; agents are the road's automated vehicles av_0 .. (ego_<i> was renamed av_<i>)"
                if str(unknown[0]).startswith("ego_")
                else ""
            )
            raise KeyError(f"action for unknown agent {unknown[0]!r} (agents: {', '.join(self.possible_agents)}){hint}")
        live = self.agents
        if not live:
            if any(v is not None for v in actions.values()):
                raise RuntimeError("step() after every agent is done: call reset() first")
            return {}, {}, {}, {}, {}  # as PettingZoo's aec_to_parallel (SuperSuit 3.11's black death needs it)
        modes = self.core.mode.copy()  # finished AVs are frozen by the core whatever we pass
        for e, a in enumerate(self._avs):
            if actions.get(a) is not None:
                modes[e] = check_action(actions[a], len(MODE_NAMES), a)
            elif not self.core.done[e]:
                raise KeyError(f"no action for live agent {a!r}")
        live_npcs = [a for a in live if a.startswith("npc_")] if self._npcs else []
        npc_accel = None
        if live_npcs:  # NaN = IDM (NPCs given no action)
            npc_accel = np.full((1, self.core.scen.num_npcs), np.nan)
            for a in live_npcs:
                if actions.get(a) is not None:
                    npc_accel[0, int(a[4:])] = NPC_ACCELERATIONS[check_action(actions[a], len(NPC_ACCELERATIONS), a)]
        # One env step holds the actions for hold_steps core steps (rewards summed); an AV whose
        # episode ends during the hold is frozen from then on and reported with the observation of
        # the step that ended it.
        last = None
        if self.hold_steps > 1:
            last = np.zeros((self.num_avs, self.core.obs_size), np.float32)

            def keep_last(_: np.ndarray, step: Any) -> None:
                if step.finished.any():
                    last[step.finished] = step.obs[step.finished]

        res = hold(self.core, modes, self.hold_steps, npc_accel, on_step=None if last is None else keep_last)
        self._truncated |= res.truncated

        obs, rew, term, trunc, infos = {}, {}, {}, {}, {}
        av_obs = self._clip_avs(res.obs if last is None else np.where(res.finished[:, None], last, res.obs))
        for e, a in enumerate(self._avs):
            if a in live:
                obs[a], rew[a] = av_obs[e], float(res.reward[e])
                term[a], trunc[a] = bool(res.terminated[e]), bool(res.truncated[e])
                infos[a] = av_info(res.info, e)
        if live_npcs:
            npc_obs = self._npc_observations()
            road_over = bool(self.core.done.all())
            # The road ends by truncation only when every AV ran out of time (E = 1: the ego's own end).
            npc_trunc = road_over and bool(self._truncated.all())
            r = -float(res.reward.sum())
            outcomes = {a: OUTCOME_NAMES[int(res.info["outcome"][e])] for e, a in enumerate(self._avs)}
            for a in live_npcs:
                j = int(a[4:])
                obs[a], rew[a], term[a], trunc[a] = npc_obs[j], r, road_over and not npc_trunc, npc_trunc
                infos[a] = {"slot": j, "lane": int(self.core.scen.npc_lane[0, j]), "av_outcomes": outcomes}
        self.agents = [a for a in live if not (term[a] or trunc[a])]
        if self.render_mode == "human":
            self.render()
        return obs, rew, term, trunc, infos

    def _npc_observations(self) -> np.ndarray:
        """(M, NPC_OBS_SIZE) float32: each NPC slot relative to its nearest AV still driving (any AV
        once all are done), all in world coordinates."""
        c, sc = self.core, self.core.scen
        assert sc is not None and sc.av_direction is not None, "reset() first"
        w = sc.lane_width[0]
        # The AVs in the world frame from their own frames (E,): s = direction * x, d mirrored.
        direction = np.concatenate([[1.0], sc.av_direction[0].astype(float)])
        av_s = direction * c.x
        av_d = np.where(direction > 0, c.y, w - c.y)
        av_v = direction * c.v * np.cos(c.psi)  # velocity along +s
        lane = sc.npc_lane[0]
        npc_dir = np.where(lane == OPPOSITE_LANE, -1.0, 1.0)
        v = c.npc_v[0]
        gaps = npc_dir[:, None] * (av_s[None, :] - c.npc_s[0][:, None])  # (M, E): AV ahead of the NPC: > 0
        driving = ~np.asarray(c.done, bool)
        far = np.where(driving | ~driving.any(), 0.0, np.inf)  # (E,): AVs that are done, while others drive
        nearest = np.argmin(np.abs(gaps) + far[None, :], axis=1)  # (M,)
        gap = np.take_along_axis(gaps, nearest[:, None], axis=1)[:, 0]
        closing = v - npc_dir * av_v[nearest]  # rate at which that distance shrinks
        lateral = (av_d[nearest] - lane * w) / w
        oc = self.config.observation
        obs = np.stack(
            [
                v / oc.speed_scale,
                lane.astype(float),
                gap / oc.position_scale,
                closing / oc.speed_scale,
                lateral,
                sc.npc_present[0].astype(float),
            ],
            axis=1,
        ).astype(np.float32)
        space = self.observation_spaces[self._npcs[0]]
        return np.clip(obs, space.low, space.high)  # a no-op but for scenarios outside the distribution

    def _clip_avs(self, obs: np.ndarray) -> np.ndarray:
        # A no-op for scenarios of the config's distribution; only scenarios given through
        # options["scenarios"] outside it can leave the Box (see envs/faces/spaces.py).
        space = self.observation_spaces[self._avs[0]]
        return np.clip(obs, space.low, space.high)

    # --------------------------------------------------------------- render
    def render(self):
        """Top view of ``av_0``'s road (see :mod:`.render`)."""
        if self.render_mode is None:
            return None
        if self.core.scen is None:
            raise RuntimeError("render() before reset()")
        return self._render_first_row()


def parallel_env(
    config: Any = None, *, suite: Any = None, hold_steps: int | None = None, **overrides: Any
) -> OvertakeParallelEnv:
    """The PettingZoo ``ParallelEnv`` of one road: ``config`` an :class:`EnvConfig`, a dict, a loaded
    suite, a built-in suite's name or a suite file's path (or ``suite=``); ``hold_steps`` core steps
    per env step: an explicit value wins, else the zoo's 1 s (10 at dt = 0.1 s) for a suite, as its
    registered id ``pettingzoo.make("parallel", "overtakezoo/<suite>-v<version>")`` holds, and
    ``decision_interval`` for a raw config; other keyword arguments are :class:`EnvConfig` keys."""
    return OvertakeParallelEnv(config, suite=suite, hold_steps=hold_steps, **overrides)


def env(config: Any = None, *, suite: Any = None, hold_steps: int | None = None, **overrides: Any):
    """The AEC version (PettingZoo's own conversion, with its bounds and order checks); the same
    arguments and the same hold as :func:`parallel_env`."""
    aec = parallel_to_aec_wrapper(parallel_env(config, suite=suite, hold_steps=hold_steps, **overrides))
    aec = wrappers.AssertOutOfBoundsWrapper(aec)
    return wrappers.OrderEnforcingWrapper(aec)


class MultiAVSuiteError(gymnasium_error.NameNotFound):
    """``gymnasium.make`` / ``gymnasium.make_vec`` of a multi-AV suite id: several AVs share a road, so
    it is a PettingZoo env only; the message shows the PettingZoo call. (A ``NameNotFound``, as
    before these ids were registered with Gymnasium, so code catching that keeps working.)"""


def gymnasium_refusal(*, suite: str = "", **_: Any) -> Any:
    """The Gymnasium entry point (and vector entry point) of a multi-AV suite's id
    (:func:`~.gym.register_envs`): raises :class:`MultiAVSuiteError` pointing at the PettingZoo face."""
    from overtakezoo.envs.suites import suite_env_ids

    ids = [env_id for env_id, entry in suite_env_ids().items() if entry.name == suite]
    env_id = ids[0] if ids else f"overtakezoo/{suite}"
    raise MultiAVSuiteError(
        f"{env_id} is a multi-AV suite (several automated vehicles share each road, one agent each), so it "
        f'is a PettingZoo env, not a Gymnasium one: use pettingzoo.make("parallel", "{env_id}") or '
        f'overtakezoo.envs.parallel_env("{suite}") (one shared policy with Stable-Baselines3: '
        f'overtakezoo.envs.sb3_vec_env(parallel_env("{suite}"), num_roads=k))'
    )


def sb3_vec_env(par: Any, num_roads: int = 1, base_class: str = "stable_baselines3", num_cpus: int = 0) -> Any:
    """SuperSuit's vector of ``num_roads`` copies of the PettingZoo env ``par`` (one row per AV:
    ``num_roads * E`` rows; every AV driven by one shared policy), ready for Stable-Baselines3:
    ``supersuit.black_death_v3`` (a finished AV gets zero observations and rewards until its road
    ends), ``pettingzoo_env_to_vec_env_v1``, then ``concat_vec_envs_v1`` (module docstring). Needs the
    ``marl`` extra (``pip install 'overtakezoo[marl]'``), imported here only.

    Unlike SuperSuit 3.11's own SB3 wrapper (whose ``seed()`` fails with ``AttributeError:
    'ConcatVecEnv' object has no attribute 'seed'``, e.g. in ``PPO(..., seed=0)``), seeding works as in
    SB3's own vector envs: ``seed(s)`` (what ``PPO(seed=s)`` calls) seeds the next ``reset()``, road
    ``i`` with ``s + i``. ``base_class="gymnasium"`` gives SuperSuit's Gymnasium ``VectorEnv`` instead
    (seeded by ``reset(seed=s)``); ``num_cpus`` as SuperSuit's (0: all roads in this process). E.g.::

        from stable_baselines3 import PPO
        from overtakezoo.envs import parallel_env
        from overtakezoo.envs.faces.pettingzoo import sb3_vec_env

        vec = sb3_vec_env(parallel_env("duel"), num_roads=8)
        model = PPO("MlpPolicy", vec, seed=0).learn(100_000)
    """
    try:
        import supersuit
    except ImportError:
        raise ImportError(
            "sb3_vec_env needs SuperSuit and Stable-Baselines3: pip install 'overtakezoo[marl]'"
        ) from None
    if base_class not in ("stable_baselines3", "gymnasium"):
        raise ValueError(f"base_class {base_class!r}: expected 'stable_baselines3' or 'gymnasium'")
    if isinstance(num_roads, bool) or not isinstance(num_roads, (int, np.integer)) or num_roads < 1:
        raise ValueError(f"num_roads {num_roads!r}: expected a positive integer")
    vec = supersuit.pettingzoo_env_to_vec_env_v1(supersuit.black_death_v3(par))
    vec = supersuit.concat_vec_envs_v1(vec, num_vec_envs=int(num_roads), num_cpus=num_cpus, base_class="gymnasium")
    if base_class == "gymnasium":
        return vec
    return _seeded_sb3_wrapper()(vec)


@functools.cache
def _seeded_sb3_wrapper() -> type:
    """SuperSuit's SB3 wrapper with SB3's seeding (built on first use: it imports Stable-Baselines3)."""
    try:
        from supersuit.vector.sb3_vector_wrapper import SB3VecEnvWrapper
    except ImportError:
        raise ImportError("sb3_vec_env needs Stable-Baselines3: pip install 'overtakezoo[marl]'") from None

    class SeededSB3VecEnv(SB3VecEnvWrapper):
        """``seed(s)`` (what ``PPO(seed=s)`` calls) applies at the next ``reset()``, road ``i`` with ``s + i``."""

        _next_seed: int | None = None
        _next_options: dict[str, Any] | None = None

        def seed(self, seed: int | None = None) -> list[int | None]:
            if seed is None:  # as SB3's VecEnv.seed: a fresh seed, so that copies differ
                seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
            self._next_seed = int(seed)
            return [self._next_seed + i for i in range(self.num_envs)]

        def reset(self, seed: int | None = None, options: dict[str, Any] | None = None) -> np.ndarray:
            if seed is not None:
                self.seed(seed)
            seed, self._next_seed = self._next_seed, None
            options, self._next_options = options if options is not None else self._next_options, None
            observations, self.reset_infos = self.venv.reset(seed=seed, options=options)
            return observations

        def set_options(self, options: dict[str, Any] | list[dict[str, Any]] | None = None) -> None:
            """As SB3's: options for the next ``reset()`` (one dict for every road)."""
            if isinstance(options, list):
                if any(o != options[0] for o in options):
                    raise ValueError("SuperSuit's vector resets every road with the same options")
                options = options[0] if options else None
            self._next_options = options

    return SeededSB3VecEnv
