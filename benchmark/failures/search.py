"""Failure search: scenarios of a suite's distribution on which a decider fails, found with CMA-ES.

The search box is the suite's own parameter ranges (:mod:`.space`), scaled to the unit cube. Each
generation, every CMA-ES instance asks for its population and all populations together are built into
one batch of scenarios (``space.build``) and run as one batch by the runner (``runner.run_indices`` on
an in-memory explicit suite), the safety monitor on.

Why CMA-ES (the ``cma`` package, BSD-3, pure Python on numpy): the objective is a black box (a closed
loop of simulator, planner and decider), noisy-looking and without gradients; CMA-ES needs only the
ranking of a population, handles box constraints (``bounds``, by its boundary transformation), its
population is a batch (one vectorised run per generation), and it is the established default for such
problems (Hansen 2016, arXiv:1604.00772). Nothing of the optimiser is written here: only the objective,
restarts and the bookkeeping of distinct failures.

The objective (minimised), per scenario, reduced over AVs (the worst):

- ``-1`` for a failure of the target (``crash``: a crash or leaving the road; ``rss``: that or an RSS
  Definition 2 violation in the opposite lane; ``ttc``: that or a head-on TTC below ``ttc_limit``);
- otherwise a continuous signal in (0, 1], so the optimiser has a gradient before it finds a failure:
  ``min(sigmoid(worst RSS margin / 10 m), sigmoid((head-on TTC - 3 s) / 2 s))`` (``tanh``-based;
  ``benchmark/safety``: ``rss_worst_margin``, ``min_headon_ttc``), 1 when the AV never met an oncoming
  vehicle in the opposite lane;
- ``0`` for a failure already found (within ``distinct`` of an earlier one): better than any safe
  scenario, so an instance stays near a failure region, but worse than a new failure, so it moves on
  along it.

Several instances run side by side (``islands``), each restarted from a new random point when it
stops (``es.stop()``) or when it has found nothing new for ``patience`` generations. Failures are
deduplicated: a failure counts only if it differs from every one found before by more than
``distinct`` (a share of the range) in at least one searched parameter (L-infinity distance in the
unit cube; counts at their cell's centre).

:func:`random_search` is the baseline: the suite's own sampler (``ScenarioDistribution.sample`` with a
seed), the same budget, the same evaluation and the same deduplication.

Everything random comes from ``numpy.random.SeedSequence(seed)``: a search with a seed gives the same
failures, and the same file, byte for byte.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.draws import Space, build, draw_plan, layout, space_for
from overtakezoo.envs.explicit import base_distribution, in_memory

TARGETS = ("crash", "rss", "ttc")
CRASH, OFF_ROAD = 2, 4
DEFAULT_BATCH = 128
DEFAULT_DISTINCT = 0.05
DEFAULT_TTC = 1.0  # s


@dataclass
class Evaluation:
    """Per scenario of a batch (reduced over AVs: the worst)."""

    failed: np.ndarray  # bool: a failure of the target
    kind: np.ndarray  # str: "crash", "off-road", "rss", "ttc" or ""
    score: np.ndarray  # the objective (see the module docstring; without the novelty term)
    outcome: np.ndarray  # int: the worst AV's outcome code (results.py)
    rss_margin: np.ndarray  # m (NaN: none)
    headon_ttc: np.ndarray  # s (inf: never closing)
    min_ttc: np.ndarray  # s (inf: never closing)
    crash_time: np.ndarray  # s of the end of an episode that failed (NaN otherwise)


def evaluate(
    suite: Any,
    decider: Any,
    scenarios: Any,
    target: str = "crash",
    ttc_limit: float = DEFAULT_TTC,
    chunk_size: int = 4096,
    core: dict[str, Any] | None = None,
) -> Evaluation:
    """Run ``scenarios`` (one batch, in chunks of ``chunk_size``; ``core``: the core's ``backend`` and
    ``device``, e.g. a GPU, with the same results) and score each."""
    from overtakezoo.benchmark.run.runner import run_indices

    n = scenarios.num
    scen = in_memory(suite, scenarios)
    per = run_indices(scen, decider, np.arange(n), chunk_size=chunk_size, safety=True, **(core or {}))
    e = scenarios.num_avs
    shaped = {
        k: np.asarray(v).reshape(e, n)
        for k, v in per.items()
        if k in ("outcome", "rss_worst_margin", "min_headon_ttc", "min_ttc", "episode_time")
    }
    outcome = shaped["outcome"].astype(np.int64)
    margin = shaped["rss_worst_margin"].astype(float)
    headon = shaped["min_headon_ttc"].astype(float)
    min_ttc = shaped["min_ttc"].astype(float)
    crash = np.isin(outcome, (CRASH, OFF_ROAD))
    with np.errstate(invalid="ignore"):
        rss = margin < 0
    low_ttc = headon < ttc_limit
    s_rss = np.where(np.isnan(margin), 1.0, 0.5 * (1 + np.tanh(np.nan_to_num(margin) / 10.0)))
    s_ttc = np.where(
        np.isfinite(headon), 0.5 * (1 + np.tanh((np.where(np.isfinite(headon), headon, 0) - 3.0) / 2.0)), 1.0
    )
    signal = np.minimum(s_rss, s_ttc)
    kinds = np.where(
        outcome == CRASH,
        "crash",
        np.where(outcome == OFF_ROAD, "off-road", np.where(rss, "rss", np.where(low_ttc, "ttc", ""))),
    )
    failed_av = crash | (rss if target in ("rss", "ttc") else False) | (low_ttc if target == "ttc" else False)
    score_av = np.where(failed_av, -1.0, signal)
    worst = np.argmin(score_av, axis=0)  # the AV whose episode is worst speaks for the scenario
    col = np.arange(n)
    pick = lambda a: a[worst, col]  # noqa: E731
    ended = pick(shaped["episode_time"].astype(float))
    failed = failed_av.any(axis=0)
    return Evaluation(
        failed=failed,
        kind=pick(kinds),
        score=score_av.min(axis=0),
        outcome=pick(outcome),
        rss_margin=np.nanmin(np.where(np.isnan(margin), np.inf, margin), axis=0),
        headon_ttc=headon.min(axis=0),
        min_ttc=min_ttc.min(axis=0),
        crash_time=np.where(failed, ended, np.nan),
    )


class Archive:
    """Distinct failures: points of the unit cube at L-infinity distance > ``distinct`` from each other."""

    def __init__(self, dims: int, distinct: float) -> None:
        self.points = np.zeros((0, dims))
        self.distinct = distinct

    def novel(self, points: np.ndarray) -> np.ndarray:
        """Whether each point is farther than ``distinct`` from every archived point (not added)."""
        if not len(self.points) or not len(points):
            return np.ones(len(points), bool)
        d = np.abs(points[:, None, :] - self.points[None, :, :]).max(axis=2)
        return d.min(axis=1) > self.distinct

    def add(self, points: np.ndarray) -> np.ndarray:
        """Add the novel ones among ``points`` in order (a point close to an earlier one of the same
        batch is not novel); returns which were added."""
        added = np.zeros(len(points), bool)
        for i in np.flatnonzero(self.novel(points)):  # (only the few novel failures of a batch)
            if added.any() and np.abs(points[added] - points[i]).max(axis=1).min() <= self.distinct:
                continue
            added[i] = True
        self.points = np.concatenate([self.points, points[added]])
        return added


@dataclass
class Found:
    """What a search (or the random baseline) found."""

    space: Space
    units: np.ndarray  # (k, D) the distinct failures, in order found
    values: dict[str, np.ndarray]  # their draw values (space.layout)
    info: list[dict[str, Any]]  # per failure: what the run showed
    episodes: int  # simulated episodes spent
    failures: int  # failing episodes, duplicates included
    restarts: int = 0
    wall_s: float = 0.0
    generations: int = 0
    history: list[int] = field(default_factory=list)  # distinct failures after each batch

    @property
    def distinct(self) -> int:
        return len(self.units)

    @property
    def rate(self) -> float:
        return self.distinct / self.episodes if self.episodes else 0.0

    def first(self, k: int) -> Found:
        """The first ``k`` distinct failures (in the order found); the counts stay the search's."""
        return dataclasses.replace(
            self, units=self.units[:k], values={n: v[:k] for n, v in self.values.items()}, info=self.info[:k]
        )


