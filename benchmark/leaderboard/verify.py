"""``leaderboard --verify``: every number on the board re-run from what the row stores.

For each row (``submissions/<suite>/<name>.json``, see :mod:`.submission`):

1. **Labels are derived, never trusted.** A built-in row must carry its zoo member's current name,
   version, weights and ``privileged`` flag; an artifact row's whole ``decider`` block must equal the
   one derived from its stored artifact (:func:`.rows.artifact_decider`: ``privileged`` is
   always false, the kind comes from the artifact's content), its name may not be a built-in's,
   and only the two data formats are stored (``.npz`` + card, ``.onnx``). Provenance fields
   (``git_commit``, ``package.version``, ``timing``) are held to strict patterns by the results
   schema.
2. **The numbers are re-run.** The row's policy (the zoo member in this process; an artifact in
   the sandbox, :mod:`.sandbox`) runs the row's scenarios and every per-scenario value must equal
   the recorded one. Which scenarios: every scenario of a row that is new or changed against the
   git base (``changed``: the row file or an artifact it references differs), and ``sample`` of each
   other row, drawn from ``seed``: by default fresh randomness (printed, so a failure replays with
   ``--seed``), so nobody can compute the draw before pushing. With no git base to compare with (a
   fresh clone of the branch under test, as CI runs) every row counts as changed.
3. **Stale rows** (measured on another suite, config or simulator) show no numbers anywhere (the
   board lists them by name), so they are not re-run; a new or changed stale row is refused.
4. **Rows have the suite's shape.** A row that is not stale must hold what a run of the current
   suite file gives (:func:`.rows.suite_mismatch`): its whole ``suite`` block, ``range`` and
   ``num_avs``, and every per-scenario array a run records, each with one value per scenario (and
   AV), so no scenario beyond the suite is appended and no array dropped; any row that does not is
   refused. Its summary was recomputed from its arrays when it loaded (results.py).
5. **Policies are deterministic.** A stored ONNX graph may hold no random op, and an artifact row's
   policy must decide a fixed set of observations the same in batches of other sizes and orders and
   on a second call (:mod:`overtakezoo.benchmark.run.determinism`, a few dozen observations; ``submit``
   checks both too): else its full re-run could pass and every later sample fail.

6. **Policies meet draws nobody knew** (:mod:`.fresh`). A row's recorded fresh draw (its suite's
   distribution with another seed) is re-run like its public scenarios (in full or on ``sample`` of
   them), and a row verified in full also runs ``fresh.CHECK_COUNT`` scenarios of a draw made from
   ``seed``, which must agree with the recorded one: a policy fit to the public scenarios (and to the
   recorded draw) is caught here; one fit to the public scenarios alone is flagged on the pages.

7. **Cross-play matrices are rows too** (:func:`verify_crossplay`): a stored matrix must be of the
   current suite, config and simulator, its ``deciders`` block the zoo's own, and its pairs re-run
   (all of a new or changed matrix, ``sample`` of the others) must give its counts exactly.

8. **Training seeds are rows too** (:mod:`.seed_verify`): each seed of ``seeds/<member>.json`` re-runs
   with its own stored weights (the shipped one: the zoo member) and must give its counts exactly (all
   (seed, suite) pairs of a new or changed file, ``pair_sample`` of the others); a seed with no
   weights to re-run is refused.

A failure is one line naming the row (and the scenario and step where a policy misbehaved).
"""

from __future__ import annotations

import fnmatch
import hashlib
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard import fresh
from overtakezoo.benchmark.leaderboard.batching import Stacked, batches, torch_single_threaded
from overtakezoo.benchmark.leaderboard.changes import fresh_seed
from overtakezoo.benchmark.leaderboard.rows import (
    ARTIFACTS,
    STORED_KINDS,
    Row,
    artifact_decider,
    describe,
    load_submissions,
    reserved_name,
    stale_reasons,
    stored_files,
    suite_mismatch,
)
from overtakezoo.benchmark.leaderboard.seed_verify import SAMPLE_PAIRS, verify_seeds
from overtakezoo.benchmark.run.determinism import check_deterministic, check_onnx_ops, probe_observations
from overtakezoo.envs.model.outcomes import OUTCOME_NAMES
from overtakezoo.envs.suites import Suite, load_suite, suite_names


