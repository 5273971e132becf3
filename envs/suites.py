"""Suites: versioned TOML files naming a scenario distribution, a count, a seed and simulator settings.

A suite file has top-level ``name``, ``version`` (an integer), ``count``, ``seed``, an optional
``description``, a ``[scenario]`` table (keys of :class:`~overtakezoo.envs.ScenarioDistribution`) and an
optional ``[sim]`` table (keys of :class:`~overtakezoo.envs.EnvConfig`, nested tables allowed). The
suite's hash is the sha256 of the file's bytes, so any edit gives results a different identity.

A suite may name a ``base``, another built-in suite: it then takes the base's ``[scenario]`` and
``[sim]`` tables, with any ``[scenario]`` / ``[sim]`` tables of its own merged over them key by key
(its other keys are its own). A *split* (``oncoming-4-train``: ``base = "oncoming-4"``, no tables)
is the base's distribution and simulator settings drawn with the split's own ``seed`` and ``count``;
a *variant* overrides a few keys. Its hash covers its own bytes and its base's (``b"\0"`` between,
then the base's base, if any), so an edit to any of them changes it. :func:`suite_document` is the
one reading of ``base``; published suite files are frozen (their hashes pin every result), so a new
variant is a new file with a base and overrides, never an edit.
"""

from __future__ import annotations

import hashlib
import os
import re
import tomllib
from collections.abc import Collection, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from overtakezoo.envs.config import ConfigError, EnvConfig, SuiteError, unknown_key
from overtakezoo.envs.scenarios import ScenarioDistribution, Scenarios

if TYPE_CHECKING:
    from overtakezoo.envs.explicit import ExplicitDistribution

SUITES_DIR = Path(__file__).with_name("suites")
NAME_RE = re.compile(r"^[a-z0-9][a-z0-9._-]{0,63}$")  # also a directory name on the leaderboard
MAX_COUNT = 1_000_000
CHUNK_SIZE = 4096  # roads the runner steps at once (runner.run_suite's chunk_size)
_KEYS = {"name", "version", "count", "seed", "description", "scenario", "sim", "base", "scenarios", "search"}
SUITE_TABLES = ("scenario", "sim")  # what a suite takes from its base, its own merged over them


@dataclass(frozen=True)
class Suite:
    name: str
    version: int
    count: int
    seed: int
    description: str
    hash: str
    path: Path
    config: EnvConfig
    distribution: ScenarioDistribution | ExplicitDistribution  # the second: a suite that lists its scenarios

    @property
    def num_avs(self) -> int:
        """Automated vehicles per scenario (1: a single-ego suite)."""
        return self.distribution.sample(1, self.seed).num_avs

    @property
    def hold_steps(self) -> int:
        """Core steps one env step of this suite's faces holds a decision by default: the zoo's 1 s at
        the suite's dt (:func:`zoo_hold`; its registered id's ``hold_steps``)."""
        return zoo_hold(self.config.dt, self.config.decision_interval)

    @property
    def builtin(self) -> bool:
        return self.path.parent == SUITES_DIR.resolve()

    def scenarios(self, shard: tuple[int, int] | None = None) -> Scenarios:
        """All ``count`` scenarios, or the contiguous slice ``shard = (i, k)`` (0 <= i < k)."""
        start, stop = shard_bounds(self.count, shard)
        check_memory(self)  # before drawing: a suite too big for memory is one error, not a MemoryError
        # Draw the whole suite then slice: a shard's rows are bit-identical to the same rows of a full run.
        return self.distribution.sample(self.count, self.seed).take(slice(start, stop))


