"""Reading OvertakeZoo MCAP archives back: the episode index, one episode, or all of them.

Every failure of the mcap reader (a damaged chunk, bad JSON, a file with no whole episode)
becomes one :class:`~overtakezoo.benchmark.errors.UserError` line. A file without a readable
summary section (cut by a killed writer, truncated in a copy) is read by a scan of its records: its
whole episodes are those closed by their ``episode`` metadata record (the writer puts that record
after the episode's last chunk), and :attr:`ArchiveIndex.note` says in one line what was lost.
"""

from __future__ import annotations

import functools
import io
import json
import math
import os
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from overtakezoo.benchmark.archive.cdr import RECORD_HEAD
from overtakezoo.benchmark.archive.format import FORMAT_VERSION, INF_FIELDS, STATE_TOPICS
from overtakezoo.benchmark.errors import UserError
from overtakezoo.benchmark.memory_cap import memory_cap, out_of_memory
from overtakezoo.envs import safe_json

# A chunk's records are inflated at most this far: the recorder writes chunks of ~4 MiB of whole
# episodes (one long episode's scene a few MiB more), so a chunk declaring or inflating past 256 MiB is a bomb.
MAX_CHUNK_BYTES = 256 << 20


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


@dataclass
class ArchiveIndex:
    """What :func:`read_index` finds: the whole episodes, the run's metadata, and ``note`` (None
    for a complete file; one line saying what was recovered and what was lost otherwise)."""

    entries: list[EpisodeEntry]
    meta: dict[str, str]
    note: str | None


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
    if out_of_memory(exc):  # not a damaged file: past the memory cap, which says so
        raise exc
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
        self.note: str | None = None
        self._chunks: list[tuple[int, int, int]] = []  # (offset, start, end): from the summary, or scanned
        self._topics: dict[int, str] = {}  # scanned channels
        try:
            self.reader = make_reader(self._f, validate_crcs=True, decoder_factories=[_JsonDecoderFactory()])
            try:
                summary = self.reader.get_summary()
            except Exception as exc:  # a cut file: its end is not a footer
                if out_of_memory(exc):
                    raise
                summary = None
            if summary is None:
                meta, entries = self._scan()
            else:  # its chunks are read here too (bounded, :func:`_inflate`), never by mcap's reader
                self._topics = {cid: ch.topic for cid, ch in summary.channels.items()}
                self._chunks = sorted(
                    (ci.chunk_start_offset, ci.message_start_time, ci.message_end_time)
                    for ci in summary.chunk_indexes
                    if any(self._topics.get(c) in STATE_TOPICS for c in ci.message_index_offsets)
                )
                meta, entries = {}, []
                for rec in self.reader.iter_metadata():
                    if rec.name == "episode":
                        entries.append(_entry(rec.metadata))
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
        if meta["format_version"] != FORMAT_VERSION:  # 2 (JSON per step) is not read: re-record it
            self._f.close()
            raise UserError(
                f"{self.path}: archive format {meta['format_version']} is not readable by this version "
                f"(it reads format {FORMAT_VERSION}; record the run again with eval --archive)"
            )
        self.meta = meta
        self.entries = sorted(entries, key=lambda e: e.index)
        self.by_index = {e.index: e for e in self.entries}

    def _scan(self) -> tuple[dict[str, str], list[EpisodeEntry]]:
        """Index a file without a summary section record by record (chunks are skipped, not read)."""
        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Channel, Metadata
        from mcap.stream_reader import read_magic

        f, size = self._f, os.fstat(self._f.fileno()).st_size
        f.seek(0)
        read_magic(ReadDataStream(f))
        meta: dict[str, str] = {}
        entries: list[EpisodeEntry] = []
        chunks: list[tuple[int, int, int]] = []
        complete = False
        while True:
            pos = f.tell()
            head = f.read(9)
            if len(head) < 9:
                break
            opcode, length = struct.unpack("<BQ", head)
            if pos + 9 + length > size:
                break  # the record runs past the end: the cut
            if opcode == Opcode.CHUNK:
                chunks.append((pos, *struct.unpack("<QQ", f.read(16))))
                f.seek(pos + 9 + length)
            elif opcode == Opcode.CHANNEL:  # the writer puts them before the first chunk
                rec = Channel.read(ReadDataStream(io.BytesIO(f.read(length))))
                self._topics[rec.id] = rec.topic
            elif opcode == Opcode.METADATA:
                rec = Metadata.read(ReadDataStream(io.BytesIO(f.read(length))))
                if rec.name == "episode":
                    entries.append(_entry(rec.metadata))
                elif rec.name == "overtakezoo":
                    meta = dict(rec.metadata)
            elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                complete = True
                break
            else:
                f.seek(pos + 9 + length)
        self._chunks = chunks
        if not entries:
            raise UserError(f"{self.path}: archive cut before its first whole episode: nothing to read")
        last = entries[-1].index  # in file order: the last episode closed before the cut
        self.note = (
            f"archive index damaged, rebuilt from the data: {len(entries)} whole episodes, none lost"
            if complete
            else f"archive cut after episode {last}: {len(entries)} whole episodes, the rest lost"
        )
        return meta, entries

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> _Archive:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def messages(self, start: int | None = None, end: int | None = None) -> Iterator[tuple[str, bytes]]:
        """The reader's topics' messages (their data), in time order per topic."""
        try:
            yield from self._chunk_messages(start, end)
        except UserError:
            raise
        except Exception as exc:
            raise _corrupt(self.path, exc) from None

    def _chunk_messages(self, start: int | None, end: int | None) -> Iterator[tuple[str, bytes]]:
        """:meth:`messages`: those of the chunks overlapping [start, end), in file order, each chunk
        inflated within :data:`MAX_CHUNK_BYTES` (:func:`_inflate`), CRCs checked."""
        import dataclasses

        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Chunk, Message
        from mcap.stream_reader import breakup_chunk

        lo, hi = (start or 0), (end if end is not None else 1 << 64)
        topics = self._topics
        wanted = set(STATE_TOPICS)
        size = os.fstat(self._f.fileno()).st_size
        for pos, first, last in self._chunks:
            if last < lo or first >= hi:
                continue
            self._f.seek(pos)
            head = self._f.read(9)
            opcode, length = struct.unpack("<BQ", head) if len(head) == 9 else (None, 0)
            if opcode != Opcode.CHUNK or pos + 9 + length > size:  # (never read a length the file does not hold)
                raise ValueError(f"no whole chunk record at offset {pos}")
            chunk = Chunk.read(ReadDataStream(io.BytesIO(self._f.read(length))))
            plain = dataclasses.replace(chunk, compression="", data=_inflate(self.path, pos, chunk))
            for rec in breakup_chunk(plain, validate_crc=True):
                if isinstance(rec, Message) and lo <= rec.log_time < hi and topics.get(rec.channel_id) in wanted:
                    yield topics[rec.channel_id], rec.data

    def episode_range(self, k: int) -> tuple[int, int]:
        if k not in self.by_index:
            known = f"{self.entries[0].index}..{self.entries[-1].index}" if self.entries else "none"
            raise UserError(f"episode {k} is not in {self.path} (episodes: {known}, {len(self.entries)} in all)")
        e = self.by_index[k]
        return e.start_ns, e.end_ns + 1


