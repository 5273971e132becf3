"""Safe file writes: a target is either left as it was or replaced by a complete file.

Every file OvertakeZoo writes (results, leaderboards, plots, GIFs, datasets, checkpoints) goes through
here. Data goes to a temp file beside the target (``.NAME.tmp-XXXXXXXX.SUFFIX``) that is renamed over
the target only once it is complete. ``os.replace`` is atomic within one filesystem, so an exception,
Ctrl-C or SIGTERM (the CLI turns it into an exception) leaves the old file or none, never a partial
one, and two writers of one path each rename their own complete file: the last rename wins.

A target that exists and is not a regular file (a FIFO, ``/dev/null``, a terminal) is opened and
written in place: renaming over it would replace the device or pipe by a regular file. A symlink is
followed, so the file it points to is replaced and the link stays.

Stale temp files: every temp file or folder is locked (``flock``) by its writer for as long as it
exists, and the kernel drops a dead process's locks. Before a new temp is made beside a target, the
target's temps that nobody holds (what SIGKILL or a crash left) are deleted: :func:`sweep_stale`.

This module sits in ``envs``, the lowest layer, so the zoo's trainers and the benchmark share it;


One mechanism (a locked temp beside the target, then a rename) in the variants the project needs:
bytes, text, JSON, a streamed file, a directory.
"""

from __future__ import annotations

import contextlib
import glob
import hashlib
import json
import os
import secrets
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

try:
    import fcntl
except ImportError:  # Windows: temps are not locked, so none is ever swept
    fcntl = None  # type: ignore[assignment]

__all__ = [
    "WriteError",
    "file_sha256",
    "atomic_output",
    "atomic_path",
    "atomic_directory",
    "atomic_write_bytes",
    "atomic_write_text",
    "atomic_write_json",
    "check_writable",
    "check_writable_dir",
    "sweep_stale",
    "temp_directory",
]


class WriteError(OSError):
    """A target cannot be written (no permission, a directory, a missing or read-only place).

    ``str(exc)`` is the whole one-line message; ``exc.strerror`` the reason alone.
    """

    def __init__(self, path: str | os.PathLike, reason: str = "") -> None:
        # With no reason, ``path`` is the whole message (as when unpickled).
        super().__init__(f"cannot write {path}: {reason}" if reason else str(path))
        self.strerror = reason or str(path)


def _fail(path: Path, exc: OSError) -> WriteError:
    return WriteError(path, str(exc.strerror or exc))


def _resolve(path: str | os.PathLike) -> tuple[Path, os.stat_result | None]:
    """The file to write (symlinks followed) and its stat, or None when it does not exist yet."""
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        st = None
    except OSError as exc:  # a parent that is a file, a loop of links, no permission
        raise _fail(path, exc) from None
    except ValueError as exc:  # a NUL byte in the name
        raise WriteError(path, str(exc)) from None
    if st is not None and stat.S_ISDIR(st.st_mode):
        raise WriteError(path, "it is a directory")
    if path.is_symlink():
        path = Path(os.path.realpath(path))
    return path, st


def _in_place(st: os.stat_result | None) -> bool:
    return st is not None and not stat.S_ISREG(st.st_mode)


_HELD: set[str] = set()  # temps this process holds (where flock falls back to per-process locks, as on NFS)


def _claim(fd: int, path: Path) -> bool:
    """Lock a temp just made, for as long as ``fd`` (or a dup of it) is open. False: a sweeper got it
    first and deletes it, so the caller makes another."""
    if fcntl is not None:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        except OSError:  # a filesystem without locks: nothing is swept there either
            pass
        # A sweeper may have locked and deleted the file between our create and our lock, and
        # released it again: then the name no longer leads to our file, and we make another.
        try:
            same = os.path.samestat(os.stat(path, follow_symlinks=False), os.fstat(fd))
        except OSError:
            same = False
        if not same:
            os.close(fd)
            return False
    _HELD.add(str(path))
    return True


def _release(fd: int, path: Path) -> None:
    _HELD.discard(str(path))
    os.close(fd)