def memory_needed(suite: Suite) -> tuple[int, int]:
    """Bytes a run of ``suite`` allocates, estimated: (the drawn scenarios, one chunk's core state).

    The whole suite is drawn at once (shards slice it), so its arrays take ``count`` times one
    scenario's bytes, and drawing them peaks at ~1.4 times that (measured). The core steps
    ``CHUNK_SIZE`` roads at a time; per AV row it holds (vehicles, rollouts) arrays and the
    observation's pairwise (vehicles, vehicles) ranks: measured ~36 bytes x vehicles^2 at 129
    vehicles, bounded here by 40 V^2 + 600 V + 2000."""
    one = suite.distribution.sample(1, suite.seed)
    row = sum(a.nbytes for a in one.to_arrays().values())
    vehicles = one.num_npcs + one.num_avs - 1  # what each AV row sees
    rows = min(suite.count, CHUNK_SIZE) * one.num_avs
    return int(1.5 * suite.count * row), rows * (40 * vehicles**2 + 600 * vehicles + 2000)


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (None when the platform does not say)."""
    try:
        import psutil

        return int(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:  # Linux: MemAvailable counts reclaimable caches, unlike sysconf's free pages
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(suite: Suite) -> None:
    """SuiteError naming the sizes when a run of ``suite`` cannot fit in the available memory."""
    scenarios, core = memory_needed(suite)
    available = available_memory()
    if available is not None and scenarios + core > available:
        one = suite.distribution
        gib = 2.0**30
        raise SuiteError(
            f"{suite.path}: count: {suite.count} scenarios of {1 + one.oncoming_count + one.follower_count} NPCs "
            f"need about {(scenarios + core) / gib:.1f} GiB ({scenarios / gib:.1f} GiB of scenarios, "
            f"{core / gib:.1f} GiB per chunk of {CHUNK_SIZE}), only {available / gib:.1f} GiB is available: "
            f"lower count, oncoming_count or follower_count"
        )


def shard_bounds(count: int, shard: tuple[int, int] | None) -> tuple[int, int]:
    """[start, stop) of shard ``(i, k)``: the i-th (0-based) of k contiguous, near-equal slices."""
    if shard is None:
        return 0, count
    i, k = shard
    if not (isinstance(i, int) and isinstance(k, int)) or k < 1 or not 0 <= i < k:
        raise SuiteError(f"shard {i}/{k}: expected i/k with 0 <= i < k")
    if k > count:
        raise SuiteError(f"shard {i}/{k}: more shards than the suite's {count} scenarios")
    return i * count // k, (i + 1) * count // k


def parse_shard(text: str | None) -> tuple[int, int] | None:
    """``"i/k"`` -> (i, k); None stays None."""
    if text is None:
        return None
    m = re.fullmatch(r"\s*(\d+)\s*/\s*(\d+)\s*", text)
    if not m:
        raise SuiteError(f"--shard {text!r}: expected i/k, e.g. 0/4 (the first of four slices)")
    i, k = int(m.group(1)), int(m.group(2))
    if k < 1 or i >= k:
        raise SuiteError(f"--shard {text!r}: expected 0 <= i < k")
    return i, k


def suite_names() -> list[str]:
    return sorted(p.stem for p in SUITES_DIR.glob("*.toml"))


def list_suites() -> list[Suite]:
    return [load_suite(n) for n in suite_names()]


# The zoo's decision: its learned members were trained holding each decision 1 s (a training hold,
# the card's action_repeat, of 10 at dt = 0.1 s); every face of a suite holds that long by default.
ZOO_DECISION_S = 1.0


def zoo_hold(dt: float, decision_interval: int = 1) -> int:
    """Core steps of the zoo's decision (:data:`ZOO_DECISION_S`) at ``dt``, a multiple of
    ``decision_interval`` (10 at dt = 0.1 s): the hold of a suite's registered id
    (:func:`suite_env_ids`) and of every face made from a suite (``parallel_env("duel")``,
    ``make_vec(suite="table1")``, ``OvertakeEnv(suite=...)``). The one place it is computed."""
    from overtakezoo.envs.hold import hold_steps

    return hold_steps(decision_interval, max(1, round(ZOO_DECISION_S / float(dt))))


@dataclass(frozen=True)
class SuiteEnvId:
    """A built-in suite as a registered environment id (``overtakezoo/<name>-v<version>``)."""

    name: str  # the suite (file stem), passed as ``suite=`` to the env
    version: int
    hold_steps: int  # core steps per env step: the zoo's decision (ZOO_DECISION_S) at the suite's dt
    multi_av: bool  # several automated vehicles per road: a PettingZoo id only


def suite_env_ids() -> dict[str, SuiteEnvId]:
    """Every built-in suite's environment id, read from the files' top-level keys only (cheap enough
    for ``import overtakezoo.envs``; the env validates the whole file when it is made)."""
    out: dict[str, SuiteEnvId] = {}
    for name in suite_names():
        data = (SUITES_DIR / f"{name}.toml").read_bytes()
        try:
            doc, _ = suite_document(data, name)
        except SuiteError:  # (made, the env names the problem)
            doc = tomllib.loads(data.decode("utf-8"))
        sim, scenario = doc.get("sim", {}), doc.get("scenario", {})
        dt, interval = sim.get("dt", 0.1), sim.get("decision_interval", 1)
        multi = scenario.get("platoon_size", 1) > 1 or scenario.get("oncoming_av", 0) > 0
        held = zoo_hold(dt, interval)
        out[f"overtakezoo/{name}-v{doc['version']}"] = SuiteEnvId(name, int(doc["version"]), held, multi)
    return out


def load_suite(name_or_path: str | Path) -> Suite:
    """A built-in suite by name (``table1``) or any suite file by path."""
    text = str(name_or_path)
    path = Path(text)
    if not (text.endswith(".toml") or path.is_file()):
        if not NAME_RE.match(text) or not (SUITES_DIR / f"{text}.toml").is_file():
            raise SuiteError(f"unknown suite {text!r} (known: {', '.join(suite_names())}; or pass a .toml path)")
        path = SUITES_DIR / f"{text}.toml"
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise SuiteError(f"cannot read suite file {path}: {exc.strerror or exc}") from None
    return parse_suite(data, path)


def parse_suite(data: bytes, path: Path) -> Suite:
    """Validate the bytes of a suite file; every problem is a SuiteError naming the file and key."""
    where = str(path)
    doc, digest = suite_document(data, where)
    for key in ("name", "version", "count", "seed", "scenario"):
        if key not in doc:
            raise SuiteError(f"{where}: {key}: missing")
    name = doc["name"]
    if not isinstance(name, str) or not NAME_RE.match(name):
        raise SuiteError(f"{where}: name: expected lowercase letters, digits, '.', '_' or '-', got {name!r}")
    version = _int(where, "version", doc["version"], 1, 10**9)
    count = _int(where, "count", doc["count"], 1, MAX_COUNT)
    seed = _int(where, "seed", doc["seed"], 0, 2**63 - 1)
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise SuiteError(f"{where}: description: expected a string")
    scenario, sim = doc["scenario"], doc.get("sim", {})
    if not isinstance(scenario, dict):
        raise SuiteError(f"{where}: scenario: expected a table")
    if not isinstance(sim, dict):
        raise SuiteError(f"{where}: sim: expected a table")
    if "scenario" in sim:
        raise SuiteError(f"{where}: sim.scenario: put scenario keys in the [scenario] table")
    distribution: ScenarioDistribution | ExplicitDistribution
    try:
        config = EnvConfig.from_dict(sim, scenario=scenario)
        distribution = ScenarioDistribution.from_dict(scenario)
    except ConfigError as exc:
        section = "" if str(exc).startswith("scenario.") else "sim."
        raise SuiteError(f"{where}: {section}{exc}") from None
    except (TypeError, ValueError) as exc:  # a value of the wrong type deep in a nested table
        raise SuiteError(f"{where}: sim: {exc}") from None
    if "scenarios" in doc or "search" in doc:  # a suite that lists its scenarios (envs/explicit.py)
        from overtakezoo.envs.explicit import explicit_distribution

        distribution = explicit_distribution(distribution, doc, where)
    return Suite(
        name=name,
        version=version,
        count=count,
        seed=seed,
        description=description,
        hash=digest,
        path=path.resolve(),
        config=config,
        distribution=distribution,
    )


def suite_document(data: bytes, where: str) -> tuple[dict[str, Any], str]:
    """The one reading of a suite file's bytes: its document with its ``base`` resolved
    (:func:`resolve_base`: the base's ``[scenario]`` and ``[sim]`` tables, the file's own merged over
    them) and the suite's hash, the sha256 of the file's bytes followed by ``b"\0"`` and each base
    file's bytes, nearest base first. Every problem is a SuiteError naming the file and the key."""
    try:
        doc = tomllib.loads(data.decode("utf-8"))
    except UnicodeDecodeError:
        raise SuiteError(f"{where}: not UTF-8 text") from None
    except tomllib.TOMLDecodeError as exc:
        raise SuiteError(f"{where}: malformed TOML: {exc}") from None
    unknown = sorted(set(doc) - _KEYS)
    if unknown:
        raise SuiteError(f"{where}: {unknown[0]}: {unknown_key(unknown[0], _KEYS)}")
    digest = hashlib.sha256(data)
    if "base" in doc:
        doc, bases = resolve_base(doc, where, SUITES_DIR, inherit=SUITE_TABLES)
        for base in bases:
            digest.update(b"\0" + base)
    return doc, digest.hexdigest()


