"""Offline-RL datasets: build + load with Minari, behaviour cloning, and the download command
against a local HTTP server (resume after a dropped connection, checksum, refused archives)."""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import tarfile
import threading
from pathlib import Path

import numpy as np
import pytest
from test_benchmark_cli import one_line_error

from overtakezoo import zoo
from overtakezoo.benchmark.cli import main

NAME = "overtakezoo/table1/test-v0"


def load_minari(path, name):
    """Load with Minari's own code, pointed at ``path`` the documented way."""
    import os

    import minari

    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        return minari.load_dataset(name)
    finally:
        if old is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def test_build_load_and_behaviour_cloning(home, capsys):
    decider = "rule-fsm" if "rule-fsm" in zoo.names() else "always-overtake"
    assert (
        main(
            [
                "dataset",
                "build",
                "--suite",
                "table1-train",
                "--decider",
                decider,
                "--count",
                "40",
                "--epsilon",
                "0.1",
                "--name",
                NAME,
            ]
        )
        == 0
    )
    assert (
        main(["dataset", "build", "--suite", "table1-train", "--decider", decider, "--count", "2", "--name", NAME]) == 2
    )  # exists already
    assert "already exists" in capsys.readouterr().err
    assert main(["dataset", "list"]) == 0
    assert NAME in capsys.readouterr().out

    ds = load_minari(home / "home" / "datasets", NAME)
    assert ds.total_episodes == 40
    episodes = list(ds.iterate_episodes())
    for e in episodes:
        assert e.observations.shape == (len(e.actions) + 1, ds.observation_space.shape[0])
        assert e.terminations[-1] or e.truncations[-1]
        assert not (e.terminations[:-1].any() or e.truncations[:-1].any())
        assert len(e.infos["outcome"]) == len(e.actions) + 1 and e.infos["outcome"][-1] != 0
    assert [int(e.infos["scenario_index"][0]) for e in episodes] == list(range(40))

    # Behaviour cloning: softmax regression on the observation, trained on 30 episodes, tested on 10.
    x = [np.concatenate([e.observations[:-1] for e in part]) for part in (episodes[:30], episodes[30:])]
    y = [np.concatenate([e.actions for e in part]) for part in (episodes[:30], episodes[30:])]
    mu, sd = x[0].mean(0), x[0].std(0) + 1e-6
    xs = [np.hstack([(a - mu) / sd, np.ones((len(a), 1))]) for a in x]
    w = np.zeros((xs[0].shape[1], 3))
    onehot = np.eye(3)[y[0]]
    for _ in range(300):
        z = xs[0] @ w
        p = np.exp(z - z.max(1, keepdims=True))
        p /= p.sum(1, keepdims=True)
        w -= 0.5 * xs[0].T @ (p - onehot) / len(onehot)
    accuracy = float(np.mean(np.argmax(xs[1] @ w, 1) == y[1]))
    majority = float(np.bincount(y[1], minlength=3).max() / len(y[1]))
    print(f"behaviour cloning: held-out accuracy {accuracy:.3f}, majority class {majority:.3f}")
    assert accuracy > 1 / 3 + 0.1 and accuracy >= majority, (accuracy, majority)


# ------------------------------------------------------------------ download
class RangeHandler(http.server.BaseHTTPRequestHandler):
    files: dict[str, bytes] = {}
    drop_first_after: int | None = None  # bytes sent before the first response is cut off
    seen: list[str | None] = []

    def do_GET(self):  # noqa: N802 - http.server's naming
        body = self.files.get(self.path)
        type(self).seen.append(self.headers.get("Range"))
        if body is None:
            self.send_error(404)
            return
        start = 0
        rng = self.headers.get("Range")
        if rng and rng.startswith("bytes=") and rng.endswith("-"):
            start = int(rng[6:-1])
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
        else:
            self.send_response(200)
        self.send_header("Content-Length", str(len(body) - start))
        self.end_headers()
        cut = type(self).drop_first_after
        if cut is not None:
            type(self).drop_first_after = None
            self.wfile.write(body[start : start + cut])
            self.wfile.flush()
            self.close_connection = True
            return  # the client sees a short body: an interrupted transfer
        self.wfile.write(body[start:])

    def log_message(self, *args):
        pass