def _info(ev: Evaluation, i: int, episode: int) -> dict[str, Any]:
    def num(x: float) -> float | str:
        x = float(x)
        return x if math.isfinite(x) else ("inf" if x > 0 else "nan" if math.isnan(x) else "-inf")

    return {
        "kind": str(ev.kind[i]),
        "episode": int(episode),
        "t": round(float(ev.crash_time[i]), 4),
        "rss_worst_margin": num(round(float(ev.rss_margin[i]), 4)),
        "min_headon_ttc": num(round(float(ev.headon_ttc[i]), 4)),
    }


class _Island:
    """One CMA-ES instance over the unit cube, restarted from a new random point (step ``sigma0``)
    when it stops (``es.stop()``) or has found nothing new and improved nothing for ``patience``
    generations."""

    def __init__(self, dims: int, popsize: int, rng: np.random.Generator, sigma0: float, patience: int) -> None:
        self.dims, self.popsize, self.rng, self.sigma0, self.patience = dims, popsize, rng, sigma0, patience
        self.restarts = -1
        self._start()

    def _start(self) -> None:
        import cma

        self.restarts += 1
        rng = self.rng
        # randn from this island's own generator: cma then never touches numpy's global random state.
        opts = {
            "bounds": [0.0, 1.0],
            "popsize": self.popsize,
            "verbose": -9,
            "seed": np.nan,
            "randn": lambda *shape: rng.standard_normal(shape),
            "tolflatfitness": 3,
        }
        x0 = rng.uniform(0.0, 1.0, self.dims)
        if self.dims == 1:  # (cma needs two coordinates; the second is ignored)
            x0 = np.array([x0[0], 0.5])
        self.es = cma.CMAEvolutionStrategy(x0, self.sigma0, opts)
        self.stalled, self.best = 0, np.inf

    def ask(self) -> np.ndarray:
        x = np.asarray(self.es.ask(), float)
        return x[:, : self.dims]

    def tell(self, x: np.ndarray, f: np.ndarray, new: int) -> None:
        if self.dims == 1:
            x = np.concatenate([x, np.full((len(x), 1), 0.5)], axis=1)
        self.es.tell(list(x), [float(v) for v in f])
        improved = float(np.min(f)) < self.best - 1e-9
        self.best = min(self.best, float(np.min(f)))
        self.stalled = 0 if (new or improved) else self.stalled + 1
        if self.es.stop() or self.stalled >= self.patience:
            self._start()


