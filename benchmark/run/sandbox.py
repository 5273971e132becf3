"""Policy files run in a box: a child process that gets observations and gives modes, nothing else.

Every policy *file* (``eval --policy FILE``, and every stored artifact ``leaderboard --verify`` and
``submit`` re-run) acts in a child process, never in the process that holds the checkout:

- the child gets the policy's bytes through a pipe (the parent read and hashed them: no file swap
  between the sha256 check and the load) and speaks length-prefixed ``.npy`` frames over its
  stdin / stdout (``allow_pickle=False`` both ways: neither side unpickles what the other sent);
- it starts in an empty temporary directory with an empty environment, under resource limits
  (CPU seconds, address space, file size, open files, no core dumps) and, where the kernel has it,
  Landlock (Linux >= 5.13): it may write, create or remove no file outside its temporary directory,
  read none outside it but the code it imports and the system's libraries (:func:`readable_paths`:
  no ``/etc``, home folder or other process's ``/proc``), open no TCP connection (ABI 4) and signal
  no process outside itself (ABI 6);
- the parent gives each call a wall-clock limit and kills the child's whole process group
  (SIGKILL: a policy that ignores SIGTERM cannot outlive it); every failure (a crash, a hang, a
  policy that cannot be loaded, an answer of the wrong shape, NaN, a mode outside {0, 1, 2}) is one
  :class:`PolicyFailure` line.

Landlock is a self-restriction any unprivileged process can apply (``landlock(7)``); it is written
here with ``ctypes`` (three syscalls) because no maintained Python binding exists on PyPI for the
versions we support. Without it (an older kernel, or ``OVERTAKEZOO_SANDBOX_LANDLOCK=0``) the child
keeps the other limits and a file-size limit of 0 bytes, and :func:`landlock_abi` says so.

Both sides of the wire protocol live in this one module (parent and child), so the frame format,
the limits and the Landlock rules are read and changed in one place.
"""

from __future__ import annotations

import ctypes
import io
import json
import os
import resource
import select
import signal
import struct
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from typing import Any

import numpy as np

NUM_MODES = 3
DATA_KINDS = ("mlp", "onnx")  # what a box loads as data; "torchscript" (code) needs allow_code
_HEADER = struct.Struct("<cQ")  # frame: one tag byte, the payload's length
_MAX_FRAME = 1 << 30