def sample_indices(count: int, sample: int | None, seed: int, rel: str) -> np.ndarray:
    """``sample`` scenario indices of a row (sorted; all of them when None), drawn from (seed, row)."""
    if sample is None or sample >= count:
        return np.arange(count)
    rng = np.random.default_rng([seed, zlib.crc32(rel.encode())])
    return np.sort(rng.choice(count, size=sample, replace=False))


# ------------------------------------------------------------------ derived labels
def row_policy(row: Row, root: Path, config: Any) -> Any:
    """The Decider that re-runs ``row`` (its built-in, or its artifact in the sandbox), once every
    label of the row equals what is derived from it; :class:`UserError` naming the row otherwise."""
    sub = row.results.meta.get("submission")
    if not sub:
        raise UserError(
            f"{row.rel}: submission: missing (filed before submissions named their policy): "
            "re-file it with `overtakezoo submit`"
        )
    policy, d = sub["policy"], row.results.decider
    if "builtin" in policy:
        from overtakezoo.benchmark.run.policy import load_zoo

        if policy["builtin"] != row.name:
            raise UserError(
                f"{row.rel}: submission.policy.builtin: {policy['builtin']!r} filed as the row "
                f"{row.name!r}: a built-in member's row carries its own name"
            )
        member = load_zoo(policy["builtin"], config, hint="")
        if (str(member.version), member.weights_sha256) != (policy["version"], policy["weights_sha256"]):
            raise UserError(
                f"{row.rel}: submission.policy: measured with {policy['builtin']} v{policy['version']} "
                f"(weights {str(policy['weights_sha256'])[:12]}), the zoo now has v{member.version} "
                f"(weights {str(member.weights_sha256)[:12]}): re-measure the row "
                "(scripts/reproduce-leaderboard.sh)"
            )
        _same(
            row,
            d,
            {
                "name": member.name,
                "version": str(member.version),
                "weights_sha256": member.weights_sha256,
                "privileged": bool(member.privileged),
            },
            f"the zoo member {member.name}",
        )
        return member
    reserved_name(row.name, f"{row.rel}: submission.name")
    art = stored_artifact(row, root, policy)
    _same(row, d, artifact_decider(row.name, art), f"its artifact {policy['artifact']}")
    from overtakezoo.benchmark.run.policy import boxed

    if art.kind == "onnx":
        check_onnx_ops(art.data, f"{row.rel}: {policy['artifact']}")  # no random op (run/determinism.py)

    return boxed(art, config, row.rel)


def stored_artifact(row: Row, root: Path, policy: dict[str, Any]) -> Any:
    """The row's stored artifact, its files' sha256 checked against the row."""
    from overtakezoo.benchmark.run.artifacts import Artifact

    kind = STORED_KINDS.get(Path(policy["artifact"]).suffix)
    if (
        kind is None
        or Path(policy["artifact"]).stem != policy["sha256"]
        or (kind == "mlp") != ("card_sha256" in policy)
    ):
        raise UserError(
            f"{row.rel}: submission.policy.artifact: {policy['artifact']} is not a stored format "
            "(<sha256>.npz with its model card, or <sha256>.onnx): re-submit it with `overtakezoo submit`"
        )
    data: dict[str, bytes] = {}
    for rel, recorded in stored_files(policy).items():  # the policy file, and an npz's model card
        path = root / "submissions" / rel
        try:
            content = path.read_bytes()
        except OSError as exc:
            raise UserError(
                f"{row.rel}: submission.policy.artifact: cannot read {rel}: {exc.strerror or exc}"
            ) from None
        sha = hashlib.sha256(content).hexdigest()
        if sha != recorded:
            raise UserError(
                f"{row.rel}: submission.policy.artifact: {rel} has sha256 {sha[:12]}..., "
                f"the row recorded {recorded[:12]}... (artifact swapped or corrupted)"
            )
        data[rel] = content
    card = None
    if kind == "mlp":
        from overtakezoo.envs.safe_json import loads

        name = Path(policy["artifact"]).with_suffix(".json").as_posix()
        try:
            card = loads(data[name], name)  # bounded: a pull request's card may nest 100k deep
        except ValueError:
            card = None
        if not isinstance(card, dict) or not isinstance(card.get("architecture"), dict):
            raise UserError(f"{row.rel}: submission.policy: its model card is not one `overtakezoo submit` stores")
    return Artifact(kind, data[policy["artifact"]], card)