def _inflate(path: Path, pos: int, chunk: Any) -> bytes:
    """A chunk's records, decompressed with a bounded output: refused (:class:`UserError`) when its declared
    ``uncompressed_size`` is over :data:`MAX_CHUNK_BYTES`, or when its data inflates past that size (read
    at most one byte further: a bomb never inflates whole)."""
    declared = int(chunk.uncompressed_size)
    if declared > MAX_CHUNK_BYTES:
        raise UserError(
            f"{path}: the chunk at offset {pos} declares {declared} bytes uncompressed, at most "
            f"{MAX_CHUNK_BYTES} are read (a decompression bomb, not an OvertakeZoo archive)"
        )
    limit = declared + 1
    if chunk.compression == "zstd":
        import zstandard

        out = bytearray()
        with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(chunk.data), read_across_frames=True) as r:
            while len(out) < limit:
                piece = r.read(min(1 << 20, limit - len(out)))
                if not piece:
                    break
                out += piece
        data = bytes(out)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=limit)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise UserError(
            f"{path}: the chunk at offset {pos} is compressed with {chunk.compression!r} (this reads zstd, lz4 or none)"
        )
    if len(data) != declared:
        how = "past" if len(data) > declared else "short of"
        raise UserError(
            f"{path}: the chunk at offset {pos} inflates {how} its declared {declared} bytes "
            "(a decompression bomb, or a corrupt archive)"
        )
    return data


