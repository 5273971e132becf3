"""Leaderboard submissions: a results file filed with the policy that re-runs it, and its verification.

Layout under ``<root>/submissions/``:

- ``<suite>/<name>.json``: one row, a results file with a ``submission`` block naming the row and
  its policy: a built-in zoo member (``{"builtin", "version", "weights_sha256"}``) or a policy file
  (``{"artifact": "artifacts/<sha256>.<ext>", "sha256"}``, plus ``"card_sha256"`` for weights
  ``overtakezoo train`` wrote, whose model card is stored beside them);
- ``artifacts/<sha256>.<ext>``: policy files, stored once by content, shared by every suite they run
  on; ``artifacts/<sha256>.json`` beside ``artifacts/<sha256>.pt``: the weights' model card, found
  by :func:`~.policy.load_policy` as beside any trained weights.

``verify`` re-runs each row's policy on (a seeded sample of) its scenarios and requires every
per-scenario value to equal the recorded one, so a results file edited by hand, or one whose
policy does not reproduce it, is refused naming the first mismatching scenario.
"""

from __future__ import annotations

import contextlib
import fnmatch
import hashlib
import json
import re
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from overtakezoo.envs import SIM_VERSION

from .errors import UserError
from .io import atomic_write_bytes
from .results import Results, config_sha256, per_scenario_keys
from .suites import Suite, load_suite, suite_names

ARTIFACTS = "artifacts"
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,63}$")  # the schema's decider-name pattern
_SHA_NAME = re.compile(r"^[0-9a-f]{64}(\.[A-Za-z0-9_-]{1,16})?$")


@dataclass
class Row:
    rel: str  # path relative to the leaderboard root, e.g. submissions/table1/dqn.json
    results: Results

    @property
    def name(self) -> str:
        sub = self.results.meta.get("submission")
        return sub["name"] if sub else self.results.decider["name"]

    @property
    def privileged(self) -> bool:
        return bool(self.results.decider["privileged"])


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def builtin_names() -> list[str]:
    from overtakezoo import zoo

    return zoo.known_names()


# ------------------------------------------------------------------ filing
def submit(results: Results, root: str | Path = "leaderboards", *, name: str | None = None,
           policy: str | Path | None = None, replace: bool = False, source: str = "results") -> Path:
    """File ``results`` as the row ``name`` with the policy that re-runs it; returns the row's path.

    Without ``policy`` the results must come from a built-in zoo member (its current version and
    weights), filed under the member's name. With ``policy`` (a file) the row takes its own name:
    built-in names are reserved. An existing row is replaced only with ``replace``."""
    root = Path(root)
    suite = _current_suite(results, source)
    decider = results.decider
    name = decider["name"] if name is None else name
    if not NAME_RE.match(name):
        raise UserError(f"--name {name!r}: expected letters, digits, '.', '_', '+' or '-' (at most 64)")
    builtins = builtin_names()
    reserved = {b.lower(): b for b in builtins}
    if policy is None:
        if decider["name"] not in builtins:
            raise UserError(f"{source}: decider {decider['name']!r} is not a built-in zoo member: pass the policy "
                            "it was measured with (--policy FILE) so the row can be verified")
        if name != decider["name"]:
            raise UserError(f"--name {name!r}: a built-in zoo member is filed under its own name "
                            f"({decider['name']!r}); a policy of your own needs --policy FILE")
        block = _builtin_block(results, suite, source)
    else:
        if name.lower() in reserved:
            raise UserError(f"--name {name!r}: reserved for the built-in zoo member {reserved[name.lower()]!r}; "
                            "submit your policy under its own name (--name my-policy)")
        if decider["privileged"]:
            raise UserError(f"{source}: decider.privileged: only built-in zoo members may read the simulator state")
        _check_policy_file(Path(policy))
    path = root / "submissions" / suite.name / f"{name}.json"
    clash = [p.name for p in path.parent.glob("*.json") if p.stem.lower() == name.lower() and p.stem != name]
    if clash:
        raise UserError(f"--name {name!r}: differs only in case from the row {clash[0]} (one file on some systems)")
    if path.exists() and not replace:
        raise UserError(f"{path}: a row named {name!r} is already on the {suite.name} leaderboard; "
                        "pass --replace to replace it")
    if policy is not None:
        block = _store_artifact(Path(policy), decider, root, path)
    filed = Results({**results.meta, "submission": {"name": name, "policy": block}}, results.per,
                    results.summary, results.timing)
    filed.save(path)
    prune_artifacts(root)
    return path