def _same(row: Row, recorded: dict[str, Any], derived: dict[str, Any], source: str) -> None:
    for key in sorted(set(recorded) | set(derived)):
        if recorded.get(key) != derived.get(key):
            raise UserError(
                f"{row.rel}: decider.{key}: recorded {recorded.get(key)!r}, derived "
                f"{derived.get(key)!r} from {source} (labels are derived, never declared)"
            )


# ------------------------------------------------------------------ verification
def verify(
    root: str | Path = "leaderboards",
    sample: int | None = None,
    seed: int | None = None,
    only: str | None = None,
    chunk_size: int = 4096,
    jobs: int = 1,
    changed: set[str] | None = None,
    log: Callable[[str], None] = print,
    pair_sample: int | None = None,
    device: str | None = None,
    backend: str | None = None,
) -> int:
    """Re-run every current row (``only``: rows whose ``suite/name`` matches this glob) on every
    scenario of the rows in ``changed`` and on ``sample`` scenarios of the others (all when None),
    drawn from ``seed`` (default :func:`.changes.fresh_seed`, logged); then the cross-play matrices:
    every pair of those in ``changed``, ``pair_sample`` pairs of the others (all when None); raises
    a UserError at the first row that does not reproduce (suites in name order). ``jobs`` > 1
    verifies suites in that many worker processes. ``device`` / ``backend`` pick the core the rows and
    matrices re-run on (:func:`~overtakezoo.benchmark.run.runner.run_suite`; None: the numpy core).
    Returns the number of rows verified."""
    root = Path(root)
    if seed is None:
        seed = fresh_seed()
        log(
            f"verify seed {seed} (fresh: it draws the sample and verify's own fresh draws; replay them with "
            f"--seed {seed})"
        )
    base = root / "submissions"
    suites = sorted(p.name for p in base.iterdir() if p.is_dir() and p.name != ARTIFACTS) if base.is_dir() else []
    args = [(root, name, sample, seed, only, chunk_size, frozenset(changed or ()), device, backend) for name in suites]
    if jobs > 1 and len(suites) > 1:
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        tasks = [(a, part) for a in args for part in (True, False)]  # each suite's look-ahead rows apart
        order = sorted(range(len(tasks)), key=lambda i: _task_cost(root, tasks[i][0][1], tasks[i][1]), reverse=True)
        # spawn: a forked copy of a process that already ran torch's thread pool can hang.
        with ProcessPoolExecutor(min(jobs, len(tasks)), mp_context=multiprocessing.get_context("spawn")) as pool:
            futures = {i: pool.submit(_verify_suite_star, (*tasks[i][0], tasks[i][1])) for i in order}
            n = sum(_log_all(futures[i].result(), log) for i in range(len(tasks)))  # reported in name order
    else:
        n = sum(_log_all(verify_suite(*a), log) for a in args)
    verify_crossplay(root, pair_sample, seed, only, jobs, changed or set(), log, device, backend)
    seeds_sample = None if pair_sample is None else SAMPLE_PAIRS
    verify_seeds(root, seeds_sample, seed, only, changed or set(), log, device=device, backend=backend)
    return n


def matrices(root: Path, only: str | None = None) -> list[Path]:
    """The stored cross-play matrices (those ``only`` matches as ``crossplay/<suite>``)."""
    from overtakezoo.benchmark.leaderboard.crossplay import DATA

    return [
        p
        for p in sorted((root / DATA).glob("*.json"))
        if only is None or fnmatch.fnmatchcase(f"{DATA.as_posix()}/{p.stem}", only)
    ]


def verify_crossplay(
    root: Path,
    sample: int | None,
    seed: int,
    only: str | None,
    jobs: int,
    changed: set[str],
    log: Callable[[str], None],
    device: str | None = None,
    backend: str | None = None,
) -> None:
    """Re-run the stored cross-play matrices (``crossplay/<suite>.json``, those ``only`` matches as
    ``crossplay/<suite>``): every pair of a matrix in ``changed`` (or with ``sample`` None), else
    ``sample`` pairs drawn from ``seed`` (:func:`.crossplay.verify_matrix`)."""
    from overtakezoo.benchmark.leaderboard import crossplay

    for path in matrices(root, only):
        rel = path.relative_to(root).as_posix()
        full = sample is None or rel in changed
        log(
            crossplay.verify_matrix(root, path, None if full else sample, seed, jobs, device, backend)
            + (" (new or changed: every pair)" if full and sample is not None else "")
        )


