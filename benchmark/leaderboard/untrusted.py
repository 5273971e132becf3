"""Hostile leaderboard input: a pull request can put anything under ``leaderboards/``.

Two guards, used wherever the leaderboard reads, writes or renders what a submission brought:

- :func:`check_tree` refuses a symlink or a non-regular file (FIFO, device, socket) anywhere
  under the root before anything there is read or written: a link would make a write land
  outside the repository, a FIFO would hang the reader.
- :func:`md` (and :func:`md_code`, :func:`md_link`, :func:`plot_text`) turn a string from input
  into inert text for a Markdown page or a matplotlib label, so a name or version cannot add
  images, links, HTML or table cells to a generated page.
"""

from __future__ import annotations

import os
import re
import stat
import unicodedata
from pathlib import Path
from urllib.parse import quote

from overtakezoo.benchmark.errors import UserError

# Backslash-escaped wherever they occur: they open code spans, emphasis, strikethrough (GFM),
# math (GitHub's $...$), links/images ([ ]) or table cells (|). With [ and ] escaped, ( ) and !
# cannot form a link or an image, so they are left as they are (the pages' prose is full of them).
_ESCAPED = set("\\`*[]|~$")
_HTML = {"&": "&amp;", "<": "&lt;", ">": "&gt;"}  # entities: no tag, comment end (-->) or entity survives
_CODE_SAFE = re.compile(r"[A-Za-z0-9._+:/ -]*")  # shown in a code span as it is (backslashes do not work there)


def _printable(text: str) -> str:
    """Control, format (bidi overrides, zero-width) and line/paragraph separators become a space."""
    return "".join(" " if unicodedata.category(ch) in ("Cc", "Cf", "Cs", "Zl", "Zp") else ch for ch in text)


def md(value: object) -> str:
    """``value`` (str() of it) as literal text inside a Markdown table cell or sentence.

    Ordinary names, versions and numbers (letters, digits, ``.-+:/%,;()'``, spaces) come out
    unchanged. ``_`` is escaped unless it sits between two letters or digits, where CommonMark
    never reads it as emphasis (``abort_clearance``); ``#`` at the start (a heading).
    """
    text = _printable(str(value))
    out = []
    for i, ch in enumerate(text):
        if ch in _HTML:
            out.append(_HTML[ch])
        elif ch in _ESCAPED or (ch == "#" and i == 0):
            out.append("\\" + ch)
        elif ch == "_" and not (0 < i < len(text) - 1 and text[i - 1].isalnum() and text[i + 1].isalnum()):
            out.append("\\_")
        else:
            out.append(ch)
    return "".join(out)


def md_code(value: object) -> str:
    """``value`` in a code span when that shows it literally, else as escaped plain text."""
    text = str(value)
    return f"`{text}`" if _CODE_SAFE.fullmatch(text) else md(text)


def md_link(text: object, target: str) -> str:
    """A link to a file under the root: escaped text, percent-encoded target."""
    return f"[{md(text)}]({quote(_printable(target), safe='/+')})"


def md_image(alt: str, target: str) -> str:
    return f"![{md(alt)}]({quote(_printable(target), safe='/+')})"


def plot_text(value: object) -> str:
    """A string for a matplotlib label: ``$`` would start mathtext, a leading ``_`` hides a legend entry."""
    text = _printable(str(value)).replace("$", r"\$")
    return " " + text if text.startswith("_") else text


# ------------------------------------------------------------------ the tree
def check_tree(root: str | Path) -> None:
    """Refuse (one-line UserError naming the path) a root that is a symlink, or any symlink or
    non-regular file under it. Only lstat is used: nothing is opened, no link is followed."""
    root = Path(root)
    try:
        st = os.lstat(root)
    except (FileNotFoundError, NotADirectoryError):
        return  # nothing there yet (regeneration creates it, or says why it cannot)
    except OSError as exc:
        raise UserError(f"{root}: cannot read it: {exc.strerror or exc}") from None
    _refuse(root, st, top=True)
    if not stat.S_ISDIR(st.st_mode):
        return
    stack = [root]
    while stack:
        folder = stack.pop()
        try:
            entries = list(os.scandir(folder))
        except OSError as exc:
            raise UserError(f"{folder}: cannot read it: {exc.strerror or exc}") from None
        for entry in sorted(entries, key=lambda e: e.name):
            path = Path(entry.path)
            st = entry.stat(follow_symlinks=False)
            _refuse(path, st)
            if stat.S_ISDIR(st.st_mode):
                stack.append(path)


def _refuse(path: Path, st: os.stat_result, top: bool = False) -> None:
    if stat.S_ISLNK(st.st_mode):
        raise UserError(
            f"{path}: is a symbolic link; the leaderboard reads and writes only regular files "
            "inside its root (replace the link by the file)"
        )
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISDIR(st.st_mode)):
        raise UserError(
            f"{path}: is not a regular file or folder (a FIFO, device or socket); the leaderboard refuses it"
        )
    if top and not stat.S_ISDIR(st.st_mode):
        raise UserError(f"{path}: is not a folder")


def plain_name(name: object) -> bool:
    """A file name directly in the root: no folder part, no ``..``, not hidden."""
    return (
        isinstance(name, str)
        and name != ""
        and not name.startswith(".")
        and not any(c in name for c in "/\\\0")
        and _printable(name) == name
    )


def check_target(root: Path, rel: str) -> Path:
    """The path to write or remove for a generated file: a plain name in a root that is a real
    folder (or absent), and, if it exists, a regular file: never a link or a folder."""
    if not plain_name(rel):
        raise UserError(f"{root}/{rel}: not a plain file name in the leaderboard folder; refusing to write it")
    path = root / rel
    for p, top in ((root, True), (path, False)):
        try:
            st = os.lstat(p)
        except (FileNotFoundError, NotADirectoryError):
            break
        _refuse(p, st, top=top)
        if not top and stat.S_ISDIR(st.st_mode):
            raise UserError(f"{p}: is a folder; the leaderboard writes a file there")
    return path
