"""``shielded:<name>`` (registry name ``<name>+shield``): any decider behind an RSS shield.

A post-posed shield (Alshiekh et al. 2018, *Safe Reinforcement Learning via Shielding*): the wrapped
decider proposes a mode, and the shield lets it through unless the overtake it asks for cannot keep
the RSS opposite-direction distance (Shalev-Shwartz et al. 2017, Definition 2; ``envs/rss.py``) to
the nearest visible oncoming vehicle until the ego is back in its lane:

- a new overtake (mode FOLLOW -> OVERTAKE), or resuming one from ABORT, is vetoed;
- an overtake under way is aborted, while the lead it is passing is not yet behind the ego (past
  that, completing is the way out).

The check uses what the shared planner will do (``envs/model/planner.py``): in OVERTAKE it accelerates at
the overtake mode's ``acceleration`` up to its ``velocity`` (capped by the speed limit) until the ego
is ``required_gap`` ahead of the lead, then returns in ``RSSParams.lateral_return_time``. Over that
time the oncoming vehicle keeps its speed, and at the end the gap left must be at least the RSS
distance between the ego at its overtaking speed (in the wrong lane) and the oncoming vehicle (in its
correct lane). Everything is read from the observation: the shield sees what the decider sees.
A vehicle beyond sensor range cannot be checked; on ``occluded`` the shield only knows what it sees.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from overtakezoo.envs import ABORT, FOLLOW, OVERTAKE, EnvConfig, ScenarioDistribution, observation_layout
from overtakezoo.envs.model.observation import SLOT_FEATURES
from overtakezoo.envs.rss import RSSParams, safe_distance_opposite_direction
from overtakezoo.zoo.base import Decider

REQUIRED_GAP = 5.0  # m the ego's rear clears the lead's front before it merges back (Glennon's g, as fuzzy)


class Shielded(Decider):
    """``inner`` behind the RSS shield (module docstring)."""

    def __init__(self, inner: Decider, params: RSSParams | None = None) -> None:
        super().__init__(inner.config)
        self.inner, self.p = inner, params or RSSParams()
        self.name, self.version = f"{inner.name}+shield", f"{inner.version}.rss1"
        self.weights_sha256, self.action_repeat = inner.weights_sha256, inner.action_repeat
        self.privileged = bool(inner.privileged)
        if self.privileged:
            self.bind = inner.bind  # type: ignore[method-assign]  # (on purpose: the inner decider is bound)
        cfg = self.config
        self.layout = observation_layout(cfg)
        dist = ScenarioDistribution.from_dict(cfg.scenario)
        self.half_lengths = (dist.ego_length + dist.vehicle_length) / 2
        self.vehicle_length = dist.vehicle_length
        overtake = cfg.planner.modes["overtake"]
        self.accel, self.v_mode = overtake.acceleration, overtake.velocity

    @property  # (read-only where Decider's is a class attribute: it follows the inner decider)
    def row_state(self) -> tuple[str, ...] | None:  # type: ignore[override]  # all of it is the inner decider's
        return None if self.inner.row_state is None else ()

    def reset(self, mask: np.ndarray | None = None) -> None:
        self.inner.reset(mask)

    def keep_rows(self, rows: np.ndarray, core: Any = None) -> None:
        self.inner.keep_rows(rows, core)

    def act_batch(self, obs: np.ndarray) -> np.ndarray:
        want = np.asarray(self.inner.act(obs), np.int64)
        mode = np.argmax(obs[:, self.layout["mode"]], axis=1)
        unsafe, passing_lead = self.unsafe(obs)
        veto = unsafe & (want == OVERTAKE) & (mode != OVERTAKE)
        force = unsafe & (mode == OVERTAKE) & (want == OVERTAKE) & passing_lead
        out = np.where(veto, np.where(mode == ABORT, ABORT, FOLLOW), want)
        return np.where(force, ABORT, out)

    def unsafe(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N,) bool: completing an overtake now would break the RSS distance to the nearest visible
        oncoming vehicle; (N,) bool: the lead being passed is not yet behind the ego."""
        oc, n = self.config.observation, obs.shape[0]
        rows = np.arange(n)
        ego = obs[:, self.layout["ego"]].astype(float)
        v_e, in_opp = ego[:, 0] * oc.speed_scale, ego[:, 2] > 0.5
        v_cap = np.minimum(self.v_mode, ego[:, 4] * oc.speed_scale)
        # The vehicle being passed: nearest ego-lane vehicle ahead (in the opposite lane: not yet cleared).
        lane = obs[:, self.layout["ego_lane"]].reshape(n, -1, SLOT_FEATURES).astype(float)
        lx = lane[:, :, 1] * oc.position_scale
        behind = -self.half_lengths - REQUIRED_GAP
        cand = (lane[:, :, 0] > 0.5) & ((lx > 0.0) | (in_opp[:, None] & (lx > behind)))
        lkey = np.where(cand, lx, np.inf)
        li = np.argmin(lkey, axis=1)
        lead_dx = lkey[rows, li]
        has_lead = np.isfinite(lead_dx)
        v_lead = v_e + lane[rows, li, 3] * oc.speed_scale
        # The nearest oncoming vehicle not yet beside-and-behind the ego.
        opp = obs[:, self.layout["opposite_lane"]].reshape(n, -1, SLOT_FEATURES).astype(float)
        ox = opp[:, :, 1] * oc.position_scale
        okey = np.where((opp[:, :, 0] > 0.5) & (ox > -self.half_lengths), ox, np.inf)
        oi = np.argmin(okey, axis=1)
        has_onc = np.isfinite(okey[rows, oi])
        gap = np.where(has_onc, okey[rows, oi] - self.half_lengths, np.inf)
        v_onc = np.maximum(-opp[rows, oi, 3] * oc.speed_scale - v_e, 0.0)  # its own speed towards the ego
        # Time to gain (lead_dx + half lengths + gap) on the lead: accelerate to v_cap, then cruise.
        need = np.where(has_lead, lead_dx + self.half_lengths + REQUIRED_GAP, 0.0)
        a, b = max(self.accel, 1e-6), v_e - v_lead
        t1 = np.maximum(v_cap - v_e, 0.0) / a
        gain1 = b * t1 + a * t1**2 / 2
        t_accel = (-b + np.sqrt(np.maximum(b**2 + 2 * a * need, 0.0))) / a
        cruise = np.where(v_cap - v_lead > 0.1, (need - gain1) / np.maximum(v_cap - v_lead, 0.1), np.inf)
        t_pass = np.where(gain1 >= need, t_accel, t1 + cruise)
        t_b = np.minimum(t_pass, t1)
        with np.errstate(invalid="ignore"):  # inf - inf where the lead cannot be passed (masked below)
            ego_travel = v_e * t_b + a * t_b**2 / 2 + v_cap * np.maximum(t_pass - t1, 0.0)
            t_out = t_pass + self.p.lateral_return_time
            left = gap - ego_travel - v_cap * self.p.lateral_return_time - v_onc * t_out
        p = self.p
        need_rss = safe_distance_opposite_direction(
            v_cap,
            v_onc,
            p.response_time,
            p.ego_accel_max,
            p.ego_brake_min,
            p.other_accel_max,
            p.other_brake_min_correct,
        )
        unsafe = has_lead & has_onc & ~(left >= need_rss)  # (NaN / -inf: cannot complete)
        passing = has_lead & (lead_dx > -self.half_lengths)
        return unsafe, passing

    def card(self) -> str:
        return (
            f"{self.name}: {self.inner.name} behind an RSS shield (Alshiekh et al. 2018): an overtake that "
            "cannot keep the RSS opposite-direction distance (Shalev-Shwartz et al. 2017, Def. 2) to the "
            "nearest visible oncoming vehicle until back in lane is vetoed, or aborted while the lead is "
            "not yet passed."
        )


def load_shielded(name: str, config: EnvConfig | None = None, **kwargs: Any) -> Shielded:
    """``shielded:<name>`` or ``<name>+shield``: the zoo member ``<name>`` behind the shield."""
    from overtakezoo.zoo.base import load

    inner = name.split(":", 1)[1] if name.startswith("shielded:") else name[: -len("+shield")]
    return Shielded(load(inner, config, **kwargs))
