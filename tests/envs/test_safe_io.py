"""Safe writes (overtakezoo.envs.io): a target is the old file or a complete new one, never partial;
FIFOs and devices are written in place, never replaced; two writers never mix; no temp file stays."""

import contextlib
import os
import stat
import subprocess
import sys
import time

import pytest

from conftest import leftovers, read_fifo
from overtakezoo.envs.io import (
    WriteError,
    atomic_directory,
    atomic_output,
    atomic_path,
    atomic_write_bytes,
    atomic_write_json,
    check_writable,
    check_writable_dir,
)


def test_write_replace_and_keep_permissions(tmp_path):
    target = tmp_path / "sub" / "r.json"
    atomic_write_json(target, {"a": 1})
    assert target.read_text() == '{\n "a": 1\n}\n'
    os.chmod(target, 0o640)
    atomic_write_bytes(target, b"new")
    assert target.read_bytes() == b"new" and stat.S_IMODE(target.stat().st_mode) == 0o640
    assert leftovers(target.parent) == []


def test_new_file_gets_umask_permissions_not_0600(tmp_path):
    old = os.umask(0o022)
    try:
        atomic_write_bytes(tmp_path / "x", b"1")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "x").stat().st_mode) == 0o644


def test_interrupted_stream_leaves_old_file_and_no_temp(tmp_path):
    target = tmp_path / "r.json"
    target.write_bytes(b"old")
    for exc in (KeyboardInterrupt, RuntimeError):
        with pytest.raises(exc):
            with atomic_output(target) as f:
                f.write(b"half of the new")
                raise exc()
        assert target.read_bytes() == b"old" and leftovers(tmp_path) == []
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(tmp_path / "new.json", "w") as f:
            f.write("partial")
            raise KeyboardInterrupt
    assert not (tmp_path / "new.json").exists() and leftovers(tmp_path) == []


class _StreamingWriter:
    """A writer with open/close methods (like an archive recorder) on top of atomic_output."""

    def __init__(self, path):
        self.stack = contextlib.ExitStack()
        self.f = self.stack.enter_context(atomic_output(path))

    def close(self, exc=None):
        if exc is None:
            self.stack.close()
        else:
            self.stack.__exit__(type(exc), exc, exc.__traceback__)


def test_streaming_writer_with_open_and_close(tmp_path):
    target = tmp_path / "run.bin"
    w = _StreamingWriter(target)
    w.f.write(b"chunk 1;")
    w.f.write(b"chunk 2")
    assert not target.exists()
    w.close()
    assert target.read_bytes() == b"chunk 1;chunk 2"
    w = _StreamingWriter(target)
    w.f.write(b"partial")
    w.close(KeyboardInterrupt())
    assert target.read_bytes() == b"chunk 1;chunk 2" and leftovers(tmp_path) == []


def test_atomic_path_keeps_suffix_and_cleans_up(tmp_path):
    target = tmp_path / "plot.png"
    with atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".png" and tmp != target
        tmp.write_bytes(b"png")
        assert not target.exists()
    assert target.read_bytes() == b"png"
    with pytest.raises(ValueError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"partial")
            raise ValueError
    assert target.read_bytes() == b"png" and leftovers(tmp_path) == []


def test_symlink_is_followed_not_replaced(tmp_path):
    real = tmp_path / "real.json"
    real.write_bytes(b"old")
    link = tmp_path / "link.json"
    link.symlink_to(real)
    atomic_write_bytes(link, b"new")
    assert link.is_symlink() and real.read_bytes() == b"new"


def test_fifo_is_written_in_place_and_stays_a_fifo(tmp_path):
    fifo = tmp_path / "out.fifo"
    os.mkfifo(fifo)
    got = []
    t = read_fifo(fifo, got)
    check_writable(fifo)  # must not open (and so block on) the FIFO
    atomic_write_bytes(fifo, b"through the pipe")
    t.join(10)
    assert got == [b"through the pipe"] and stat.S_ISFIFO(os.stat(fifo).st_mode)
    got = []
    t = read_fifo(fifo, got)
    with atomic_path(fifo) as tmp:  # a library writing by name: copied into the FIFO at the end
        assert tmp.parent != tmp_path
        tmp.write_bytes(b"by name")
    t.join(10)
    assert got == [b"by name"] and stat.S_ISFIFO(os.stat(fifo).st_mode) and not tmp.exists()
    assert leftovers(tmp_path) == []


def test_dev_null_counts_as_written_in_place():
    # Read-only check (nothing is written to /dev): a device is streamed into, never renamed over.
    from overtakezoo.envs.io import _in_place, _resolve

    target, st = _resolve(os.devnull)
    assert _in_place(st) and str(target) == os.devnull and stat.S_ISCHR(os.stat(os.devnull).st_mode)


def test_unwritable_targets_raise_one_line_write_errors(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for bad in (blocker / "r.json", tmp_path, tmp_path / "a\0b"):
        with pytest.raises(WriteError, match=r"^cannot write .*: [^\n]+$") as info:
            atomic_write_bytes(bad, b"1")
        assert isinstance(info.value, OSError) and info.value.strerror
        with pytest.raises(WriteError):
            check_writable(bad)
    with pytest.raises(WriteError, match="not a folder"):
        check_writable_dir(blocker)
    assert check_writable_dir(tmp_path / "new" / "dir").is_dir() and leftovers(tmp_path / "new" / "dir") == []


def test_atomic_directory_swaps_whole_folders(tmp_path):
    target = tmp_path / "ds"
    with atomic_directory(target) as tmp:
        (tmp / "a").write_text("1")
    assert (target / "a").read_text() == "1"
    with pytest.raises(KeyboardInterrupt):
        with atomic_directory(target) as tmp:
            (tmp / "b").write_text("partial")
            raise KeyboardInterrupt
    assert sorted(p.name for p in target.iterdir()) == ["a"]
    with atomic_directory(target) as tmp:
        (tmp / "c").write_text("2")
    assert sorted(p.name for p in target.iterdir()) == ["c"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


_WRITER = """
import sys
from overtakezoo.envs.io import atomic_write_bytes
path, byte, size, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
for _ in range(n):
    atomic_write_bytes(path, bytes([byte]) * size)
"""


def test_two_writer_processes_never_mix(tmp_path):
    target = tmp_path / "shared.bin"
    size, rounds = 1 << 20, 30
    procs = [
        subprocess.Popen([sys.executable, "-c", _WRITER, str(target), str(b), str(size), str(rounds)]) for b in (1, 2)
    ]
    seen = set()
    while any(p.poll() is None for p in procs):
        if target.exists():
            data = target.read_bytes()  # each read sees one writer's complete file
            assert len(data) == size and data.count(data[:1]) == size
            seen.add(data[0])
        time.sleep(0.005)
    assert [p.wait() for p in procs] == [0, 0]
    data = target.read_bytes()
    assert len(data) == size and data.count(data[:1]) == size and seen <= {1, 2}
    assert leftovers(tmp_path) == []
