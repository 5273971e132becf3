"""The official datasets' recipes: build a dataset from its registry entry, and regenerate the registry.

``registry/recipes.toml`` is the declarative table: suites x levels (random, medium, expert,
mixed). :func:`regenerate` expands it, builds every dataset, packs its archive, and writes
``registry/datasets.json`` in one piece; each entry there carries its full recipe, so
:func:`build_entry` (``dataset download NAME`` when no mirror delivers) rebuilds a dataset from the registry alone
and installs it only if its content hash (see :mod:`overtakezoo.benchmark.datasets.store`) equals the
registry's.

A recipe: ``suite`` (name, version, sha256 of the file), ``count`` (its first N scenarios),
``chunk_size``, and ``policies``, each a decider (name, version, weights sha256) with ``epsilon``
and ``seed``; episode i is recorded by policy ``i mod len(policies)`` (one policy: all of them), so
a mixed dataset's episodes are exactly the matching episodes of its components.
"""

from __future__ import annotations

import json
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.datasets.record import collect
from overtakezoo.benchmark.datasets.registry import load_registry, registry_path
from overtakezoo.benchmark.datasets.store import check_name, pack, write_dataset
from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs.io import atomic_write_json
from overtakezoo.envs.model.outcomes import OUTCOME_NAMES

RECIPES_FILE = Path(__file__).with_name("registry") / "recipes.toml"
REGISTRY_FORMAT = (
    "name -> {level, description, recipe {suite, suite_version, suite_sha256, count, chunk_size, "
    "policies [{decider, decider_version, weights_sha256, epsilon, seed}]; episode i comes from policy "
    "i mod len(policies)}, content_sha256 (canonical arrays, see overtakezoo.benchmark.datasets.store), "
    "episodes, steps, mirrors (URLs of the .tar.gz, tried in order), size and sha256 of that archive}; "
    "regenerate with `overtakezoo dataset regenerate`"
)
LEVEL_KEYS = {"name", "decider", "epsilon", "seed", "interleave"}


