"""Leaderboard rows as stored: reading them, and what every row's labels must be.

Layout under ``<root>/submissions/``:

- ``<suite>/<name>.json``: one row, a results file with a ``submission`` block naming the row and
  its policy: a built-in zoo member (``{"builtin", "version", "weights_sha256"}``) or a stored
  artifact (``{"artifact": "artifacts/<sha256>.npz|.onnx", "sha256"}``, plus ``"card_sha256"`` for an
  npz, whose model card is stored beside it as ``artifacts/<sha256>.json``, and ``"source"``: the
  kind and sha256 of the file the submitter brought);
- ``artifacts/``: stored policies, once by content, shared by every suite they run on.

A row is *stale* when its suite file, environment config or simulator version is not the current
one (:func:`stale_reasons`): the board lists it by name only. A row that names the current suite
file must have its shape (:func:`suite_mismatch`: the suite block, range, and every array a run
records, one value per scenario): ``submit`` and ``leaderboard --verify`` refuse one that does not,
and the board lists it by name only, as a stale row (:func:`board_reasons`).
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.results.results import Results, config_sha256
from overtakezoo.benchmark.results.schema import recorded_keys
from overtakezoo.benchmark.run.artifacts import Artifact, policy_kind
from overtakezoo.envs import SIM_VERSION
from overtakezoo.envs.suites import Suite

ARTIFACTS = "artifacts"
STORED_KINDS = {".npz": "mlp", ".onnx": "onnx"}  # what a stored artifact may be: data, never code


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


def builtin_names() -> list[str]:
    from overtakezoo import zoo

    return zoo.known_names()


def reserved_name(name: str, where: str) -> None:
    """Refuse a row name that is a built-in member's (in any case): those rows re-run the zoo itself."""
    reserved = {b.lower(): b for b in builtin_names()}
    if name.lower() in reserved:
        raise UserError(
            f"{where} {name!r}: reserved for the built-in zoo member {reserved[name.lower()]!r}; "
            "submit your policy under its own name (--name my-policy)"
        )


def artifact_decider(name: str, art: Artifact) -> dict[str, Any]:
    """The ``decider`` block of a row re-run from ``art``: every field derived from the artifact."""
    kind = policy_kind(art.card) if art.kind == "mlp" else "onnx"
    return {
        "name": name,
        "version": "1",
        "weights_sha256": art.sha256,
        "privileged": False,
        "policy": {"kind": kind, "file": f"{art.sha256}{art.ext}", "sha256": art.sha256},
    }


def stored_files(policy: dict[str, Any]) -> dict[str, str]:
    """The files under ``submissions/`` a row's policy block stores, with their recorded sha256."""
    if "artifact" not in policy:
        return {}
    out = {policy["artifact"]: policy["sha256"]}
    if "card_sha256" in policy:
        out[Path(policy["artifact"]).with_suffix(".json").as_posix()] = policy["card_sha256"]
    return out


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
        out.append(
            (
                "suite.hash",
                f"suite {s['name']} v{s['version']} ({s['hash'][:12]}; now v{suite.version}, {suite.hash[:12]})",
            )
        )
    current = config_sha256(suite.config)
    if results.meta["config_sha256"] != current:
        out.append(("config_sha256", f"environment config {results.meta['config_sha256'][:12]} (now {current[:12]})"))
    sim = results.meta.get("sim_version")
    if sim != SIM_VERSION:
        out.append(
            ("sim_version", f"simulator {'of unknown version' if sim is None else f'v{sim}'} (now v{SIM_VERSION})")
        )
    return out


def suite_mismatch(results: Results, suite: Suite) -> list[tuple[str, str]]:
    """(field, what the row holds) for each way a row that is not stale (it names the current suite
    file) differs from what a run of that file gives: its whole ``suite`` block, ``range``,
    ``num_avs``, and every per-scenario array a run records
    (:func:`~overtakezoo.benchmark.results.schema.recorded_keys`: none missing, none extra), each of
    ``count`` x AVs values. A row's own fields agree with each other when it loads; this checks them
    against the suite, so no scenario can be appended, and no array dropped, by hand."""
    out: list[tuple[str, str]] = []
    want = {"name": suite.name, "version": suite.version, "hash": suite.hash, "count": suite.count}
    have = results.suite
    for key in sorted(set(have) | set(want), key=lambda k: (k not in want, k)):
        if have.get(key) != want.get(key):
            out.append(
                (f"suite.{key}", f"a suite block with {key} {have.get(key)!r} (the suite file gives {want.get(key)!r})")
            )
    if list(results.meta["range"]) != [0, suite.count]:
        out.append(("range", f"scenarios {results.meta['range']} (the suite file gives [0, {suite.count}])"))
    e = suite.num_avs
    if results.num_avs != e:
        out.append(("num_avs", f"{results.num_avs} automated vehicle(s) per scenario (the suite file gives {e})"))
    n = suite.count * e
    wanted = recorded_keys(e)
    for key in wanted:
        a = results.per.get(key)
        if a is None:
            out.append((f"scenarios.{key}", f"a run without scenarios.{key}, which every run records"))
        elif np.shape(a) != (n,):
            out.append(
                (
                    f"scenarios.{key}",
                    f"{np.size(a)} values of {key} (the suite file gives {n}: {suite.count} scenarios x {e} AV)",
                )
            )
    for key in sorted(set(results.per) - set(wanted)):
        out.append((f"scenarios.{key}", f"an array {key} that no run of this suite records"))
    return out


def board_reasons(results: Results, suite: Suite | None) -> list[tuple[str, str]]:
    """Why a row shows no numbers on the board: it is stale (:func:`stale_reasons`), or it names the
    current suite file without its shape (:func:`suite_mismatch`; ``submit`` and ``--verify`` refuse those)."""
    return stale_reasons(results, suite) or suite_mismatch(results, suite)


def describe(reasons: list[tuple[str, str]]) -> str:
    return "; ".join(why for _, why in reasons)
