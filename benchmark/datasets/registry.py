"""The registry of published datasets: the shipped ``registry/datasets.json`` (or
``$OVERTAKEZOO_REGISTRY``), validated."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from overtakezoo.benchmark.errors import UserError
from overtakezoo.envs import safe_json

REGISTRY_FILE = Path(__file__).with_name("registry") / "datasets.json"


# ---------------------------------------------------------------------------- registry + download
def registry_path() -> Path:
    return Path(os.environ.get("OVERTAKEZOO_REGISTRY") or REGISTRY_FILE)


def load_registry(path: Path | None = None) -> dict[str, dict[str, Any]]:
    """Registry entries: name -> {mirrors (list of URLs; a legacy single ``url`` counts as one), size
    and sha256 of the archive (absent when none is packed), recipe, content_sha256, ...}."""
    path = registry_path() if path is None else path
    try:
        data = safe_json.load_file(path, f"dataset registry {path}")
    except OSError as exc:
        raise UserError(f"cannot read dataset registry {path}: {exc.strerror or exc}") from None
    except safe_json.JSONInputError as exc:
        raise UserError(str(exc)) from None
    entries = data.get("datasets", {}) if isinstance(data, dict) else None
    if not isinstance(entries, dict):
        raise UserError(f'dataset registry {path}: expected {{"datasets": {{name: {{mirrors, size, sha256}}}}}}')
    out = {}
    for name, e in entries.items():
        if not isinstance(e, dict):
            raise UserError(f"dataset registry {path}: entry {name!r} is not an object")
        e = dict(e)
        mirrors = e.pop("url", None)
        mirrors = [mirrors] if isinstance(mirrors, str) else e.get("mirrors", [])
        archive_ok = (e.get("size") is None and e.get("sha256") is None) or (
            isinstance(e.get("size"), int) and _is_sha(e.get("sha256"))
        )
        if not (
            isinstance(mirrors, list)
            and all(isinstance(u, str) for u in mirrors)
            and archive_ok
            and (mirrors == [] or e.get("sha256") is not None)
            and (e.get("content_sha256") is None or _is_sha(e["content_sha256"]))
            and isinstance(e.get("rebuild_sha256", []), list)
            and all(_is_sha(h) for h in e.get("rebuild_sha256", []))
            and isinstance(e.get("recipe", {}), dict)
            and _is_shares(e.get("outcomes", {}))
        ):
            raise UserError(
                f"dataset registry {path}: entry {name!r} needs mirrors (list of URLs) with the "
                "archive's size (int) and sha256 (64 hex), and optionally recipe (object) and "
                "content_sha256 (64 hex), rebuild_sha256 (a list of 64 hex), outcomes ({name: share in [0, 1]})"
            )
        e["mirrors"] = mirrors
        out[name] = e
    return out


def _is_shares(value: Any) -> bool:
    return isinstance(value, dict) and all(
        isinstance(k, str) and isinstance(v, (int, float)) and not isinstance(v, bool) and 0 <= v <= 1
        for k, v in value.items()
    )


def _is_sha(value: Any) -> bool:
    return isinstance(value, str) and len(value) == 64 and all(c in "0123456789abcdefABCDEF" for c in value)
