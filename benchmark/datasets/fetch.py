"""Downloading a published dataset: mirrors tried in order, resumed over HTTP Range, verified by SHA-256, unpacked
safely; when no mirror delivers (and ``build``, the default), a rebuild from the registry's recipe,
installed only if its content hash matches the registry's. ``say`` hears each step in one line."""

from __future__ import annotations

import http.client
import os
import tarfile
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Callable
from pathlib import Path, PurePosixPath

from overtakezoo.benchmark.datasets.registry import load_registry, registry_path
from overtakezoo.benchmark.datasets.store import (
    cache_dir,
    check_name,
    datasets_dir,
    install,
    minari_module,
    staging_root,
)
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.memory_cap import memory_cap
from overtakezoo.envs.io import check_writable_dir, file_sha256


def download(
    name: str,
    progress: bool = True,
    chunk: int = 1 << 16,
    timeout: float = 30.0,
    build: bool = True,
    say: Callable[[str], None] = lambda line: None,
) -> Path:
    """Fetch, verify and unpack dataset ``name`` from the registry's mirrors (in order); returns its
    local folder. With ``build``, a dataset no mirror delivers is rebuilt from its recipe instead.
    Without minari (a base install) a :class:`UserError` naming the extra comes first, before any
    download or rebuild is tried or announced."""
    minari_module()  # a downloaded or rebuilt dataset is Minari's format: useless (and unbuildable) without it
    registry = load_registry()
    if name not in registry:
        known = ", ".join(sorted(registry)) or "none"
        raise UserError(f"unknown dataset {name!r} (registry {registry_path()} lists: {known})")
    check_name(name)
    entry = registry[name]
    for url in entry["mirrors"]:
        if urllib.parse.urlsplit(url).scheme not in ("http", "https"):
            raise UserError(f"refusing {url!r}: only http(s) URLs are downloaded")
    root = datasets_dir()
    failures = []
    if entry["mirrors"]:
        downloads = check_writable_dir(cache_dir() / "downloads")
        final = downloads / (name.replace("/", "__") + ".tar.gz")
        part = final.with_name(final.name + ".part")
        size, sha = int(entry["size"]), entry["sha256"].lower()
        ok = final.exists() and file_sha256(final) == sha
        if ok:
            say(f"{final}: already downloaded (sha256 {sha[:16]}... matches)")
        for url in [] if ok else entry["mirrors"]:
            say(f"trying {url}")
            try:  # each mirror resumes the same .part: the sha256 proves the pieces belong together
                _fetch(url, part, size, progress, chunk, timeout)
            except _MirrorFailed as exc:
                failures.append(f"{url}: {exc}")
                say(f"  failed: {exc}")
                continue
            got = file_sha256(part)
            if got == sha:
                os.replace(part, final)
                say(f"  downloaded {size} bytes; sha256 {sha[:16]}... matches the registry's")
                ok = True
                break
            part.unlink(missing_ok=True)
            failures.append(
                f"{url}: checksum mismatch (expected sha256 {sha[:16]}..., got {got[:16]}...; deleted the partial file)"
            )
            say(f"  failed: {failures[-1].split(': ', 1)[1]}")
        if ok:
            _extract(final, root, name)
            return root / name
    if build and entry.get("recipe"):
        from overtakezoo.benchmark.datasets.recipes import build_entry

        recipe = entry["recipe"]
        say(
            f"no mirror delivered {name}; rebuilding it from the registry's recipe (suite {recipe['suite']}, "
            f"{recipe['count']} scenarios, {', '.join(p['decider'] for p in recipe['policies'])})"
        )
        digest = build_entry(name, entry, progress=progress)  # installed only if the content hash matches
        say(f"  rebuilt; its content hash matches the registry's ({digest[:16]}...)")
        return root / name
    where = "; ".join(failures) if failures else f"the registry lists no mirror for {name}"
    kept = part.stat().st_size if entry["mirrors"] and part.exists() else 0
    hint = f"run the command again to resume ({kept} of {size} bytes kept), or " if kept else ""
    how = (
        "drop --no-build to rebuild it locally from its recipe"
        if entry.get("recipe")
        else "the registry has no recipe to rebuild it from"
    )
    raise UserError(f"could not download {name} ({where}); {hint}{how}")


