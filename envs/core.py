"""The batched simulation core: N roads stepped at once as a structure of arrays.

A road holds E automated vehicles (AVs; E = 1 is the paper's single-ego road) and M NPCs. One call
to :meth:`OvertakeCore.step` advances every road by ``dt``: the shared planner turns each AV's mode
into a path and an acceleration (planner.py) that the AV tracks (dynamics.py), the NPCs' controllers
set their accelerations (controllers.py: one IDM for everyone), then contacts (collisions.py),
outcomes (outcomes.py) and rewards (reward.py) are resolved. There is no Python loop over roads or
vehicles. Finished rows are either held frozen (evaluation; their ``dt`` is zero) or replaced by
fresh scenarios (training, ``auto_reset=True``).

AV rows: the batch the deciders see has one row per AV, ``B = E * N`` rows, AV ``e`` of road ``n``
in row ``e * N + n``. Each AV's state (``x, y, psi, v, ...``, (B,)) is kept in its own frame: x along
its direction of travel, y from its own lane's centre towards the lane it overtakes through. For an
AV driving towards -s that frame is the road turned half a turn (x = -s, y = lane_width - d), so the
planner, the observation and every decider work unchanged for AVs in either direction. What an AV
sees (``geometry()``, (B, M + E - 1)) is every NPC of its road and every other AV, in its frame.

Layout: public arrays are batch-first, (N,) and (N, M). Internally every per-NPC array is kept
batch-last, (M, N), and the planner works on (R, M, N): numpy reduces a short trailing axis at
~20 ns per row, so with the batch last, reductions over vehicles and rollouts become a few fast
elementwise passes (about 10x faster per step at N = 4096). ``npc_s`` etc. are (N, M) views.

Backends: the model is written once against ``self.xp`` (envs/backend.py): numpy by default, or
torch tensors on a device (``backend="torch"``), e.g. to step very large batches on a GPU.

This module is the batch's state and the step order only: every state array is allocated, reset,
cloned and advanced here, while the physics lives in ``envs/model/`` as functions of these arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from overtakezoo.envs.backend import make_backend
from overtakezoo.envs.config import ABORT, OVERTAKE, EnvConfig
from overtakezoo.envs.model.collisions import av_contacts, lane_contacts
from overtakezoo.envs.model.controllers import IDM, PLANNER, SCRIPTED_KIND, notices_avs, npc_accelerations, speeds_up
from overtakezoo.envs.model.dynamics import AVMotion, advance_npcs, track
from overtakezoo.envs.model.frames import (
    av_constants,
    av_velocity,
    avs_world,
    multi_geometry,
    other_avs,
    view_constants,
    view_terms,
)
from overtakezoo.envs.model.observation import observation_size, observe
from overtakezoo.envs.model.outcomes import CRASH, OFFROAD, OUTCOME_NAMES, RUNNING, SUCCESS, TIMEOUT, Ending, resolve
from overtakezoo.envs.model.planner import ModeTable, Plan, plan
from overtakezoo.envs.model.reward import step_reward
from overtakezoo.envs.scenarios import OPPOSITE_LANE, SCRIPTED, Scenarios

__all__ = ["OvertakeCore", "StepResult", "RUNNING", "SUCCESS", "CRASH", "TIMEOUT", "OFFROAD", "OUTCOME_NAMES"]

ScenarioSource = Callable[[int, np.random.Generator], Scenarios]


@dataclass
class StepResult:
    obs: np.ndarray  # (B, D) float32, after any auto-reset
    reward: np.ndarray  # (B,)
    terminated: np.ndarray  # (B,) bool: success / crash / off-road this step
    truncated: np.ndarray  # (B,) bool: time limit this step
    final_obs: np.ndarray | None  # (B, D) the observation before an auto-reset (auto_reset only)
    info: dict[str, np.ndarray]  # per-row arrays (outcome, crash vehicle/lane, episode stats)

    @property
    def finished(self) -> np.ndarray:
        """(B,) bool: the rows whose episode ended at this step (a frozen row is not finished again)."""
        return self.terminated | self.truncated


class OvertakeCore:
    """Steps a batch of roads. ``modes`` are ints, one per AV row: 0 follow, 1 overtake, 2 abort."""

    _NPC_STATE = ("npc_s", "npc_v", "npc_a", "npc_boosted", "npc_crashed")
    _STATE = (
        "x",
        "y",
        "psi",
        "v",
        "a",
        "steer",
        "yaw_rate",
        "mode",
        "rollout",
        "t",
        "done",
        "outcome",
        "crash_npc",
        "crash_lane",
        "crash_av",
        "episode_return",
        "episode_steps",
    )

    def __init__(
        self,
        config: EnvConfig | None = None,
        auto_reset: bool = False,
        source: ScenarioSource | None = None,
        seed: int | np.random.Generator | None = None,
        backend: str = "numpy",
        device: Any = None,
        dtype: Any = None,
        bank: Scenarios | None = None,
        sync_free: bool | None = None,
    ) -> None:
        self.cfg = config or EnvConfig()
        self.auto_reset = auto_reset
        self.source = source
        self.rng = np.random.default_rng(seed)
        self.xp = make_backend(backend, device, dtype, sync_free)
        if bank is not None and (not auto_reset or source is not None or bank.num_avs != 1 or not bank.num):
            raise ValueError("bank: auto-reset from a bank needs auto_reset=True, no source and single-AV scenarios")
        self.bank = bank
        self.table = ModeTable.from_config(self.cfg.planner).to(self.xp)
        self.last_plan: Plan | None = None
        self.scen: Scenarios | None = None

    # Per-NPC state is stored (M, N); these properties give the public (N, M) views.
    npc_s = property(lambda self: self._npc_s.T, lambda self, v: setattr(self, "_npc_s", self.xp.batch_last(v)))
    npc_v = property(lambda self: self._npc_v.T, lambda self, v: setattr(self, "_npc_v", self.xp.batch_last(v)))
    npc_a = property(lambda self: self._npc_a.T, lambda self, v: setattr(self, "_npc_a", self.xp.batch_last(v)))
    npc_boosted = property(
        lambda self: self._npc_boosted.T, lambda self, v: setattr(self, "_npc_boosted", self.xp.batch_last(v))
    )
    npc_crashed = property(
        lambda self: self._npc_crashed.T, lambda self, v: setattr(self, "_npc_crashed", self.xp.batch_last(v))
    )

    @property
    def num(self) -> int:
        """AV rows: one per automated vehicle, ``num_avs * num_roads``."""
        assert self.scen is not None, "reset() first"
        return self.num_avs * self.scen.num

    @property
    def obs_size(self) -> int:
        return observation_size(self.cfg)

    # ------------------------------------------------------------------ reset
    def reset(self, scenarios: Scenarios) -> np.ndarray:
        """Start every road on ``scenarios``; returns the first observation of every AV row."""
        xp, n, m, e = self.xp, scenarios.num, scenarios.num_npcs, scenarios.num_avs
        b = n * e
        self.num_roads, self.num_npcs, self.num_avs = n, m, e
        self.x, self.y, self.v, self.psi, self.a, self.steer, self.yaw_rate, self.t, self.episode_return = (
            xp.zeros(b) for _ in range(9)
        )
        self.mode, self.rollout, self.episode_steps = (xp.zeros(b, xp.int) for _ in range(3))
        self.done, self.outcome = xp.zeros(b, xp.bool), xp.zeros(b, xp.int8)
        self.crash_npc, self.crash_lane, self.crash_av = (xp.full(b, -1, xp.int) for _ in range(3))
        self.stats = {key: xp.zeros(b, xp.int if key in ("aborts", "switches") else None) for key in _STAT_INIT}
        self._npc_s, self._npc_v, self._npc_a = (xp.zeros((m, n)) for _ in range(3))
        self._npc_aware = xp.zeros((e, m, n))
        self._npc_boosted, self._npc_crashed = xp.zeros((m, n), xp.bool), xp.zeros((m, n), xp.bool)
        self._npc_crashed_any = False  # (cheaper than asking _npc_crashed every step; stays set until reset)
        self._npc_leader = xp.full((m, n), -1, xp.int)
        self._all_present = xp.full((1, n), True, xp.bool)
        if self.auto_reset:  # auto-reset rewrites rows of the batch in place: keep a private copy
            scenarios = Scenarios.from_arrays({k: v.copy() for k, v in scenarios.to_arrays().items()})
        self.scen = scenarios
        if self.bank is not None:
            self._setup_bank(scenarios)
        self._set_scenarios(scenarios)
        if self.bank is not None:
            self._lane_mates: bool = self._lane_mates or self._bank_lane_mates
        self._start_rows(xp.arange(n), scenarios)
        self.last_plan = None
        self._step_geo: dict[str, Any] | None = None
        return self.observe()

    def _set_scenarios(self, sc: Scenarios, rows: Any = None) -> None:
        """Cache the scenarios' constants in the backend's layout: per AV row (B,), per NPC (M, N) and
        the view each AV row has of the NPCs (M, B); they do not change within an episode. With
        ``rows`` (roads), ``sc`` holds only those roads' scenarios and just their columns are rewritten."""
        ego, npc = self._constants(sc)
        if rows is None:
            self._ego, self._npc = ego, npc
        else:
            cols = self._av_rows(rows)
            for key, value in ego.items():
                self._ego[key][cols] = value
            for key, value in npc.items():
                self._npc[key][..., rows] = value
        self._lane_mates = bool(self._npc["lane_mates"].any())
        if self.num_avs == 1:  # the single-AV road: its view of the NPCs is the NPCs
            self._sc = self._npc
        else:
            self._npc_view = view_constants(self._npc, self._ego, self.num_avs, self.xp)

    def _av_rows(self, roads: Any) -> Any:
        """The AV rows of ``roads`` (all AVs of each)."""
        xp = self.xp
        assert self.scen is not None, "reset() first"
        roads = xp.asarray(roads, xp.int).reshape(-1)
        return (xp.arange(self.num_avs)[:, None] * self.scen.num + roads[None, :]).reshape(-1)

    def _constants(self, sc: Scenarios) -> tuple[dict[str, Any], dict[str, Any]]:
        xp, e = self.xp, sc.num_avs
        ego = {name: xp.asarray(getattr(sc, name), xp.float) for name in _EGO_FIELDS}
        T = {name[4:]: xp.batch_last(getattr(sc, name)) for name in _NPC_FIELDS}
        T["same_dir"] = T["lane"] != OPPOSITE_LANE
        T["direction"] = xp.where(T["same_dir"], 1.0, -1.0)
        w = ego["lane_width"]
        T["d"] = T["lane"] * w
        T["half_length"], T["half_width"] = T["length"] / 2, T["width"] / 2
        T["speedup"] = speeds_up(T["behaviour"])
        T["notices_ego"] = notices_avs(T["behaviour"])  # a scripted NPC drives its speed profile, blind to AVs
        T["pair_same_lane"] = (T["lane"][:, None] == T["lane"][None, :]) & T["present"][None, :]  # (M, M, N)
        T["pair_half_len"] = (T["length"][:, None] + T["length"][None, :]) / 2
        others = xp.arange(T["lane"].shape[0])[:, None] != xp.arange(T["lane"].shape[0])[None, :]
        T["lane_mates"] = xp.any(xp.any(T["pair_same_lane"] & others[:, :, None], axis=0), axis=0)  # (N,)
        if e > 1:  # every AV row gets its road's constants, and its own direction, goal and lead
            ego = {k: xp.concatenate([v] * e) for k, v in ego.items()}
            ego.update(av_constants(sc, xp))
        else:
            T.update(view_terms(T, ego, self.cfg.planner, xp))
        ego["half_ego_length"], ego["half_ego_width"] = ego["ego_length"] / 2, ego["ego_width"] / 2
        ego["half_lane_width"] = half_w = ego["lane_width"] / 2
        ego["offroad_low"], ego["offroad_high"] = -half_w - 0.5, 3 * half_w + 0.5
        ego["time_up"] = ego["time_limit"] - 1e-9
        return ego, T

    def _start_rows(self, rows: Any, fresh: Scenarios) -> None:
        """Initial state of roads ``rows`` from the scenarios ``fresh`` (one per road)."""
        xp = self.xp
        assert fresh.av_s is not None and fresh.av_d is not None and fresh.av_v is not None
        assert fresh.av_direction is not None  # (Scenarios.__post_init__ fills the AV fields)
        cols = rows if self.num_avs == 1 else self._av_rows(rows)
        start_x, start_y, start_v = (np.asarray(getattr(fresh, k), float) for k in ("ego_s", "ego_d", "ego_v"))
        if self.num_avs > 1:  # the further AVs' starts, in their own frames
            flip = fresh.av_direction < 0
            start_x = np.concatenate([start_x, (fresh.av_s * fresh.av_direction).T.reshape(-1)])
            start_y = np.concatenate(
                [start_y, np.where(flip, fresh.lane_width[:, None] - fresh.av_d, fresh.av_d).T.reshape(-1)]
            )
            start_v = np.concatenate([start_v, fresh.av_v.T.reshape(-1)])
        self.x[cols], self.y[cols], self.v[cols] = (xp.asarray(a, xp.float) for a in (start_x, start_y, start_v))
        for name in ("psi", "a", "steer", "yaw_rate", "t", "episode_return"):
            getattr(self, name)[cols] = 0.0
        self._npc_s[:, rows] = xp.batch_last(fresh.npc_s, xp.float)
        self._npc_v[:, rows] = xp.batch_last(fresh.npc_v, xp.float)
        self._npc_a[:, rows] = 0.0
        # NPCs that start with the ego ahead in their lane (followers) already know it is there.
        behind_ego = (fresh.npc_lane == 0) & (fresh.npc_s < fresh.ego_s[:, None])
        aware = [behind_ego]
        if self.num_avs > 1:  # ... and so do NPCs that start behind any other AV in its lane
            lane = np.where(fresh.av_direction < 0, OPPOSITE_LANE, 0)[:, :, None]  # (N, K, 1)
            ahead = np.where(fresh.npc_lane == OPPOSITE_LANE, -1.0, 1.0)[:, None, :] * (
                fresh.av_s[:, :, None] - fresh.npc_s[:, None, :]
            )
            aware += list(np.moveaxis((fresh.npc_lane[:, None, :] == lane) & (ahead > 0), 1, 0))
        for e, knows in enumerate(aware):
            per_av = self._npc_aware[e]  # a view
            per_av[:, rows] = xp.batch_last(np.where(knows, np.inf, 0.0), xp.float)
        self._npc_boosted[:, rows] = False
        self._npc_crashed[:, rows] = False
        self._npc_leader[:, rows] = -1
        self.mode[cols], self.rollout[cols] = 0, 0
        self.done[cols], self.outcome[cols] = False, RUNNING
        self.crash_npc[cols], self.crash_lane[cols], self.crash_av[cols] = -1, -1, -1
        self.episode_steps[cols] = 0
        for key, arr in self.stats.items():
            arr[cols] = _STAT_INIT[key]

    # ---------------------------------------------------------- scenario bank
    def _setup_bank(self, batch: Scenarios) -> None:
        """The bank's scenarios in the backend's layout, once: the constants (_constants) and the
        start state of every entry, so that a restart is a gather and a masked write (no host)."""
        xp, bank = self.xp, self.bank
        assert bank is not None
        if batch.num_avs != 1:
            raise ValueError("bank: auto-reset from a bank runs single-AV batches")
        m = max(bank.num_npcs, batch.num_npcs)
        if batch.num_npcs < m:
            raise ValueError(
                f"bank: its scenarios have {bank.num_npcs} NPC slots, more than the batch's {batch.num_npcs}"
            )
        bank = bank.pad_npcs(m)
        ego, npc = self._constants(bank)
        behind_ego = (bank.npc_lane == 0) & (bank.npc_s < bank.ego_s[:, None])
        start = {
            "x": xp.asarray(bank.ego_s, xp.float),
            "y": xp.asarray(bank.ego_d, xp.float),
            "v": xp.asarray(bank.ego_v, xp.float),
            "_npc_s": xp.batch_last(bank.npc_s, xp.float),
            "_npc_v": xp.batch_last(bank.npc_v, xp.float),
            "_npc_aware": xp.batch_last(np.where(behind_ego, np.inf, 0.0), xp.float)[None],
        }
        self._bank = {"ego": ego, "npc": npc, "start": start}
        self._bank_lane_mates = bool(npc["lane_mates"].any())
        self._bank_next = xp.zeros((), xp.int)  # the next entry to start (a device scalar: never read on the host)
        self.bank_row = xp.full(batch.num, -1, xp.int)  # each road's bank entry (-1: the reset batch's own)

    def reset_from_bank(self, num_roads: int) -> Any:
        """Start ``num_roads`` roads on the bank's first entries (cycling) and go on from the entry
        after them; returns the first observation (an auto-reset core with a ``bank`` only)."""
        if self.bank is None:
            raise ValueError("reset_from_bank: the core has no bank (OvertakeCore(bank=...))")
        obs = self.reset(self.bank.take(np.arange(num_roads) % self.bank.num))
        self._bank_next = self._bank_next + num_roads % self.bank.num
        self.bank_row = self.xp.asarray(np.arange(num_roads) % self.bank.num, self.xp.int)
        return obs

    def _restart_from_bank(self, ended: Any) -> None:
        """Start the next bank entries (in order, cycling) in the roads ``ended`` (N,) bool, by masked
        writes: no index list, no host read, so the step stays sync-free. ``self.scen`` keeps the
        reset batch; ``bank_row`` says which entry each road now runs."""
        xp, bank = self.xp, self._bank
        k = self.bank.num if self.bank is not None else 1
        idx = (self._bank_next + xp.cumsum(xp.astype(ended, xp.int)) - 1) % k  # (N,): ended rows in order
        self._bank_next = (self._bank_next + xp.sum(xp.astype(ended, xp.int))) % k

        def put(old: Any, new: Any) -> Any:
            return xp.astype(xp.where(ended, new, old), old.dtype)

        for key, value in bank["ego"].items():
            self._ego[key] = put(self._ego[key], value[idx])
        for key, value in bank["npc"].items():
            self._npc[key] = put(self._npc[key], value[..., idx])
        self._sc = self._npc
        for key, value in bank["start"].items():
            setattr(self, key, put(getattr(self, key), value[..., idx]))
        for name in ("psi", "a", "steer", "yaw_rate", "t", "episode_return", "_npc_a"):
            setattr(self, name, put(getattr(self, name), 0.0))
        for name in ("_npc_boosted", "_npc_crashed", "done"):
            setattr(self, name, put(getattr(self, name), False))
        for name in ("mode", "rollout", "episode_steps"):
            setattr(self, name, put(getattr(self, name), 0))
        for name in ("crash_npc", "crash_lane", "crash_av", "_npc_leader"):
            setattr(self, name, put(getattr(self, name), -1))
        self.outcome = put(self.outcome, RUNNING)
        self.stats = {key: put(value, _STAT_INIT[key]) for key, value in self.stats.items()}
        if self.last_plan is not None:
            self.last_plan.blocked = xp.where(ended[:, None], False, self.last_plan.blocked)
        self.bank_row = put(self.bank_row, idx)

    def _replace_rows(self, rows: Any, fresh: Scenarios) -> None:
        """Put ``fresh`` scenarios into roads ``rows`` (auto-reset) without touching other roads."""
        assert self.scen is not None, "reset() first"
        if fresh.num_npcs > self.scen.num_npcs:
            raise ValueError("auto-reset scenarios have more NPC slots than the batch")
        if fresh.num_avs != self.num_avs:
            raise ValueError("auto-reset scenarios have another number of automated vehicles than the batch")
        fresh = fresh.pad_npcs(self.scen.num_npcs)
        host_rows = self.xp.to_numpy(rows)
        for name, value in fresh.to_arrays().items():  # in place: the batch's Scenarios is private
            getattr(self.scen, name)[host_rows] = value
        self._set_scenarios(fresh, rows)
        self._start_rows(rows, fresh)
        if self.last_plan is not None:  # a new episode starts with no planner flags, as after reset()
            self.last_plan.blocked[rows if self.num_avs == 1 else self._av_rows(rows)] = False

    def restart(self, rows: Any, fresh: Scenarios) -> Any:
        """Start ``fresh`` scenarios in roads ``rows`` (the other roads untouched); the first
        observations of their AV rows. The batch's Scenarios are rewritten in place: reset the core
        on a private copy."""
        self._replace_rows(rows, fresh)
        return self.observe(self._geometry(), rows if self.num_avs == 1 else self._av_rows(rows))

    def clone(self, rows: Any = None) -> OvertakeCore:
        """An independent copy of roads ``rows`` (all when None), e.g. for look-ahead search."""
        xp = self.xp
        assert self.scen is not None, "reset() first"
        idx = xp.arange(self.scen.num) if rows is None else xp.asarray(rows)
        cols = idx if self.num_avs == 1 else self._av_rows(idx)
        other = OvertakeCore(self.cfg, auto_reset=False)
        other.xp, other.table = xp, self.table
        other.scen = self.scen.take(xp.to_numpy(idx))
        other.num_roads, other.num_npcs, other.num_avs = other.scen.num, self.num_npcs, self.num_avs
        other._set_scenarios(other.scen)
        for name in self._STATE:
            setattr(other, name, xp.copy(getattr(self, name)[cols]))
        for name in self._NPC_STATE:
            setattr(other, "_" + name, xp.copy(getattr(self, "_" + name)[:, idx]))
        other._npc_aware = xp.copy(self._npc_aware[:, :, idx])
        other._npc_leader = xp.copy(self._npc_leader[:, idx])
        other._npc_crashed_any = bool(other._npc_crashed.any())
        other._all_present = xp.full((1, other.scen.num), True, xp.bool)
        other.stats = {k: xp.copy(v[cols]) for k, v in self.stats.items()}
        return other

    # ------------------------------------------------------------- geometry
    def _avs_world(self) -> dict[str, Any]:
        """The AVs in world coordinates, (E, N) arrays (for the NPCs' controllers and the views)."""
        if self.num_avs == 1:  # the ego's frame is the world's (velocity: _av_velocity, once the AVs have moved)
            return {"s": self.x[None], "d": self.y[None], "psi": self.psi[None], "present": self._all_present}
        return avs_world(self.x, self.y, self.psi, self.v, self.done, self.outcome, self._ego, self.num_avs, self.xp)

    def _av_velocity(self) -> Any:
        """(E, N): each AV's velocity along +s (zero once it is done: it has stopped or left)."""
        if self.num_avs == 1:
            return (self.v * self.xp.cos(self.psi))[None]
        return av_velocity(self.v, self.psi, self.done, self._ego["direction"], self.num_avs, self.xp)

    @property
    def _other_av(self) -> Any:
        """(E - 1, B): for each AV row, the index of each other AV of its road, in order."""
        assert self.scen is not None, "reset() first"
        return other_avs(self.num, self.scen.num, self.num_avs, self.xp)

    def _geometry(self) -> dict[str, Any]:
        """Relative geometry of every vehicle an AV row sees, in its frame, batch-last (M', B); shared
        by the planner, collisions, outcomes, observation and statistics. ``s`` is their position."""
        if self.num_avs == 1:
            T = self._sc
            dx = self._npc_s - self.x
            return {
                "s": self._npc_s,
                "dx": dx,
                "dy": T["d"] - self.y,
                "d": T["d"],
                "same_dir": T["same_dir"],
                "direction": T["direction"],
                "v_along": T["direction"] * self._npc_v,  # NPC velocity along +s
                "half_len": T["half_len"],
                "half_wid": T["half_wid"],
                "visible": T["present"] & (self.xp.abs(dx) <= T["reach"]),
            }
        geo, self._sc = multi_geometry(
            self._avs_world(),
            self.x,
            self.y,
            self._npc_s,
            self._npc_v,
            self._npc,
            self._npc_view,
            self._ego,
            self.num_avs,
            self.cfg.planner,
            self.xp,
        )
        return geo

    def _plan_inputs(self, geo: dict[str, Any]) -> dict[str, Any]:
        T = self._sc
        return {
            **geo,
            "offsets": T["offsets"],
            "lat_margin": T["lat_margin"],
            "inside": T["inside"],
            "lat_cost": T["lat_cost"],
            "priority": T["priority"],
            "lon_reach": T["lon_reach"],
            "beside_reach": T["beside_reach"],
        }

    def step_geometry(self) -> dict[str, Any] | None:
        """The batch-last geometry (M', B) the last :meth:`step` computed after the vehicles moved (the
        one its outcomes and statistics used; before any auto-reset), with ``present`` (which slots
        hold a vehicle); None before the first step. Read-only: the arrays are the core's own."""
        return getattr(self, "_step_geo", None)

    def geometry(self) -> dict[str, Any]:
        """The same geometry as (B, M') arrays: dx, dy, d, same_dir, direction, v_along, half_len,
        half_wid, visible."""
        return {key: value.T for key, value in self._geometry().items() if key not in ("s", "psi")}

    def _motion(self) -> AVMotion:
        return AVMotion(self.x, self.y, self.psi, self.v, self.a, self.steer, self.yaw_rate)

    def observe(self, geo: dict[str, Any] | None = None, cols: Any = None) -> Any:
        """The observation of every AV row (only rows ``cols`` when given) from ``geo`` (now's when None)."""
        geo = geo if geo is not None else self._geometry()
        p = self.last_plan
        blocked = p.blocked if p is not None and p.blocked.shape[0] == self.num else None
        motion = self._motion()
        view_mode = self._view_mode() if self.cfg.observation.v2v else None
        return observe(self.cfg, motion, self.mode, blocked, self._ego, self._sc, geo, self.xp, cols, view_mode, self.t)

    def _view_mode(self) -> Any:
        """(M', B): the mode of each vehicle an AV row sees that is another AV, -1 for an NPC (the
        v2v observation block); None on single-AV roads (no AV in view)."""
        if self.num_avs == 1:
            return None
        xp, n = self.xp, self.num_roads
        cols = xp.arange(self.num)[None, :] % n
        av_modes = self.mode[self._other_av * n + cols]  # (E - 1, B), in the view's order (after the NPCs)
        return xp.concatenate([xp.full((self.num_npcs, self.num), -1, xp.int), av_modes])

    # ----------------------------------------------------------------- step
    def step(self, modes: Any, npc_accel: Any = None) -> StepResult:
        """Advance every road by one ``dt`` under ``modes`` (B,), one per AV row. ``npc_accel`` (N, M)
        overrides the IDM acceleration of NPCs where it is finite (NPCs exposed as agents)."""
        reward, terminated, truncated, info, geo = self.advance(modes, npc_accel)
        finished = terminated | truncated
        obs = self.observe(geo)
        final_obs = None
        if self.bank is not None:  # sync-free: every step, masked (the rows that did not end keep theirs)
            final_obs, ended = obs, self.done
            self._restart_from_bank(ended)
            obs = self.xp.where(ended[:, None], self.observe(), obs)
        elif self.auto_reset and finished.any():
            final_obs = obs  # (an AV that finished while its road runs on keeps this observation)
            ended = self._ended_roads()
            if ended.any():
                roads = self.xp.nonzero(ended)
                obs = self.xp.copy(obs)
                cols = roads if self.num_avs == 1 else self._av_rows(roads)
                assert self.source is not None, "auto_reset needs a scenario source"
                obs[cols] = self.restart(roads, self.source(len(roads), self.rng))  # only those rows change
        return StepResult(obs, reward, terminated, truncated, final_obs, info)

    def advance(self, modes: Any, npc_accel: Any = None) -> tuple[Any, Any, Any, dict[str, Any], dict[str, Any]]:
        """:meth:`step` without the observation and the auto-reset: (reward, terminated, truncated,
        info, the geometry after the move). A look-ahead on a clone that reads only outcomes steps
        with it (the observation is about a seventh of a platoon step)."""
        xp, cfg, pc, E = self.xp, self.cfg, self.cfg.planner, self._ego
        modes = xp.asarray(modes, xp.int).reshape(-1)
        if modes.shape[0] != self.num:
            raise ValueError(f"expected {self.num} modes, got {modes.shape[0]}")
        if not xp.sync_free and ((modes < 0) | (modes > 2)).any():  # (sync-free: the caller's modes are trusted)
            raise ValueError("modes must be 0 (follow), 1 (overtake) or 2 (abort)")
        active = ~self.done
        dt = cfg.dt * xp.astype(active, xp.float)  # finished rows are frozen: their clock does not run
        prev_mode = self.mode
        modes = xp.where(active, modes, prev_mode)
        switched = modes != prev_mode  # (all False on the usual step, where no row changes its mode)
        if xp.some(switched):
            # An abort counts only when it ends an overtake under way (from OVERTAKE): ABORT chosen
            # while following changes nothing the planner does, so it is no abort.
            self.stats["aborts"] += active & (modes == ABORT) & (prev_mode == OVERTAKE)
            switched = active & switched & ((modes == OVERTAKE) | (prev_mode == OVERTAKE))
            self.stats["switches"] += switched
        self.mode = modes

        geo = self._geometry()
        ego = {"y": self.y, "v": self.v, "lane_width": E["lane_width"], "speed_limit": E["speed_limit"]}
        p = plan(pc, self.table, modes, self.rollout, ego, self._plan_inputs(geo), xp)
        self.last_plan = p
        self.rollout = xp.where(active, p.rollout, self.rollout)

        road_dt = (
            dt if self.num_avs == 1 else cfg.dt * xp.astype(xp.any(active.reshape(self.num_avs, -1), axis=0), xp.float)
        )
        avs = self._avs_for_npcs(geo)  # where the NPCs see the AVs: before they move, as the planner did
        motion, jerk = track(self._motion(), p, dt, pc, cfg.dt, E, xp)
        self.x, self.y, self.psi, self.v, self.a, self.steer, self.yaw_rate = motion
        avs["v_along"] = self._av_velocity()  # ... and how fast they now go
        self._npc_a, self._npc_aware, self._npc_boosted, leader = npc_accelerations(
            self._npc_s,
            self._npc_v,
            self._npc,
            self._npc_aware,
            self._npc_boosted,
            avs,
            road_dt,
            npc_accel,
            cfg.npc,
            self._lane_mates,
            xp,
        )
        if leader is not None:
            self._npc_leader = leader
        self._npc_s, self._npc_v = advance_npcs(
            self._npc_s,
            self._npc_v,
            self._npc_a,
            road_dt,
            self._npc["direction"],
            self._npc["present"],
            self._npc_crashed if self._npc_crashed_any else None,
            xp,
        )
        self.t = self.t + dt
        self.episode_steps += active

        geo = self._geometry()
        self._step_geo = {**geo, "present": self._sc["present"]}  # for step_geometry(): not recomputed
        hit = self._contacts(geo)
        self._npc_collisions(hit)
        prev = Ending(
            self.outcome, self.crash_npc, self.crash_lane, self.crash_av, self.stats["completion_time"], self.done
        )
        terminated, truncated, end = resolve(
            self.x,
            self.y,
            self.t,
            prev,
            E,
            self._sc,
            geo,
            hit,
            active,
            self.num_npcs,
            self._other_av if self.num_avs > 1 else None,
            xp,
        )
        (self.outcome, self.crash_npc, self.crash_lane, self.crash_av, self.stats["completion_time"], self.done) = end
        self._update_stats(geo, active, jerk)
        reward = step_reward(cfg.reward, self.x, self.outcome, E, terminated, truncated, switched, active, xp)
        self.episode_return += reward
        return reward, terminated, truncated, self.info(), geo

    def _contacts(self, geo: dict[str, Any]) -> Any:
        E, T = self._ego, self._sc
        return av_contacts(
            self.xp,
            self.psi,
            E["half_ego_length"],
            E["half_ego_width"],
            geo["dx"],
            geo["dy"],
            T["half_length"],
            T["half_width"],
            T["present"],
            geo.get("psi"),
        )

    def contacts(self) -> Any:
        """(B, M') bool: which vehicles in each AV row's view touch that AV now."""
        return self._contacts(self._geometry()).T

    def _ended_roads(self) -> Any:
        """(N,) bool: roads whose every AV is done."""
        return self.done if self.num_avs == 1 else self.xp.all(self.done.reshape(self.num_avs, -1), axis=0)

    def _avs_for_npcs(self, geo: dict[str, Any]) -> dict[str, Any]:
        """The AVs as the NPCs' controllers see them: world positions, each NPC's offset from each AV
        (``dx``, ``dy``) and the half-size sums (E, M, N)."""
        avs = self._avs_world()
        if self.num_avs == 1:  # the ego's frame is the world's: the planner's geometry is the NPCs' view
            avs.update(
                dx=geo["dx"][None], dy=geo["dy"][None], half_len=geo["half_len"][None], half_wid=geo["half_wid"][None]
            )
            return avs
        E, T, e = self._ego, self._npc, self.num_avs
        length, width = E["ego_length"].reshape(e, 1, -1), E["ego_width"].reshape(e, 1, -1)
        avs.update(
            dx=self._npc_s - avs["s"][:, None],
            dy=T["d"] - avs["d"][:, None],
            half_len=(length + T["length"][None]) / 2,
            half_wid=(width + T["width"][None]) / 2,
        )
        return avs

    def _npc_collisions(self, hit: Any) -> None:
        """NPCs hit by an AV, and NPC-NPC contacts (both parties): a crashed NPC stops where it is."""
        xp, m = self.xp, self.num_npcs
        crashed = None
        if m and xp.some(hit):  # (the usual step: no AV touches anything)
            struck = xp.any(hit[:m].reshape(m, self.num_avs, -1), axis=1)
            if xp.some(struck):
                crashed = self._npc_crashed | struck
        if self._lane_mates:  # (at most one NPC per lane in every road: no NPC-NPC contact)
            follower, lead = lane_contacts(
                xp,
                self._npc_s,
                self._npc["direction"],
                self._npc["half_length"],
                self._npc_leader,
                self._npc["present"],
            )
            if xp.some(follower):
                crashed = (self._npc_crashed if crashed is None else crashed) | follower
                if xp.sync_free:  # NPC i is run into where some follower's lead is i: (M, M, N), no indices
                    struck_lead = follower[:, None] & (lead[:, None] == xp.arange(m)[None, :, None])
                    crashed = crashed | xp.any(struck_lead, axis=0)
                else:
                    rows_j, rows_n = xp.nonzero2(follower)
                    crashed[lead[rows_j, rows_n], rows_n] = True  # the NPC it ran into
        if crashed is not None:
            self._npc_crashed, self._npc_crashed_any = crashed, True

    def _update_stats(self, geo: dict[str, Any], active: Any, jerk: Any) -> None:
        xp, st, E = self.xp, self.stats, self._ego
        in_opposite = self.y + E["half_ego_width"] > E["half_lane_width"]
        st["opposite_time"] += xp.astype(in_opposite & active, xp.float) * self.cfg.dt
        # Time to collision with vehicles ahead whose lane the ego overlaps.
        gap = geo["dx"] - geo["half_len"]
        closing = self.v - geo["v_along"]
        in_path = self._sc["present"] & (xp.abs(geo["dy"]) < geo["half_wid"]) & (gap > 0) & (closing > 1e-6)
        ttc = xp.amin(xp.where(in_path, gap / xp.where(in_path, closing, 1.0), INF), axis=0)
        st["min_ttc"] = xp.where(active, xp.minimum(st["min_ttc"], ttc), st["min_ttc"])
        lat_acc = xp.abs(self.v * self.yaw_rate)
        st["peak_lat_accel"] = xp.where(active, xp.maximum(st["peak_lat_accel"], lat_acc), st["peak_lat_accel"])
        st["peak_jerk"] = xp.where(active, xp.maximum(st["peak_jerk"], jerk), st["peak_jerk"])

    def info(self) -> dict[str, Any]:
        xp = self.xp
        out = {
            "outcome": xp.copy(self.outcome),
            "crash_npc": xp.copy(self.crash_npc),
            "crash_lane": xp.copy(self.crash_lane),
            "t": xp.copy(self.t),
            "episode_return": xp.copy(self.episode_return),
            "episode_steps": xp.copy(self.episode_steps),
        }
        if self.num_avs > 1:
            out["crash_av"] = xp.copy(self.crash_av)
        out.update({k: xp.copy(v) for k, v in self.stats.items()})
        return out

    def state_arrays(self) -> dict[str, Any]:
        """AV and NPC state of every row, batch-first (for recording, rendering, privileged deciders)."""
        return {
            "x": self.x,
            "y": self.y,
            "psi": self.psi,
            "v": self.v,
            "a": self.a,
            "steer": self.steer,
            "mode": self.mode,
            "rollout": self.rollout,
            "t": self.t,
            "npc_s": self.npc_s,
            "npc_v": self.npc_v,
            "done": self.done,
            "outcome": self.outcome,
        }

    def vehicles(self) -> dict[str, np.ndarray]:
        """Every vehicle of every road in world coordinates, (N, V) host arrays with V = E + M: the
        AVs first, then the NPC slots. ``kind`` is the controller (controllers.KIND_NAMES)."""
        sc = self.scen
        assert sc is not None and sc.av_direction is not None, "reset() first"
        xp, e, n = self.xp, self.num_avs, sc.num
        avs = self._avs_world()
        host = lambda a: np.asarray(xp.to_numpy(a), float)  # noqa: E731
        kind_npc = np.where(sc.npc_behaviour == SCRIPTED, SCRIPTED_KIND, IDM)
        length = np.concatenate([np.repeat(sc.ego_length[:, None], e, 1), sc.npc_length], axis=1)
        width = np.concatenate([np.repeat(sc.ego_width[:, None], e, 1), sc.npc_width], axis=1)
        direction = np.concatenate(
            [np.ones((n, 1)), sc.av_direction.astype(float), np.where(sc.npc_lane == OPPOSITE_LANE, -1.0, 1.0)], axis=1
        )
        return {
            "s": np.concatenate([host(avs["s"]).T, host(self._npc_s).T], axis=1),
            "d": np.concatenate([host(avs["d"]).T, sc.npc_lane * sc.lane_width[:, None]], axis=1),
            "v": np.concatenate([host(self.v).reshape(e, n).T, host(self._npc_v).T], axis=1),
            "direction": direction,
            "length": length,
            "width": width,
            "kind": np.concatenate([np.full((n, e), PLANNER), kind_npc], axis=1).astype(np.int8),
            "present": np.concatenate([host(avs["present"]).T > 0, sc.npc_present], axis=1),
        }


INF = float("inf")
_EGO_FIELDS = (
    "lane_width",
    "speed_limit",
    "goal_s",
    "road_length",
    "sensor_range",
    "time_limit",
    "ego_length",
    "ego_width",
)
_NPC_FIELDS = (
    "npc_present",
    "npc_lane",
    "npc_v_des",
    "npc_behaviour",
    "npc_boost",
    "npc_length",
    "npc_width",
    "npc_reaction",
    "npc_reveal",
    "npc_must_pass",
)
_STAT_INIT = {
    "completion_time": np.nan,
    "aborts": 0,
    "switches": 0,
    "opposite_time": 0.0,
    "min_ttc": np.inf,
    "peak_lat_accel": 0.0,
    "peak_jerk": 0.0,
}