def check_budget(budget: Any) -> int:
    """A positive number of episodes (an int, or its text as given on the command line)."""
    if isinstance(budget, str):
        try:
            budget = int(budget.strip())
        except ValueError:
            raise UserError(f"--budget {budget!r}: expected a positive number of episodes") from None
    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise UserError(f"--budget {budget!r}: expected a positive number of episodes")
    if budget > 10_000_000:
        raise UserError(f"--budget {budget}: at most 10000000 episodes")
    return budget


def _progress(total: int, desc: str, progress: bool) -> Any:
    from tqdm import tqdm

    return tqdm(
        total=total,
        unit="episode",
        desc=desc,
        leave=False,
        file=sys.stderr,
        disable=not progress or not sys.stderr.isatty(),
    )


def cma_search(
    suite: Any,
    decider: Any,
    budget: int,
    seed: int = 0,
    params: list[str] | None = None,
    target: str = "crash",
    batch: int = DEFAULT_BATCH,
    distinct: float = DEFAULT_DISTINCT,
    ttc_limit: float = DEFAULT_TTC,
    patience: int = 6,
    sigma0: float = 0.2,
    progress: bool = True,
    space: Space | None = None,
    popsize: int | None = None,
    core: dict[str, Any] | None = None,
) -> Found:
    """Search ``budget`` episodes for distinct failures of ``decider`` on ``suite`` (module docstring)."""
    budget = check_budget(budget)
    try:
        import cma  # noqa: F401
    except ImportError:
        raise UserError("search needs the cma package: pip install 'overtakezoo[search]'") from None
    if target not in TARGETS:
        raise UserError(f"--target {target!r}: expected one of {', '.join(TARGETS)}")
    space = space or space_for(base_distribution(suite), params, f"suite {suite.name!r}")
    D = space.size
    popsize = popsize or max(4 + int(3 * math.log(max(D, 2))), 16)  # cma's default, at least 16
    islands_n = max(1, batch // popsize)
    seq = np.random.SeedSequence(seed)
    archive = Archive(D, distinct)
    islands = [_Island(D, popsize, np.random.default_rng(s), sigma0, patience) for s in seq.spawn(islands_n)]
    found_units, found_values, infos = [], [], []
    episodes = failures = generations = 0
    history: list[int] = []
    t0 = time.perf_counter()
    bar = _progress(budget, f"search {suite.name}/{decider.name}", progress)
    try:
        while episodes < budget:
            asks = [isl.ask() for isl in islands]
            sizes = [len(a) for a in asks]
            x = np.concatenate(asks)
            take = min(len(x), budget - episodes)  # the last batch may be cut short (and not told)
            x = x[:take]
            unit = space.canonical(x)
            ev = evaluate(suite, decider, space.build(x), target, ttc_limit, core=core)
            new = _keep_new(ev, unit, space.values(x), archive, episodes, infos, found_units, found_values)
            failures += int(ev.failed.sum())
            episodes += take
            generations += 1
            history.append(len(archive.points))
            f = np.where(ev.failed & ~new, 0.0, ev.score)  # a known failure scores 0 (module docstring)
            if take == len(np.concatenate(asks)):
                lo = 0
                for isl, size in zip(islands, sizes, strict=True):
                    isl.tell(x[lo : lo + size], f[lo : lo + size], int(new[lo : lo + size].sum()))
                    lo += size
            bar.update(take)
            bar.set_postfix(failures=len(archive.points), refresh=False)
    finally:
        bar.close()
    return _found(
        space,
        found_units,
        found_values,
        infos,
        episodes,
        failures,
        time.perf_counter() - t0,
        restarts=sum(isl.restarts for isl in islands),
        generations=generations,
        history=history,
    )


def _keep_new(
    ev: Any,
    unit: np.ndarray,
    vals: dict[str, np.ndarray],
    archive: Any,
    offset: int,
    infos: list,
    found_units: list,
    found_values: list,
) -> np.ndarray:
    """The batch's failures that the archive had not seen (each added to it), recorded with their
    values and episode info; returns which rows they are."""
    new = np.zeros(len(unit), bool)
    fail = np.flatnonzero(ev.failed)
    if fail.size:
        new[fail] = archive.add(unit[fail])
    infos.extend(_info(ev, i, offset + i) for i in np.flatnonzero(new))
    found_units.append(unit[new])
    found_values.append({k: v[new] for k, v in vals.items()})
    return new


def random_search(
    suite: Any,
    decider: Any,
    budget: int,
    seed: int = 0,
    params: list[str] | None = None,
    target: str = "crash",
    batch: int = 4096,
    distinct: float = DEFAULT_DISTINCT,
    ttc_limit: float = DEFAULT_TTC,
    progress: bool = True,
    space: Space | None = None,
    core: dict[str, Any] | None = None,
) -> Found:
    """The baseline: ``budget`` scenarios drawn by the suite's own sampler with ``seed`` (when
    ``params`` widen the box: uniformly in it), the same evaluation and deduplication."""
    budget = check_budget(budget)
    space = space or space_for(base_distribution(suite), params, f"suite {suite.name!r}")
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    archive = Archive(space.size, distinct)
    found_units, found_values, infos = [], [], []
    episodes = failures = 0
    history: list[int] = []
    t0 = time.perf_counter()
    bar = _progress(budget, f"random {suite.name}/{decider.name}", progress)
    try:
        while episodes < budget:
            n = min(batch, budget - episodes)
            if params:  # the box is the user's: uniform in it
                unit = space.canonical(rng.uniform(size=(n, space.size)))
                vals = space.values(unit)
            else:  # the suite's own draws, recorded so that failures can be deduplicated and written
                vals = _recorded_sample(space, n, rng)
                unit = space.units(vals)
            ev = evaluate(suite, decider, build(space.dist, vals), target, ttc_limit, core=core)
            _keep_new(ev, unit, vals, archive, episodes, infos, found_units, found_values)
            failures += int(ev.failed.sum())
            episodes += n
            history.append(len(archive.points))
            bar.update(n)
    finally:
        bar.close()
    return _found(
        space, found_units, found_values, infos, episodes, failures, time.perf_counter() - t0, history=history
    )


def _recorded_sample(space: Space, n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` draws of the distribution's own sampler (its ``uniform`` calls, in order), as values."""
    dist = space.dist
    vals = {}
    for d in draw_plan(dist):
        lo, hi = getattr(dist, d.field)
        vals[d.key] = rng.uniform(lo, hi, size=(n,) if d.width is None else (n, d.width))
    return layout(dist, n, vals)


def _found(
    space: Space,
    units: list[np.ndarray],
    values: list[dict[str, np.ndarray]],
    infos: list[dict[str, Any]],
    episodes: int,
    failures: int,
    wall: float,
    **extra: Any,
) -> Found:
    keys = values[0].keys() if values else space.fixed(0).keys()
    joined = {k: np.concatenate([v[k] for v in values]) if values else space.fixed(0)[k] for k in keys}
    return Found(
        space=space,
        units=np.concatenate(units) if units else np.zeros((0, space.size)),
        values=joined,
        info=infos,
        episodes=episodes,
        failures=failures,
        wall_s=round(wall, 3),
        **extra,
    )


def compare(
    suite: Any,
    decider: Any,
    budget: int,
    seeds: list[int],
    random_seeds: list[int],
    params: list[str] | None = None,
    target: str = "crash",
    progress: bool = False,
    **kwargs: Any,
) -> dict[str, Any]:
    """Distinct failures per episode, CMA-ES search against random sampling, at the same budget,
    over several seeds of each; the ratio of the pooled rates."""
    searches = [cma_search(suite, decider, budget, s, params, target, progress=progress, **kwargs) for s in seeds]
    randoms = [
        random_search(
            suite,
            decider,
            budget,
            10_000 + s,
            params,
            target,
            progress=progress,
            distinct=kwargs.get("distinct", DEFAULT_DISTINCT),
        )
        for s in random_seeds
    ]
    s_rate = sum(f.distinct for f in searches) / sum(f.episodes for f in searches)
    r_found = sum(f.distinct for f in randoms)
    r_episodes = sum(f.episodes for f in randoms)
    r_rate = r_found / r_episodes
    # With no random failure the ratio has no finite estimate; the rule of three bounds the random rate
    # (95 %: at most 3 / episodes), so the ratio is at least s_rate / that.
    return {
        "suite": suite.name,
        "decider": decider.name,
        "budget": budget,
        "target": target,
        "search": [
            {
                "seed": s,
                "distinct": f.distinct,
                "failures": f.failures,
                "episodes": f.episodes,
                "restarts": f.restarts,
                "wall_s": f.wall_s,
            }
            for s, f in zip(seeds, searches, strict=True)
        ],
        "random": [
            {
                "seed": 10_000 + s,
                "distinct": f.distinct,
                "failures": f.failures,
                "episodes": f.episodes,
                "wall_s": f.wall_s,
            }
            for s, f in zip(random_seeds, randoms, strict=True)
        ],
        "search_rate": s_rate,
        "random_rate": r_rate,
        "ratio": (s_rate / r_rate) if r_found else None,
        "ratio_at_least": (s_rate / (3.0 / r_episodes)) if not r_found else None,
    }


def default_name(suite: Any, decider: Any) -> str:
    """``<suite>-<decider>-failures`` made a suite name (lowercase, digits, '.', '_', '-'; 64 at most)."""
    import re

    raw = f"{suite.name}-{decider.name}".lower()
    stem = re.sub(r"[^a-z0-9._-]+", "-", raw).strip("-._")[: 64 - len("-failures")] or "search"
    return f"{stem}-failures"


def failure_suite(
    suite: Any, decider: Any, found: Found, *, name: str, seed: int, budget: int, target: str, command: str
) -> bytes:
    """The explicit suite (TOML bytes) of ``found``: loadable by ``load_suite``, its own hash."""
    from overtakezoo.envs import SIM_VERSION
    from overtakezoo.envs.explicit import entries_of, suite_tables, to_toml

    entries = entries_of(found.space, found.values)
    for entry, info in zip(entries, found.info, strict=True):
        entry["found"] = info
    doc = {
        "name": name,
        "version": 1,
        "description": (
            f"{found.distinct} distinct {target} failures of {decider.name} on {suite.name} "
            f"(failure search, {found.episodes} episodes)"
        ),
        "count": found.distinct,
        "seed": seed,
        "scenario": found.space.base.to_dict(),
        "sim": suite_tables(suite),
        "search": {
            "decider": decider.name,
            "decider_version": str(getattr(decider, "version", "")),
            "weights_sha256": str(getattr(decider, "weights_sha256", None) or ""),
            "suite": suite.name,
            "suite_version": suite.version,
            "suite_hash": suite.hash,
            "sim_version": SIM_VERSION,
            "target": target,
            "budget": budget,
            "seed": seed,
            "episodes": found.episodes,
            "failing_episodes": found.failures,
            "parameters": [d.label for d in found.space.dims],
            "command": command,
        },
        "scenarios": entries,
    }
    header = (
        f"Failures of {decider.name} on {suite.name}, found by `{command}`.\n"
        "Generated by overtakezoo search (benchmark/failures/search.py); do not edit (edits change the hash).\n"
        "Each [[scenarios]] entry gives the values of the [scenario] distribution's draws for one scenario\n"
        "(envs/draws.py); [scenarios.found] is what the search saw and is not read back."
    )
    return to_toml(header, doc)


def check_distinct(value: float) -> float:
    if not (isinstance(value, (int, float)) and 0 <= value < 1):
        raise UserError(f"--distinct {value!r}: expected a share of each range in [0, 1)")
    return float(value)