class PolicyFailure(Exception):
    """A policy failed while acting (or loading); ``str`` is one line."""

    def __init__(self, reason: str, rows: np.ndarray | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.rows = rows  # the batch rows at fault, where the failure names some


class BadAnswer(PolicyFailure):
    """The policy took the observations but answered with something that is not modes (a wrong
    shape, dtype or value): its output is at fault, not the observations."""


@dataclass(frozen=True)
class Limits:
    """What the child may use. ``call_s``: wall seconds per decision batch (and to load);
    ``cpu_s``: CPU seconds over the child's life; ``memory_bytes``: address space."""

    call_s: float = 60.0
    load_s: float = 120.0
    cpu_s: int = 900
    memory_bytes: int = 8 << 30  # address space: a CUDA build of torch reserves a few GB just to import
    open_files: int = 256

    @classmethod
    def from_env(cls) -> Limits:
        """Defaults, overridden by ``OVERTAKEZOO_SANDBOX_CALL_S`` / ``_CPU_S`` / ``_MEMORY_MB``."""
        env, d = os.environ, cls()

        def read(name: str, default: float, kind: type) -> Any:
            try:
                value = kind(env.get(name, default))
            except ValueError:
                return default  # (a malformed override falls back to the default, never a traceback)
            return value if value > 0 else default

        return cls(
            call_s=read("OVERTAKEZOO_SANDBOX_CALL_S", d.call_s, float),
            load_s=read("OVERTAKEZOO_SANDBOX_LOAD_S", d.load_s, float),
            cpu_s=read("OVERTAKEZOO_SANDBOX_CPU_S", d.cpu_s, int),
            memory_bytes=read("OVERTAKEZOO_SANDBOX_MEMORY_MB", d.memory_bytes >> 20, int) << 20,
        )


def check_modes(modes: Any, n: int) -> np.ndarray:
    """``modes`` as an (n,) int64 array of 0, 1 or 2; :class:`PolicyFailure` naming what is wrong
    (and, for bad values, the rows)."""
    a = np.asarray(modes)
    if a.ndim == 2 and a.shape[1] == 1:  # (N, 1): one mode per row in a column
        a = a[:, 0]
    if a.shape != (n,):
        raise BadAnswer(f"returned shape {a.shape} for {n} observation(s), expected ({n},)")
    if a.dtype.kind not in "iub":
        if a.dtype.kind != "f":
            raise BadAnswer(f"returned modes of dtype {a.dtype}, expected integers 0, 1 or 2")
        bad = ~np.isfinite(a) | (a != np.round(a))
        if bad.any():
            raise BadAnswer(f"returned mode {a[bad][0].item()!r}, expected 0, 1 or 2", np.flatnonzero(bad))
    bad = (a < 0) | (a >= NUM_MODES)
    if bad.any():
        raise BadAnswer(f"returned mode {a[bad][0].item()!r}, expected 0, 1 or 2", np.flatnonzero(bad))
    return a.astype(np.int64)


def modes_of(out: Any, n: int) -> np.ndarray:
    """A policy's output for n observations as modes: scores (n, 3) -> their argmax (every score
    finite), modes (n,) or (n, 1) checked by :func:`check_modes`."""
    out = np.asarray(out)
    if out.shape not in ((n,), (n, 1), (n, NUM_MODES)):  # e.g. (n, 5): not the 3 modes' scores
        raise BadAnswer(
            f"returned shape {out.shape} for {n} observation(s), expected {NUM_MODES} mode scores "
            f"per observation ({n}, {NUM_MODES}) or one mode per observation ({n},) or ({n}, 1)"
        )
    if out.shape == (n, NUM_MODES) and out.dtype.kind != "f":
        raise BadAnswer(f"returned {NUM_MODES} scores per observation of dtype {out.dtype}, expected floats")
    if out.ndim == 2 and out.shape[1] == NUM_MODES and out.dtype.kind == "f":
        bad = ~np.isfinite(out).all(axis=1)
        if bad.any():
            raise BadAnswer(f"returned non-finite scores {out[bad][0].tolist()}", np.flatnonzero(bad))
        return out.argmax(axis=1).astype(np.int64)
    return check_modes(out, n)


# ------------------------------------------------------------------ the parent's side
class SandboxedPolicy:
    """A policy file acting in a child process (module docstring). ``kind``: ``mlp`` (an ``.npz``
    with its model card ``card``), ``onnx`` (its policy card inside it) or ``torchscript`` (``card``:
    its policy card, if any); ``config``: the EnvConfig the observations come from. ``info`` is what
    the child reported after loading: the training hold (``action_repeat``), and ``card``, the policy card it read."""

    def __init__(
        self,
        kind: str,
        data: bytes,
        config: Any,
        card: bytes | None = None,
        who: str = "policy",
        limits: Limits | None = None,
        allow_code: bool = False,
    ) -> None:
        if kind not in DATA_KINDS and not (allow_code and kind == "torchscript"):
            # Loading TorchScript runs its code (boxed all the same): only a user's own file, by request
            # (eval --policy, submit's conversion), never a stored artifact a verifier re-runs.
            raise PolicyFailure(f"kind {kind!r} is not a stored data format ({', '.join(DATA_KINDS)})")
        self.who, self.limits = who, limits or Limits.from_env()
        self._tmp = tempfile.TemporaryDirectory(prefix="overtakezoo-sandbox-", ignore_cleanup_errors=True)
        # The child imports what this process imports (its sys.path: user installs, checkouts), nothing else.
        env = {
            "PATH": os.defpath,
            "HOME": self._tmp.name,
            "TMPDIR": self._tmp.name,
            "LANG": "C.UTF-8",
            "PYTHONPATH": os.pathsep.join(p for p in sys.path if p),
            "PYTHONNOUSERSITE": "1",
            "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
            "OVERTAKEZOO_SANDBOX_LANDLOCK": os.environ.get("OVERTAKEZOO_SANDBOX_LANDLOCK", "1"),
        }
        lim = self.limits
        self._proc = subprocess.Popen(
            [
                sys.executable,
                "-B",
                "-m",
                "overtakezoo.benchmark.run.sandbox",
                str(lim.cpu_s),
                str(lim.memory_bytes),
                str(lim.open_files),
            ],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            cwd=self._tmp.name,
            env=env,
            start_new_session=True,
            close_fds=True,
        )
        header = json.dumps({"kind": kind, "config": config.to_dict()}).encode()
        try:
            self._send(b"L", header)
            self._send(b"W", data)
            self._send(b"C", card or b"")
            tag, payload = self._receive(lim.load_s, "load")
        except PolicyFailure:
            self.close()
            raise
        if tag == b"E":
            self.close()
            raise PolicyFailure(payload.decode(errors="replace"))
        self.info = _json_object(payload)

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.ascontiguousarray(obs, np.float32)
        buf = io.BytesIO()
        np.save(buf, obs, allow_pickle=False)
        self._send(b"A", buf.getvalue())
        tag, payload = self._receive(self.limits.call_s, "act")
        if tag == b"E":
            raise PolicyFailure(payload.decode(errors="replace"))
        try:
            out = np.load(io.BytesIO(payload), allow_pickle=False)
        except Exception:
            raise BadAnswer("answered with something that is not an array") from None
        return modes_of(out, obs.shape[0])

    def export_onnx(self, obs_dim: int) -> bytes:
        """A loaded TorchScript policy exported to ONNX by the child (loading it runs its code), its
        policy card (if any) in the ONNX metadata."""
        self._send(b"X", str(int(obs_dim)).encode())
        tag, payload = self._receive(self.limits.load_s, "load")
        if tag == b"E":
            raise PolicyFailure(payload.decode(errors="replace"))
        return payload

    def close(self) -> None:
        proc = getattr(self, "_proc", None)
        if proc is not None and proc.poll() is None:
            try:
                os.killpg(proc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            proc.wait()
        for f in (proc.stdin, proc.stdout) if proc is not None else ():
            try:
                f.close()
            except OSError:
                pass
        tmp = getattr(self, "_tmp", None)
        if tmp is not None:
            tmp.cleanup()

    def __del__(self) -> None:
        self.close()

    # framing
    def _send(self, tag: bytes, payload: bytes) -> None:
        try:
            self._proc.stdin.write(_HEADER.pack(tag, len(payload)) + payload)
            self._proc.stdin.flush()
        except (BrokenPipeError, OSError, ValueError):  # (ValueError: the pipe was closed after a failure)
            raise PolicyFailure(self._died("while receiving observations")) from None

    def _receive(self, timeout: float, what: str) -> tuple[bytes, bytes]:
        head = self._read(_HEADER.size, timeout, what)
        tag, size = _HEADER.unpack(head)
        if tag not in (b"R", b"M", b"E") or size > _MAX_FRAME:
            raise PolicyFailure("broke the sandbox protocol")
        return tag, self._read(size, timeout, what)

    def _read(self, n: int, timeout: float, what: str) -> bytes:
        fd, out = self._proc.stdout.fileno(), bytearray()
        while len(out) < n:
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                self.close()
                raise PolicyFailure(f"did not {'load' if what == 'load' else 'answer'} within {timeout:g} s (killed)")
            chunk = os.read(fd, n - len(out))
            if not chunk:
                raise PolicyFailure(self._died(f"while {'loading' if what == 'load' else 'acting'}"))
            out += chunk
        return bytes(out)

    def _died(self, when: str) -> str:
        try:
            code = self._proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # alive but silent: killed like a hang
            self.close()
            return f"stopped answering {when} (killed)"
        self.close()
        if code < 0:
            name = signal.Signals(-code).name
            why = {
                "SIGXCPU": "CPU time limit",
                "SIGKILL": "killed (memory or time limit)",
                "SIGSEGV": "crashed",
                "SIGXFSZ": "tried to write a file",
            }.get(name, name)
            return f"process ended {when}: {why} ({name})"
        return f"process ended {when} (exit status {code})"


def _json_object(payload: bytes) -> dict[str, Any]:
    try:
        info = json.loads(payload)
    except ValueError:
        info = None
    if not isinstance(info, dict):
        raise PolicyFailure("broke the sandbox protocol")
    return info


# ------------------------------------------------------------------ the child's side
_PR_SET_NO_NEW_PRIVS = 38
_SYS_CREATE_RULESET, _SYS_ADD_RULE, _SYS_RESTRICT_SELF = 444, 445, 446  # the same on every architecture
_FS_WRITE = sum(1 << b for b in (1, 4, 5, 6, 7, 8, 9, 10, 11, 12))  # write, remove, make anything
_READ_FILE, _FS_READ = 1 << 2, (1 << 2) | (1 << 3)  # read a file; list a directory too
_FS_BY_ABI = {2: 1 << 13, 3: 1 << 14, 5: 1 << 15}  # refer (link/rename across), truncate, ioctl on devices


def landlock_abi() -> int:
    """The kernel's Landlock ABI version (0: none)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        abi = libc.syscall(_SYS_CREATE_RULESET, None, ctypes.c_size_t(0), ctypes.c_uint32(1))
    except (OSError, AttributeError):
        return 0
    return max(int(abi), 0)


def readable_paths() -> tuple[list[str], list[str]]:
    """(directories, files) the child may read besides its temporary directory: the code it imports
    (Python's prefixes, its ``sys.path``, OvertakeZoo's own packages: not the rest of a checkout),
    system libraries, and what CPU and thread-count probes read. Not ``/etc``, home folders or
    another process's ``/proc`` entry (a parent's ``environ`` holds its secrets)."""
    import importlib.util

    dirs = {sys.prefix, sys.base_prefix, sys.exec_prefix, *(p for p in sys.path if p)}
    for sub in ("envs", "zoo", "benchmark"):  # an editable install maps these from a checkout
        spec = importlib.util.find_spec(f"overtakezoo.{sub}")
        dirs |= set(spec.submodule_search_locations or []) if spec else set()
    dirs |= {
        "/usr/lib",
        "/usr/lib64",
        "/lib",
        "/lib64",
        "/usr/local/lib",
        "/usr/share/zoneinfo",
        "/sys/devices/system/cpu",
        "/sys/fs/cgroup",
        f"/proc/{os.getpid()}",
    }
    files = {"/etc/ld.so.cache", "/dev/null", "/dev/urandom", "/proc/cpuinfo", "/proc/meminfo", "/proc/stat"}
    return sorted(d for d in dirs if os.path.isdir(d)), sorted(f for f in files if os.path.exists(f))


def _restrict(writable: str) -> int:
    """Landlock this process: no writes outside ``writable``, no reads outside it and
    :func:`readable_paths`, no TCP (ABI 4), no signals or abstract sockets outside (ABI 6). Returns
    the ABI applied (0: unavailable)."""
    abi = landlock_abi()
    if abi < 1:
        return 0
    libc = ctypes.CDLL(None, use_errno=True)
    fs = _FS_WRITE | _FS_READ | sum(bit for v, bit in _FS_BY_ABI.items() if abi >= v)
    net = 0b11 if abi >= 4 else 0  # bind, connect
    scoped = 0b11 if abi >= 6 else 0  # abstract unix sockets, signals
    attr = struct.pack("<QQQ", fs, net, scoped)[: 8 if abi < 4 else 16 if abi < 6 else 24]
    fd = libc.syscall(_SYS_CREATE_RULESET, attr, ctypes.c_size_t(len(attr)), ctypes.c_uint32(0))
    if fd < 0:
        return 0
    dirs, files = readable_paths()
    rules = [(writable, fs), *((d, _FS_READ) for d in dirs), *((f, _READ_FILE) for f in files)]
    for path, allowed in rules:
        try:
            handle = os.open(path, os.O_PATH | (os.O_DIRECTORY if allowed != _READ_FILE else 0))
        except OSError:
            continue  # gone since it was listed: nothing to allow
        rule = struct.pack("<Qi", allowed, handle)  # struct landlock_path_beneath_attr (packed)
        added = libc.syscall(_SYS_ADD_RULE, fd, ctypes.c_int(1), rule, ctypes.c_uint32(0)) == 0
        os.close(handle)
        if not added and path == writable:
            return 0
    if (
        libc.prctl(_PR_SET_NO_NEW_PRIVS, 1, 0, 0, 0) != 0
        or libc.syscall(_SYS_RESTRICT_SELF, fd, ctypes.c_uint32(0)) != 0
    ):
        return 0
    os.close(fd)
    return abi


def _confine(cpu_s: int, memory: int, open_files: int) -> int:
    landlock = _restrict(os.getcwd()) if os.environ.get("OVERTAKEZOO_SANDBOX_LANDLOCK") != "0" else 0
    for res, value in (
        (resource.RLIMIT_CPU, cpu_s),
        (resource.RLIMIT_AS, memory),
        (resource.RLIMIT_NOFILE, open_files),
        (resource.RLIMIT_CORE, 0),
        # Without Landlock no file may grow at all (a backstop, not a wall).
        (resource.RLIMIT_FSIZE, 64 << 20 if landlock else 0),
    ):
        resource.setrlimit(res, (value, value))
    return landlock


def _read_frame(stream: Any) -> tuple[bytes, bytes]:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError
    tag, size = _HEADER.unpack(head)
    payload = stream.read(size)
    if len(payload) < size:
        raise EOFError
    return tag, payload


def _write_frame(stream: Any, tag: bytes, payload: bytes) -> None:
    stream.write(_HEADER.pack(tag, len(payload)) + payload)
    stream.flush()


def _one_line(exc: BaseException) -> str:
    text = [line for line in str(exc).strip().splitlines() if line.strip()]
    if text and text[0].startswith("The following operation failed in the TorchScript interpreter"):
        text = text[-1:]  # the interpreter's traceback ends with the error itself
    return f"{type(exc).__name__}: {text[0].strip()}" if text else type(exc).__name__


def _load(kind: str, data: bytes, card: bytes, config: Any) -> tuple[Any, dict[str, Any]]:
    """(batch function (N, D) float32 -> modes or scores, what the parent is told)."""
    if kind == "mlp":
        from overtakezoo.zoo.members.learned import MLPDecider
        from overtakezoo.zoo.members.mlp import NumpyMLP, read_npz

        meta = json.loads(card)
        arch = meta.get("architecture") or {}
        net = NumpyMLP.from_arrays(read_npz(data), arch.get("activation", "relu"), bool(arch.get("dueling", False)))
        dec = MLPDecider(net, str(meta.get("name", "policy")), config, meta)
        info = {"action_repeat": dec.action_repeat}
        if meta.get("policy_card") is not None:  # (a converted SB3 file's card, checked again here)
            from overtakezoo.benchmark.run.artifacts import parse_card

            info["card"] = parse_card(json.dumps(meta["policy_card"]), "policy card")
            if info["card"]["action_repeat"] != dec.action_repeat:
                raise ValueError(
                    f"the model card's action_repeat {dec.action_repeat} differs from its policy card's "
                    f"{info['card']['action_repeat']}"
                )
        return dec.act_batch, info
    if kind == "onnx":
        import onnxruntime as ort

        opts = ort.SessionOptions()
        opts.intra_op_num_threads = opts.inter_op_num_threads = 1
        from overtakezoo.benchmark.run.artifacts import CARD_KEY, legacy_repeat, parse_card

        session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        name = session.get_inputs()[0].name
        props = session.get_modelmeta().custom_metadata_map
        card = parse_card(props[CARD_KEY], f"ONNX metadata {CARD_KEY}") if CARD_KEY in props else None
        info = {"action_repeat": legacy_repeat(props, card), **({"card": card} if card else {})}
        if (session.get_inputs()[0].shape or [None])[0] == 1:  # a fixed batch of 1 (rsl-rl's export): row by row

            def act(obs: np.ndarray) -> np.ndarray:
                if obs.shape[0] == 0:
                    return np.zeros((0,), np.int64)
                return np.concatenate(
                    [np.asarray(session.run(None, {name: obs[i : i + 1]})[0]) for i in range(obs.shape[0])], axis=0
                )

            return act, info
        return (lambda obs: session.run(None, {name: obs})[0]), info
    if kind == "torchscript":
        import torch

        torch.set_num_threads(1)
        module = torch.jit.load(io.BytesIO(data), map_location="cpu").eval()

        def act(obs: np.ndarray) -> np.ndarray:
            with torch.no_grad():
                return module(torch.from_numpy(obs)).numpy()

        act.module = module  # for an export to ONNX (a 'X' request)
        if not card:
            return act, {"action_repeat": getattr(module, "action_repeat", 1)}
        from overtakezoo.benchmark.run.artifacts import parse_card

        info = {"action_repeat": parse_card(card, "policy card")["action_repeat"], "card": parse_card(card)}
        if hasattr(module, "action_repeat") and str(module.action_repeat) != str(info["action_repeat"]):
            raise ValueError(
                f"the module's action_repeat {module.action_repeat!r} differs from its "
                f"policy card's {info['action_repeat']} (remove one)"
            )
        return act, info
    raise ValueError(f"unknown policy kind {kind!r}")


def _to_onnx(act: Any, obs_dim: int, info: dict[str, Any]) -> bytes:
    """The loaded TorchScript module as one self-contained ONNX file (batch axis dynamic)."""
    import warnings

    import onnx
    import torch

    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(
            act.module,
            (torch.zeros(2, obs_dim),),
            buf,
            input_names=["obs"],
            output_names=["out"],
            dynamic_axes={"obs": {0: "n"}, "out": {0: "n"}},
            dynamo=False,
        )
    model = onnx.load_model_from_string(buf.getvalue())
    entry = model.metadata_props.add()
    entry.key, entry.value = "action_repeat", str(int(info.get("action_repeat", 1)))
    if info.get("card"):  # the policy card travels into the stored ONNX file
        from overtakezoo.benchmark.run.artifacts import CARD_KEY

        entry = model.metadata_props.add()
        entry.key, entry.value = CARD_KEY, json.dumps(info["card"], sort_keys=True)
    return model.SerializeToString()


def _serve(cpu_s: int, memory: int, open_files: int) -> None:
    landlock = _confine(cpu_s, memory, open_files)
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # a policy that prints must not corrupt the frames
    from overtakezoo.envs import EnvConfig

    try:
        _, header = _read_frame(stdin)
        _, data = _read_frame(stdin)
        _, card = _read_frame(stdin)
        request = json.loads(header)
        act, info = _load(request["kind"], data, card, EnvConfig.from_dict(request["config"]))
        info = {**info, "landlock_abi": landlock}
        _write_frame(stdout, b"R", json.dumps(info, default=str).encode())
    except EOFError:
        return
    except BaseException as exc:  # noqa: BLE001 - anything the policy's loader raises becomes one line
        _write_frame(stdout, b"E", f"cannot load ({_one_line(exc)})".encode())
        return
    while True:
        try:
            tag, payload = _read_frame(stdin)
        except EOFError:
            return
        if tag == b"X":
            try:
                _write_frame(stdout, b"M", _to_onnx(act, int(payload), info))
            except BaseException as exc:  # noqa: BLE001
                _write_frame(stdout, b"E", f"cannot be exported to ONNX ({_one_line(exc)})".encode())
            continue
        try:
            obs = np.load(io.BytesIO(payload), allow_pickle=False)
            out = np.ascontiguousarray(np.asarray(act(obs)))
            if out.dtype.kind not in "iubf":
                raise TypeError(f"returned an array of dtype {out.dtype}")
            buf = io.BytesIO()
            np.save(buf, out, allow_pickle=False)
            _write_frame(stdout, b"M", buf.getvalue())
        except BaseException as exc:  # noqa: BLE001
            _write_frame(stdout, b"E", f"raised {_one_line(exc)}".encode())


if __name__ == "__main__":
    _serve(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
