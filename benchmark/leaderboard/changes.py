"""Which leaderboard rows a pull request changed: the rows' files against a git base (the verifier re-runs
those in full), and the seed that samples the others from the tree's content."""

from __future__ import annotations

import hashlib
import os
import subprocess
from pathlib import Path

from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.leaderboard.rows import ARTIFACTS, load_submissions, stored_files
from overtakezoo.envs.io import file_sha256


# ------------------------------------------------------------------ what to verify
def tree_seed(root: str | Path) -> int:
    """A seed from the content of every file under ``<root>/submissions`` (paths and bytes)."""
    base = Path(root) / "submissions"
    h = hashlib.sha256()
    for path in sorted(p for p in base.rglob("*") if p.is_file() and p.name != ".lock") if base.is_dir() else []:
        h.update(path.relative_to(base).as_posix().encode() + b"\0" + file_sha256(path).encode())
    return int.from_bytes(h.digest()[:8], "little")


def default_base(root: str | Path) -> str | None:
    """The git revision a pull request is compared with: ``$OVERTAKEZOO_VERIFY_BASE``, else the
    merge base of HEAD with ``origin/$GITHUB_BASE_REF`` or ``origin/HEAD``; None outside git."""
    wanted = os.environ.get("OVERTAKEZOO_VERIFY_BASE")
    if wanted:
        return wanted
    ref = f"origin/{os.environ['GITHUB_BASE_REF']}" if os.environ.get("GITHUB_BASE_REF") else "origin/HEAD"
    for candidate in (ref, "HEAD"):
        out = _git(root, "merge-base", "HEAD", candidate)
        if out is not None:
            return out.strip()
    return None


def changed_rows(root: str | Path, base: str) -> set[str]:
    """Rows (paths relative to ``root``) new or changed in the working tree against ``base``, and
    rows that reference a stored artifact that is; :class:`UserError` when ``base`` is no revision."""
    root = Path(root)
    top = _git(root, "rev-parse", "--show-toplevel")
    if top is None or _git(root, "rev-parse", "--verify", "--quiet", f"{base}^{{commit}}") is None:
        raise UserError(f"--base {base}: not a git revision of the repository holding {root}")
    sub = (root / "submissions").resolve()
    listed = (_git(root, "diff", "--name-only", "--no-renames", base, "--", str(sub)) or "") + \
             (_git(root, "ls-files", "--others", "--exclude-standard", "--", str(sub)) or "")
    top_path = Path(top.strip())
    changed = set()
    for line in listed.splitlines():
        path = (top_path / line).resolve()
        if path.is_relative_to(sub):
            changed.add(path.relative_to(root.resolve()).as_posix())
    artifacts = {c.split("/", 2)[2] for c in changed if c.startswith(f"submissions/{ARTIFACTS}/")}
    if artifacts:
        for rows in load_submissions(root).values():
            for row in rows:
                sub_block = row.results.meta.get("submission") or {}
                if any(rel.split("/", 1)[1] in artifacts for rel in stored_files(sub_block.get("policy") or {})):
                    changed.add(row.rel)
    return changed


def _git(root: str | Path, *args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None
