"""Offline-RL datasets in Minari's format: build from any decider, list, and download published ones.

Datasets live under ``$MINARI_DATASETS_PATH`` when set, else ``<cache>/datasets`` where ``<cache>``
is ``$OVERTAKEZOO_HOME`` or the platform's user cache directory (``~/.cache/overtakezoo`` on Linux).
Minari reads ``MINARI_DATASETS_PATH`` itself, so point it at the same folder to load a dataset with
plain Minari code, or call :func:`load` (which sets it for the call)::

    MINARI_DATASETS_PATH=~/.cache/overtakezoo/datasets python -c \
        "import minari; print(minari.load_dataset('overtakezoo/table1/rule-fsm-v0').total_episodes)"

A transition is one simulator step (the Gymnasium env's step): observation (float32, the core's
vector), action (0 follow, 1 overtake, 2 abort; the decider's choice, replaced by a uniform random
mode with probability ``epsilon`` at each decision), reward, termination (success / crash /
off-road), truncation (time limit), infos (``outcome``, ``t``, ``scenario_index``; one per
observation, as Minari stores them).

Download: a registry file shipped with the package (``registry/datasets.json``, overridable with
``$OVERTAKEZOO_REGISTRY``) maps a name to ``url``, ``size`` and ``sha256`` of a ``.tar.gz`` holding the
dataset folder. The transfer resumes from a ``.part`` file (HTTP Range), is verified by SHA-256, and
is unpacked only if every member stays inside the datasets folder (no absolute paths, no ``..``,
no links or devices).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import http.client
import json
import os
import sys
import tarfile
import tempfile
import urllib.error
import urllib.parse
import urllib.request
import warnings
from pathlib import Path, PurePosixPath
from typing import Any, Iterator

import numpy as np

from .errors import UserError
from .io import atomic_directory, atomic_path, check_writable_dir

REGISTRY_FILE = Path(__file__).with_name("registry") / "datasets.json"


# ---------------------------------------------------------------------------- places
def cache_dir() -> Path:
    """``$OVERTAKEZOO_HOME``, else the platform's user cache directory + ``overtakezoo``."""
    home = os.environ.get("OVERTAKEZOO_HOME")
    if home:
        return Path(home).expanduser()
    if sys.platform == "darwin":
        return Path.home() / "Library" / "Caches" / "overtakezoo"
    if os.name == "nt":
        base = os.environ.get("LOCALAPPDATA") or str(Path.home() / "AppData" / "Local")
        return Path(base) / "overtakezoo" / "Cache"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "overtakezoo"


def datasets_dir() -> Path:
    env = os.environ.get("MINARI_DATASETS_PATH")
    return Path(env).expanduser() if env else cache_dir() / "datasets"


@contextlib.contextmanager
def _minari_path(path: Path | None = None) -> Iterator[Path]:
    """Point Minari at our datasets folder (or ``path``) for the duration of a call."""
    path = datasets_dir() if path is None else path
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)
    try:
        check_writable_dir(path)
        yield path
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old


def _minari() -> Any:
    try:
        import minari
    except ImportError:
        raise UserError("datasets need minari: pip install 'overtakezoo[data]'") from None
    return minari


def check_name(name: str) -> None:
    """Minari ids are ``(namespace/)(env/)name-vN``; refuse anything that could leave the folder."""
    parts = name.split("/")
    if not name or any(p in ("", ".", "..") for p in parts) or "\\" in name or name.startswith("/"):
        raise UserError(f"bad dataset name {name!r} (expected e.g. overtakezoo/table1/rule-fsm-v0)")
    if not parts[-1].rpartition("-v")[2].isdigit():
        raise UserError(f"bad dataset name {name!r}: it must end in -vN (e.g. rule-fsm-v0)")


# ---------------------------------------------------------------------------- build
class EpsilonRandom:
    """Wraps a decider: each decision is replaced by a uniformly random mode with probability
    ``epsilon`` (seeded), for datasets with some exploration."""

    def __init__(self, decider: Any, epsilon: float, seed: int) -> None:
        self.inner, self.epsilon, self.rng = decider, epsilon, np.random.default_rng(seed)
        self.name, self.version = decider.name, decider.version
        self.privileged = getattr(decider, "privileged", False)
        self.weights_sha256 = getattr(decider, "weights_sha256", None)

    def bind(self, core: Any) -> None:
        self.inner.bind(core)

    def reset(self, mask: Any = None) -> None:
        self.inner.reset(mask)

    def act(self, obs: np.ndarray) -> np.ndarray:
        modes = np.asarray(self.inner.act(obs), dtype=np.int64)
        explore = self.rng.random(modes.shape[0]) < self.epsilon
        return np.where(explore, self.rng.integers(0, 3, modes.shape[0]), modes)


