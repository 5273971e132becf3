"""``overtakezoo submit``: a results file filed as a leaderboard row, with the policy that re-runs it.

A built-in zoo member's row names the member (its version and weights must be the zoo's current
ones). A policy file is converted to a stored format (:mod:`.artifacts`: the npz MLP with its card,
or one self-contained ONNX file; never code), the converted artifact is re-run on every scenario in
the sandbox and must give the submitted numbers exactly, and it is stored once by content under
``submissions/artifacts/``; the row's ``decider`` block is derived from it
(:func:`.rows.artifact_decider`). Filing and pruning hold a lock on the submissions directory. The
layout is described in :mod:`.rows`; verification in :mod:`.verify`.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard import fresh
from overtakezoo.benchmark.leaderboard.rows import (
    ARTIFACTS,
    Row,
    artifact_decider,
    builtin_names,
    reserved_name,
    stale_reasons,
    stored_files,
    suite_mismatch,
)
from overtakezoo.benchmark.leaderboard.untrusted import check_tree
from overtakezoo.benchmark.leaderboard.verify import compare, torch_single_threaded
from overtakezoo.benchmark.results.results import Results, same_summary, summary_of
from overtakezoo.benchmark.run.artifacts import Artifact
from overtakezoo.benchmark.run.sandbox import PolicyFailure
from overtakezoo.envs import safe_json
from overtakezoo.envs.io import atomic_write_bytes, file_sha256
from overtakezoo.envs.suites import Suite, load_suite, suite_names

LOCK = ".lock"  # submissions_lock's file
NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]{0,63}$")  # the schema's decider-name pattern
_SHA_NAME = re.compile(r"^[0-9a-f]{64}(\.[A-Za-z0-9_-]{1,16})?$")


# ------------------------------------------------------------------ filing
def submit(
    results: Results,
    root: str | Path = "leaderboards",
    *,
    name: str | None = None,
    policy: str | Path | None = None,
    replace: bool = False,
    source: str = "results",
    report: Callable[[str], None] | None = None,
    device: str | None = None,
    backend: str | None = None,
) -> Path:
    """File ``results`` as the row ``name`` with the policy that re-runs it; returns the row's path.

    Without ``policy`` the results must come from a built-in zoo member (its current version and
    weights), filed under the member's name. With ``policy`` (a file) the row takes its own name
    (built-in names are reserved): the file is converted to a stored format (:mod:`.artifacts`),
    the converted artifact is re-run on every scenario in the sandbox and must reproduce the results
    exactly, and the row's ``decider`` block is derived from it. An existing row is replaced only with
    ``replace``. The submissions directory is locked while a row is filed. Once it is filed,
    ``report`` (``submit`` prints them on stderr) gets the lines saying the hold the row is run with
    and where it came from (:func:`~overtakezoo.benchmark.run.policy.hold_lines`). ``device`` /
    ``backend`` pick the core of the re-run and the fresh draw (the runner's keywords; None: the numpy
    core, whose per-scenario results the torch core in float64 gives too)."""
    root = Path(root)
    suite = _current_suite(results, source)
    said: list[str] = []  # the hold lines, reported once the row is filed
    decider = results.decider
    name = decider["name"] if name is None else name
    if not NAME_RE.match(name):
        raise UserError(f"--name {name!r}: expected letters, digits, '.', '_', '+' or '-' (at most 64)")
    builtins = builtin_names()
    if policy is None:
        if decider["name"] not in builtins:
            raise UserError(
                f"{source}: decider {decider['name']!r} is not a built-in zoo member: pass the policy "
                "it was measured with (--policy FILE) so the row can be verified"
            )
        if name != decider["name"]:
            raise UserError(
                f"--name {name!r}: a built-in zoo member is filed under its own name "
                f"({decider['name']!r}); a policy of your own needs --policy FILE"
            )
        block = _builtin_block(results, suite, source, said)
        from overtakezoo.benchmark.run.policy import load_zoo

        drawn = _fresh_block(suite, load_zoo(decider["name"], suite.config, hint=""), device, backend)
    else:
        reserved_name(name, "--name")
        if decider["name"].endswith("+shield"):
            raise UserError(
                f"{source}: decider {decider['name']!r} ran behind --shield, which the stored policy file "
                "does not carry: submit the results of the policy without --shield"
            )
        if decider["privileged"]:
            raise UserError(f"{source}: decider.privileged: only built-in zoo members may read the simulator state")
        art = _converted(Path(policy), decider, suite)
        _not_zoo_weights(art, Path(policy))  # a member's weights under a new name would rank beside the member
        meta = {**results.meta, "decider": artifact_decider(name, art)}
        drawn = _reproduces(
            Results(meta, results.per, results.summary, results.timing),
            suite,
            art,
            Path(policy),
            source,
            said,
            device,
            backend,
        )
    with submissions_lock(root):
        check_tree(root)  # no symlink or FIFO planted under the root is written through
        path = root / "submissions" / suite.name / f"{name}.json"
        clash = [p.name for p in path.parent.glob("*.json") if p.stem.lower() == name.lower() and p.stem != name]
        if clash:
            raise UserError(f"--name {name!r}: differs only in case from the row {clash[0]} (one file on some systems)")
        if path.exists() and not replace:
            raise UserError(
                f"{path}: a row named {name!r} is already on the {suite.name} leaderboard; pass --replace to replace it"
            )
        if policy is not None:
            block = _store_artifact(art, root, path, Path(policy))
            results = Results(meta, results.per, results.summary, results.timing)
        filed = Results(
            {**results.meta, "submission": {"name": name, "policy": block, "fresh": drawn}},
            results.per,
            results.summary,
            results.timing,
        )
        filed.save(path)
        said += _fresh_lines(filed)
        prune_artifacts(root, locked=True)
    for line in said if report is not None else ():
        report(line)
    return path


@contextlib.contextmanager
def submissions_lock(root: Path) -> Iterator[None]:
    """An exclusive lock on ``<root>/submissions`` (``flock``): two ``submit`` runs in one clone file
    one after the other, and pruning never removes an artifact another run is filing."""
    import fcntl

    base = root / "submissions"
    base.mkdir(parents=True, exist_ok=True)
    fd = os.open(base / LOCK, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _current_suite(results: Results, source: str) -> Suite:
    suite = results.suite
    if not results.complete:
        raise UserError(
            f"{source}: range: covers scenarios {results.meta['range']} of {suite['count']}; "
            "submit every shard of the run together"
        )
    if suite["name"] not in suite_names():
        raise UserError(
            f"{source}: suite.name: {suite['name']!r} is not a built-in suite "
            f"(leaderboards exist for: {', '.join(suite_names())})"
        )
    current = load_suite(suite["name"])
    reasons = stale_reasons(results, current)
    if reasons:
        field, why = reasons[0]
        raise UserError(f"{source}: {field}: measured on {why}: re-run the evaluation")
    mismatch = suite_mismatch(results, current)  # the suite's shape: no scenario appended, no array dropped
    if mismatch:
        field, why = mismatch[0]
        raise UserError(
            f"{source}: {field}: measured on {why}: not what a run of the current suite file "
            "gives (edited by hand?); submit the results `overtakezoo eval` wrote"
        )
    if not same_summary(results.summary, summary_of(results.per, results.meta["seed"], results.num_avs)):
        raise UserError(f"{source}: summary: does not match the per-scenario arrays (edited by hand?)")
    return current


def _builtin_block(results: Results, suite: Suite, source: str, said: list[str] | None = None) -> dict[str, Any]:
    from overtakezoo.benchmark.run.policy import hold_lines, load_zoo

    d, member = results.decider, load_zoo(results.decider["name"], suite.config, hint="")
    if said is not None:
        said += hold_lines(member, suite.config, suite.name)
    now = (str(member.version), member.weights_sha256, bool(member.privileged))
    if (d["version"], d["weights_sha256"], d["privileged"]) != now or "policy" in d:
        raise UserError(
            f"{source}: decider: measured with {d['name']} v{d['version']} (weights "
            f"{str(d['weights_sha256'])[:12]}), the zoo has v{now[0]} (weights {str(now[1])[:12]}): "
            "re-run the evaluation, or submit your own policy with --policy FILE --name NAME"
        )
    return {"builtin": d["name"], "version": now[0], "weights_sha256": now[1]}


def _converted(policy: Path, decider: dict[str, Any], suite: Suite) -> Artifact:
    """The stored form of the policy file the results were measured with (module docstring)."""
    from overtakezoo.benchmark.run.artifacts import read_policy_file

    if not policy.is_file():
        raise UserError(
            f"--policy {policy}: not a file (a row needs its policy file, e.g. an SB3 .zip, "
            "an .onnx file or `overtakezoo train` weights, so that it can be re-run)"
        )
    data = _read_policy(policy)
    measured = decider["weights_sha256"]
    if policy.suffix != ".onnx" and measured not in (None, hashlib.sha256(data).hexdigest()):
        _not_evaluated(policy, hashlib.sha256(data).hexdigest(), measured)
    art = read_policy_file(policy, data, suite.config)
    if measured not in (None, art.source_sha256):  # (ONNX: the sha256 of the model with its external data)
        _not_evaluated(policy, art.source_sha256, measured)
    if art.kind == "torchscript":  # loading it runs its code: exported to ONNX inside the sandbox
        from overtakezoo.benchmark.run.policy import boxed
        from overtakezoo.envs import observation_size

        dec = boxed(art, suite.config, str(policy), allow_code=True)
        try:
            onnx_bytes = dec.inner.export_onnx(observation_size(suite.config))
        except PolicyFailure as exc:
            raise UserError(f"--policy {policy}: {exc}; export it to ONNX yourself and submit the .onnx") from None
        finally:
            dec.inner.close()
        art = Artifact("onnx", onnx_bytes, None, "torchscript", art.source_sha256, policy_card=art.policy_card)
    return art


def _not_zoo_weights(art: Artifact, policy: Path) -> None:
    """:class:`UserError` when the stored form of ``policy`` carries a built-in zoo member's weights
    (:func:`zoo_weights_of`): that member already has its row, under its own name."""
    member = zoo_weights_of(art)
    if member is not None:
        raise UserError(
            f"--policy {policy}: its weights are the built-in zoo member {member!r}'s (zoo/pretrained/"
            f"{member}.npz): the zoo's own row ranks them; submit weights of your own (a member's "
            "results are filed under its name, without --policy)"
        )


def _weights_prints(arrays: list[np.ndarray]) -> set[str]:
    """sha256 of each weight matrix (float32 values and shape; a matrix and its transpose, as an ONNX
    MatMul stores it), so the same weights match whatever format or precision carries them."""
    out = set()
    for a in arrays:
        if a.ndim != 2 or a.size < 64 or a.dtype.kind not in "fiu":  # matrices only: biases may well coincide
            continue
        for m in (a, a.T):
            m = np.ascontiguousarray(m, dtype="<f4")
            out.add(hashlib.sha256(repr(m.shape).encode() + m.tobytes()).hexdigest())
    return out


def _zoo_prints() -> dict[str, set[str]]:
    """Each built-in member's weight-matrix prints (:func:`_weights_prints`) from ``zoo/pretrained/*.npz``."""
    if not _ZOO_PRINTS:
        from overtakezoo.zoo.members.learned import PRETRAINED

        for path in sorted(PRETRAINED.glob("*.npz")):
            with np.load(path, allow_pickle=False) as z:
                _ZOO_PRINTS[path.stem] = _weights_prints([z[k] for k in z.files])
    return _ZOO_PRINTS


