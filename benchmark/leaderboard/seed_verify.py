"""``leaderboard --verify`` for the training seeds (``seeds/<member>.json``): their counts are rows too.

The headline reports a learned member as the mean over its training seeds, so every seed's counts
are re-derived like a row's: each seed is re-run on its suites with its own weights and must give
the recorded counts exactly. Where a seed's weights come from:

- **stored** (``seeds/weights/<member>-seed<k>.npz`` + its model card, written by ``overtakezoo seeds``):
  a regular file, the card naming the member and the seed, the npz's sha256 the card's; it runs in
  the sandbox like any stored artifact (:func:`overtakezoo.benchmark.run.policy.boxed`);
- **the zoo's**: the shipped seed without stored weights is the zoo member itself (its weights'
  sha256 is checked when the file loads, :func:`.headline.load_seeds`).

A seed with neither is refused: nothing could re-run its counts. (The members trained up to
2026-11-30 kept only the shipped seed's weights; their other seeds were retrained and stored on
2026-12-06/07, see docs/zoo.md, so no seed's counts are taken on trust.)

Which (seed, suite) pairs re-run: all of them for a seeds file new or changed against the git base
(or whose stored weights changed), ``sample`` pairs of each other file drawn from ``seed``
(:data:`SAMPLE_PAIRS` when verify samples).
"""

from __future__ import annotations

import fnmatch
import hashlib
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError

WEIGHTS = Path("seeds") / "weights"  # under the leaderboard root
SAMPLE_PAIRS = 2  # (seed, suite) pairs re-run per unchanged seeds file when verify samples (a few s each)


def weights_rel(member: str, seed: int) -> str:
    """Where ``overtakezoo seeds`` stores a seed's weights, relative to the leaderboard root."""
    return (WEIGHTS / f"{member}-seed{seed}.npz").as_posix()


def source(member: str, entry: dict[str, Any], shipped_seed: Any) -> str:
    """How a seed re-runs: ``stored`` or ``zoo`` (the shipped seed, the zoo member)."""
    if "weights" in entry:
        return "stored"
    if entry.get("seed") == shipped_seed:
        return "zoo"
    raise UserError(
        f"seeds/{member}.json: seed {entry.get('seed')!r} has no stored weights (seeds/weights/), so "
        "nothing can re-run its counts: evaluate it with `overtakezoo seeds`, which stores every seed's weights"
    )


def sources(member: str, doc: dict[str, Any]) -> dict[int, str]:
    """Each seed's :func:`source`, once the file holds seeds 0..n-1 (n >= 3: a member is reported over
    several seeds, none dropped)."""
    seeds = [e.get("seed") for e in doc["seeds"]]
    if len(seeds) < 3 or seeds != list(range(len(seeds))):
        raise UserError(f"seeds/{member}.json: seeds {seeds}: a member reports its seeds 0..n-1, at least 3")
    return {e["seed"]: source(member, e, doc["shipped_seed"]) for e in doc["seeds"]}


def _stored_decider(root: Path, member: str, entry: dict[str, Any], config: Any) -> Any:
    """The seed's stored weights as a sandboxed decider, after checking the files against the entry."""
    from overtakezoo.benchmark.run.artifacts import read_policy_file
    from overtakezoo.benchmark.run.policy import boxed
    from overtakezoo.envs import safe_json

    who = f"seeds/{member}.json: seed {entry['seed']}"
    rel = weights_rel(member, entry["seed"])
    w = entry["weights"]
    if not isinstance(w, dict) or w.get("file") != rel:
        raise UserError(f"{who}: weights.file must be {rel}")
    path, card_path = root / rel, (root / rel).with_suffix(".json")
    for p in (path, card_path):
        if p.is_symlink() or not p.is_file():
            raise UserError(f"{who}: {p.relative_to(root).as_posix()} is not a regular file")
    data = path.read_bytes()
    for p, content, key in ((path, data, "npz_sha256"), (card_path, card_path.read_bytes(), "card_sha256")):
        if hashlib.sha256(content).hexdigest() != w.get(key):
            raise UserError(f"{who}: {p.relative_to(root).as_posix()} is not the file the entry recorded ({key})")
    card = safe_json.load_file(card_path, card_path.name)
    if card.get("name") != member or card.get("seed") != entry["seed"]:
        raise UserError(f"{who}: its model card is {card.get('name')!r} seed {card.get('seed')!r}, not {member} seed")
    art = read_policy_file(path, data, config)
    if art.kind != "mlp":
        raise UserError(f"{who}: {rel} is not numpy weights with their model card")
    return boxed(art, config, rel)