def _verify_suite_star(args: tuple) -> list[str]:
    return verify_suite(*args)


LOOKAHEAD_COST = (2.0, 8.0)  # a look-ahead row costs ~2 policy rows, x ~8 per AV beyond the first (order only)


def _task_cost(root: Path, suite_name: str, privileged: bool) -> float:
    """A rough cost of verifying a suite's privileged rows or its others, so that the workers start the
    longest first: the look-ahead members simulate every plan ahead (2^AVs of them for the joint
    oracle), and one such row alone can outlast the rest of the board (``platoon/joint-oracle``: 26 min
    on a 2-core Xeon against 86 s for ``duel/joint-oracle`` and 17 s for ``table1/oracle``).
    Only the order of the work depends on it, never what is verified."""
    try:
        rows = [r for r in load_submissions(root, suite_name).get(suite_name, []) if r.privileged == privileged]
    except UserError:
        return 0.0  # (its worker reports it, in name order)
    # (per-scenario arrays hold one value per scenario and AV)
    return sum(
        r.results.per["outcome"].size
        * (LOOKAHEAD_COST[0] * LOOKAHEAD_COST[1] ** (r.results.num_avs - 1) if privileged else 1)
        for r in rows
    )


def _log_all(lines: list[str], log: Callable[[str], None]) -> int:
    for line in lines:
        log(line)
    return sum(line.startswith("verified submissions/") for line in lines)


@dataclass
class Plan:
    """What one row's policy re-runs in a batch, as consecutive pieces of one scenario batch: ``public``
    (the row's scenarios ``idx``), ``fresh`` (scenarios ``idx`` of its recorded fresh draw) and
    ``check`` (verify's own draw of the suite, only for rows verified in full)."""

    row: Row
    pieces: list[tuple[str, np.ndarray, Any]]  # (kind, indices, Scenarios)

    @property
    def size(self) -> int:
        return sum(idx.size for _, idx, _ in self.pieces)


class _Draws:
    """One suite's scenario batches, each drawn once per verify run: the public suite, rows' recorded
    fresh draws, verify's own draw."""

    def __init__(self, suite: Suite) -> None:
        self.suite, self._cache = suite, {}

    def get(self, seed: int, count: int) -> Any:
        if (seed, count) not in self._cache:
            self._cache[seed, count] = fresh.fresh_suite(self.suite, seed, count).scenarios()
        return self._cache[seed, count]


def verify_suite(
    root: Path,
    suite_name: str,
    sample: int | None,
    seed: int,
    only: str | None,
    chunk_size: int = 4096,
    changed: frozenset[str] = frozenset(),
    device: str | None = None,
    backend: str | None = None,
    privileged: bool | None = None,
) -> list[str]:
    """Verify the rows of one suite (see :func:`verify`, also for ``device`` / ``backend``; ``privileged``:
    only the rows that say they are privileged, or only the others; None: all); returns one report
    line per row."""
    suite = load_suite(suite_name) if suite_name in suite_names() else None
    lines: list[str] = []
    todo: list[tuple[Row, Plan, Any]] = []
    probe = None  # the observations every artifact row's policy is probed on (run/determinism.py)
    public = fresh.public_seeds()
    try:
        for row in load_submissions(root, suite_name, only).get(suite_name, []):
            if privileged is not None and row.privileged != privileged:
                continue  # (row_policy holds the flag to the member's: a row cannot skip both parts)
            reasons = stale_reasons(row.results, suite)
            if reasons:
                if row.rel in changed:
                    raise UserError(
                        f"{row.rel}: stale (measured on {describe(reasons)}): a new or changed row must "
                        "measure the current benchmark; re-run the evaluation"
                    )
                lines.append(f"stale {row.rel}: listed by name only, not re-run (measured on {describe(reasons)})")
                continue
            mismatch = suite_mismatch(row.results, suite)  # new or not: never an honest row (rows.py)
            if mismatch:
                field, why = mismatch[0]
                raise UserError(
                    f"{row.rel}: {field}: measured on {why}: not what a run of the current suite file "
                    "gives (results edited by hand?)"
                )
            policy = row_policy(row, root, suite.config)  # (labels first: they name what the row claims to be)
            todo.append((row, None, policy))
            if "artifact" in row.results.meta["submission"]["policy"]:  # deterministic, or refused (cheap)
                if probe is None:
                    probe = probe_observations(suite)
                check_deterministic(policy.inner.act, suite, row.rel, probe)
            bad = fresh.shape_error(row.results, suite, public)
            if bad:
                raise UserError(f"{row.rel}: {bad}")
            todo[-1] = (row, _plan(row, suite, sample, seed, row.rel in changed), policy)
        for batch in batches(todo, chunk_size):
            with torch_single_threaded():
                _verify_batch(suite, batch, chunk_size, seed, device, backend)
            lines += [
                _report(row, plan, suite) + (" (new or changed: every scenario)" if row.rel in changed else "")
                for row, plan, _ in batch
            ]
    finally:
        for _, _, dec in todo:
            if hasattr(getattr(dec, "inner", None), "close"):
                dec.inner.close()
    return lines