class TransitionRecorder:
    """A runner recorder (see benchmark/runner.py) that keeps every transition of every episode:
    per step only the rows still running are kept; one lexsort per chunk groups them by episode."""

    def __init__(self) -> None:
        self.episodes: list[dict[str, np.ndarray]] = []

    def begin_chunk(self, core: Any, scenario_index: np.ndarray) -> None:
        n = core.num
        self.index, self.k = scenario_index, 0
        self.obs_parts = [(np.arange(n), np.zeros(n, np.int64), core.observe(), core.outcome.copy(), core.t.copy())]
        self.step_parts: list[tuple[np.ndarray, ...]] = []

    def record_step(self, core: Any, modes: np.ndarray, res: Any) -> None:
        active = np.flatnonzero(~core.done | res.info["_finished"])  # the rows this step advanced
        self.k += 1
        steps = np.full(active.size, self.k)
        self.obs_parts.append((active, steps, res.obs[active], core.outcome[active].copy(), core.t[active].copy()))
        self.step_parts.append((active, steps, modes[active], res.reward[active], res.terminated[active],
                                res.truncated[active]))

    def end_chunk(self, core: Any) -> None:
        n = core.num
        o_rows, o_steps, o_obs, o_out, o_t = (np.concatenate(c) for c in zip(*self.obs_parts))
        s_rows, s_steps, act, rew, term, trunc = (np.concatenate(c) for c in zip(*self.step_parts))
        o_ord, s_ord = np.lexsort((o_steps, o_rows)), np.lexsort((s_steps, s_rows))
        o_b = np.searchsorted(o_rows[o_ord], np.arange(n + 1))
        s_b = np.searchsorted(s_rows[s_ord], np.arange(n + 1))
        o_obs, o_out, o_t = o_obs[o_ord], o_out[o_ord], o_t[o_ord]
        act, rew, term, trunc = act[s_ord], rew[s_ord], term[s_ord], trunc[s_ord]
        for r in range(n):  # Minari takes one buffer per episode; slicing, not simulation
            oa, ob, sa, sb = o_b[r], o_b[r + 1], s_b[r], s_b[r + 1]
            self.episodes.append({
                "observations": o_obs[oa:ob].astype(np.float32), "actions": act[sa:sb].astype(np.int64),
                "rewards": rew[sa:sb].astype(np.float64), "terminations": term[sa:sb].astype(bool),
                "truncations": trunc[sa:sb].astype(bool),
                "infos": {"outcome": o_out[oa:ob].astype(np.int64), "t": o_t[oa:ob].astype(np.float64),
                          "scenario_index": np.full(ob - oa, self.index[r], np.int64)},
            })


def collect(suite: Any, decider: Any, epsilon: float = 0.0, seed: int = 0, count: int | None = None,
            chunk_size: int = 4096, progress: bool = False) -> list[dict[str, np.ndarray]]:
    """Run ``decider`` (epsilon-random) on the first ``count`` scenarios of ``suite`` through the
    benchmark runner; one dict of arrays per episode, in scenario order."""
    from .runner import run_suite

    recorder = TransitionRecorder()
    run_suite(suite, EpsilonRandom(decider, epsilon, seed), chunk_size=chunk_size, progress=progress,
              recorder=recorder, limit=count)
    return recorder.episodes


