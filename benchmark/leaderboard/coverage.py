"""What the board's measured tables cover, against what the zoo holds.

The cross-play matrices (``crossplay/<suite>.json``) and the failure board (``failures/board.json``)
are measured over the zoo's members, which the registry declares (:mod:`overtakezoo.zoo.base`). A
member added to the registry and not yet measured there would leave them silently short, so
``leaderboard --check`` reports each such file with the command that measures it again."""

from __future__ import annotations

import json
from pathlib import Path

from overtakezoo.benchmark.failures.board import UPPER_BOUNDS, board_deciders
from overtakezoo.benchmark.leaderboard.crossplay import DATA, zoo_deciders

FAILURES = Path("failures") / "board.json"


def _names(path: Path, key: str) -> set[str] | None:
    """The decider names a measured file lists (None: not a readable file of that shape, which the
    loaders that own the file report)."""
    try:
        doc = json.loads(path.read_text("utf-8"))
        listed = doc[key]
        return {d["name"] for d in listed} if isinstance(listed, list) else set(listed)
    except (OSError, ValueError, KeyError, TypeError):
        return None


def _line(rel: str, missing: set[str], extra: set[str], command: str) -> str:
    parts = [f"no entry for {', '.join(sorted(missing))}"] if missing else []
    parts += [f"{', '.join(sorted(extra))} no longer in the zoo"] if extra else []
    return f"{rel}: {'; '.join(parts)}: measure it again with `{command}`"


def uncovered(root: str | Path) -> list[str]:
    """One line per measured file whose deciders are not the zoo's: what is missing or gone, and the
    command that measures the file again (empty when every file covers the zoo)."""
    root = Path(root)
    out = []
    zoo = set(zoo_deciders(None))
    for path in sorted((root / DATA).glob("*.json")):
        names = _names(path, "deciders")
        if names is not None and names != zoo:
            command = f"overtakezoo crossplay --suite {path.stem} --jobs 2"
            out.append(_line(f"{DATA.as_posix()}/{path.name}", zoo - names, names - zoo, command))
    board = root / FAILURES
    names = _names(board, "deciders") if board.is_file() else None
    rows = set(board_deciders()) | set(UPPER_BOUNDS)
    if names is not None and names != rows:
        out.append(_line(FAILURES.as_posix(), rows - names, names - rows, "overtakezoo failure-board --jobs 2"))
    return out