class _Builder:
    """One episode's messages: the spec and summary (JSON), the /state records (CDR)."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.spec: dict | None = None
        self.summary: dict | None = None
        self.state: list[bytes] = []

    def add(self, topic: str, data: bytes) -> None:
        if topic == "/state":
            self.state.append(data)
        elif topic == "/episode/spec":
            self.spec = safe_json.loads(data, f"episode {self.index}: its {topic} message")
        elif topic == "/episode/summary":
            self.summary = safe_json.loads(data, f"episode {self.index}: its {topic} message")

    def build(self, path: Path) -> Episode:
        if self.spec is None or self.summary is None or not self.state:
            raise UserError(f"{path}: episode {self.index} is incomplete (truncated or corrupt archive)")
        scen = {k: _restore(k, v) for k, v in self.spec["scenario"].items()}
        summary = {k: _restore(k, v) for k, v in self.summary.items()}
        st = _decode_state(path, self.state, len(scen["npc_s"]))
        if not (st["episode"] == self.index).all() or not np.array_equal(st["step"], np.arange(len(st))):
            raise UserError(f"{path}: episode {self.index} has misplaced state messages (corrupt archive)")
        return Episode(
            index=self.index,
            scenario=scen,
            summary=summary,
            t=st["t"].copy(),
            ego={k: st[k].copy() for k in ("x", "y", "psi", "v", "a", "steer")},
            npc_s=st["npc_s"].copy(),
            npc_v=st["npc_v"].copy(),
            npc_lane=np.array(scen["npc_lane"], dtype=np.int8),
            mode=st["mode"][1:].astype(np.int64),
            rollout=st["rollout"][1:].astype(np.int64),
            offsets=st["offsets"][1:].copy(),
            blocked=st["blocked"][1:].astype(bool),
            reward=st["reward"][1:].copy(),
        )


@functools.lru_cache(maxsize=16)
def _state_template(m: int, size: int) -> tuple[np.dtype, bytes, np.ndarray]:
    """The /state layout for M NPC slots whose messages are ``size`` bytes (R follows from it): its
    dtype, template and which bytes are constants (sequence lengths, padding, the CDR header)."""
    from overtakezoo.benchmark.archive.recorder import state_layout

    for r in range(64):
        lay = state_layout(0, m, r)
        if lay.size - RECORD_HEAD == size:
            dt = lay.payload_dtype()
            const = np.ones(size, bool)
            for name in dt.names:
                fmt, off = dt.fields[name][:2]
                const[off : off + fmt.itemsize] = False
            return dt, lay.payload(), const
    raise ValueError(f"no /state layout of {size} bytes for {m} NPC slots")


def _decode_state(path: Path, msgs: list[bytes], m: int) -> np.ndarray:
    """The /state messages of one episode as one structured array (fixed layout: numpy, no per-message work)."""
    size = len(msgs[0])
    blob = b"".join(msgs)
    try:
        dt, template, const = _state_template(m, size)
        if len(blob) != size * len(msgs):
            raise ValueError("messages of different sizes")
        raw = np.frombuffer(blob, np.uint8).reshape(len(msgs), size)
        if not (raw[:, const] == np.frombuffer(template, np.uint8)[const]).all():
            raise ValueError("not the /state layout")
    except ValueError as exc:
        raise UserError(f"{path}: unreadable /state messages ({exc})") from None
    return np.frombuffer(blob, dt)


def _entry(m: dict[str, str]) -> EpisodeEntry:
    return EpisodeEntry(
        int(m["episode"]),
        int(m["start_ns"]),
        int(m["end_ns"]),
        int(m["steps"]),
        m["outcome"],
        float(m["episode_return"]),
    )


def _capped(read: Any) -> Any:
    """``read(path, ...)`` under a memory cap (benchmark/memory_cap.py): an archive is an outside file."""

    @functools.wraps(read)
    def wrapper(path: str | os.PathLike, *args: Any) -> Any:
        with memory_cap(f"archive {path}"):
            return read(path, *args)

    return wrapper


@_capped
def read_index(path: str | os.PathLike) -> ArchiveIndex:
    """The whole episodes (index, time range, outcome), the run's metadata, and a note if the file
    was cut; from the summary section only (or a scan of the record headers of a cut file)."""
    with _Archive(path) as ar:
        return ArchiveIndex(list(ar.entries), dict(ar.meta), ar.note)


def list_episodes(path: str | os.PathLike) -> list[EpisodeEntry]:
    """Episode index, time range and outcome of every (whole) episode."""
    return read_index(path).entries


@_capped
def read_archive_meta(path: str | os.PathLike) -> dict[str, str]:
    with _Archive(path) as ar:
        return dict(ar.meta)


@_capped
def read_episode(path: str | os.PathLike, k: int) -> Episode:
    """Episode ``k`` (its global scenario index), reading only the chunks of its time window."""
    with _Archive(path) as ar:
        start, end = ar.episode_range(int(k))
        b = _Builder(int(k))
        try:
            for topic, data in ar.messages(start, end):
                b.add(topic, data)
        except safe_json.JSONInputError as exc:
            raise UserError(f"{ar.path}: {exc}") from None
        return b.build(ar.path)


@_capped
def read_archive(path: str | os.PathLike) -> list[Episode]:
    """Every (whole) episode of the archive, in scenario order."""
    with _Archive(path) as ar:
        builders: dict[int, _Builder] = {}
        try:
            for topic, data in ar.messages():
                ep = _episode_of(topic, data)
                if ep not in ar.by_index:  # the part of an episode a cut file lost
                    continue
                if ep not in builders:
                    builders[ep] = _Builder(ep)
                builders[ep].add(topic, data)
        except safe_json.JSONInputError as exc:
            raise UserError(f"{ar.path}: {exc}") from None
        missing = set(ar.by_index) - set(builders)
        if missing:
            raise UserError(f"{ar.path}: episodes {sorted(missing)[:5]} listed but have no data (corrupt archive)")
        return [builders[k].build(ar.path) for k in sorted(builders)]


def _episode_of(topic: str, data: bytes) -> int:
    if topic == "/state":  # the first field after the CDR header
        return struct.unpack_from("<I", data, 4)[0]
    return safe_json.loads(data, f"a {topic} message")["episode"]