def _plan(row: Row, suite: Suite, sample: int | None, seed: int, full: bool) -> Plan:
    draws = _draw_cache(suite)
    rec = row.results.meta["submission"]["fresh"]
    n = None if full else sample
    pieces = [
        ("public", sample_indices(suite.count, n, seed, row.rel), draws.get(suite.seed, suite.count)),
        ("fresh", sample_indices(rec["count"], n, seed, row.rel + "#fresh"), draws.get(rec["seed"], rec["count"])),
    ]
    if full or sample is None:  # a row verified in full also meets a draw nobody knew before this run
        count = min(fresh.CHECK_COUNT, suite.count)
        pieces.append(("check", np.arange(count), draws.get(fresh.check_seed(seed, suite.name), count)))
    return Plan(row, [(kind, idx, scen.take(idx)) for kind, idx, scen in pieces])


_DRAWS: dict[str, _Draws] = {}


def _draw_cache(suite: Suite) -> _Draws:
    if suite.name not in _DRAWS or _DRAWS[suite.name].suite != suite:
        _DRAWS.clear()  # one suite at a time: a suite's draws are dropped once its rows are planned
        _DRAWS[suite.name] = _Draws(suite)
    return _DRAWS[suite.name]


def _report(row: Row, plan: Plan, suite: Suite) -> str:
    n = {kind: idx.size for kind, idx, _ in plan.pieces}
    rec = row.results.meta["submission"]["fresh"]
    return (
        f"verified {row.rel}: {n['public']} of {suite.count} scenarios reproduce exactly; fresh draw: "
        f"{n['fresh']} of {rec['count']} reproduce"
        + (f", verify's own draw of {n['check']} agrees" if "check" in n else "")
    )


def _verify_batch(
    suite: Suite, batch: list, chunk_size: int, seed: int, device: str | None = None, backend: str | None = None
) -> None:
    from overtakezoo.benchmark.run.runner import RunFailure, run_scenarios
    from overtakezoo.envs.scenarios import Scenarios

    e = batch[0][0].results.num_avs  # rows of one suite: the same number of AVs
    decider = batch[0][2] if len(batch) == 1 else Stacked([(d, plan.size) for _, plan, d in batch], e)
    pieces = [piece for _, plan, _ in batch for piece in plan.pieces]
    scenarios = Scenarios.concat([scen for _, _, scen in pieces])
    labels = np.concatenate([idx for _, idx, _ in pieces])
    # A stacked batch fits one chunk by construction (the runner resets deciders per chunk).
    try:
        got = run_scenarios(
            suite,
            decider,
            scenarios,
            labels,
            chunk_size if len(batch) == 1 else labels.size,
            device=device,
            backend=backend,
        )
    except RunFailure as exc:
        row = batch[exc.part or 0][0]
        raise UserError(f"{row.rel}: {exc}") from None
    lo = 0
    for row, plan, _ in batch:  # (multi-AV arrays are AV-major: each AV's block holds every row's scenarios)
        for kind, idx, _ in plan.pieces:
            part = {k: v.reshape(e, -1)[:, lo : lo + idx.size].reshape(-1) for k, v in got.items()}
            lo += idx.size
            if kind == "public":
                compare(row, idx, part)
            elif kind == "fresh":
                compare_fresh(row, idx, part["outcome"])
            else:
                compare_check(row, part["outcome"], fresh.check_seed(seed, suite.name))