def _current_suite(results: Results, source: str) -> Suite:
    suite = results.suite
    if not results.complete:
        raise UserError(f"{source}: range: covers scenarios {results.meta['range']} of {suite['count']}; "
                        "submit every shard of the run together")
    if suite["name"] not in suite_names():
        raise UserError(f"{source}: suite.name: {suite['name']!r} is not a built-in suite "
                        f"(leaderboards exist for: {', '.join(suite_names())})")
    current = load_suite(suite["name"])
    reasons = stale_reasons(results, current)
    if reasons:
        field, why = reasons[0]
        raise UserError(f"{source}: {field}: measured on {why}: re-run the evaluation")
    return current


def _builtin_block(results: Results, suite: Suite, source: str) -> dict[str, Any]:
    from .cmdutil import load_decider

    d, member = results.decider, load_decider(results.decider["name"], suite.config)
    now = (str(member.version), member.weights_sha256, bool(member.privileged))
    if (d["version"], d["weights_sha256"], d["privileged"]) != now:
        raise UserError(f"{source}: decider: measured with {d['name']} v{d['version']} (weights "
                        f"{str(d['weights_sha256'])[:12]}), the zoo has v{now[0]} (weights {str(now[1])[:12]}): "
                        "re-run the evaluation, or submit your own policy with --policy FILE --name NAME")
    return {"builtin": d["name"], "version": now[0], "weights_sha256": now[1]}


def _check_policy_file(policy: Path) -> None:
    if not policy.is_file():
        raise UserError(f"--policy {policy}: not a file (a row needs its policy file, e.g. an SB3 .zip, "
                        "a TorchScript .pt or an .onnx file, so that it can be re-run)")


def _store_artifact(policy: Path, decider: dict[str, Any], root: Path, row: Path) -> dict[str, Any]:
    from .policy import model_card

    data = _read_policy(policy)
    sha = hashlib.sha256(data).hexdigest()
    if decider["weights_sha256"] not in (None, sha):
        raise UserError(f"--policy {policy}: sha256 {sha[:12]}..., but the results were measured with weights "
                        f"{decider['weights_sha256'][:12]}...: submit the file that was evaluated")
    card = model_card(policy)  # weights from `overtakezoo train`: their model card is needed to load them
    ext = policy.suffix.lower()
    if not _SHA_NAME.match(sha + ext):
        ext = ""
    block = {"artifact": f"{ARTIFACTS}/{sha}{ext}", "sha256": sha}
    todo = [(block["artifact"], data)]
    if card is not None:
        card_data = _read_policy(card)
        block["card_sha256"] = hashlib.sha256(card_data).hexdigest()
        card_rel = f"{ARTIFACTS}/{sha}.json"
        stored = root / "submissions" / card_rel
        refs = _references(root, row)
        if stored.is_file() and file_sha256(stored) != block["card_sha256"] and (refs is None or card_rel in refs):
            raise UserError(f"--policy {policy}: another model card for these weights is already stored "
                            f"({card_rel}, used by another row): submit the weights with that card")
        todo.append((card_rel, card_data))
    for rel, content in todo:
        target = root / "submissions" / rel
        if not target.is_file() or file_sha256(target) != hashlib.sha256(content).hexdigest():
            atomic_write_bytes(target, content)
    return block


