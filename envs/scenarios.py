"""Scenarios: one row of arrays per scenario, drawn deterministically from a distribution + seed.

Coordinates are Frenet on a straight road (s along the road, d lateral, metres): the ego lane's
centre is d = 0 and the opposite lane's centre is d = +lane_width (right-hand traffic, the ego drives
towards +s). NPC slots are padded: ``npc_present`` says which slots hold a vehicle. Slot order from a
distribution is: the lead (NPC1), the oncoming vehicles (NPC2, ...), the followers, then the
oncoming AV's lead when there is one.

A scenario may hold more than one automated vehicle (AV). The ego (``ego_*``) is AV 0; ``av_*``
arrays (N, K) describe the K others: where they start, their direction of travel (+1 towards +s in
lane 0 like the ego, -1 towards -s in lane 1), their goal line and the NPC slot each must pass to
succeed (its own slow lead). Every AV shares the row's size, speed limit, sensor range and time limit.
A distribution's AV order is: the ego's platoon behind it (AV 1, 2, ...; ``av_lead`` 0, the shared
lead), then the oncoming AV (``av_lead`` its own lead's slot, the last).

The scenario arrays and the distribution that draws them field by field stay together: a field is
added in both at once.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from overtakezoo.envs.config import ConfigError, bounded, check_ranges, unknown_key

EGO_LANE, OPPOSITE_LANE = 0, 1
# The paper's two named vehicles (its Table I) by slot: NPC1, the lead the ego overtakes, is slot 0
# in the ego's lane; NPC2, the first oncoming vehicle, is slot 1 in the opposite lane.
NPC1_SLOT, NPC2_SLOT = 0, 1
# NPC behaviours. IDM (the env's default) is reactive: it brakes for whatever occupies its lane
# ahead, the ego included once its reaction time has passed. SCRIPTED drives the scenario's speed
# profile (its desired speed) in its lane, blind to the ego, like the scripted NPCs of an
# OpenSCENARIO scenario (the paper's Table I); it still keeps its distance to NPCs ahead of it.
# SPEEDUP_WHEN_PASSED is a reactive lead that raises its desired speed once the ego draws level.
IDM, SPEEDUP_WHEN_PASSED, SCRIPTED = 0, 1, 2
BEHAVIOURS = {"idm": IDM, "speedup": SPEEDUP_WHEN_PASSED, "scripted": SCRIPTED}
KMH = 1.0 / 3.6


@dataclass
class Scenarios:
    """A batch of N scenarios with M NPC slots, as a structure of arrays."""

    lane_width: np.ndarray  # (N,)
    speed_limit: np.ndarray  # (N,) ego speed cap, m/s
    goal_s: np.ndarray  # (N,) the ego's front must pass this, in its lane, ahead of NPC1
    road_length: np.ndarray  # (N,)
    sensor_range: np.ndarray  # (N,)
    time_limit: np.ndarray  # (N,) s
    ego_s: np.ndarray  # (N,) centre position
    ego_d: np.ndarray  # (N,)
    ego_v: np.ndarray  # (N,)
    ego_length: np.ndarray  # (N,)
    ego_width: np.ndarray  # (N,)
    npc_present: np.ndarray  # (N, M) bool
    npc_lane: np.ndarray  # (N, M) int8: 0 ego lane (same direction), 1 opposite lane (oncoming)
    npc_s: np.ndarray  # (N, M) centre position
    npc_v: np.ndarray  # (N, M) speed along its own direction of travel (>= 0)
    npc_v_des: np.ndarray  # (N, M) IDM desired speed
    npc_behaviour: np.ndarray  # (N, M) int8, see BEHAVIOURS
    npc_boost: np.ndarray  # (N, M) desired-speed increase of a speed-up lead once passed
    npc_length: np.ndarray  # (N, M)
    npc_width: np.ndarray  # (N, M)
    npc_reaction: np.ndarray  # (N, M) s before an NPC reacts to the ego entering its lane
    npc_reveal: np.ndarray  # (N, M) m: the vehicle is perceived only this close (occlusion); inf = always
    npc_must_pass: np.ndarray  # (N, M) bool: success requires the ego ahead of these (NPC1)
    # Further automated vehicles (N, K), world coordinates; K = 0 (the default) is the single-ego road.
    av_s: np.ndarray | None = None  # centre position
    av_d: np.ndarray | None = None  # lateral position (0 = lane 0's centre, lane_width = lane 1's)
    av_v: np.ndarray | None = None  # speed along its own direction
    av_direction: np.ndarray | None = None  # int8: +1 drives towards +s (lane 0), -1 towards -s (lane 1)
    av_goal_s: np.ndarray | None = None  # world s its front must pass (for direction -1: reach s <= goal)
    av_lead: np.ndarray | None = None  # int16: the NPC slot it must pass to succeed, -1 none

    def __post_init__(self) -> None:
        n = self.lane_width.shape[0]
        for name, dtype in _AV_DTYPES.items():
            if getattr(self, name) is None:
                setattr(self, name, np.zeros((n, 0), dtype))

    @property
    def num(self) -> int:
        return int(self.lane_width.shape[0])

    @property
    def num_avs(self) -> int:
        """Automated vehicles per scenario, the ego included."""
        assert self.av_s is not None  # (__post_init__ fills the AV fields)
        return 1 + int(self.av_s.shape[1])

    @property
    def num_npcs(self) -> int:
        return int(self.npc_s.shape[1])

    def take(self, index: Any) -> Scenarios:
        """Rows ``index`` (an int array, slice or mask) as a new batch."""
        return Scenarios(**{f.name: np.asarray(getattr(self, f.name))[index] for f in dataclasses.fields(self)})

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, Any]) -> Scenarios:
        """The inverse of :meth:`to_arrays`; files written before AVs existed have no ``av_*``."""
        return cls(
            **{
                f.name: np.asarray(arrays[f.name])
                for f in dataclasses.fields(cls)
                if f.name in arrays or f.name not in _AV_DTYPES
            }
        )

    @classmethod
    def concat(cls, batches: list[Scenarios]) -> Scenarios:
        """Stack batches, padding NPC slots to the widest batch (their AV counts must agree)."""
        if len({b.num_avs for b in batches}) > 1:
            raise ValueError("cannot stack scenarios with different numbers of automated vehicles")
        width = max(b.num_npcs for b in batches)
        padded = [b.pad_npcs(width) for b in batches]
        return cls(**{f.name: np.concatenate([getattr(b, f.name) for b in padded]) for f in dataclasses.fields(cls)})

    def pad_npcs(self, width: int) -> Scenarios:
        extra = width - self.num_npcs
        if extra <= 0:
            return self
        out = {}
        for f in dataclasses.fields(self):
            a = getattr(self, f.name)
            if f.name.startswith("npc_"):
                fill = np.inf if f.name == "npc_reveal" else 0
                pad = np.full((a.shape[0], extra), fill, dtype=a.dtype)
                if f.name in ("npc_length", "npc_width"):
                    pad[:] = 1.0
                a = np.concatenate([a, pad], axis=1)
            out[f.name] = a
        return Scenarios(**out)


_AV_DTYPES = {
    "av_s": np.float64,
    "av_d": np.float64,
    "av_v": np.float64,
    "av_direction": np.int8,
    "av_goal_s": np.float64,
    "av_lead": np.int16,
}

Range = tuple[float, float]


@dataclass(frozen=True)
class ScenarioDistribution:
    """The paper's distribution and its scale-ups. Ranges are uniform [lo, hi].

    Defaults are the paper's setting where it gives one (NPC speeds 1-3 m/s, ego capped at
    15 km/h); the suites in ``envs/suites`` choose and justify the values the paper leaves open.
    """

    # Each setting's physical range is beside it (``bounded``; for a [low, high] pair both ends). They
    # span a slow shuttle to a rural road's 144 km/h, a narrow lane to a wide one, a small car to a
    # truck, and distances and times far beyond any shipped suite (most use 15 km/h, 3.5 m lanes,
    # 4.54 m cars, 100-400 m goals and 60-80 s limits) but short of a run that never ends.
    speed_limit: float = bounded(15.0 * KMH, 0.5, 40.0, "m/s")
    lane_width: float = bounded(3.5, 2.0, 6.0, "m")
    goal: float = bounded(100.0, 1.0, 5000.0, "m")  # from the ego's start to the goal line
    road_extra: float = bounded(
        150.0, 0.0, 5000.0, "m"
    )  # road beyond the goal (ends a follower's episode by truncation)
    sensor_range: float = bounded(60.0, 1.0, 1000.0, "m")
    time_limit: float = bounded(60.0, 0.1, 3600.0, "s")  # (tests end episodes within a few steps)
    ego_speed: Range = bounded((15.0 * KMH, 15.0 * KMH), 0.0, 40.0, "m/s")
    ego_length: float = bounded(4.54, 1.0, 20.0, "m")
    ego_width: float = bounded(1.82, 0.5, 3.0, "m")
    vehicle_length: float = bounded(4.54, 1.0, 20.0, "m")
    vehicle_width: float = bounded(1.82, 0.5, 3.0, "m")
    lead_speed: Range = bounded((1.0, 3.0), 0.0, 40.0, "m/s")
    lead_gap: Range = bounded((8.0, 25.0), 0.0, 5000.0, "m")  # D1: bumper gap from the ego to NPC1
    lead_behaviour: str = "idm"  # one of BEHAVIOURS
    lead_boost: Range = bounded((0.0, 0.0), 0.0, 20.0, "m/s")  # added to a speed-up lead's desired speed once passed
    oncoming_behaviour: str = "idm"  # "idm" (reactive) or "scripted" (blind to the ego)
    oncoming_count: int = bounded(1, 0, 64)
    oncoming_speed: Range = bounded((1.0, 3.0), 0.0, 40.0, "m/s")
    oncoming_gap: Range = bounded(
        (20.0, 150.0), 0.0, 5000.0, "m"
    )  # D2: from the ego's front to the first oncoming front
    oncoming_headway: Range = bounded(
        (15.0, 60.0), 0.0, 5000.0, "m"
    )  # bumper gaps between successive oncoming vehicles
    # Perceived only this close (a late-appearing car); [inf, inf], the default, means never hidden.
    oncoming_reveal: Range = bounded((math.inf, math.inf), 1.0, 1000.0, "m")
    follower_count: int = bounded(0, 0, 64)
    follower_speed: Range = bounded((3.0, 4.0), 0.0, 40.0, "m/s")
    follower_gap: Range = bounded((5.0, 20.0), 0.0, 5000.0, "m")  # bumper gaps behind the ego, then between followers
    reaction_time: Range = bounded((0.5, 1.0), 0.0, 10.0, "s")  # before an NPC reacts to the ego in its lane
    # Further automated vehicles (AVs); the defaults are the single-ego road. Everything below is
    # drawn after all the above, and only when used, so single-ego batches stay bit-identical.
    platoon_size: int = bounded(1, 1, 16)  # AVs in lane 0 behind NPC1: the ego, then AV 1, 2, ... each behind the last
    platoon_gap: Range = bounded((5.0, 20.0), 0.0, 5000.0, "m")  # bumper gaps between successive platoon AVs (> 0)
    oncoming_av: int = bounded(0, 0, 1)  # 1: one AV driving towards -s in lane 1, behind its own slow lead
    oncoming_av_distance: Range = bounded(
        (60.0, 200.0), 0.0, 5000.0, "m"
    )  # from the ego's front to that AV's front (> 0)
    oncoming_av_lead_gap: Range = bounded((8.0, 25.0), 0.0, 5000.0, "m")  # bumper gap from that AV to its lead (> 0)
    oncoming_av_lead_speed: Range = bounded((1.0, 3.0), 0.0, 40.0, "m/s")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ScenarioDistribution:
        if data is not None and not isinstance(data, dict):
            raise ConfigError(f"scenario: expected a table, got {data!r}")
        data = dict(data or {})
        names = {f.name: f for f in dataclasses.fields(cls)}
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key not in names:
                raise ConfigError(f"scenario.{key}: {unknown_key(key, names)}")
            default = names[key].default
            if isinstance(default, tuple):
                if not (isinstance(value, (list, tuple)) and len(value) == 2):
                    raise ConfigError(f"scenario.{key}: expected [low, high], got {value!r}")
                value = (_num(key, value[0]), _num(key, value[1]))
                if value[0] > value[1]:
                    raise ConfigError(f"scenario.{key}: low {value[0]} is above high {value[1]}")
            elif isinstance(default, str):
                allowed = BEHAVIOURS if key == "lead_behaviour" else _ONCOMING_BEHAVIOURS
                if value not in allowed:
                    raise ConfigError(f"scenario.{key}: {value!r} is not one of {', '.join(allowed)}")
            elif isinstance(default, int):  # its range is checked in validate
                if isinstance(value, bool) or not isinstance(value, int):
                    raise ConfigError(f"scenario.{key}: expected an integer, got {value!r}")
            else:
                value = _num(key, value)
            kwargs[key] = value
        dist = cls(**kwargs)
        dist.validate()
        return dist

    def validate(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, str):
                continue
            values = value if isinstance(value, tuple) else (value,)
            # inf/NaN would overflow the sampler or the step count; the one exception is
            # oncoming_reveal = [inf, inf], the default: the oncoming car is seen from the start.
            if f.name == "oncoming_reveal" and all(v == math.inf for v in values):
                continue
            if not all(math.isfinite(v) for v in values):
                raise ConfigError(
                    f"scenario.{f.name}: must be finite, got {value!r}"
                    + (" ([inf, inf] means never hidden)" if f.name == "oncoming_reveal" else "")
                )
        self._validate_avs()  # first: its messages say why (vehicles may not start in contact, ...)
        never_hidden = ("oncoming_reveal",) if self.oncoming_reveal == (math.inf, math.inf) else ()
        check_ranges(self, "scenario.", skip=never_hidden)

    def _validate_avs(self) -> None:
        """The AV layout: counts in range, and no two vehicles overlapping (or touching) at the start."""
        if not 1 <= self.platoon_size <= 16:
            raise ConfigError(f"scenario.platoon_size: expected 1 (the ego alone) to 16, got {self.platoon_size!r}")
        if self.oncoming_av not in (0, 1):
            raise ConfigError(f"scenario.oncoming_av: expected 0 or 1, got {self.oncoming_av!r}")
        for key in ("platoon_gap", "oncoming_av_distance", "oncoming_av_lead_gap"):
            if not getattr(self, key)[0] > 0:
                raise ConfigError(
                    f"scenario.{key}: must be > 0 (vehicles may not start in contact), got {getattr(self, key)!r}"
                )
        if self.oncoming_av_lead_speed[0] < 0:
            raise ConfigError(f"scenario.oncoming_av_lead_speed: must be >= 0, got {self.oncoming_av_lead_speed!r}")
        if not self.oncoming_av:
            return
        # The oncoming AV's lead starts between the two AVs: its front ahead of the ego's front.
        room = self.oncoming_av_lead_gap[1] + self.vehicle_length
        if not self.oncoming_av_distance[0] > room:
            raise ConfigError(
                f"scenario.oncoming_av_distance: the low end must exceed oncoming_av_lead_gap's "
                f"high end + vehicle_length ({room:g} m) so the AV's lead starts ahead of the "
                f"ego, got {self.oncoming_av_distance!r}"
            )
        # Oncoming NPCs share lane 1 with the oncoming AV: they start behind it (they follow it).
        behind = self.oncoming_av_distance[1] + self.ego_length
        if self.oncoming_count and not self.oncoming_gap[0] > behind:
            raise ConfigError(
                f"scenario.oncoming_gap: with an oncoming AV the oncoming vehicles start behind "
                f"it, so the low end must exceed oncoming_av_distance's high end + ego_length "
                f"({behind:g} m), got {self.oncoming_gap!r}"
            )

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    def sample(self, n: int, seed: int | np.random.Generator | None) -> Scenarios:
        """Draw ``n`` scenarios. The same seed gives the same batch, bit for bit."""
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        K, F = self.oncoming_count, self.follower_count
        M = 1 + K + F

        def u(r: Range, *shape: int) -> np.ndarray:
            return rng.uniform(r[0], r[1], size=(n, *shape))

        # Draw every quantity once, in a fixed order, so a batch depends only on (seed, n).
        ego_v = u(self.ego_speed)
        lead_v, lead_gap, lead_boost = u(self.lead_speed), u(self.lead_gap), u(self.lead_boost)
        onc_v, onc_gap, onc_head = u(self.oncoming_speed, K), u(self.oncoming_gap), u(self.oncoming_headway, K)
        onc_reveal = u(self.oncoming_reveal, K) if np.isfinite(self.oncoming_reveal[1]) else np.full((n, K), np.inf)
        fol_v, fol_gap = u(self.follower_speed, F), u(self.follower_gap, F)
        reaction = u(self.reaction_time, M)
        # The AVs' quantities last, and only when there are AVs, so single-ego draws are unchanged.
        P, O = self.platoon_size, self.oncoming_av
        plat_v, plat_gap = (u(self.ego_speed, P - 1), u(self.platoon_gap, P - 1)) if P > 1 else (None, None)
        oav = (
            (
                u(self.ego_speed),
                u(self.oncoming_av_distance),
                u(self.oncoming_av_lead_gap),
                u(self.oncoming_av_lead_speed),
                u(self.reaction_time),
            )
            if O
            else None
        )

        Le, L = self.ego_length, self.vehicle_length
        lane = np.zeros((n, M), np.int8)
        s = np.zeros((n, M))
        v = np.zeros((n, M))
        behaviour = np.zeros((n, M), np.int8)
        boost = np.zeros((n, M))
        reveal = np.full((n, M), np.inf)
        must_pass = np.zeros((n, M), bool)
        # NPC1: the slow lead in the ego lane, D1 ahead (bumper to bumper).
        s[:, 0] = lead_gap + (Le + L) / 2
        v[:, 0] = lead_v
        behaviour[:, 0] = BEHAVIOURS[self.lead_behaviour]
        boost[:, 0] = lead_boost
        must_pass[:, 0] = True
        # Oncoming vehicles: the first D2 ahead of the ego's front, then random headways.
        if K:
            fronts = (
                Le / 2
                + onc_gap[:, None]
                + np.concatenate([np.zeros((n, 1)), np.cumsum(onc_head[:, 1:] + L, axis=1)], axis=1)
            )
            lane[:, 1 : 1 + K] = OPPOSITE_LANE
            s[:, 1 : 1 + K] = fronts + L / 2  # an oncoming car's front faces -s
            v[:, 1 : 1 + K] = onc_v
            behaviour[:, 1 : 1 + K] = BEHAVIOURS[self.oncoming_behaviour]
            reveal[:, 1 : 1 + K] = onc_reveal
        # Followers behind the ego, in the ego lane.
        if F:
            offsets = np.cumsum(fol_gap + L, axis=1) - L / 2 + Le / 2
            s[:, 1 + K :] = -offsets
            v[:, 1 + K :] = fol_v

        full = lambda x: np.full(n, float(x))  # noqa: E731
        single = Scenarios(
            lane_width=full(self.lane_width),
            speed_limit=full(self.speed_limit),
            goal_s=full(self.goal),
            road_length=full(self.goal + self.road_extra),
            sensor_range=full(self.sensor_range),
            time_limit=full(self.time_limit),
            ego_s=np.zeros(n),
            ego_d=np.zeros(n),
            ego_v=np.minimum(ego_v, self.speed_limit),
            ego_length=full(Le),
            ego_width=full(self.ego_width),
            npc_present=np.ones((n, M), bool),
            npc_lane=lane,
            npc_s=s,
            npc_v=v,
            npc_v_des=v.copy(),
            npc_behaviour=behaviour,
            npc_boost=boost,
            npc_length=np.full((n, M), L),
            npc_width=np.full((n, M), self.vehicle_width),
            npc_reaction=reaction,
            npc_reveal=reveal,
            npc_must_pass=must_pass,
        )
        if P == 1 and not O:
            return single
        return _with_avs(
            single, slice(1 + K, M), plat_gap, plat_v, oav, (L, self.vehicle_width), BEHAVIOURS[self.oncoming_behaviour]
        )


def _with_avs(
    sc: Scenarios,
    followers: slice,
    plat_gap: np.ndarray | None,
    plat_v: np.ndarray | None,
    oav: tuple[np.ndarray, ...] | None,
    vehicle: tuple[float, float],
    oav_lead_behaviour: int,
) -> Scenarios:
    """``sc`` (single-ego rows) with further AVs: a platoon behind the ego and/or an oncoming AV.

    ``plat_gap``/``plat_v`` (N, P-1): bumper gaps and speeds of the platoon AVs behind the ego, each
    behind the last (the followers ``followers`` move back behind the platoon's tail); their goal is the
    ego's and they must pass the ego's lead (slot 0). ``oav`` = (speed, distance from the ego's front to
    its front, bumper gap to its lead, lead speed, lead reaction time), each (N,): one AV towards -s in
    lane 1 whose slow lead (a new NPC slot of size ``vehicle``, appended last, driving
    ``oav_lead_behaviour``) is between the two AVs; its goal lies the ego's goal distance ahead of its
    start, in its own direction.
    AV order: the platoon (AV 1, 2, ...), then the oncoming AV.
    """
    n = sc.num
    Le = sc.ego_length
    lim = sc.speed_limit
    goal = sc.goal_s - sc.ego_s  # the ego's goal distance, from its centre
    av: dict[str, list[np.ndarray]] = {k: [] for k in _AV_DTYPES}
    npc = {f.name: getattr(sc, f.name).copy() for f in dataclasses.fields(sc) if f.name.startswith("npc_")}
    if plat_gap is not None and plat_gap.shape[1]:
        assert plat_v is not None  # (given with plat_gap)
        behind = np.cumsum(plat_gap + Le[:, None], axis=1)  # centre offsets behind the ego
        av["av_s"].append(sc.ego_s[:, None] - behind)
        av["av_d"].append(np.zeros_like(behind))
        av["av_v"].append(np.minimum(plat_v, lim[:, None]))
        av["av_direction"].append(np.ones_like(behind, np.int8))
        av["av_goal_s"].append(np.repeat(sc.goal_s[:, None], behind.shape[1], axis=1))
        has_lead = sc.npc_present[:, :1] & sc.npc_must_pass[:, :1] if sc.num_npcs else np.zeros((n, 1), bool)
        av["av_lead"].append(np.where(has_lead, 0, -1).astype(np.int16).repeat(behind.shape[1], axis=1))
        npc["npc_s"][:, followers] -= behind[:, -1:]  # followers queue behind the platoon's tail
    if oav is not None:
        speed, distance, lead_gap, lead_speed, reaction = (np.asarray(a, float).reshape(n) for a in oav)
        front = sc.ego_s + Le / 2 + distance  # the oncoming AV's front faces -s
        slot = sc.num_npcs
        L, W = vehicle
        lead = {
            "npc_present": True,
            "npc_lane": OPPOSITE_LANE,
            "npc_s": front - lead_gap - L / 2,
            "npc_v": lead_speed,
            "npc_v_des": lead_speed,
            "npc_behaviour": oav_lead_behaviour,
            "npc_boost": 0.0,
            "npc_length": L,
            "npc_width": W,
            "npc_reaction": reaction,
            "npc_reveal": np.inf,
            "npc_must_pass": False,
        }
        for k, value in lead.items():
            npc[k] = np.concatenate([npc[k], np.broadcast_to(np.asarray(value, npc[k].dtype), (n,))[:, None]], axis=1)
        s = front + Le / 2
        av["av_s"].append(s[:, None])
        av["av_d"].append(sc.lane_width[:, None].copy())
        av["av_v"].append(np.minimum(speed, lim)[:, None])
        av["av_direction"].append(np.full((n, 1), -1, np.int8))
        av["av_goal_s"].append((s - goal)[:, None])
        av["av_lead"].append(np.full((n, 1), slot, np.int16))
    arrays = {**sc.to_arrays(), **npc}
    arrays.update({k: np.concatenate(v, axis=1).astype(_AV_DTYPES[k]) for k, v in av.items() if v})
    return Scenarios(**arrays)


# Speeding up when passed only makes sense for the lead being passed.
_ONCOMING_BEHAVIOURS = {k: v for k, v in BEHAVIOURS.items() if k != "speedup"}


def _num(key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"scenario.{key}: expected a number, got {value!r}")
    return float(value)


def make_scenario(
    *,
    lead: tuple[float, float] | None = (15.0, 2.0),
    oncoming: Sequence[tuple[float, float]] = (),
    followers: Sequence[tuple[float, float]] = (),
    ego_speed: float = 15.0 * KMH,
    lead_behaviour: str = "idm",
    lead_boost: float = 0.0,
    oncoming_behaviour: str = "idm",
    reaction_time: float = 0.7,
    reveal: float = math.inf,
    platoon: Sequence[tuple[float, float]] = (),
    oncoming_av: tuple[float, float, float, float] | None = None,
    **road: Any,
) -> Scenarios:
    """One hand-built scenario: ``lead=(gap, speed)``, ``oncoming=[(gap, speed), ...]`` with gaps from
    the ego's front to each oncoming front, ``followers=[(gap, speed), ...]`` bumper gaps behind the ego
    (behind the platoon's tail when there is one).
    Further AVs: ``platoon=[(gap, speed), ...]`` AVs behind the ego (bumper gaps, each behind the last),
    ``oncoming_av=(distance, speed, lead_gap, lead_speed)``: an AV driving towards -s in lane 1, its
    front ``distance`` ahead of the ego's, behind its own lead (``lead_gap`` bumper to bumper, driving
    ``oncoming_behaviour``). A duel: ``make_scenario(lead=(10, 1), oncoming_av=(120, 15 / 3.6, 10, 1))``.
    Road keys are those of :class:`ScenarioDistribution` (``goal``, ``sensor_range``, ...)."""
    dist = ScenarioDistribution.from_dict(road)
    Le, L = dist.ego_length, dist.vehicle_length
    rows = []  # (lane, s, v, behaviour, boost, must_pass, reveal)
    if lead is not None:
        rows.append((EGO_LANE, lead[0] + (Le + L) / 2, lead[1], BEHAVIOURS[lead_behaviour], lead_boost, True, math.inf))
    for gap, speed in oncoming:
        rows.append((OPPOSITE_LANE, Le / 2 + gap + L / 2, speed, BEHAVIOURS[oncoming_behaviour], 0.0, False, reveal))
    for gap, speed in followers:
        rows.append((EGO_LANE, -(Le / 2 + gap + L / 2), speed, IDM, 0.0, False, math.inf))
    M = max(len(rows), 1)
    cols = list(zip(*rows, strict=True)) if rows else [[0]] * 7
    present = np.zeros((1, M), bool)
    present[0, : len(rows)] = True

    def col(i: int, dtype: Any, fill: Any) -> np.ndarray:
        a = np.full((1, M), fill, dtype=dtype)
        if rows:
            a[0, : len(rows)] = cols[i]
        return a

    v = col(2, float, 0.0)
    single = Scenarios(
        lane_width=np.array([dist.lane_width]),
        speed_limit=np.array([dist.speed_limit]),
        goal_s=np.array([dist.goal]),
        road_length=np.array([dist.goal + dist.road_extra]),
        sensor_range=np.array([dist.sensor_range]),
        time_limit=np.array([dist.time_limit]),
        ego_s=np.zeros(1),
        ego_d=np.zeros(1),
        ego_v=np.array([min(ego_speed, dist.speed_limit)]),
        ego_length=np.array([Le]),
        ego_width=np.array([dist.ego_width]),
        npc_present=present,
        npc_lane=col(0, np.int8, 0),
        npc_s=col(1, float, 0.0),
        npc_v=v,
        npc_v_des=v.copy(),
        npc_behaviour=col(3, np.int8, 0),
        npc_boost=col(4, float, 0.0),
        npc_length=np.full((1, M), L),
        npc_width=np.full((1, M), dist.vehicle_width),
        npc_reaction=np.full((1, M), reaction_time),
        npc_reveal=col(6, float, math.inf),
        npc_must_pass=col(5, bool, False),
    )
    if not platoon and oncoming_av is None:
        return single
    plat = np.array(platoon, float).reshape(1, -1, 2)
    oav: tuple[np.ndarray, ...] | None = None
    if oncoming_av is not None:
        distance, oav_speed, lead_gap, lead_speed = (np.array([float(x)]) for x in oncoming_av)
        oav = (oav_speed, distance, lead_gap, lead_speed, np.array([reaction_time]))
    return _with_avs(
        single,
        slice(len(rows) - len(followers), len(rows)),
        plat[..., 0],
        plat[..., 1],
        oav,
        (L, dist.vehicle_width),
        BEHAVIOURS[oncoming_behaviour],
    )


def npc1_npc2_speeds(sc: Scenarios) -> tuple[np.ndarray, np.ndarray]:
    """(N,) initial speeds of each road's NPC1 and NPC2 (NaN where the road has none)."""
    npc1 = np.where(sc.npc_present[:, NPC1_SLOT], sc.npc_v[:, NPC1_SLOT], np.nan)
    if sc.num_npcs <= NPC2_SLOT:
        return npc1, np.full(sc.num, np.nan)
    is_npc2 = sc.npc_present[:, NPC2_SLOT] & (sc.npc_lane[:, NPC2_SLOT] == OPPOSITE_LANE)
    return npc1, np.where(is_npc2, sc.npc_v[:, NPC2_SLOT], np.nan)


def crash_roles(
    crash_npc: np.ndarray, crash_lane: np.ndarray, lead_npc: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Whether each episode's crash partner was NPC1 and whether it was NPC2. On a multi-AV road
    (``lead_npc``: each AV's own lead slot) NPC1 is the AV's own lead and NPC2 any NPC in its
    opposite lane."""
    if lead_npc is None:
        return crash_npc == NPC1_SLOT, (crash_npc == NPC2_SLOT) & (crash_lane == OPPOSITE_LANE)
    npc1 = (crash_npc >= 0) & (crash_npc == lead_npc)
    return npc1, (crash_npc >= 0) & ~npc1 & (crash_lane == OPPOSITE_LANE)
