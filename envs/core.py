"""The batched simulation core: N scenarios stepped at once as a structure of arrays.

One call to :meth:`OvertakeCore.step` advances every scenario by ``dt``: the shared planner turns
each row's mode into a path and an acceleration, the ego tracks the path (kinematic bicycle +
pure pursuit, acceleration / jerk / steering-rate limits), the NPCs drive with IDM reacting to
whatever is ahead in their lane (the ego included, after their reaction delay), then collisions
(oriented boxes, separating axes) and outcomes are resolved. There is no Python loop over scenarios
or vehicles. Finished rows are either held frozen (evaluation; their ``dt`` is zero) or replaced by
fresh scenarios (training, ``auto_reset=True``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .config import ABORT, OVERTAKE, EnvConfig
from .observation import observe, observation_size
from .planner import ModeTable, Plan, clip, lateral_profile, plan
from .scenarios import OPPOSITE_LANE, SPEEDUP_WHEN_PASSED, Scenarios

RUNNING, SUCCESS, CRASH, TIMEOUT, OFFROAD = 0, 1, 2, 3, 4
OUTCOME_NAMES = ("running", "success", "crash", "timeout", "offroad")

ScenarioSource = Callable[[int, np.random.Generator], Scenarios]


@dataclass
class StepResult:
    obs: np.ndarray  # (N, D) float32, after any auto-reset
    reward: np.ndarray  # (N,)
    terminated: np.ndarray  # (N,) bool: success / crash / off-road this step
    truncated: np.ndarray  # (N,) bool: time limit this step
    final_obs: np.ndarray | None  # (N, D) the observation before an auto-reset (auto_reset only)
    info: dict[str, np.ndarray]  # per-row arrays (outcome, crash vehicle/lane, episode stats)


class OvertakeCore:
    """Steps a batch of scenarios. ``modes`` are ints: 0 follow, 1 overtake, 2 abort."""

    def __init__(self, config: EnvConfig | None = None, auto_reset: bool = False,
                 source: ScenarioSource | None = None, seed: int | None = None) -> None:
        self.cfg = config or EnvConfig()
        self.auto_reset = auto_reset
        self.source = source
        self.rng = np.random.default_rng(seed)
        self.table = ModeTable.from_config(self.cfg.planner)
        self.last_plan: Plan | None = None
        self.scen: Scenarios | None = None

    # ------------------------------------------------------------------ reset
    @property
    def num(self) -> int:
        return self.scen.num

    @property
    def obs_size(self) -> int:
        return observation_size(self.cfg)

    def reset(self, scenarios: Scenarios) -> np.ndarray:
        """Start every row on ``scenarios``; returns the first observation."""
        self.scen = scenarios
        n, m = scenarios.num, scenarios.num_npcs
        self.x = scenarios.ego_s.astype(float).copy()
        self.y = scenarios.ego_d.astype(float).copy()
        self.psi = np.zeros(n)
        self.v = scenarios.ego_v.astype(float).copy()
        self.a = np.zeros(n)
        self.steer = np.zeros(n)
        self.yaw_rate = np.zeros(n)
        self.npc_s = scenarios.npc_s.astype(float).copy()
        self.npc_v = scenarios.npc_v.astype(float).copy()
        self.npc_a = np.zeros((n, m))
        # NPCs that start with the ego ahead in their lane (followers) already know it is there.
        self.npc_aware = np.where((scenarios.npc_lane == 0) & (scenarios.npc_s < scenarios.ego_s[:, None]), np.inf, 0.0)
        self.npc_boosted = np.zeros((n, m), bool)
        self.mode = np.zeros(n, np.int64)
        self.rollout = np.zeros(n, np.int64)
        self.t = np.zeros(n)
        self.done = np.zeros(n, bool)
        self.outcome = np.zeros(n, np.int8)
        self.crash_npc = np.full(n, -1, np.int64)
        self.crash_lane = np.full(n, -1, np.int64)
        self.stats = {
            "completion_time": np.full(n, np.nan),
            "aborts": np.zeros(n, np.int64),
            "switches": np.zeros(n, np.int64),
            "opposite_time": np.zeros(n),
            "min_ttc": np.full(n, np.inf),
            "peak_lat_accel": np.zeros(n),
            "peak_jerk": np.zeros(n),
        }
        self.episode_return = np.zeros(n)
        self.episode_steps = np.zeros(n, np.int64)
        return self.observe()

    def _replace_rows(self, rows: np.ndarray, fresh: Scenarios) -> None:
        """Put ``fresh`` scenarios into ``rows`` (auto-reset) without touching other rows."""
        fresh = fresh.pad_npcs(self.scen.num_npcs)
        if fresh.num_npcs > self.scen.num_npcs:
            raise ValueError("auto-reset scenarios have more NPC slots than the batch")
        arrays = self.scen.to_arrays()
        for name, value in fresh.to_arrays().items():
            arrays[name] = arrays[name].copy()
            arrays[name][rows] = value
        self.scen = Scenarios.from_arrays(arrays)
        self.x[rows], self.y[rows], self.v[rows] = fresh.ego_s, fresh.ego_d, fresh.ego_v
        for name in ("psi", "a", "steer", "yaw_rate", "t", "episode_return"):
            getattr(self, name)[rows] = 0.0
        self.npc_s[rows], self.npc_v[rows] = fresh.npc_s, fresh.npc_v
        self.npc_a[rows] = 0.0
        self.npc_aware[rows] = np.where((fresh.npc_lane == 0) & (fresh.npc_s < fresh.ego_s[:, None]), np.inf, 0.0)
        self.npc_boosted[rows] = False
        self.mode[rows] = 0
        self.rollout[rows] = 0
        self.done[rows] = False
        self.outcome[rows] = RUNNING
        self.crash_npc[rows] = -1
        self.crash_lane[rows] = -1
        self.episode_steps[rows] = 0
        for key, arr in self.stats.items():
            arr[rows] = {"completion_time": np.nan, "min_ttc": np.inf}.get(key, 0)

    _STATE = ("x", "y", "psi", "v", "a", "steer", "yaw_rate", "npc_s", "npc_v", "npc_a", "npc_aware",
              "npc_boosted", "mode", "rollout", "t", "done", "outcome", "crash_npc", "crash_lane",
              "episode_return", "episode_steps")

    def clone(self, rows: np.ndarray | None = None) -> "OvertakeCore":
        """An independent copy of ``rows`` (all rows when None), e.g. for look-ahead search."""
        idx = np.arange(self.num) if rows is None else np.asarray(rows)
        other = OvertakeCore(self.cfg, auto_reset=False)
        other.scen = self.scen.take(idx)
        for name in self._STATE:
            setattr(other, name, getattr(self, name)[idx].copy())
        other.stats = {k: v[idx].copy() for k, v in self.stats.items()}
        other.last_plan = None
        return other

    # ------------------------------------------------------------- geometry
    def geometry(self) -> dict[str, np.ndarray]:
        """Relative geometry of every NPC w.r.t. the ego, shared by planner, observation and reward."""
        sc = self.scen
        same_dir = sc.npc_lane != OPPOSITE_LANE
        direction = np.where(same_dir, 1.0, -1.0)
        dx = self.npc_s - self.x[:, None]
        d = sc.npc_lane * sc.lane_width[:, None]
        reach = np.minimum(sc.sensor_range[:, None], sc.npc_reveal)
        visible = sc.npc_present & (np.abs(dx) <= reach)
        return {
            "dx": dx, "dy": d - self.y[:, None], "d": d, "same_dir": same_dir, "direction": direction,
            "v_along": direction * self.npc_v,  # NPC velocity along +s
            "half_len": (sc.ego_length[:, None] + sc.npc_length) / 2,
            "half_wid": (sc.ego_width[:, None] + sc.npc_width) / 2,
            "visible": visible,
        }

    def observe(self, geo: dict[str, np.ndarray] | None = None) -> np.ndarray:
        return observe(self, geo if geo is not None else self.geometry())

    # ----------------------------------------------------------------- step
    def step(self, modes: np.ndarray, npc_accel: np.ndarray | None = None) -> StepResult:
        """Advance every row by one ``dt`` under ``modes`` (N,). ``npc_accel`` (N, M) overrides the
        IDM acceleration of NPCs where it is finite (NPCs exposed as agents)."""
        cfg, pc, sc = self.cfg, self.cfg.planner, self.scen
        modes = np.asarray(modes, dtype=np.int64).reshape(-1)
        if modes.shape[0] != self.num:
            raise ValueError(f"expected {self.num} modes, got {modes.shape[0]}")
        if modes.size and (modes.min() < 0 or modes.max() > 2):
            raise ValueError("modes must be 0 (follow), 1 (overtake) or 2 (abort)")
        active = ~self.done
        dt = cfg.dt * active  # finished rows are frozen: their clock does not run
        prev_mode = self.mode
        modes = np.where(active, modes, prev_mode)
        switched = active & (modes != prev_mode) & ((modes == OVERTAKE) | (prev_mode == OVERTAKE))
        self.stats["switches"] += switched
        self.stats["aborts"] += active & (modes == ABORT) & (prev_mode != ABORT)
        self.mode = modes

        geo = self.geometry()
        ego = {"x": self.x, "y": self.y, "v": self.v, "lane_width": sc.lane_width, "speed_limit": sc.speed_limit}
        p = plan(pc, self.table, modes, self.rollout, ego, geo, geo["visible"])
        self.last_plan = p
        self.rollout = np.where(active, p.rollout, self.rollout)

        # Ego longitudinal: jerk-limited acceleration, speed in [0, limit].
        jerk_step = pc.max_jerk * dt
        a_new = self.a + clip(p.accel - self.a, -jerk_step, jerk_step)
        jerk = np.abs(a_new - self.a) / cfg.dt
        self.a = a_new
        v_new = clip(self.v + self.a * dt, 0.0, sc.speed_limit)
        self.a = np.where(v_new <= 0.0, np.maximum(self.a, 0.0), self.a)  # at standstill the brake holds
        # Ego lateral: pure pursuit on the chosen rollout, steering angle and rate limited.
        lookahead = np.maximum(pc.lookahead_min, pc.lookahead_gain * self.v)
        roll_in = pc.roll_in_speed_factor * self.v + pc.roll_in_margin
        target_y = lateral_profile(self.y, p.target_d, lookahead, sc.lane_width, roll_in, pc.car_tip_margin)
        alpha = np.arctan2(target_y - self.y, lookahead) - self.psi
        steer_cmd = np.arctan(2.0 * pc.wheelbase * np.sin(alpha) / lookahead)
        steer_cmd = clip(steer_cmd, -pc.max_steer, pc.max_steer)
        rate = pc.max_steer_rate * dt
        self.steer = self.steer + clip(steer_cmd - self.steer, -rate, rate)
        self.yaw_rate = v_new * np.tan(self.steer) / pc.wheelbase
        self.x = self.x + v_new * np.cos(self.psi) * dt
        self.y = self.y + v_new * np.sin(self.psi) * dt
        self.psi = self.psi + self.yaw_rate * dt
        self.v = v_new

        self._step_npcs(geo, dt, npc_accel)
        self.t = self.t + dt
        self.episode_steps += active

        geo = self.geometry()
        hit = self._collisions(geo)
        terminated, truncated = self._resolve(hit, active)
        self._update_stats(geo, active, jerk)
        reward = self._reward(terminated, truncated, switched, active)
        self.episode_return += reward
        finished = terminated | truncated
        info = self.info()
        info["_finished"] = finished
        obs = observe(self, geo)
        final_obs = None
        if self.auto_reset and finished.any():
            final_obs = obs
            rows = np.flatnonzero(finished)
            self._replace_rows(rows, self.source(len(rows), self.rng))
            obs = self.observe()
        return StepResult(obs, reward, terminated, truncated, final_obs, info)

    def _step_npcs(self, geo: dict[str, np.ndarray], dt: np.ndarray, npc_accel: np.ndarray | None) -> None:
        """IDM for every NPC behind the nearest vehicle ahead in its lane (NPC or, once noticed, ego)."""
        sc, nc = self.scen, self.cfg.npc
        direction, half_wid = geo["direction"], geo["half_wid"]
        # Other NPCs ahead in the same lane, measured along each NPC's own direction of travel.
        same_lane = (sc.npc_lane[:, :, None] == sc.npc_lane[:, None, :]) & sc.npc_present[:, None, :]
        ahead = direction[:, :, None] * (self.npc_s[:, None, :] - self.npc_s[:, :, None])
        pair_gap = ahead - (sc.npc_length[:, :, None] + sc.npc_length[:, None, :]) / 2
        pair_gap = np.where(same_lane & (ahead > 0), pair_gap, np.inf)
        lead_idx = pair_gap.argmin(axis=2)
        gap = pair_gap.min(axis=2)
        lead_v = self.npc_v[np.arange(sc.num)[:, None], lead_idx]
        # The ego counts once it occupies this lane ahead and the reaction delay has passed.
        ego_gap = -direction * geo["dx"] - geo["half_len"]
        ego_in_lane = (np.abs(geo["dy"]) < half_wid) & (ego_gap > -2 * geo["half_len"])
        self.npc_aware = np.where(ego_in_lane, self.npc_aware + dt[:, None], 0.0)
        sees_ego = ego_in_lane & (self.npc_aware >= sc.npc_reaction) & (ego_gap < gap)
        gap = np.where(sees_ego, ego_gap, gap)
        ego_v_along = direction * (self.v * np.cos(self.psi))[:, None]
        lead_v = np.where(sees_ego, ego_v_along, lead_v)
        # A speed-up lead raises its desired speed once the ego draws level in the other lane.
        passing = (sc.npc_behaviour == SPEEDUP_WHEN_PASSED) & (geo["dy"] < -half_wid) & (
            geo["dx"] - geo["half_len"] < nc.speedup_trigger)
        self.npc_boosted |= passing & (dt[:, None] > 0)
        v_des = sc.npc_v_des + np.where(self.npc_boosted, sc.npc_boost, 0.0)
        v = self.npc_v
        s_star = nc.min_gap + np.maximum(
            0.0, v * nc.time_headway + v * (v - lead_v) / (2.0 * np.sqrt(nc.max_acceleration * nc.comfortable_braking)))
        interaction = np.where(np.isfinite(gap), (s_star / np.maximum(gap, 0.1)) ** 2, 0.0)
        acc = nc.max_acceleration * (1.0 - (v / np.maximum(v_des, 1e-3)) ** 4 - interaction)
        if npc_accel is not None:
            acc = np.where(np.isfinite(npc_accel), npc_accel, acc)
        acc = clip(acc, -nc.max_braking, nc.max_acceleration)
        self.npc_a = acc
        self.npc_v = np.maximum(v + acc * dt[:, None], 0.0) * sc.npc_present
        self.npc_s = self.npc_s + direction * self.npc_v * dt[:, None]

    def _collisions(self, geo: dict[str, np.ndarray]) -> np.ndarray:
        """Ego (oriented box) against every NPC (axis-aligned box) by separating axes, (N, M) bool."""
        sc = self.scen
        c, s = np.abs(np.cos(self.psi))[:, None], np.abs(np.sin(self.psi))[:, None]
        cs, sn = np.cos(self.psi)[:, None], np.sin(self.psi)[:, None]
        he_l, he_w = sc.ego_length[:, None] / 2, sc.ego_width[:, None] / 2
        hn_l, hn_w = sc.npc_length / 2, sc.npc_width / 2
        dx, dy = geo["dx"], geo["dy"]
        hit = (np.abs(dx) <= hn_l + he_l * c + he_w * s)
        hit &= np.abs(dy) <= hn_w + he_l * s + he_w * c
        hit &= np.abs(dx * cs + dy * sn) <= he_l + hn_l * c + hn_w * s
        hit &= np.abs(-dx * sn + dy * cs) <= he_w + hn_l * s + hn_w * c
        return hit & sc.npc_present

    def _resolve(self, hit: np.ndarray, active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sc = self.scen
        crash = active & hit.any(axis=1)
        half_w = sc.lane_width / 2
        offroad = active & ~crash & ((self.y - sc.ego_width / 2 < -half_w - 0.5)
                                     | (self.y + sc.ego_width / 2 > 3 * half_w + 0.5))
        front, rear = self.x + sc.ego_length / 2, self.x - sc.ego_length / 2
        passed = np.logical_and.reduce(~sc.npc_must_pass | (rear[:, None] >= self.npc_s + sc.npc_length / 2), axis=1)
        in_lane = self.y + sc.ego_width / 2 <= half_w
        success = active & ~crash & ~offroad & (front >= sc.goal_s) & in_lane & passed
        # Out of time, or out of road (a follower stuck behind the lead past the goal): truncation.
        timeout = active & ~crash & ~offroad & ~success & (
            (self.t >= sc.time_limit - 1e-9) | (self.x > sc.road_length))
        hit_idx = hit.argmax(axis=1)
        self.crash_npc = np.where(crash, hit_idx, self.crash_npc)
        self.crash_lane = np.where(crash, sc.npc_lane[np.arange(sc.num), hit_idx], self.crash_lane)
        outcome = np.where(timeout, TIMEOUT, self.outcome)
        outcome = np.where(success, SUCCESS, outcome)
        outcome = np.where(offroad, OFFROAD, outcome)
        self.outcome = np.where(crash, CRASH, outcome).astype(np.int8)
        self.stats["completion_time"] = np.where(success, self.t, self.stats["completion_time"])
        terminated = crash | offroad | success
        self.done |= terminated | timeout
        return terminated, timeout

    def _update_stats(self, geo: dict[str, np.ndarray], active: np.ndarray, jerk: np.ndarray) -> None:
        sc, st = self.scen, self.stats
        in_opposite = self.y + sc.ego_width / 2 > sc.lane_width / 2
        st["opposite_time"] += in_opposite * self.cfg.dt * active
        # Time to collision with vehicles ahead whose lane the ego overlaps.
        gap = geo["dx"] - geo["half_len"]
        closing = self.v[:, None] - geo["v_along"]
        in_path = sc.npc_present & (np.abs(geo["dy"]) < geo["half_wid"]) & (gap > 0) & (closing > 1e-6)
        ttc = np.minimum.reduce(np.where(in_path, gap / np.where(in_path, closing, 1.0), np.inf), axis=1)
        st["min_ttc"] = np.where(active, np.minimum(st["min_ttc"], ttc), st["min_ttc"])
        lat_acc = np.abs(self.v * self.yaw_rate)
        st["peak_lat_accel"] = np.where(active, np.maximum(st["peak_lat_accel"], lat_acc), st["peak_lat_accel"])
        st["peak_jerk"] = np.where(active, np.maximum(st["peak_jerk"], jerk), st["peak_jerk"])

    def _reward(self, terminated: np.ndarray, truncated: np.ndarray, switched: np.ndarray,
                active: np.ndarray) -> np.ndarray:
        rc, sc = self.cfg.reward, self.scen
        dist = np.maximum(sc.goal_s - (self.x + sc.ego_length / 2), 0.0)
        r = rc.progress / (1.0 + dist / rc.progress_scale) * active
        r = r + rc.switch * switched
        terminal = np.array([0.0, rc.success, rc.crash, rc.timeout, rc.offroad])[self.outcome]
        r = r + terminal * (terminated | truncated)
        return r

    def info(self) -> dict[str, np.ndarray]:
        out = {"outcome": self.outcome.copy(), "crash_npc": self.crash_npc.copy(),
               "crash_lane": self.crash_lane.copy(), "t": self.t.copy(),
               "episode_return": self.episode_return.copy(), "episode_steps": self.episode_steps.copy()}
        out.update({k: v.copy() for k, v in self.stats.items()})
        return out

    def state_arrays(self) -> dict[str, np.ndarray]:
        """Ego and NPC state of every row (for recording, rendering and privileged deciders)."""
        return {"x": self.x, "y": self.y, "psi": self.psi, "v": self.v, "a": self.a, "steer": self.steer,
                "mode": self.mode, "rollout": self.rollout, "t": self.t, "npc_s": self.npc_s,
                "npc_v": self.npc_v, "done": self.done, "outcome": self.outcome}