def sweep_stale(target: str | os.PathLike, kinds: tuple[str, ...] = ("tmp",)) -> None:
    """Delete ``target``'s temp files and folders (``.NAME.<kind>-*`` beside it) that no live process
    holds: the leftovers of a writer killed by SIGKILL or a crash."""
    target = Path(target)
    if fcntl is None:
        return
    for kind in kinds:
        for p in target.parent.glob(f".{glob.escape(target.name[:180])}.{kind}-*"):
            if str(p) in _HELD:
                continue
            try:  # no links followed; O_NONBLOCK: a FIFO of that name cannot block us
                fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_NOFOLLOW", 0))
            except OSError:
                continue
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # fails while its writer lives
                if stat.S_ISDIR(os.fstat(fd).st_mode):
                    shutil.rmtree(p, ignore_errors=True)
                else:
                    os.unlink(p)
            except OSError:
                pass
            finally:
                os.close(fd)


def _open_temp(target: Path) -> tuple[int, Path]:
    """A new, exclusively created and locked file beside ``target`` with the target's name and suffix
    in it; stale temps of ``target`` are swept first."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _fail(target, exc) from None
    sweep_stale(target)
    for _ in range(100):
        tmp = target.with_name(f".{target.name[:180]}.tmp-{secrets.token_hex(4)}{target.suffix[:20]}")
        try:  # mode 0o666 minus the umask, as for any new file (mkstemp would give 0600)
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666)
        except FileExistsError:
            continue
        except OSError as exc:
            raise _fail(target, exc) from None
        if _claim(fd, tmp):
            return fd, tmp
    raise WriteError(target, "no free temp file name beside it")


def _commit(tmp: Path, target: Path, st: os.stat_result | None) -> None:
    try:
        if st is not None:  # a replaced file keeps its permission bits
            os.chmod(tmp, stat.S_IMODE(st.st_mode))
        os.replace(tmp, target)
    except OSError as exc:
        raise _fail(target, exc) from None


def _sync(path: Path) -> None:
    """Flush a file written by a library to disk before it is renamed into place."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # some filesystems refuse fsync on a read-only descriptor; the rename is still atomic
    finally:
        os.close(fd)