def build_dataset(name: str, suite: Any, decider: Any, epsilon: float = 0.1, count: int | None = None,
                  seed: int = 0, chunk_size: int = 4096, overwrite: bool = False) -> Any:
    """Record ``decider`` on ``suite`` (its first ``count`` scenarios) and store a Minari dataset."""
    check_name(name)
    if not 0.0 <= epsilon <= 1.0:
        raise UserError(f"--epsilon {epsilon}: must be in [0, 1]")
    minari = _minari()
    from gymnasium import spaces

    if count is not None and not 1 <= count <= suite.count:
        raise UserError(f"--count {count}: suite {suite.name} has {suite.count} scenarios")
    target = datasets_dir() / name
    if target.exists() and not overwrite:
        raise UserError(f"dataset {name} already exists in {datasets_dir()} (use --overwrite to replace it)")
    check_writable_dir(target.parent)  # fail before recording, not after
    episodes = collect(suite, decider, epsilon=epsilon, seed=seed, count=count, chunk_size=chunk_size)
    num = len(episodes)
    from minari.data_collector import EpisodeBuffer

    buffers = [EpisodeBuffer(id=i, observations=e["observations"], actions=e["actions"], rewards=e["rewards"],
                             terminations=e["terminations"], truncations=e["truncations"], infos=e["infos"])
               for i, e in enumerate(episodes)]
    obs_dim = episodes[0]["observations"].shape[1]
    spec = _env_spec(suite.config)
    description = (f"{decider.name} v{decider.version} on suite {suite.name} v{suite.version} "
                   f"({suite.hash[:12]}), first {num} scenarios, epsilon-random {epsilon}, "
                   f"seed {seed}. One transition per simulator step (dt={suite.config.dt} s).")
    with _staging(target) as staging:  # Minari writes a scratch root; the finished folder is swapped in
        with _minari_path(staging), warnings.catch_warnings():  # Minari nags about optional metadata
            warnings.simplefilter("ignore", UserWarning)
            minari.create_dataset_from_buffers(
                dataset_id=name, buffer=buffers, env=spec, eval_env=spec,
                observation_space=spaces.Box(-np.inf, np.inf, (obs_dim,), np.float32),
                action_space=spaces.Discrete(3), algorithm_name=f"{decider.name} (epsilon={epsilon})",
                author="OvertakeZoo", description=description, data_format="hdf5", requirements=["overtakezoo"])
        _install(staging, name, target)
    return load(name)


@contextlib.contextmanager
def _staging(target: Path) -> Iterator[Path]:
    """A scratch datasets root beside ``target``, removed afterwards (also on Ctrl-C or an error)."""
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(prefix=f".{target.name}.build-", dir=target.parent) as staging:
            yield Path(staging)
    except OSError as exc:
        raise UserError(f"cannot write dataset {target}: {exc.strerror or exc}") from None


def _install(staging: Path, name: str, target: Path) -> None:
    """Swap ``staging/name`` in as ``target`` whole: readers see the old dataset or the new one."""
    if not (staging / name).is_dir():
        raise UserError(f"dataset {name}: nothing was written for it")
    with atomic_directory(target) as tmp:
        tmp.rmdir()
        os.replace(staging / name, tmp)


def _env_spec(config: Any) -> Any:
    """The Gymnasium spec of ``overtakezoo/Overtake-v0`` with the suite's config, so Minari can
    recover the environment; ``None`` when the env face is not available."""
    try:
        import gymnasium

        from overtakezoo.envs.gym_env import ENV_ID

        spec = gymnasium.spec(ENV_ID)
        cfg = json.loads(json.dumps(config.to_dict()))  # plain JSON types for Minari's metadata
        return dataclasses.replace(spec, kwargs={**spec.kwargs, "config": cfg})
    except Exception:  # noqa: BLE001 - the dataset is valid without an env spec
        return None


def load(name: str) -> Any:
    """``minari.load_dataset(name)`` from our datasets folder."""
    check_name(name)
    minari = _minari()
    with _minari_path() as root:
        if not (root / name).is_dir():
            raise UserError(f"no local dataset {name!r} in {root} (see `overtakezoo dataset list`)")
        return minari.load_dataset(name)


def list_datasets() -> dict[str, dict[str, Any]]:
    """Local datasets: name -> metadata (episodes, steps, size)."""
    minari = _minari()
    with _minari_path():
        return dict(minari.list_local_datasets())


# ---------------------------------------------------------------------------- registry + download
def registry_path() -> Path:
    return Path(os.environ.get("OVERTAKEZOO_REGISTRY") or REGISTRY_FILE)