_ZOO_PRINTS: dict[str, set[str]] = {}


def zoo_weights_of(art: Artifact) -> str | None:
    """The built-in zoo member whose every weight matrix ``art`` (an npz MLP or an ONNX model) holds, or None."""
    import io

    arrays: list[np.ndarray] = []
    try:
        if art.kind == "mlp":
            with np.load(io.BytesIO(art.data), allow_pickle=False) as z:
                arrays = [z[k] for k in z.files]
        elif art.kind == "onnx":
            import onnx
            from onnx import numpy_helper

            model = onnx.load_model_from_string(art.data)
            graphs = [model.graph]
            while graphs:
                g = graphs.pop()
                arrays += [numpy_helper.to_array(t) for t in g.initializer]
                for node in g.node:
                    for attr in node.attribute:
                        if attr.type == onnx.AttributeProto.TENSOR:
                            arrays.append(numpy_helper.to_array(attr.t))
                        elif attr.type == onnx.AttributeProto.GRAPH:
                            graphs.append(attr.g)
                        elif attr.type == onnx.AttributeProto.GRAPHS:
                            graphs.extend(attr.graphs)
    except Exception:  # unreadable here: the re-run in the sandbox refuses it
        return None
    have = _weights_prints(arrays)
    return next((name for name, prints in _zoo_prints().items() if prints and prints <= have), None)