def _discard(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        os.unlink(tmp)


@contextlib.contextmanager
def _replacing(target: Path, st: os.stat_result | None) -> Iterator[tuple[int, Path]]:
    """A new temp file beside ``target`` (descriptor, path): renamed over it when the block ends
    without an exception, deleted otherwise."""
    fd, tmp = _open_temp(target)
    lock = os.dup(fd)  # the caller closes ``fd``; the lock stays until the temp is renamed or deleted
    try:
        yield fd, tmp
        _commit(tmp, target, st)
    except BaseException:
        _discard(tmp)
        raise
    finally:
        _release(lock, tmp)


@contextlib.contextmanager
def atomic_output(
    path: str | os.PathLike, mode: str = "wb", encoding: str | None = None, newline: str | None = None
) -> Iterator[IO[Any]]:
    """Stream into ``path``: ``with atomic_output(p) as f: f.write(...)``.

    ``f`` is a temp file beside ``path``, renamed over it when the block ends without an exception
    and deleted otherwise. ``mode`` is ``"wb"`` or ``"w"`` (text, UTF-8 unless ``encoding``). A
    target that is not a regular file (FIFO, device) is streamed into directly.

    ``f.name`` is the path written: the temp file (what a killed writer leaves behind) or, in place,
    the target.

    A writer with its own open/close methods keeps the context in a ``contextlib.ExitStack``:
    ``f = stack.enter_context(atomic_output(path))`` on open; ``stack.close()`` on a clean close
    renames; ``stack.__exit__(type(exc), exc, exc.__traceback__)`` on failure deletes the temp file.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_output: mode must be 'w' or 'wb', got {mode!r}")
    if "b" not in mode and encoding is None:
        encoding = "utf-8"
    target, st = _resolve(path)
    if _in_place(st):
        try:
            f = open(target, mode, encoding=encoding, newline=newline)
        except OSError as exc:
            raise _fail(target, exc) from None
        with f:
            yield f
        return
    with _replacing(target, st) as (fd, tmp):
        # opener: the descriptor _open_temp created; f.name is the temp file's path.
        with open(tmp, mode, encoding=encoding, newline=newline, opener=lambda *_: fd) as f:
            yield f
            try:
                f.flush()
                os.fsync(f.fileno())  # the data is on disk before the name points at it
            except OSError as exc:  # a full disk shows here at the latest
                raise _fail(target, exc) from None


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """A temp file name for libraries that write by name (``torch.save``, ``savefig``, ``tarfile``).

    The yielded path ends with the target's suffix (libraries pick the format from it). It is renamed
    over ``path`` when the block ends without an exception, deleted otherwise. For a target that is
    not a regular file the temp file lives in the system temp folder and is copied into the target.
    """
    target, st = _resolve(path)
    if _in_place(st):
        if not os.access(target, os.W_OK):
            raise WriteError(target, "permission denied")
        fd, name = tempfile.mkstemp(suffix=target.suffix[:20])
        os.close(fd)
        tmp = Path(name)
        try:
            yield tmp
            with open(tmp, "rb") as src, atomic_output(target) as dst:
                shutil.copyfileobj(src, dst)
        finally:
            _discard(tmp)
        return
    with _replacing(target, st) as (fd, tmp):
        os.close(fd)
        yield tmp
        _sync(tmp)


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike) -> Iterator[Path]:
    """A temp folder beside ``path`` to fill; it replaces ``path`` (a folder or nothing) on success.

    An old folder is first renamed aside and removed after the swap, so ``path`` is always either the
    old complete folder or the new one (for the instant between the two renames, absent).
    """
    target = Path(path)
    if target.exists() and not target.is_dir():
        raise WriteError(target, "a file is in the way of the folder")
    with temp_directory(target) as tmp:
        yield tmp
        old = None
        if target.exists():
            old = target.with_name(f".{target.name[:180]}.old-{secrets.token_hex(4)}")
            os.replace(target, old)
        try:
            os.replace(tmp, target)
        except OSError as exc:
            if old is not None:
                os.replace(old, target)
            raise _fail(target, exc) from None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def temp_directory(target: str | os.PathLike, kind: str = "tmp") -> Iterator[Path]:
    """A new, locked folder ``.NAME.<kind>-XXXXXXXX`` beside ``target``, removed when the block ends
    (unless renamed away); stale ones of ``target`` are swept first."""
    target = Path(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        sweep_stale(target, (kind,))
        for _ in range(100):
            tmp = Path(tempfile.mkdtemp(prefix=f".{target.name[:180]}.{kind}-", dir=target.parent))
            fd = os.open(tmp, os.O_RDONLY)
            if _claim(fd, tmp):
                break
    except OSError as exc:
        raise _fail(target, exc) from None
    else:
        if str(tmp) not in _HELD:
            raise WriteError(target, "no free temp folder name beside it")
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        _release(fd, tmp)


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` in one piece (see :func:`atomic_output`); returns ``path``."""
    with atomic_output(path) as f:
        try:
            f.write(data)
        except OSError as exc:
            raise _fail(Path(path), exc) from None
    return Path(path)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    return atomic_write_bytes(path, text.encode("utf-8"))


def atomic_write_json(path: str | os.PathLike, obj: Any) -> Path:
    return atomic_write_text(path, json.dumps(obj, indent=1, sort_keys=True) + "\n")


def check_writable(path: str | os.PathLike) -> Path:
    """Fail before a long run, not after it, when ``path`` cannot be written; returns ``path``."""
    target, st = _resolve(path)
    if _in_place(st):
        if not os.access(target, os.W_OK):
            raise WriteError(path, "permission denied")
        return Path(path)
    fd, tmp = _open_temp(target)
    _discard(tmp)
    _release(fd, tmp)
    return Path(path)


def check_writable_dir(path: str | os.PathLike) -> Path:
    """Create folder ``path`` if needed and check a file can be made in it; returns ``path``."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise WriteError(path, "not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _fail(path, exc) from None
    check_writable(path / ".write-probe")
    return path


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks (datasets, artifacts, leaderboard files)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()
