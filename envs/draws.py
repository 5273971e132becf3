"""A suite's scenario parameters as a search box, and scenarios built from parameter values.

:meth:`ScenarioDistribution.sample` draws every random quantity of a scenario with
``rng.uniform(lo, hi, size)``, in a fixed order (``envs/scenarios.py``): the ego's speed, the lead's
speed, gap and boost, the oncoming speeds, gap and headways, ... A scenario is therefore given by the
values of those draws. :func:`build` hands ``sample`` a generator that returns given values instead of
random ones, so a searched or listed scenario is built by the very code, positions and padding
included, that draws a suite's scenarios: it is the scenario the distribution would have drawn had
its random numbers come out that way. Each draw is checked against :func:`draw_plan` (its range and
shape), so a change to ``sample`` raises here rather than building different scenarios silently.

The search box (:class:`Space`) is the distribution's own ranges: one dimension per draw whose range
is not a single value and that can change the episode (a scripted NPC's reaction time cannot, nor a
lead's boost unless it speeds up, nor the first oncoming car's headway, which ``sample`` never uses).
``--param NAME[=LO:HI]`` narrows the search to named parameters and may widen or move a range (within
the setting's physical range), including three the distribution holds as a single value per suite:
``sensor_range`` (set per scenario after drawing) and the counts ``oncoming_count`` /
``follower_count`` (rows of each count drawn together, padded to the widest, as
:meth:`Scenarios.concat` does).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from overtakezoo.envs.config import ConfigError
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios

# Searchable parameters that are one value per suite in a distribution, set per scenario here.
COUNTS = ("oncoming_count", "follower_count")
PER_ROW = ("sensor_range",)


@dataclass(frozen=True)
class Draw:
    """One ``rng.uniform`` call of ``ScenarioDistribution.sample``."""

    key: str  # its name in an explicit scenario
    field: str  # the distribution range it is drawn from
    width: int | None  # None: one value per scenario; k: one per vehicle slot (k may be 0)


def draw_plan(dist: ScenarioDistribution) -> list[Draw]:
    """The draws of ``dist.sample`` in its order (see the module docstring)."""
    K, F, P, O = dist.oncoming_count, dist.follower_count, dist.platoon_size, dist.oncoming_av
    plan = [
        Draw("ego_speed", "ego_speed", None),
        Draw("lead_speed", "lead_speed", None),
        Draw("lead_gap", "lead_gap", None),
        Draw("lead_boost", "lead_boost", None),
        Draw("oncoming_speed", "oncoming_speed", K),
        Draw("oncoming_gap", "oncoming_gap", None),
        Draw("oncoming_headway", "oncoming_headway", K),
    ]
    if math.isfinite(dist.oncoming_reveal[1]):
        plan.append(Draw("oncoming_reveal", "oncoming_reveal", K))
    plan += [
        Draw("follower_speed", "follower_speed", F),
        Draw("follower_gap", "follower_gap", F),
        Draw("reaction_time", "reaction_time", 1 + K + F),
    ]
    if P > 1:
        plan += [Draw("platoon_speed", "ego_speed", P - 1), Draw("platoon_gap", "platoon_gap", P - 1)]
    if O:
        plan += [
            Draw("oncoming_av_speed", "ego_speed", None),
            Draw("oncoming_av_distance", "oncoming_av_distance", None),
            Draw("oncoming_av_lead_gap", "oncoming_av_lead_gap", None),
            Draw("oncoming_av_lead_speed", "oncoming_av_lead_speed", None),
            Draw("oncoming_av_lead_reaction", "reaction_time", None),
        ]
    return plan


class _Given(np.random.Generator):
    """A generator whose ``uniform`` calls return given arrays, in :func:`draw_plan`'s order."""

    def __init__(self, dist: ScenarioDistribution, plan: list[Draw], values: list[np.ndarray]) -> None:
        super().__init__(np.random.PCG64(0))
        self._dist, self._todo = dist, list(zip(plan, values, strict=True))

    # (narrower than Generator.uniform, whose scalar form, size=None, sample() never draws)
    def uniform(self, low: Any = 0.0, high: Any = 1.0, size: Any = None) -> np.ndarray:  # type: ignore[override]
        if not self._todo:
            raise RuntimeError("ScenarioDistribution.sample drew more than envs/draws.py's draw_plan lists")
        draw, value = self._todo.pop(0)
        expected = tuple(getattr(self._dist, draw.field))
        shape = (size,) if isinstance(size, int) else tuple(size)
        if (float(low), float(high)) != expected or shape != value.shape:
            raise RuntimeError(
                f"ScenarioDistribution.sample drew [{low}, {high}] of shape {shape} where "
                f"envs/draws.py's draw_plan expects {draw.key} {list(expected)} of shape "
                f"{value.shape}: update draw_plan"
            )
        return np.array(value, dtype=float)

    def _refuse(self, *args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("ScenarioDistribution.sample drew other than uniform: update envs/draws.py")

    random = normal = standard_normal = integers = choice = permutation = shuffle = exponential = _refuse

    def finish(self) -> None:
        if self._todo:
            raise RuntimeError(f"ScenarioDistribution.sample skipped {self._todo[0][0].key}: update draw_plan")


def layout(dist: ScenarioDistribution, n: int, values: dict[str, Any]) -> dict[str, np.ndarray]:
    """``values`` as arrays of the layout of ``dist`` (widths at its counts): (n,) per scenario,
    (n, width) per vehicle; the reaction times are [lead, oncoming x K, followers x F]."""
    out: dict[str, np.ndarray] = {}
    for d in draw_plan(dist):
        shape = (n,) if d.width is None else (n, d.width)
        out[d.key] = np.broadcast_to(np.asarray(values[d.key], float), shape).copy()
    for key in COUNTS + PER_ROW:
        if key in values:
            out[key] = np.broadcast_to(np.asarray(values[key], np.int64 if key in COUNTS else float), (n,)).copy()
    return out


def build(dist: ScenarioDistribution, values: dict[str, np.ndarray]) -> Scenarios:
    """Scenarios from draw values in the layout of ``dist`` (:func:`layout`), one batch: each group of
    rows with the same counts is one ``sample`` call, and the groups are stacked back in row order."""
    n = int(np.asarray(values["lead_gap"]).shape[0])
    K0, F0 = dist.oncoming_count, dist.follower_count
    ks = np.asarray(values.get("oncoming_count", np.full(n, K0)), np.int64)
    fs = np.asarray(values.get("follower_count", np.full(n, F0)), np.int64)
    if n and (ks.max() > K0 or fs.max() > F0 or min(ks.min(), fs.min()) < 0):
        raise ValueError("counts beyond the layout's widths")
    groups = sorted(set(zip(ks.tolist(), fs.tolist(), strict=True)))
    parts, order = [], []
    for k, f in groups:
        rows = np.flatnonzero((ks == k) & (fs == f))
        sub = dist if (k, f) == (K0, F0) else dataclasses.replace(dist, oncoming_count=k, follower_count=f)
        arrays = []
        for d in draw_plan(sub):
            a = np.asarray(values[d.key], float)[rows]
            if d.key == "reaction_time":  # [lead, oncoming x k, followers x f] out of the K0 / F0 layout
                a = np.concatenate([a[:, : 1 + k], a[:, 1 + K0 : 1 + K0 + f]], axis=1)
            elif d.width is not None:
                a = a[:, : d.width]
            arrays.append(a)
        rng = _Given(sub, draw_plan(sub), arrays)
        parts.append(sub.sample(rows.size, rng))
        rng.finish()
        order.append(rows)
    sc = parts[0] if len(parts) == 1 else Scenarios.concat(parts)
    if len(parts) > 1:
        sc = sc.take(np.argsort(np.concatenate(order), kind="stable"))
    if "sensor_range" in values:
        sc.sensor_range = np.asarray(values["sensor_range"], float).copy()
    return sc


# ------------------------------------------------------------------ the search box
@dataclass(frozen=True)
class Dim:
    """One searched coordinate: a draw (a vehicle slot of it for per-vehicle draws), a count or a
    per-scenario setting, over [lo, hi]."""

    key: str
    slot: int | None
    lo: float
    hi: float
    integer: bool = False
    field: str = ""  # the distribution setting it comes from (--param's name)

    @property
    def label(self) -> str:
        return self.key if self.slot is None else f"{self.key}[{self.slot}]"


@dataclass(frozen=True)
class Space:
    """The box: ``dist`` is the suite's distribution with any ``--param`` ranges applied and the
    counts at their largest searched value (the layout); ``base`` is what an explicit suite's
    ``[scenario]`` table holds (the counts as the suite has them)."""

    dist: ScenarioDistribution
    base: ScenarioDistribution
    dims: tuple[Dim, ...]

    @property
    def size(self) -> int:
        return len(self.dims)

    def fixed(self, n: int) -> dict[str, np.ndarray]:
        """Every draw at its fixed value: the range's low end when it is one value, else its middle."""
        vals = {}
        for d in draw_plan(self.dist):
            lo, hi = getattr(self.dist, d.field)
            vals[d.key] = lo if lo == hi else 0.5 * (lo + hi)
        for dim in self.dims:
            if dim.key in COUNTS + PER_ROW:
                vals[dim.key] = getattr(self.base, dim.key)
        return layout(self.dist, n, vals)

    def values(self, unit: np.ndarray) -> dict[str, np.ndarray]:
        """Draw values of points ``unit`` (n, D) of the unit cube (D = ``size``): each coordinate
        mapped linearly onto its range, counts to the integers lo..hi (equal shares). Slots a row's
        counts leave out hold the fixed value, so equal scenarios have equal values."""
        unit = np.clip(np.asarray(unit, float).reshape(-1, self.size), 0.0, 1.0)
        n = unit.shape[0]
        vals = self.fixed(n)
        for j, dim in enumerate(self.dims):
            u = unit[:, j]
            if dim.integer:
                span = int(dim.hi - dim.lo)
                v = dim.lo + np.minimum(np.floor(u * (span + 1)), span).astype(np.int64)
            else:
                v = dim.lo + u * (dim.hi - dim.lo)
            if dim.slot is None:
                vals[dim.key] = v.astype(vals[dim.key].dtype)
            else:
                vals[dim.key][:, dim.slot] = v
        self._blank_unused(vals)
        return vals

    def units(self, vals: dict[str, np.ndarray]) -> np.ndarray:
        """The inverse of :meth:`values` (n, D): where each value lies in its range, 0..1."""
        cols = []
        for dim in self.dims:
            v = np.asarray(vals[dim.key], float)
            v = v if dim.slot is None else v[:, dim.slot]
            if dim.integer:
                span = dim.hi - dim.lo
                cols.append((v - dim.lo + 0.5) / (span + 1))
            else:
                cols.append((v - dim.lo) / (dim.hi - dim.lo))
        return np.stack(cols, axis=1) if cols else np.zeros((0, 0))

    def canonical(self, unit: np.ndarray) -> np.ndarray:
        """``unit`` with counts at their cells' centres and unused slots at the fixed value: two
        points that give the same scenario give the same coordinates (what deduplication compares)."""
        return self.units(self.values(unit))

    def _blank_unused(self, vals: dict[str, np.ndarray]) -> None:
        K0, F0 = self.dist.oncoming_count, self.dist.follower_count
        if not any(k in vals for k in COUNTS):
            return
        fixed = self.fixed(1)
        ks = vals.get("oncoming_count", np.full(len(vals["lead_gap"]), K0))
        fs = vals.get("follower_count", np.full(len(vals["lead_gap"]), F0))
        slot_k, slot_f = np.arange(K0)[None], np.arange(F0)[None]
        for key in ("oncoming_speed", "oncoming_headway", "oncoming_reveal"):
            if key in vals:
                vals[key] = np.where(slot_k < ks[:, None], vals[key], fixed[key])
        for key in ("follower_speed", "follower_gap"):
            vals[key] = np.where(slot_f < fs[:, None], vals[key], fixed[key])
        slots = np.arange(1 + K0 + F0)[None]
        used = (slots < 1 + ks[:, None]) | ((slots >= 1 + K0) & (slots < 1 + K0 + fs[:, None]))
        vals["reaction_time"] = np.where(used, vals["reaction_time"], fixed["reaction_time"])

    def build(self, unit: np.ndarray) -> Scenarios:
        return build(self.dist, self.values(unit))


def _relevant(dist: ScenarioDistribution, draw: Draw, slot: int | None) -> bool:
    """Whether a draw's value (of vehicle ``slot``) can change an episode (see the module docstring)."""
    K = dist.oncoming_count
    if draw.key == "lead_boost":
        return dist.lead_behaviour == "speedup"
    if draw.key == "oncoming_headway":
        return slot != 0  # sample() spaces the oncoming cars by headways[1:]
    if draw.key == "reaction_time":  # a scripted NPC never reacts; followers are always IDM
        if slot == 0:
            return dist.lead_behaviour != "scripted"
        assert slot is not None  # (a per-vehicle draw)
        return dist.oncoming_behaviour != "scripted" if slot <= K else True
    if draw.key == "oncoming_av_lead_reaction":
        return dist.oncoming_behaviour != "scripted"
    return True


def searchable(dist: ScenarioDistribution) -> list[str]:
    """Names ``--param`` takes: the distribution's ranges that its scenarios draw, and the per-row ones."""
    fields = {d.field for d in draw_plan(dist) if d.width != 0}
    return sorted(fields) + list(COUNTS) + list(PER_ROW)


def parse_param(spec: str) -> tuple[str, tuple[float, float] | None]:
    """``NAME`` or ``NAME=LO:HI`` -> (name, (lo, hi) or None)."""
    name, sep, rng = spec.partition("=")
    name = name.strip()
    if not sep:
        return name, None
    lo, colon, hi = rng.partition(":")
    try:
        if not colon:
            raise ValueError
        bounds = (float(lo), float(hi))
    except ValueError:
        raise ConfigError(f"--param {spec!r}: expected NAME or NAME=LO:HI, e.g. lead_speed=0.5:4") from None
    if not all(math.isfinite(b) for b in bounds) or not bounds[0] < bounds[1]:
        raise ConfigError(f"--param {spec!r}: expected finite LO < HI")
    return name, bounds


def space_for(dist: ScenarioDistribution, params: list[str] | None = None, where: str = "suite") -> Space:
    """The search box of ``dist``: every relevant draw with a range, or only the ``--param`` names
    (``NAME`` or ``NAME=LO:HI``; a range replaces the suite's, within the setting's physical range).
    ConfigError for an unknown name, a range outside the physical one, or no searchable dimension."""
    parsed = [parse_param(p) for p in params or []]
    known = searchable(dist)
    names = [n for n, _ in parsed]
    for name in names:
        if name not in known:
            raise ConfigError(f"--param {name}: unknown parameter for {where} (searchable: {', '.join(known)})")
    if len(set(names)) != len(names):
        raise ConfigError(f"--param: {sorted(n for n in names if names.count(n) > 1)[0]} given twice")
    overrides = {n: r for n, r in parsed if r is not None}
    for name in COUNTS + PER_ROW:
        if name in names and name not in overrides:
            raise ConfigError(
                f"--param {name}: {where} has one {name} ({getattr(dist, name)!r}); give a range to "
                f"search, e.g. {name}={_example(name, dist)}"
            )
    table = dist.to_dict()
    for name, (lo, hi) in overrides.items():
        if name in COUNTS:
            if lo != int(lo) or hi != int(hi):
                raise ConfigError(f"--param {name}={lo:g}:{hi:g}: a count takes integers")
            table[name] = int(hi)
        elif name not in PER_ROW:
            table[name] = [lo, hi]
        else:
            table[name] = hi  # validated as the setting; per-scenario values replace it
    try:
        box = ScenarioDistribution.from_dict(table)
        for name in PER_ROW:
            if name in overrides:
                ScenarioDistribution.from_dict({**table, name: overrides[name][0]})
    except ConfigError as exc:
        raise ConfigError(f"--param: {exc}") from None
    base = dataclasses.replace(box, **{n: getattr(dist, n) for n in COUNTS + PER_ROW})
    dims: list[Dim] = []
    for draw in draw_plan(box):
        lo, hi = getattr(box, draw.field)
        if (names and draw.field not in names) or lo == hi:
            continue
        for slot in [None] if draw.width is None else range(draw.width):
            if _relevant(box, draw, slot):
                dims.append(Dim(draw.key, slot, lo, hi, field=draw.field))
    for name in COUNTS + PER_ROW:
        if name in overrides:
            lo, hi = overrides[name]
            dims.append(Dim(name, None, lo, hi, integer=name in COUNTS, field=name))
    for name in names:
        if not any(d.field == name for d in dims):
            lo, hi = getattr(box, name)
            why = (
                f"its range [{lo:g}, {hi:g}] is a single value; give one, e.g. {name}={_example(name, dist)}"
                if lo == hi
                else "it cannot change an episode here (scripted NPCs never react; a lead's boost "
                'needs lead_behaviour = "speedup")'
            )
            raise ConfigError(f"--param {name}: {where}: {why}")
    if not dims:
        raise ConfigError(
            f"{where} has no searchable range (each range of its [scenario] table is a single value or "
            f"cannot change an episode); name a parameter with a range, e.g. --param lead_speed=1:3"
        )
    return Space(box, base, tuple(dims))


def _example(name: str, dist: ScenarioDistribution) -> str:
    value = getattr(dist, name)
    if name in COUNTS:
        return f"{value}:{value + 3}"
    v = value[0] if isinstance(value, tuple) else value
    return f"{v / 2:g}:{max(v * 1.5, v + 1):g}"