def _not_evaluated(policy: Path, sha: str, measured: str) -> None:
    raise UserError(
        f"--policy {policy}: sha256 {sha[:12]}..., but the results were measured with weights "
        f"{measured[:12]}...: submit the file that was evaluated"
    )


def _reproduces(
    results: Results,
    suite: Suite,
    art: Artifact,
    policy: Path,
    source: str,
    said: list[str] | None = None,
    device: str | None = None,
    backend: str | None = None,
) -> dict[str, Any]:
    """Re-run the stored form on every scenario: a row whose artifact does not give its numbers is refused,
    and so is one that is not deterministic (:mod:`~overtakezoo.benchmark.run.determinism`: no random op,
    the same decisions by batch size, row order and call), whose row would fail later verifications."""
    from overtakezoo.benchmark.run.determinism import check_deterministic, check_onnx_ops
    from overtakezoo.benchmark.run.policy import boxed, hold_lines
    from overtakezoo.benchmark.run.runner import RunFailure, run_indices

    who = f"--policy {policy}" + (" (its ONNX export)" if art.source_kind == "torchscript" else "")
    if art.kind == "onnx":
        check_onnx_ops(art.data, who)
    dec = boxed(art, suite.config, str(policy))
    if said is not None:
        said += hold_lines(dec, suite.config, suite.name)
    try:
        check_deterministic(dec.inner.act, suite, who)
        with torch_single_threaded():
            got = run_indices(suite, dec, np.arange(suite.count), device=device, backend=backend)
        drawn = _fresh_block(suite, dec, device, backend)
    except RunFailure as exc:
        raise UserError(f"{source}: the stored form of --policy {policy} fails: {exc}") from None
    finally:
        dec.inner.close()
    try:
        compare(Row(source, results), np.arange(suite.count), got)
    except UserError as exc:
        raise UserError(
            f"{exc} [the stored {art.kind} form of --policy {policy}: evaluate it with `overtakezoo eval "
            "--policy` and submit those results]"
        ) from None
    return drawn