def _read_policy(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise UserError(f"--policy {path}: cannot read it: {exc.strerror or exc}") from None


def stored_files(policy: dict[str, Any]) -> dict[str, str]:
    """The files under ``submissions/`` a row's policy block stores, with their recorded sha256."""
    if "artifact" not in policy:
        return {}
    out = {policy["artifact"]: policy["sha256"]}
    if "card_sha256" in policy:
        out[Path(policy["artifact"]).with_suffix(".json").as_posix()] = policy["card_sha256"]
    return out


def _references(root: Path, skip: Path | None = None) -> set[str] | None:
    """The stored files some row (other than ``skip``) references; None when a row is unreadable."""
    used: set[str] = set()
    for path in (root / "submissions").glob("*/*.json"):  # only the references: no need to validate every row
        if path.parent.name == ARTIFACTS or path == skip:
            continue
        try:
            used |= set(stored_files(json.loads(path.read_bytes()).get("submission", {})["policy"]))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None
    return used


def prune_artifacts(root: str | Path) -> list[Path]:
    """Remove stored policy files no row references any more (after a --replace)."""
    base = Path(root) / "submissions"
    used = _references(Path(root))
    if used is None:
        return []  # a row we cannot read might reference anything: remove nothing
    gone = [p for p in sorted((base / ARTIFACTS).glob("*")) if _SHA_NAME.match(p.name)
            and f"{ARTIFACTS}/{p.name}" not in used]
    for p in gone:
        p.unlink()
    return gone


# ------------------------------------------------------------------ reading
def load_submissions(root: Path, suite: str = "*", only: str | None = None) -> dict[str, list[Row]]:
    """Every row (of ``suite``; matching the glob ``only`` on ``suite/name``), by suite directory; a
    file filed under the wrong suite or name is a UserError."""
    out: dict[str, list[Row]] = {}
    base = root / "submissions"
    for path in sorted(base.glob(f"{suite}/*.json")) if base.is_dir() else []:
        if path.parent.name == ARTIFACTS or (only and not fnmatch.fnmatchcase(f"{path.parent.name}/{path.stem}", only)):
            continue
        rel = path.relative_to(root).as_posix()
        row = Row(rel, Results.load(path))
        if row.results.suite["name"] != path.parent.name:
            raise UserError(f"{rel}: suite.name: {row.results.suite['name']!r} filed under {path.parent.name!r}")
        if row.name != path.stem:
            raise UserError(f"{rel}: submission.name: {row.name!r} filed as {path.stem!r}")
        sub = row.results.meta.get("submission")
        for stored in stored_files(sub["policy"]) if sub else ():
            if not (base / stored).is_file():
                raise UserError(f"{rel}: submission.policy.artifact: {stored} is missing")
        out.setdefault(path.parent.name, []).append(row)
    return out


def stale_reasons(results: Results, suite: Suite | None) -> list[tuple[str, str]]:
    """(field, what it was measured on) for each way a row no longer measures the current benchmark."""
    s = results.suite
    if suite is None:
        return [("suite.name", f"suite {s['name']!r}, which is not built in (any more)")]
    out = []
    if s["hash"] != suite.hash:
        out.append(("suite.hash", f"suite {s['name']} v{s['version']} ({s['hash'][:12]}; now v{suite.version}, "
                                  f"{suite.hash[:12]})"))
    current = config_sha256(suite.config)
    if results.meta["config_sha256"] != current:
        out.append(("config_sha256", f"environment config {results.meta['config_sha256'][:12]} (now {current[:12]})"))
    sim = results.meta.get("sim_version")
    if sim != SIM_VERSION:
        out.append(("sim_version", f"simulator {'of unknown version' if sim is None else f'v{sim}'} "
                                   f"(now v{SIM_VERSION})"))
    return out


def describe(reasons: list[tuple[str, str]]) -> str:
    return "; ".join(why for _, why in reasons)


# ------------------------------------------------------------------ verification
def sample_indices(count: int, sample: int | None, seed: int, rel: str) -> np.ndarray:
    """``sample`` scenario indices of a row (sorted; all of them when None), drawn from (seed, row)."""
    if sample is None or sample >= count:
        return np.arange(count)
    rng = np.random.default_rng([seed, zlib.crc32(rel.encode())])
    return np.sort(rng.choice(count, size=sample, replace=False))


def row_policy(row: Row, root: Path, config: Any) -> Any:
    """The Decider that re-runs ``row``: its built-in (same version and weights) or its artifact."""
    sub = row.results.meta.get("submission")
    if not sub:
        raise UserError(f"{row.rel}: submission: missing (filed before submissions named their policy): "
                        "re-file it with `overtakezoo submit`")
    policy = sub["policy"]
    if "builtin" in policy:
        from .cmdutil import load_decider

        d = load_decider(policy["builtin"], config)
        if (str(d.version), d.weights_sha256) != (policy["version"], policy["weights_sha256"]):
            raise UserError(f"{row.rel}: submission.policy: measured with {policy['builtin']} v{policy['version']} "
                            f"(weights {str(policy['weights_sha256'])[:12]}), the zoo now has v{d.version} (weights "
                            f"{str(d.weights_sha256)[:12]}): re-measure the row (scripts/reproduce-leaderboard.sh)")
        return d
    for rel, recorded in stored_files(policy).items():  # the policy file, and a trained one's model card
        try:
            sha = file_sha256(root / "submissions" / rel)
        except OSError as exc:
            raise UserError(f"{row.rel}: submission.policy.artifact: cannot read {rel}: "
                            f"{exc.strerror or exc}") from None
        if sha != recorded:
            raise UserError(f"{row.rel}: submission.policy.artifact: {rel} has sha256 {sha[:12]}..., "
                            f"the row recorded {recorded[:12]}... (artifact swapped or corrupted)")
    from . import policy as policies

    return policies.load_policy(str(root / "submissions" / policy["artifact"]), config)


def verify(root: str | Path = "leaderboards", sample: int | None = None, seed: int = 0, only: str | None = None,
           chunk_size: int = 4096, jobs: int = 1, log: Callable[[str], None] = print) -> int:
    """Re-run every current row (``only``: rows whose ``suite/name`` matches this glob) on ``sample``
    scenarios each (all when None); raises a UserError at the first row that does not reproduce
    (suites in name order). Stale rows are skipped: their simulator is gone. ``jobs`` > 1 verifies
    suites in that many worker processes. Returns the number of rows verified."""
    root = Path(root)
    base = root / "submissions"
    suites = sorted(p.name for p in base.iterdir() if p.is_dir() and p.name != ARTIFACTS) if base.is_dir() else []
    args = [(root, name, sample, seed, only, chunk_size) for name in suites]
    if jobs > 1 and len(suites) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        # spawn: a forked copy of a process that already ran torch's thread pool can hang.
        with ProcessPoolExecutor(min(jobs, len(suites)), mp_context=multiprocessing.get_context("spawn")) as pool:
            reports = pool.map(_verify_suite_star, args)
            return sum(_log_all(lines, log) for lines in reports)
    return sum(_log_all(verify_suite(*a), log) for a in args)


def _verify_suite_star(args: tuple) -> list[str]:
    return verify_suite(*args)


def _log_all(lines: list[str], log: Callable[[str], None]) -> int:
    for line in lines:
        log(line)
    return sum(line.startswith("verified ") for line in lines)


def verify_suite(root: Path, suite_name: str, sample: int | None, seed: int, only: str | None,
                 chunk_size: int = 4096) -> list[str]:
    """Verify the rows of one suite (see :func:`verify`); returns one report line per row."""
    suite = load_suite(suite_name) if suite_name in suite_names() else None
    lines: list[str] = []
    todo: list[tuple[Row, np.ndarray, Any]] = []
    for row in load_submissions(root, suite_name, only).get(suite_name, []):
        reasons = stale_reasons(row.results, suite)
        if reasons:
            lines.append(f"skipped {row.rel}: stale (measured on {describe(reasons)})")
            continue
        todo.append((row, sample_indices(suite.count, sample, seed, row.rel), row_policy(row, root, suite.config)))
    for batch in _batches(todo, chunk_size):
        with _torch_single_threaded():
            _verify_batch(suite, batch, chunk_size)
        lines += [f"verified {row.rel}: {idx.size} of {suite.count} scenarios reproduce exactly"
                  for row, idx, _ in batch]
    return lines


def _batches(todo: list, chunk_size: int) -> list[list]:
    """Rows stepped together in one batch (fewer Python steps). Only deciders that hold their
    decisions equally long share a batch (the runner holds one batch as one); privileged deciders
    bind the whole core, so each runs alone."""
    out: list[list] = []
    size, key = 0, None
    for item in sorted(todo, key=lambda it: _batch_key(it[2])):  # stable
        n, privileged = item[1].size, getattr(item[2], "privileged", False)
        if not out or size + n > chunk_size or privileged or _batch_key(item[2]) != key:
            out.append([])
            size, key = 0, _batch_key(item[2])
        out[-1].append(item)
        size += n
    return out


def _batch_key(decider: Any) -> tuple[bool, int]:
    return bool(getattr(decider, "privileged", False)), int(getattr(decider, "action_repeat", 1))


def _verify_batch(suite: Suite, batch: list, chunk_size: int) -> None:
    from .runner import run_indices

    indices = np.concatenate([idx for _, idx, _ in batch])
    e = batch[0][0].results.num_avs  # rows of one suite: the same number of AVs
    decider = batch[0][2] if len(batch) == 1 else _Stacked([(d, idx.size) for _, idx, d in batch], e)
    # A stacked batch fits one chunk by construction (the runner resets deciders per chunk).
    got = run_indices(suite, decider, indices, chunk_size=chunk_size if len(batch) == 1 else indices.size)
    lo = 0
    for row, idx, _ in batch:  # (multi-AV arrays are AV-major: each AV's block holds every row's scenarios)
        compare(row, idx, {k: v.reshape(e, -1)[:, lo:lo + idx.size].reshape(-1) for k, v in got.items()})
        lo += idx.size


def compare(row: Row, indices: np.ndarray, got: dict[str, np.ndarray]) -> None:
    """Raise naming the first scenario (then the first field) where a re-run differs from the row.
    Multi-AV rows compare every AV's value (AV-major arrays, results.py)."""
    first: tuple[int, str, Any, Any, int] | None = None
    e = row.results.num_avs
    for key in per_scenario_keys(e):
        want, have = row.results.per[key].reshape(e, -1)[:, indices].reshape(-1), got[key]
        indices_av = np.tile(indices, e)
        same = (want == have) | (np.isnan(want) & np.isnan(have)) if want.dtype.kind == "f" else want == have
        bad = np.flatnonzero(~same)
        if bad.size:
            bad = bad[np.argsort(indices_av[bad], kind="stable")]  # the first scenario, then the lowest AV
        if bad.size and (first is None or indices_av[bad[0]] < first[0]):
            first = (int(indices_av[bad[0]]), key, want[bad[0]].item(), have[bad[0]].item(), int(bad[0]) // indices.size)
    if first is not None:
        i, key, want, have, av = first
        where = f"scenario {i}" + (f", AV {av}" if e > 1 else "")
        raise UserError(f"{row.rel}: {where}: {key}: recorded {_show(want)}, the re-run gives {_show(have)} "
                        "(results edited by hand, or not produced by this policy)")


def _show(v: Any) -> str:
    return "null" if isinstance(v, float) and np.isnan(v) else repr(v)


@contextlib.contextmanager
def _torch_single_threaded() -> Iterator[None]:
    """Sampled rows are small batches: torch's intra-op threads only add synchronisation there (a
    forward pass took 36 ms instead of 0.7 ms on a busy 2-core machine)."""
    torch = sys.modules.get("torch")  # imported by the learned policies only
    if torch is None:
        yield
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(threads)


class _Stacked:
    """Several deciders on one batch: decider i acts on the next ``n_i`` roads. Roads never interact,
    so each decider's roads evolve exactly as in a run of its own. On a multi-AV batch (``num_avs``
    AV-major blocks of rows) decider i gets its roads' rows of every block, AV-major as in its own run."""

    name, version, privileged, weights_sha256 = "verify", "1", False, None

    def __init__(self, parts: list[tuple[Any, int]], num_avs: int = 1) -> None:
        bounds = np.cumsum([0] + [n for _, n in parts])
        self.parts = [(d, slice(int(a), int(b))) for (d, _), a, b in zip(parts, bounds[:-1], bounds[1:])]
        self.action_repeat = int(getattr(parts[0][0], "action_repeat", 1))  # equal in a batch (_batches)
        self.num_avs = num_avs

    def _mine(self, a: np.ndarray, rows: slice) -> np.ndarray:
        e = self.num_avs
        return a.reshape(e, -1, *a.shape[1:])[:, rows].reshape(-1, *a.shape[1:])

    def reset(self, mask: np.ndarray | None = None) -> None:
        for d, rows in self.parts:
            d.reset(None if mask is None else self._mine(np.asarray(mask), rows))

    def act(self, obs: np.ndarray) -> np.ndarray:
        out = np.empty((self.num_avs, obs.shape[0] // self.num_avs), np.int64)
        for d, rows in self.parts:
            out[:, rows] = np.asarray(d.act(self._mine(obs, rows))).reshape(self.num_avs, -1)
        return out.reshape(-1)
