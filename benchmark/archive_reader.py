"""Reading OvertakeZoo MCAP archives back: the episode index, one episode, or all of them.

Every failure of the mcap reader (a truncated file, a damaged chunk, bad JSON) becomes one
:class:`~overtakezoo.benchmark.errors.UserError` line.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .archive_format import INF_FIELDS, STATE_TOPICS
from .errors import UserError


@dataclass
class Episode:
    """One archived episode: arrays indexed by step (0 = after reset)."""

    index: int
    scenario: dict[str, Any]
    summary: dict[str, Any]
    t: np.ndarray  # (T+1,)
    ego: dict[str, np.ndarray]  # x, y, psi, v, a, steer: (T+1,)
    npc_s: np.ndarray  # (T+1, M)
    npc_v: np.ndarray  # (T+1, M)
    npc_lane: np.ndarray  # (M,)
    mode: np.ndarray  # (T,) mode applied during step k+1
    rollout: np.ndarray  # (T,)
    offsets: np.ndarray  # (T, R)
    blocked: np.ndarray  # (T, R)
    reward: np.ndarray  # (T,)

    @property
    def outcome(self) -> str:
        return self.summary["outcome_name"]

    @property
    def steps(self) -> int:
        return len(self.reward)


@dataclass
class EpisodeEntry:
    index: int
    start_ns: int
    end_ns: int
    steps: int
    outcome: str
    episode_return: float


def _restore(key: str, value: Any) -> Any:
    if value is None:
        return math.inf if key in INF_FIELDS else math.nan
    if isinstance(value, list):
        return [_restore(key, v) for v in value]
    return value


class _JsonDecoderFactory:
    """mcap ships no JSON decoder: messages with encoding "json" decode to dicts."""

    def decoder_for(self, message_encoding: str, schema: Any):
        if message_encoding == "json":
            return lambda data: json.loads(data)
        return None


def _corrupt(path: Path, exc: BaseException) -> UserError:
    detail = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    return UserError(f"{path}: not a readable MCAP archive (truncated or corrupt: {detail})")


class _Archive:
    """An open archive file; every mcap failure becomes one UserError line."""

    def __init__(self, path: str | os.PathLike) -> None:
        from mcap.reader import make_reader

        self.path = Path(path)
        try:
            self._f = open(self.path, "rb")
        except OSError as exc:
            raise UserError(f"cannot read archive {self.path}: {exc.strerror or exc}") from None
        try:
            self.reader = make_reader(self._f, validate_crcs=True, decoder_factories=[_JsonDecoderFactory()])
            self.summary = self.reader.get_summary()
            if self.summary is None:
                raise ValueError("no summary section (the writer did not finish)")
            meta = {}
            entries = []
            for rec in self.reader.iter_metadata():
                if rec.name == "episode":
                    m = rec.metadata
                    entries.append(EpisodeEntry(int(m["episode"]), int(m["start_ns"]), int(m["end_ns"]),
                                                int(m["steps"]), m["outcome"], float(m["episode_return"])))
                elif rec.name == "overtakezoo":
                    meta = dict(rec.metadata)
        except UserError:
            self._f.close()
            raise
        except Exception as exc:  # mcap raises many types (McapError, EndOfFile, struct.error, zstd errors)
            self._f.close()
            raise _corrupt(self.path, exc) from None
        if "format_version" not in meta:
            self._f.close()
            raise UserError(f"{self.path}: not an OvertakeZoo archive (no overtakezoo metadata record)")
        self.meta = meta
        self.entries = sorted(entries, key=lambda e: e.index)
        self.by_index = {e.index: e for e in self.entries}

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> "_Archive":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def messages(self, start: int | None = None, end: int | None = None) -> Iterator[tuple[str, dict]]:
        """Decoded state messages in file order (the writer wrote them in time order)."""
        loads = json.loads
        try:
            for _, channel, msg in self.reader.iter_messages(
                    topics=list(STATE_TOPICS), starting_at=start, ending_before=end, log_time_order=False):
                yield channel.topic, loads(msg.data)
        except Exception as exc:
            raise _corrupt(self.path, exc) from None

    def episode_range(self, k: int) -> tuple[int, int]:
        if k not in self.by_index:
            known = f"{self.entries[0].index}..{self.entries[-1].index}" if self.entries else "none"
            raise UserError(f"episode {k} is not in {self.path} (episodes: {known}, {len(self.entries)} in all)")
        e = self.by_index[k]
        return e.start_ns, e.end_ns + 1


class _Builder:
    def __init__(self, index: int) -> None:
        self.index = index
        self.spec: dict | None = None
        self.summary: dict | None = None
        self.lists: dict[str, list[dict]] = {t: [] for t in ("/ego", "/npcs", "/decision", "/planner", "/reward")}
        self.ego, self.npcs, self.dec, self.plan, self.rew = self.lists.values()

    def add(self, topic: str, msg: dict) -> None:
        if topic == "/episode/spec":
            self.spec = msg
        elif topic == "/episode/summary":
            self.summary = msg
        else:
            self.lists[topic].append(msg)

    def build(self, path: Path) -> Episode:
        if self.spec is None or self.summary is None or not self.ego:
            raise UserError(f"{path}: episode {self.index} is incomplete (truncated or corrupt archive)")
        # Per-step floats are finite unless written as null (then NaN); float() keeps them exact.
        col = lambda rows, key: np.array([r[key] for r in rows], dtype=float)  # noqa: E731
        scen = {k: _restore(k, v) for k, v in self.spec["scenario"].items()}
        summary = {k: _restore(k, v) for k, v in self.summary.items()}
        m = len(scen["npc_s"])
        r = len(self.plan[0]["offsets"]) if self.plan else 0
        return Episode(
            index=self.index, scenario=scen, summary=summary, t=col(self.ego, "t"),
            ego={k: col(self.ego, k) for k in ("x", "y", "psi", "v", "a", "steer")},
            npc_s=np.array([n["s"] for n in self.npcs], dtype=float).reshape(-1, m),
            npc_v=np.array([n["v"] for n in self.npcs], dtype=float).reshape(-1, m),
            npc_lane=np.array(self.npcs[0]["lane"], dtype=np.int8),
            mode=np.array([d["mode"] for d in self.dec], dtype=np.int64),
            rollout=np.array([p["rollout"] for p in self.plan], dtype=np.int64),
            offsets=np.array([p["offsets"] for p in self.plan], dtype=float).reshape(-1, r),
            blocked=np.array([p["blocked"] for p in self.plan], dtype=bool).reshape(-1, r),
            reward=col(self.rew, "reward"),
        )


def list_episodes(path: str | os.PathLike) -> list[EpisodeEntry]:
    """Episode index, time range and outcome of every episode, from the summary section only."""
    with _Archive(path) as ar:
        return list(ar.entries)


def read_archive_meta(path: str | os.PathLike) -> dict[str, str]:
    with _Archive(path) as ar:
        return dict(ar.meta)


def read_episode(path: str | os.PathLike, k: int) -> Episode:
    """Episode ``k`` (its global scenario index), reading only the chunks of its time window."""
    with _Archive(path) as ar:
        start, end = ar.episode_range(int(k))
        b = _Builder(int(k))
        for topic, msg in ar.messages(start, end):
            if msg.get("episode") == k:
                b.add(topic, msg)
        return b.build(ar.path)


def read_archive(path: str | os.PathLike) -> list[Episode]:
    """Every episode of the archive, in scenario order."""
    with _Archive(path) as ar:
        builders: dict[int, _Builder] = {}
        for topic, msg in ar.messages():
            ep = msg["episode"]
            if ep not in builders:
                builders[ep] = _Builder(ep)
            builders[ep].add(topic, msg)
        missing = set(ar.by_index) - set(builders)
        if missing:
            raise UserError(f"{ar.path}: episodes {sorted(missing)[:5]} listed but have no data (corrupt archive)")
        return [builders[k].build(ar.path) for k in sorted(builders)]


