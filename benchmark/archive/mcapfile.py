"""A minimal MCAP writer for pre-built record blocks (the archive's write path).

mcap's ``Writer.add_message`` builds and packs one Message object per call (microseconds each;
an archive of table1 has millions of messages) and compresses chunks with ``zstandard.compress``
at level 3, with no way to choose. The archive's messages are built by numpy as whole Message
records (:mod:`.cdr`), so this writer takes a block of records with their channels, times and
sizes, and writes chunks, message indexes and the summary itself, with mcap's own record classes
(``mcap.records``) for the few records per file, and packs the many ones itself (chunks, message
indexes as numpy little-endian (log time, offset) u64 pairs, metadata), as the spec lays them out
(https://mcap.dev/spec). The file is a
plain MCAP file: mcap's readers (Python and TypeScript, CRCs checked) read it; tests/benchmark/test_archive.py
checks that.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any

import numpy as np
import zstandard
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, ChunkIndex, DataEnd, Footer, Header, MetadataIndex, Schema, Statistics, SummaryOffset
from mcap.writer import MCAP0_MAGIC

# zstd's fast levels on this format's chunks: level -3 compresses about three times as fast as mcap's
# Writer (level 3) for about a tenth more bytes; the measured speeds and ratios are in
# docs/archive-overhead.json (scripts/archive_overhead.py --breakdown --json), shown on
# docs/archive-overhead.md.
ZSTD_LEVEL = -3


def _string(text: str) -> bytes:
    data = text.encode()
    return struct.pack("<I", len(data)) + data


class McapFile:
    """Writes an MCAP file to ``stream`` (anything with write/flush; offsets are counted here, so a
    FIFO works). Schemas and channels go at the start of the data section (outside chunks, so a
    reader of a cut file finds them first), then :meth:`write_chunk` blocks and :meth:`add_metadata`
    records, then :meth:`finish` writes the summary (schemas, channels, statistics, chunk and
    metadata indexes, summary offsets) and the footer with its CRC."""

    def __init__(self, stream: Any, profile: str = "", library: str = "overtakezoo") -> None:
        self._stream = stream
        self._pos = 0
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
        self.schemas: list[Schema] = []
        self.channels: list[Channel] = []
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._counts: dict[int, int] = {}
        self._stats = [0, None, None]  # message count, start, end
        self._write(MCAP0_MAGIC)
        self._record(Header(profile=profile, library=library))

    def _write(self, data: bytes) -> None:
        self._stream.write(data)
        self._pos += len(data)

    def _record(self, rec: Any) -> int:
        b = RecordBuilder()
        rec.write(b)
        data = b.end()
        start = self._pos
        self._write(data)
        return start

    def register(self, topic: str, schema_name: str, encoding: str, schema: bytes, message_encoding: str) -> int:
        sid = next((s.id for s in self.schemas if s.name == schema_name and s.data == schema), None)
        if sid is None:
            sid = len(self.schemas) + 1
            self.schemas.append(Schema(id=sid, name=schema_name, encoding=encoding, data=schema))
            self._record(self.schemas[-1])
        cid = len(self.channels) + 1
        self.channels.append(
            Channel(id=cid, topic=topic, message_encoding=message_encoding, schema_id=sid, metadata={})
        )
        self._record(self.channels[-1])
        self._counts[cid] = 0
        return cid

    def write_chunk(self, parts: list, channel: np.ndarray, log_time: np.ndarray, size: np.ndarray) -> None:
        """One chunk of whole Message records (the buffers ``parts``, in file order: compressed and
        CRC'd piece by piece, never joined), with each record's channel, log time and byte size
        (header included)."""
        if not len(size):
            return
        offsets = np.concatenate([[0], np.cumsum(size[:-1])]).astype(np.uint64)
        lo, hi = int(log_time.min()), int(log_time.max())
        total, crc = int(size.sum()), 0
        z = self._zstd.compressobj(size=total)
        packed = []
        for part in parts:
            crc = zlib.crc32(part, crc)
            packed.append(z.compress(part))
        packed.append(z.flush())
        # The Chunk record, packed here so the compressed pieces go out without being joined
        # (https://mcap.dev/spec#chunk-op0x06): start, end, uncompressed size and CRC, compression, records.
        size_c = sum(map(len, packed))
        head = struct.pack("<QQQI", lo, hi, total, crc) + _string("zstd") + struct.pack("<Q", size_c)
        start = self._pos
        self._write(struct.pack("<BQ", Opcode.CHUNK, len(head) + size_c) + head)
        for piece in packed:
            self._write(piece)
        chunk_length = self._pos - start
        index_offsets: dict[int, int] = {}
        # Message indexes, per channel in id order, entries by log time (stable: file order on ties).
        order = np.lexsort((log_time, channel))
        ch_sorted = channel[order]
        bounds = np.flatnonzero(np.diff(ch_sorted)) + 1
        parts = []
        pos = self._pos
        for seg in np.split(order, bounds):
            cid = int(channel[seg[0]])
            pairs = np.stack([log_time[seg].astype(np.uint64), offsets[seg]], axis=1).astype("<u8").tobytes()
            index_offsets[cid] = pos
            parts.append(struct.pack("<BQHI", Opcode.MESSAGE_INDEX, 2 + 4 + len(pairs), cid, len(pairs)) + pairs)
            pos += len(parts[-1])
            self._counts[cid] += len(seg)
        blob = b"".join(parts)
        self._write(blob)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=lo,
                message_end_time=hi,
                chunk_start_offset=start,
                chunk_length=chunk_length,
                message_index_offsets=index_offsets,
                message_index_length=len(blob),
                compression="zstd",
                compressed_size=size_c,
                uncompressed_size=total,
            )
        )
        st = self._stats
        st[0] += len(size)
        st[1] = lo if st[1] is None else min(st[1], lo)
        st[2] = hi if st[2] is None else max(st[2], hi)

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """A Metadata record, packed here (one per episode: mcap's RecordBuilder costs ~70 us a
        record, a tenth of the archive's budget per episode). Layout: opcode, length, name, then
        the map as its byte length and (key, value) string pairs (https://mcap.dev/spec#metadata-op0x0c)."""
        pairs = b"".join(_string(k) + _string(v) for k, v in data.items())
        body = _string(name) + struct.pack("<I", len(pairs)) + pairs
        start = self._pos
        self._write(struct.pack("<BQ", Opcode.METADATA, len(body)) + body)
        self._metadata_indexes.append(MetadataIndex(offset=start, length=self._pos - start, name=name))

    def flush(self) -> None:
        self._stream.flush()

    def finish(self) -> None:
        self._record(DataEnd(data_section_crc=0))  # 0: not computed (the chunks carry their own CRCs)
        summary_start = self._pos
        b = RecordBuilder()
        offsets = []
        st = self._stats
        groups = [
            (Opcode.SCHEMA, self.schemas),
            (Opcode.CHANNEL, self.channels),
            (
                Opcode.STATISTICS,
                [
                    Statistics(
                        message_count=st[0],
                        schema_count=len(self.schemas),
                        channel_count=len(self.channels),
                        attachment_count=0,
                        metadata_count=len(self._metadata_indexes),
                        chunk_count=len(self._chunk_indexes),
                        message_start_time=st[1] or 0,
                        message_end_time=st[2] or 0,
                        channel_message_counts=dict(self._counts),
                    )
                ],
            ),
            (Opcode.CHUNK_INDEX, self._chunk_indexes),
            (Opcode.METADATA_INDEX, self._metadata_indexes),
        ]
        for opcode, recs in groups:
            if not recs:
                continue
            start = b.count
            for rec in recs:
                rec.write(b)
            offsets.append(
                SummaryOffset(group_opcode=opcode, group_start=summary_start + start, group_length=b.count - start)
            )
        summary_offset_start = summary_start + b.count
        for off in offsets:
            off.write(b)
        summary = b.end()
        crc = zlib.crc32(
            struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), zlib.crc32(summary)
        )
        self._write(summary)
        self._record(Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(MCAP0_MAGIC)
        self._stream.flush()
