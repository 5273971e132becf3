"""Which leaderboard rows a pull request changed: the rows' files against a git base (the verifier re-runs
those in full; with no base, every row), and the fresh seed that samples the others."""

from __future__ import annotations

import os
import secrets
import subprocess
from pathlib import Path

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.rows import ARTIFACTS, load_submissions, stored_files


# ------------------------------------------------------------------ what to verify
def fresh_seed() -> int:
    """The sample's seed when none is given: fresh randomness from the OS, so nobody can compute the
    draw before pushing and tune a forged row around it (the verifier prints it, so a failure can
    be replayed with ``--seed``)."""
    return secrets.randbits(63)


def default_base(root: str | Path) -> str | None:
    """The git revision a pull request is compared with, or None when there is nothing to compare
    with, and then every row counts as changed (verified in full).

    ``$OVERTAKEZOO_VERIFY_BASE`` when set; else the merge base of HEAD with the target branch:
    ``origin/$GITHUB_BASE_REF`` in a pull-request job (fetched when the clone lacks it), else
    ``origin/HEAD``. A merge base that *is* HEAD says nothing: that is a fresh clone of the branch
    being checked (how CI runs), where the target's history holds the pull request's own commits,
    so no row can be taken as already verified. Outside git, or with no such branch: None."""
    wanted = os.environ.get("OVERTAKEZOO_VERIFY_BASE")
    if wanted:
        return wanted
    target = os.environ.get("GITHUB_BASE_REF")
    ref = f"origin/{target}" if target else "origin/HEAD"
    if target and _git(root, "rev-parse", "--verify", "--quiet", ref) is None:
        _git(root, "fetch", "--quiet", "--no-tags", "origin", f"+refs/heads/{target}:refs/remotes/{ref}")
    base, head = _git(root, "merge-base", "HEAD", ref), _git(root, "rev-parse", "HEAD")
    if base is None or head is None or base.strip() == head.strip():
        return None
    return base.strip()


def is_row(rel: str) -> bool:
    """Whether ``rel`` (relative to ``submissions/``) names a row: ``<suite>/<name>.json`` outside
    ``artifacts/``, the files :func:`.rows.load_submissions` reads (one row each)."""
    parts = rel.split("/")
    return len(parts) == 2 and parts[0] != ARTIFACTS and parts[1].endswith(".json")


def changed_rows(root: str | Path, base: str) -> set[str]:
    """Rows (``submissions/<suite>/<name>.json``, relative to ``root``) of the working tree that are
    new or changed against ``base``: a row file that differs from ``base`` or is not in it (an
    untracked row is new, staged or not), and a row that references a stored artifact that is. A
    deleted row is on no board, so it is not counted. :class:`UserError` when ``base`` is no revision."""
    root = Path(root)
    sub = (root / "submissions").resolve()
    files = changed_files(root, base, "submissions")
    changed = {f"submissions/{rel}" for rel in files if is_row(rel) and (sub / rel).is_file()}
    artifacts = {rel.split("/", 1)[1] for rel in files if rel.startswith(f"{ARTIFACTS}/")}
    if artifacts:
        for rows in load_submissions(root).values():
            for row in rows:
                sub_block = row.results.meta.get("submission") or {}
                if any(rel.split("/", 1)[1] in artifacts for rel in stored_files(sub_block.get("policy") or {})):
                    changed.add(row.rel)
    return changed


def changed_files(root: str | Path, base: str, folder: str) -> set[str]:
    """Files under ``root/folder`` (relative to it) that differ from ``base`` or are untracked (new, staged
    or not; ignored ones too: the board reads them). :class:`UserError` when ``base`` is no revision."""
    root = Path(root)
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or _git(root, "rev-parse", "--verify", "--quiet", f"{base}^{{commit}}") is None:
        raise UserError(f"--base {base}: not a git revision of the repository holding {root}")
    sub = (root / folder).resolve()
    # Both lists name paths from the repository's top (ls-files would name them from `root` without
    # --full-name); no --exclude-standard: an ignored file is still read by the board, so it is new.
    listed = (_git(root, "diff", "-z", "--name-only", "--no-renames", base, "--", str(sub)) or "") + (
        _git(root, "ls-files", "-z", "--others", "--full-name", "--", str(sub)) or ""
    )
    top_path = Path(top.strip()).resolve()
    files = set()
    for line in listed.split("\0"):
        path = (top_path / line).resolve() if line else None
        if path is not None and path.is_relative_to(sub):
            files.add(path.relative_to(sub).as_posix())
    return files


def _git(root: str | Path, *args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None