def compare_fresh(row: Row, indices: np.ndarray, outcome: np.ndarray) -> None:
    """Raise naming the first scenario of the row's recorded fresh draw whose outcome the re-run does not give."""
    rec = row.results.meta["submission"]["fresh"]
    e = row.results.num_avs
    want = fresh.decode(rec["outcomes"]).reshape(e, -1)[:, indices].reshape(-1)
    bad = np.flatnonzero(want != outcome)
    if bad.size:
        i = int(np.tile(indices, e)[bad].min())
        j = int(bad[np.argmin(np.tile(indices, e)[bad])])
        raise UserError(
            f"{row.rel}: submission.fresh (seed {rec['seed']}): scenario {i}"
            + (f", AV {j // indices.size}" if e > 1 else "")
            + f": outcome recorded {OUTCOME_NAMES[want[j]]}, the re-run gives {OUTCOME_NAMES[outcome[j]]} "
            "(results edited by hand, or not produced by this policy)"
        )


def compare_check(row: Row, outcome: np.ndarray, check_seed: int) -> None:
    """Raise when verify's own draw disagrees with the row's recorded fresh draw (:mod:`.fresh`)."""
    rec = row.results.meta["submission"]["fresh"]
    why = fresh.disagreement(fresh.rates(outcome), fresh.rates(fresh.decode(rec["outcomes"])))
    if why is not None:
        raise UserError(
            f"{row.rel}: submission.fresh: verify's own draw of the suite (seed {check_seed}) against "
            f"the recorded fresh draw (seed {rec['seed']}): {why}: a recorded draw must be one the "
            "policy never saw, not a seed it was fit to"
        )


# Per-scenario minima of a time to collision count a vehicle only while it is in the ego's path
# (|lateral offset| < half width, envs/core.py _update_stats): a vehicle at that edge is counted in or
# out by the last bit of its offset, and those bits depend on the CPU's float kernels (NumPy's float64
# exp / log / power run AVX-512 kernels on an Intel Xeon, others on an AMD EPYC), so on another kind
# of CPU a row can re-run with every outcome and every other value equal and a few of these minima
# moved (measured: mixed-drivers-aggressive/double-dqn, recorded on a Xeon, re-run on an EPYC: 2 of
# 1000 roads, min_ttc 0.0112 -> 0.0162 s). Each may differ in at most EDGE_SHARE of the values compared
# (at least one); everything else must be equal.
EDGE_KEYS = ("min_ttc", "min_headon_ttc")
EDGE_SHARE = 0.01


def compare(row: Row, indices: np.ndarray, got: dict[str, np.ndarray]) -> None:
    """Raise naming the first scenario (then the first field) where a re-run differs from the row
    (the time-to-collision minima: where more than EDGE_SHARE of them differ). Multi-AV rows compare
    every AV's value (AV-major arrays, results.py)."""
    first: tuple[int, str, Any, Any, int] | None = None
    e = row.results.num_avs
    for key in row.results.per:  # the keys the row has (older rows have no safety arrays)
        want, have = row.results.per[key].reshape(e, -1)[:, indices].reshape(-1), got[key]
        indices_av = np.tile(indices, e)
        same = (want == have) | (np.isnan(want) & np.isnan(have)) if want.dtype.kind == "f" else want == have
        bad = np.flatnonzero(~same)
        if key in EDGE_KEYS and bad.size <= max(1, math.ceil(EDGE_SHARE * want.size)):
            continue
        if bad.size:
            bad = bad[np.argsort(indices_av[bad], kind="stable")]  # the first scenario, then the lowest AV
        if bad.size and (first is None or indices_av[bad[0]] < first[0]):
            first = (
                int(indices_av[bad[0]]),
                key,
                want[bad[0]].item(),
                have[bad[0]].item(),
                int(bad[0]) // indices.size,
            )
    if first is not None:
        i, key, want, have, av = first
        where = f"scenario {i}" + (f", AV {av}" if e > 1 else "")
        raise UserError(
            f"{row.rel}: {where}: {key}: recorded {_show(want)}, the re-run gives {_show(have)} "
            "(results edited by hand, or not produced by this policy)"
        )


def _show(v: Any) -> str:
    return "null" if isinstance(v, float) and np.isnan(v) else repr(v)