def resolve_base(
    doc: dict[str, Any],
    where: str,
    folder: Path,
    *,
    inherit: Collection[str] | None = None,
    error: type[ConfigError] = SuiteError,
    what: str = "built-in suite",
) -> tuple[dict[str, Any], list[bytes]]:
    """``doc`` (a file's document) completed with its base: the file ``folder/<base>.toml`` named by
    ``doc["base"]``, itself resolved first if it names a base. The base's keys in ``inherit`` (None:
    all) come first, the file's own keys are merged over them (:func:`merged`: tables key by key).
    Suites (``inherit`` their two tables) and hyperparameter files (everything) both read ``base``
    here. Returns the document (``base`` kept) and the bytes of each base file, nearest first. A base
    that is not a file of ``folder`` or a loop of bases is one ``error`` naming ``where: base``."""
    names: list[str] = []
    layers: list[dict[str, Any]] = []
    chain: list[bytes] = []
    current = doc
    while "base" in current:
        name = current["base"]
        path = folder / f"{name}.toml" if isinstance(name, str) and NAME_RE.match(name) else None
        if path is None or not path.is_file():
            known = ", ".join(sorted(p.stem for p in folder.glob("*.toml")))
            raise error(f"{where}: base: {name!r} is not a {what} (known: {known})")
        if name in names:
            raise error(f"{where}: base: {' -> '.join([*names, name])} is a loop")
        names.append(name)
        data = path.read_bytes()
        try:
            current = tomllib.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
            raise error(f"{where}: base: {path} is not readable TOML: {exc}") from None
        chain.append(data)
        layers.append(current)
    out: dict[str, Any] = {}
    for layer in reversed(layers):
        out = merged(out, {k: v for k, v in layer.items() if k != "base" and (inherit is None or k in inherit)})
    return merged(out, doc), chain


def merged(base: Mapping[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` applied (tables merged key by key, not replaced; any other value,
    an array too, replaced)."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merged(out[key], value)
        else:
            out[key] = value
    return out


def _int(where: str, key: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise SuiteError(f"{where}: {key}: expected an integer in [{lo}, {hi}], got {value!r}")
    return value