def rerun(root: Path, member: str, entry: dict[str, Any], how: str, suite: Any, **on: Any) -> dict[str, Any]:
    """The seed's counts on ``suite``, re-run from its weights (``on``: the runner's device keywords)."""
    from overtakezoo.benchmark.leaderboard.seeds import evaluate
    from overtakezoo.benchmark.run.policy import load_zoo

    if how == "zoo":
        decider = load_zoo(member, suite.config)
    else:
        decider = _stored_decider(root, member, entry, suite.config)
    try:
        return evaluate(suite, decider, **on)
    finally:
        close = getattr(getattr(decider, "inner", None), "close", None)
        if close is not None:
            close()


def seed_files(root: str | Path, only: str | None = None) -> list[Path]:
    """The seeds files (those ``only`` matches as ``seeds/<member>``)."""
    paths = sorted((Path(root) / "seeds").glob("*.json"))
    return [p for p in paths if only is None or fnmatch.fnmatchcase(f"seeds/{p.stem}", only)]


def verify_seeds(
    root: Path,
    sample: int | None,
    seed: int,
    only: str | None,
    changed: set[str],
    log: Callable[[str], None],
    **on: Any,
) -> None:
    """Re-run the seeds files (those ``only`` matches as ``seeds/<member>``): every (seed, suite) pair
    of a file in ``changed`` (or of any file with ``sample`` None), ``sample`` pairs of the others
    (``on``: the runner's ``device`` / ``backend`` keywords)."""
    from overtakezoo.benchmark.leaderboard.headline import load_seeds
    from overtakezoo.envs.suites import load_suite

    suites: dict[str, Any] = {}  # each suite loaded once for every file and seed
    for member, doc in load_seeds(root).items():
        rel = f"seeds/{member}.json"
        if only is not None and not fnmatch.fnmatchcase(rel.removesuffix(".json"), only):
            continue
        hows = sources(member, doc)
        stored = {weights_rel(member, s) for s, h in hows.items() if h == "stored"}
        full = (
            sample is None
            or rel in changed
            or any(r in changed or r.removesuffix(".npz") + ".json" in changed for r in stored)
        )
        pairs, stale = [], 0
        for e in doc["seeds"]:
            for name, recorded in sorted(e["suites"].items()):
                if name not in suites:
                    suites[name] = load_suite(name)
                suite = suites[name]
                if recorded.get("suite_sha256") != suite.hash:
                    stale += 1  # (the headline refuses a scoring suite at another hash)
                    continue
                pairs.append((e, name, suite, recorded))
        if not full and pairs:
            rng = np.random.default_rng([seed, zlib.crc32(rel.encode())])
            pairs = [pairs[i] for i in sorted(rng.choice(len(pairs), min(sample or 1, len(pairs)), replace=False))]
        for e, name, suite, recorded in pairs:
            got = rerun(root, member, e, hows[e["seed"]], suite, **on)
            diff = [k for k in sorted(got) if got[k] != recorded.get(k)]
            if diff:
                k = diff[0]
                raise UserError(
                    f"{rel}: seed {e['seed']} on {name}: {k} re-runs as {got[k]!r}, the file says {recorded.get(k)!r}"
                )
        log(
            f"verified {rel}: {len(pairs)} (seed, suite) pair(s) re-run"
            + (" (new or changed: every pair)" if full and sample is not None else "")
            + (f"; {stale} pair(s) at an older suite hash not re-run" if stale else "")
        )