def _fresh_block(suite: Suite, decider: Any, device: str | None = None, backend: str | None = None) -> dict[str, Any]:
    """The row's fresh draw (:mod:`.fresh`): ``decider`` on its suite's distribution drawn with a seed
    from fresh randomness, so nobody knew its scenarios when the policy was made (on the core ``device``
    / ``backend`` pick)."""
    from overtakezoo.benchmark.leaderboard.changes import fresh_seed

    seed, public = fresh_seed(), fresh.public_seeds()
    while seed in public:  # (2^-63 odds; a built-in suite's seed is no fresh draw)
        seed = fresh_seed()
    with torch_single_threaded():
        outcome = fresh.run_fresh(suite, decider, seed, device=device, backend=backend)
        return fresh.block(seed, fresh.fresh_count(suite), outcome)


def _fresh_lines(row: Results) -> list[str]:
    """What ``submit`` says about the row's fresh draw, and its flag if it has one."""
    s, why = fresh.summary(row), fresh.flag(row)
    lines = [
        f"fresh draw: seed {s['seed']}, {s['count']} scenarios: success {100 * s['success_rate']:.1f} %, "
        f"crash {100 * s['crash_rate']:.1f} % (the public suite: success "
        f"{100 * row.summary['success_rate']['value']:.1f} %, crash {100 * row.summary['crash_rate']['value']:.1f} %)"
    ]
    if why:
        lines.append(
            f"flagged: {why}: the row is listed apart and not ranked (a policy that does as well on "
            "scenarios nobody knew in advance ranks)"
        )
    return lines


def _store_artifact(art: Artifact, root: Path, row: Path, policy: Path) -> dict[str, Any]:
    block = {
        "artifact": f"{ARTIFACTS}/{art.sha256}{art.ext}",
        "sha256": art.sha256,
        "source": {"kind": art.source_kind, "sha256": art.source_sha256},
    }
    todo = [(block["artifact"], art.data)]
    if art.card is not None:
        card_data = art.card_bytes
        block["card_sha256"] = hashlib.sha256(card_data).hexdigest()
        card_rel = f"{ARTIFACTS}/{art.sha256}.json"
        stored = root / "submissions" / card_rel
        refs = _references(root, row)
        if stored.is_file() and file_sha256(stored) != block["card_sha256"] and (refs is None or card_rel in refs):
            raise UserError(
                f"--policy {policy}: another model card for these weights is already stored "
                f"({card_rel}, used by another row): submit the weights with that card"
            )
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


def _references(root: Path, skip: Path | None = None) -> set[str] | None:
    """The stored files some row (other than ``skip``) references; None when a row is unreadable."""
    used: set[str] = set()
    for path in (root / "submissions").glob("*/*.json"):  # only the references: no need to validate every row
        if path.parent.name == ARTIFACTS or path == skip:
            continue
        try:
            used |= set(stored_files(safe_json.load_file(path).get("submission", {})["policy"]))
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None
    return used


def prune_artifacts(root: str | Path, locked: bool = False) -> list[Path]:
    """Remove stored policy files no row references any more (after a --replace), under the
    submissions lock (``locked``: the caller holds it)."""
    if not locked:
        with submissions_lock(Path(root)):
            return prune_artifacts(root, locked=True)
    base = Path(root) / "submissions"
    used = _references(Path(root))
    if used is None:
        return []  # a row we cannot read might reference anything: remove nothing
    gone = [
        p
        for p in sorted((base / ARTIFACTS).glob("*"))
        if _SHA_NAME.match(p.name) and f"{ARTIFACTS}/{p.name}" not in used
    ]
    for p in gone:
        p.unlink()
    return gone