@pytest.fixture
def server():
    RangeHandler.files, RangeHandler.seen, RangeHandler.drop_first_after = {}, [], None
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), RangeHandler)
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


def publish(home, server, name, path, blob, sha=None):
    RangeHandler.files[path] = blob
    reg = json.loads((home / "registry.json").read_text())
    reg["datasets"][name] = {"url": server + path, "size": len(blob), "sha256": sha or hashlib.sha256(blob).hexdigest()}
    (home / "registry.json").write_text(json.dumps(reg))


def test_download_resumes_verifies_and_unpacks(home, server, monkeypatch, capsys):
    assert (
        main(
            [
                "dataset",
                "build",
                "--suite",
                "table1-train",
                "--decider",
                "always-overtake",
                "--count",
                "3",
                "--name",
                NAME,
            ]
        )
        == 0
    )
    packed = home / "ds.tar.gz"
    assert main(["dataset", "pack", NAME, "--out", str(packed)]) == 0
    blob = packed.read_bytes()
    monkeypatch.setenv("OVERTAKEZOO_HOME", str(home / "fresh"))  # an empty cache to download into
    publish(home, server, NAME, "/ds.tar.gz", blob)

    RangeHandler.drop_first_after = len(blob) // 3
    assert main(["dataset", "download", NAME, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "run the command again to resume" in err and err.count("\n") == 1
    part = next((home / "fresh" / "downloads").glob("*.part"))
    assert part.stat().st_size == len(blob) // 3
    assert main(["dataset", "download", NAME, "--no-progress"]) == 0
    assert RangeHandler.seen == [None, f"bytes={len(blob) // 3}-"]  # the second request resumed
    assert not part.exists()
    ds = load_minari(home / "fresh" / "datasets", NAME)
    assert ds.total_episodes == 3

    # A corrupted copy: the checksum rejects it and the partial file is deleted.
    bad_name = "overtakezoo/table1/corrupt-v0"
    corrupt = bytearray(blob)
    corrupt[len(corrupt) // 2] ^= 0xFF
    publish(home, server, bad_name, "/corrupt.tar.gz", bytes(corrupt), sha=hashlib.sha256(blob).hexdigest())
    assert main(["dataset", "download", bad_name, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "checksum mismatch" in err and "deleted" in err and err.count("\n") == 1
    assert not list((home / "fresh" / "downloads").glob("corrupt*"))
    assert not (home / "fresh" / "datasets" / bad_name).exists()


def _tar(members):
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, kind in members:
            info = tarfile.TarInfo(name)
            if kind == "file":
                info.size = 2
                tar.addfile(info, io.BytesIO(b"ok"))
            elif kind == "dir":
                info.type = tarfile.DIRTYPE
                tar.addfile(info)
            elif kind == "symlink":
                info.type, info.linkname = tarfile.SYMTYPE, "/etc/passwd"
                tar.addfile(info)
    return buf.getvalue()


@pytest.mark.parametrize(
    "members",
    [
        [("overtakezoo/evil/x-v0/../../../../escape.txt", "file")],
        [("/tmp/overtakezoo-abs.txt", "file")],
        [("overtakezoo/evil/x-v0/link", "symlink")],
        [("overtakezoo/other/y-v0/data.txt", "file")],  # inside the cache, but not the dataset's folder
    ],
)
def test_archives_that_escape_are_refused(home, server, members, capsys):
    name = "overtakezoo/evil/x-v0"
    publish(home, server, name, "/evil.tar.gz", _tar(members))
    assert main(["dataset", "download", name, "--no-progress"]) == 2
    assert "refusing" in capsys.readouterr().err
    assert not (home / "escape.txt").exists() and not (home / "home" / "escape.txt").exists()
    assert not (home / "home" / "datasets" / "overtakezoo" / "other").exists()
    assert not Path("/tmp/overtakezoo-abs.txt").exists()


def test_parent_folder_entries_are_fine_and_http_errors_are_one_line(home, server, capsys):
    name = "overtakezoo/ok/x-v0"
    publish(
        home,
        server,
        name,
        "/ok.tar.gz",
        _tar(
            [
                ("overtakezoo", "dir"),
                ("overtakezoo/ok", "dir"),
                ("overtakezoo/ok/x-v0", "dir"),
                ("overtakezoo/ok/x-v0/data.txt", "file"),
            ]
        ),
    )
    assert main(["dataset", "download", name, "--no-progress"]) == 0
    assert (home / "home" / "datasets" / name / "data.txt").read_bytes() == b"ok"
    capsys.readouterr()
    publish(home, server, "overtakezoo/gone/x-v0", "/ok.tar.gz", b"x")
    RangeHandler.files.pop("/ok.tar.gz")
    assert main(["dataset", "download", "overtakezoo/gone/x-v0", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "HTTP 404" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    "argv", [["dataset"], ["dataset", "build"], ["dataset", "list"], ["dataset", "download"], ["dataset", "pack"]]
)
def test_help_has_examples(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0 and "examples:" in capsys.readouterr().out


def test_bad_names_and_urls(home, server, capsys):
    assert main(["dataset", "download", "overtakezoo/nope-v0"]) == 2
    assert "unknown dataset" in capsys.readouterr().err
    reg = {"datasets": {"overtakezoo/local/f-v0": {"url": "file:///etc/passwd", "size": 1, "sha256": "0" * 64}}}
    (home / "registry.json").write_text(json.dumps(reg))
    assert main(["dataset", "download", "overtakezoo/local/f-v0"]) == 2
    assert "only http(s)" in capsys.readouterr().err
    assert (
        main(["dataset", "build", "--suite", "table1-train", "--decider", "always-follow", "--name", "../escape-v0"])
        == 2
    )
    assert "bad dataset name" in capsys.readouterr().err


# ---------------------------------------------------------------------------- full disk, crashes, leftovers (issue 18)
BUILD = ["dataset", "build", "--suite", "table1-train", "--decider", "always-overtake", "--count", "2", "--name", NAME]


def _content(name):
    from overtakezoo.benchmark.datasets.store import content_sha256, load

    return content_sha256(load(name))


def _hidden(home):
    """Temp folders beside the dataset (``.test-v0.build-*`` and the like)."""
    return sorted(p.name for p in (home / "home" / "datasets" / "overtakezoo" / "table1").glob(".*"))


@pytest.mark.parametrize("failure", ["too-little-room", "enospc-in-hdf5"])
def test_full_disk_is_one_error_line_and_keeps_the_old_dataset(home, capsys, monkeypatch, failure):
    """A disk too small for the arrays is refused before HDF5 starts; ENOSPC inside the HDF5 write
    is one `error:` line too. No temp folder stays and the dataset being replaced is untouched."""
    import errno
    import shutil

    import minari

    assert main(BUILD) == 0
    before = _content(NAME)
    capsys.readouterr()
    if failure == "too-little-room":
        usage = shutil.disk_usage(home)
        monkeypatch.setattr(shutil, "disk_usage", lambda p: usage._replace(free=1000))
    else:

        def full(**kw):
            raise OSError(errno.ENOSPC, "No space left on device")

        monkeypatch.setattr(minari, "create_dataset_from_buffers", full)
    err = one_line_error(capsys, BUILD + ["--overwrite"])
    assert err.startswith(f"error: cannot write dataset {NAME}") and "nothing was changed" in err
    assert ("MB free" if failure == "too-little-room" else "no space left on device") in err
    assert _hidden(home) == [] and _content(NAME) == before


_CRASHING_BUILD = """
import os, signal, sys
import minari
from overtakezoo.benchmark.cli import main
def crash(**kw):  # what h5py does on a full disk: a segfault in the middle of the write
    root = os.environ["MINARI_DATASETS_PATH"]
    os.makedirs(os.path.join(root, {name!r}, "data"))
    open(os.path.join(root, {name!r}, "data", "main_data.hdf5"), "wb").write(b"half a file")
    os.kill(os.getpid(), signal.SIGSEGV)
minari.create_dataset_from_buffers = crash
sys.exit(main({argv!r}))
"""


def test_a_crashing_hdf5_writer_is_one_error_line_not_a_segfault(home):
    """The HDF5 write runs in a child process: its crash (rc 139 and hundreds of lines before) is one
    `error:` line and exit 2, with no temp folder left and the old dataset kept."""
    import os
    import subprocess
    import sys

    assert main(BUILD) == 0
    before = _content(NAME)
    code = _CRASHING_BUILD.format(name=NAME, argv=BUILD + ["--overwrite"])
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={**os.environ, "PYTHONFAULTHANDLER": ""},
    )
    err = proc.stderr.strip()
    assert proc.returncode == 2 and err.startswith(f"error: cannot write dataset {NAME}") and "\n" not in err, err
    assert "crashed" in err and _hidden(home) == [] and _content(NAME) == before


def test_a_killed_builds_temp_folder_is_swept_by_the_next_build(home):
    """SIGKILL during a build leaves its `.NAME.build-*` folder; the next build of that dataset deletes it."""
    import subprocess
    import sys

    code = (
        "import os, signal\nfrom overtakezoo.benchmark.datasets.store import datasets_dir, staging_root\n"
        f"with staging_root(datasets_dir() / {NAME!r}) as staging:\n"
        "    (staging / 'half.hdf5').write_bytes(b'x')\n    os.kill(os.getpid(), signal.SIGKILL)\n"
    )
    assert subprocess.run([sys.executable, "-c", code], timeout=120).returncode == -9
    [stale] = _hidden(home)
    assert stale.startswith(".test-v0.build-")
    assert main(BUILD) == 0
    assert _hidden(home) == []


def test_minari_finds_an_installed_dataset_with_no_environment_variable(tmp_path, monkeypatch):
    """With neither MINARI_DATASETS_PATH nor OVERTAKEZOO_HOME set, a build lands in Minari's own
    default folder, and plain `minari.load_dataset` (a fresh process, no variable) reads it."""
    import os
    import subprocess
    import sys

    monkeypatch.setenv("HOME", str(tmp_path))  # Minari's default is ~/.minari/datasets
    monkeypatch.delenv("OVERTAKEZOO_HOME", raising=False)
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    assert (
        main(["dataset", "build", "--suite", "table1-train", "--decider", "rule-fsm", "--count", "3", "--name", NAME])
        == 0
    )
    assert (tmp_path / ".minari" / "datasets" / NAME).is_dir()
    env = {k: v for k, v in os.environ.items() if k not in ("OVERTAKEZOO_HOME", "MINARI_DATASETS_PATH")}
    out = subprocess.run(
        [sys.executable, "-c", f"import minari; print(minari.load_dataset({NAME!r}).total_episodes)"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0 and out.stdout.strip() == "3", out.stderr


def test_list_shows_the_registrys_datasets(monkeypatch, tmp_path, capsys):
    """`dataset list` names every published dataset of the shipped registry, with its suite and size."""
    from overtakezoo.benchmark.datasets.registry import load_registry

    monkeypatch.setenv("OVERTAKEZOO_HOME", str(tmp_path / "home"))
    monkeypatch.delenv("MINARI_DATASETS_PATH", raising=False)
    monkeypatch.delenv("OVERTAKEZOO_REGISTRY", raising=False)
    assert main(["dataset", "list"]) == 0
    out = capsys.readouterr().out
    registry = load_registry()
    assert len(registry) == 8
    for name, entry in registry.items():
        line = next(line for line in out.splitlines() if line.strip().startswith(name + " "))
        assert f"suite {entry['recipe']['suite']}" in line and f"episodes {entry['episodes']}" in line
        assert line.rstrip().endswith("not installed")
        # How the episodes ended, as the regenerate command measured them: shares that sum to 1.
        shares = entry["outcomes"]
        assert set(shares) <= {"success", "crash", "timeout", "offroad"} and abs(sum(shares.values()) - 1) < 1e-3
        assert all(f"{k} {100 * v:.1f} %" in line for k, v in shares.items())