# ---------------------------------------------------------------------------- the recipe table
def read_recipes(path: Path = RECIPES_FILE) -> dict[str, Any]:
    """The recipe table, checked: unknown keys and bad values are refused with the key named."""
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as exc:
        raise UserError(f"cannot read recipes {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UserError(f"recipes {path}: {exc}") from None
    bad = set(data) - {"version", "chunk_size", "mirrors", "suites", "levels"}
    if bad:
        raise UserError(f"recipes {path}: unknown key(s) {sorted(bad)}")
    if not (
        isinstance(data.get("version"), int)
        and isinstance(data.get("chunk_size"), int)
        and data["chunk_size"] >= 1
        and isinstance(data.get("mirrors", []), list)
    ):
        raise UserError(f"recipes {path}: needs version (int), chunk_size (int >= 1), mirrors (list of URL patterns)")
    levels = data.get("levels", {})
    for level, spec in levels.items():
        bad = set(spec) - LEVEL_KEYS
        if bad:
            raise UserError(f"recipes {path}: levels.{level}: unknown key(s) {sorted(bad)}")
        if "interleave" in spec:
            missing = [x for x in spec["interleave"] if x not in levels or "interleave" in levels[x]]
            if missing or not spec["interleave"]:
                raise UserError(
                    f"recipes {path}: levels.{level}.interleave: {missing or '[]'} are not single-policy levels"
                )
        elif not (
            isinstance(spec.get("decider"), str)
            and isinstance(spec.get("epsilon"), (int, float))
            and 0.0 <= spec["epsilon"] <= 1.0
            and isinstance(spec.get("seed", 0), int)
        ):
            raise UserError(f"recipes {path}: levels.{level} needs decider (str), epsilon in [0, 1], seed (int)")
    for s in data.get("suites", []):
        if not (
            isinstance(s, dict)
            and isinstance(s.get("suite"), str)
            and isinstance(s.get("env"), str)
            and set(s) <= {"suite", "env", "count"}
        ):
            raise UserError(f"recipes {path}: each suites entry is {{suite = NAME, env = SHORT, count = N (optional)}}")
    return data


def plan(data: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Dataset name -> {level, env, suite, count, policies (level specs), components} from the table."""
    from overtakezoo.envs.suites import load_suite

    out = {}
    levels = data.get("levels", {})

    def level_name(level: str) -> str:
        spec = levels[level]
        return f"{spec.get('name') or spec['decider']}-v{data['version']}"

    for s in data.get("suites", []):
        suite = load_suite(s["suite"])
        count = int(s.get("count", suite.count))
        for level, spec in levels.items():
            parts = spec.get("interleave", [level])
            name = f"overtakezoo/{s['env']}/{level_name(level)}"
            check_name(name)
            out[name] = {
                "level": level,
                "env": s["env"],
                "suite": suite,
                "count": count,
                "policies": [levels[p] for p in parts],
                "components": [f"overtakezoo/{s['env']}/{level_name(p)}" for p in parts]
                if "interleave" in spec
                else [],
            }
    return out


# ---------------------------------------------------------------------------- building
def resolve_recipe(suite: Any, count: int, chunk_size: int, policies: list[dict[str, Any]]) -> dict[str, Any]:
    """The registry's recipe: the table's choices plus the identities of the suite and deciders used."""
    from overtakezoo.benchmark.run.policy import load_zoo

    resolved = []
    for p in policies:
        d = load_zoo(p["decider"], suite.config)
        resolved.append(
            {
                "decider": d.name,
                "decider_version": str(d.version),
                "weights_sha256": getattr(d, "weights_sha256", None),
                "epsilon": float(p["epsilon"]),
                "seed": int(p.get("seed", 0)),
            }
        )
    return {
        "suite": suite.name,
        "suite_version": suite.version,
        "suite_sha256": suite.hash,
        "count": count,
        "chunk_size": chunk_size,
        "policies": resolved,
    }


def collect_recipe(
    recipe: dict[str, Any], name: str = "", progress: bool = True, memo: dict[str, Any] | None = None
) -> tuple[Any, list[dict[str, Any]]]:
    """(suite, episodes) for a registry recipe, after checking that this installation has the suite
    file and decider versions it names (else the rebuild could not match; said with the reason)."""
    from overtakezoo.benchmark.run.policy import load_zoo
    from overtakezoo.envs.suites import load_suite

    try:
        suite = load_suite(recipe["suite"])
        count, chunk = int(recipe["count"]), int(recipe.get("chunk_size", 4096))
        policies = [
            {**p, "decider": str(p["decider"]), "epsilon": float(p["epsilon"]), "seed": int(p["seed"])}
            for p in recipe["policies"]
        ]
    except (KeyError, TypeError, ValueError) as exc:
        raise UserError(f"dataset {name}: the registry's recipe is incomplete ({exc})") from None
    if suite.hash != recipe.get("suite_sha256"):
        raise UserError(
            f"dataset {name}: suite {suite.name} here has sha256 {suite.hash[:16]}..., the recipe used "
            f"{str(recipe.get('suite_sha256'))[:16]}... (another version): a rebuild cannot match"
        )
    if not 1 <= count <= suite.count:
        raise UserError(f"dataset {name}: the recipe's count {count} is outside suite {suite.name}'s 1..{suite.count}")
    parts = []
    for p in policies:
        decider = load_zoo(p["decider"], suite.config)
        have = (str(decider.version), getattr(decider, "weights_sha256", None))
        want = (str(p.get("decider_version")), p.get("weights_sha256"))
        if have != want:
            raise UserError(
                f"dataset {name}: decider {p['decider']} here is v{have[0]} (weights {str(have[1])[:16]}), "
                f"the recipe used v{want[0]} (weights {str(want[1])[:16]}): a rebuild cannot match"
            )
        key = json.dumps([suite.hash, count, chunk, p], sort_keys=True)
        if memo is None or key not in memo:
            episodes = collect(
                suite,
                decider,
                epsilon=float(p["epsilon"]),
                seed=int(p["seed"]),
                count=count,
                chunk_size=chunk,
                progress=progress,
            )
            if memo is not None:
                memo[key] = episodes
        parts.append(episodes if memo is None else memo[key])
    return suite, [parts[i % len(parts)][i] for i in range(count)]


def describe(level: str, recipe: dict[str, Any], components: list[str]) -> str:
    who = "; ".join(
        f"{p['decider']} v{p['decider_version']} epsilon {p['epsilon']} seed {p['seed']}" for p in recipe["policies"]
    )
    mix = (
        f"; episode i is episode i of the (i mod {len(components)})-th of {', '.join(components)}" if components else ""
    )
    return (
        f"{level}: {who} on suite {recipe['suite']} v{recipe['suite_version']} ({recipe['suite_sha256'][:12]}), "
        f"its first {recipe['count']} scenarios{mix}. One transition per simulator step."
    )


def _algorithm(recipe: dict[str, Any]) -> str:
    return " + ".join(f"{p['decider']} (epsilon={p['epsilon']})" for p in recipe["policies"])


def build_entry(name: str, entry: dict[str, Any], progress: bool = True) -> str:
    """Rebuild registry dataset ``name`` from its recipe; installed only if the content hash matches."""
    recipe, expect = entry.get("recipe"), entry.get("content_sha256")
    if not recipe:
        raise UserError(f"dataset {name}: the registry has no recipe to rebuild it from")
    if not expect:
        raise UserError(f"dataset {name}: the registry has no content_sha256 to check a rebuild against")
    suite, episodes = collect_recipe(recipe, name, progress)
    description = entry.get("description") or describe(entry.get("level", "?"), recipe, [])
    # (the same rebuild under other CPUs' float kernels: store.py's docstring)
    accepted = [h.lower() for h in [expect, *entry.get("rebuild_sha256", [])]]
    return write_dataset(name, episodes, suite.config, _algorithm(recipe), description, expect_content=accepted)


# ---------------------------------------------------------------------------- regeneration
def outcome_shares(episodes: list[dict[str, Any]]) -> dict[str, float]:
    """How the episodes ended (each episode's last outcome), as shares that sum to 1, for `dataset list`."""
    last = np.array([int(e["infos"]["outcome"][-1]) for e in episodes], np.int64)
    counts = np.bincount(last, minlength=len(OUTCOME_NAMES))
    return {name: round(float(c) / max(1, last.size), 4) for name, c in zip(OUTCOME_NAMES, counts, strict=False) if c}


def regenerate(
    recipes: Path = RECIPES_FILE, registry: Path | None = None, archives: Path | None = None, progress: bool = True
) -> tuple[dict[str, dict[str, Any]], Path]:
    """Build every dataset of the recipe table into the datasets folder, pack each into ``archives``,
    and write the registry (atomically, once everything is built); returns (its entries, the archives' folder)."""
    from tqdm import tqdm

    from overtakezoo.benchmark.datasets.store import cache_dir

    data = read_recipes(recipes)
    registry = registry_path() if registry is None else Path(registry)
    archives = Path(archives) if archives else cache_dir() / "release" / f"datasets-v{data['version']}"
    plans = plan(data)
    entries: dict[str, dict[str, Any]] = {}
    memo: dict[str, Any] = {}  # recorded episodes per policy: the mixed dataset reuses its components'
    memo_suite = None
    for name, p in tqdm(plans.items(), desc="datasets", unit="dataset", disable=not progress):
        if memo_suite != p["suite"].name:  # a new suite: free the last one's episodes
            memo, memo_suite = {}, p["suite"].name
        recipe = resolve_recipe(p["suite"], p["count"], data["chunk_size"], p["policies"])
        suite, episodes = collect_recipe(recipe, name, progress, memo)
        description = describe(p["level"], recipe, p["components"])
        digest = write_dataset(name, episodes, suite.config, _algorithm(recipe), description)
        archive = name.replace("/", "__") + ".tar.gz"
        _, size, sha = pack(name, archives / archive)
        entries[name] = {
            "level": p["level"],
            "description": description,
            "recipe": recipe,
            "content_sha256": digest,
            "episodes": len(episodes),
            "steps": int(sum(len(e["actions"]) for e in episodes)),
            "outcomes": outcome_shares(episodes),
            "mirrors": [m.format(version=data["version"], archive=archive) for m in data.get("mirrors", [])],
            "size": size,
            "sha256": sha,
        }
    atomic_write_json(registry, {"format": REGISTRY_FORMAT, "datasets": entries})
    load_registry(registry)  # what was written reads back
    return entries, archives