class _MirrorFailed(Exception):
    """One mirror did not deliver the archive (the reason is the message)."""


class _Oversized(Exception):
    """A mirror's body is longer than the registry's size: the download stops there (a mirror cannot fill the disk)."""


def _fetch(url: str, part: Path, size: int, progress: bool, chunk: int, timeout: float) -> None:
    """Download into ``part``, resuming from its current length with an HTTP Range request."""
    from tqdm import tqdm

    have = part.stat().st_size if part.exists() else 0
    if have > size:  # a stale partial from another version: start over
        part.unlink()
        have = 0
    if have == size:
        return
    req = urllib.request.Request(url, headers={"Range": f"bytes={have}-"} if have else {})
    try:
        with urllib.request.urlopen(req, timeout=timeout) as resp:
            if have and resp.status != 206:  # server ignored the range: take the whole body
                have = 0
            declared = resp.headers.get("Content-Length", "")
            if declared.strip().isdigit() and int(declared) > size - have:  # refused before a byte is read
                raise _Oversized(f"announced {have + int(declared)} bytes, the registry's archive has {size}")
            mode = "ab" if have else "wb"
            with (
                open(part, mode) as f,
                tqdm(
                    total=size,
                    initial=have,
                    unit="B",
                    unit_scale=True,
                    desc=part.name.removesuffix(".tar.gz.part"),
                    disable=not progress,
                ) as bar,
            ):
                got = have
                while True:  # at most the registry's size (+1 byte, to tell a longer body): never more
                    block = resp.read(min(chunk, size - got + 1))
                    if not block:
                        break
                    if got + len(block) > size:
                        raise _Oversized(f"sent more than the registry's {size} bytes")
                    f.write(block)
                    got += len(block)
                    bar.update(len(block))
    except _Oversized as exc:
        part.unlink(missing_ok=True)
        raise _MirrorFailed(f"{exc} (deleted the partial file)") from None
    except urllib.error.HTTPError as exc:
        raise _MirrorFailed(f"HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, http.client.HTTPException) as exc:
        got = part.stat().st_size if part.exists() else 0
        reason = getattr(exc, "reason", None) or exc
        raise _MirrorFailed(
            f"interrupted at {got} of {size} bytes ({reason})" if got else f"unreachable ({reason})"
        ) from None
    got = part.stat().st_size
    if got < size:
        raise _MirrorFailed(f"stopped at {got} of {size} bytes")


def _extract(archive: Path, root: Path, name: str) -> None:
    """Unpack ``archive`` into ``root`` after checking every member lands inside ``root/name``."""
    root = root.resolve()
    target = (root / name).resolve()
    try:
        with memory_cap(f"dataset archive {archive.name}"), tarfile.open(archive, "r:*") as tar:
            members = tar.getmembers()
            for m in members:
                p = PurePosixPath(m.name)
                if (
                    not p.parts
                    or p.is_absolute()
                    or ".." in p.parts
                    or m.name.startswith(("/", "\\"))
                    or ":" in p.parts[0]
                ):
                    raise UserError(f"refusing {archive.name}: member {m.name!r} would land outside {root}")
                if not (m.isfile() or m.isdir()):
                    raise UserError(f"refusing {archive.name}: member {m.name!r} is a link or special file")
                dest = (root / m.name).resolve()
                parent_dir = m.isdir() and dest in target.parents and root in (dest, *dest.parents)
                if dest != target and target not in dest.parents and not parent_dir:
                    raise UserError(f"refusing {archive.name}: member {m.name!r} is outside {name}/")
            with staging_root(target) as staging:  # unpacked beside, swapped in whole
                if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4: the stdlib's own safety net too
                    tar.extractall(staging, members=members, filter="data")
                else:
                    tar.extractall(staging, members=members)
                install(staging, name, target)
    except tarfile.TarError as exc:
        raise UserError(f"{archive}: not a readable .tar.gz dataset archive ({exc})") from None