def load_registry() -> dict[str, dict[str, Any]]:
    path = registry_path()
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise UserError(f"cannot read dataset registry {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise UserError(f"dataset registry {path} is not valid JSON: {exc}") from None
    entries = data.get("datasets", {}) if isinstance(data, dict) else None
    if not isinstance(entries, dict):
        raise UserError(f"dataset registry {path}: expected {{\"datasets\": {{name: {{url, size, sha256}}}}}}")
    for name, e in entries.items():
        if not (isinstance(e, dict) and isinstance(e.get("url"), str) and isinstance(e.get("size"), int)
                and isinstance(e.get("sha256"), str) and len(e["sha256"]) == 64):
            raise UserError(f"dataset registry {path}: entry {name!r} needs url (str), size (int), sha256 (64 hex)")
    return entries


def download(name: str, progress: bool = True, chunk: int = 1 << 16, timeout: float = 30.0) -> Path:
    """Fetch, verify and unpack dataset ``name`` from the registry; returns its local folder."""
    registry = load_registry()
    if name not in registry:
        known = ", ".join(sorted(registry)) or "none"
        raise UserError(f"unknown dataset {name!r} (registry {registry_path()} lists: {known})")
    check_name(name)
    entry = registry[name]
    url, size, sha = entry["url"], int(entry["size"]), entry["sha256"].lower()
    if urllib.parse.urlsplit(url).scheme not in ("http", "https"):
        raise UserError(f"refusing {url!r}: only http(s) URLs are downloaded")
    root = datasets_dir()
    downloads = check_writable_dir(cache_dir() / "downloads")
    final = downloads / (name.replace("/", "__") + ".tar.gz")
    part = final.with_name(final.name + ".part")
    if not (final.exists() and _sha256(final) == sha):
        _fetch(url, part, size, progress, chunk, timeout)
        got = _sha256(part)
        if got != sha:
            part.unlink(missing_ok=True)
            raise UserError(f"checksum mismatch for {name}: expected sha256 {sha[:16]}..., got {got[:16]}...; "
                            "deleted the partial file, run the command again")
        os.replace(part, final)
    _extract(final, root, name)
    return root / name


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
            mode = "ab" if have else "wb"
            with open(part, mode) as f, tqdm(total=size, initial=have, unit="B", unit_scale=True,
                                             desc=part.name.removesuffix(".tar.gz.part"),
                                             disable=not progress) as bar:
                while True:
                    block = resp.read(chunk)
                    if not block:
                        break
                    f.write(block)
                    bar.update(len(block))
    except urllib.error.HTTPError as exc:
        raise UserError(f"download of {url} failed: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError, http.client.HTTPException) as exc:
        got = part.stat().st_size if part.exists() else 0
        reason = getattr(exc, "reason", None) or exc
        raise UserError(f"download of {url} interrupted at {got} of {size} bytes ({reason}); "
                        "run the command again to resume") from None
    got = part.stat().st_size
    if got < size:
        raise UserError(f"download of {url} stopped at {got} of {size} bytes; run the command again to resume")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _extract(archive: Path, root: Path, name: str) -> None:
    """Unpack ``archive`` into ``root`` after checking every member lands inside ``root/name``."""
    root = root.resolve()
    target = (root / name).resolve()
    try:
        with tarfile.open(archive, "r:*") as tar:
            members = tar.getmembers()
            for m in members:
                p = PurePosixPath(m.name)
                if (not p.parts or p.is_absolute() or ".." in p.parts or m.name.startswith(("/", "\\"))
                        or ":" in p.parts[0]):
                    raise UserError(f"refusing {archive.name}: member {m.name!r} would land outside {root}")
                if not (m.isfile() or m.isdir()):
                    raise UserError(f"refusing {archive.name}: member {m.name!r} is a link or special file")
                dest = (root / m.name).resolve()
                parent_dir = m.isdir() and dest in target.parents and root in (dest, *dest.parents)
                if dest != target and target not in dest.parents and not parent_dir:
                    raise UserError(f"refusing {archive.name}: member {m.name!r} is outside {name}/")
            with _staging(target) as staging:  # unpacked beside, swapped in whole
                if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4: the stdlib's own safety net too
                    tar.extractall(staging, members=members, filter="data")
                else:
                    tar.extractall(staging, members=members)
                _install(staging, name, target)
    except tarfile.TarError as exc:
        raise UserError(f"{archive}: not a readable .tar.gz dataset archive ({exc})") from None


def pack(name: str, out: str | Path) -> tuple[Path, int, str]:
    """Write local dataset ``name`` as a ``.tar.gz`` for publishing; returns (path, size, sha256)."""
    check_name(name)
    root = datasets_dir()
    if not (root / name).is_dir():
        raise UserError(f"no local dataset {name!r} in {root}")
    out = Path(out)
    with atomic_path(out) as tmp:
        with tarfile.open(tmp, "w:gz") as tar:
            tar.add(root / name, arcname=name)
        size, sha = tmp.stat().st_size, _sha256(tmp)
    return out, size, sha

