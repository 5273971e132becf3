"""Batched message writes into an open ``mcap.writer.Writer`` (the archive's hot path)."""

from __future__ import annotations

import collections
from typing import Any

import numpy as np
from mcap.opcode import Opcode
from mcap.records import MessageIndex

FAST_WRITES = True  # append messages to mcap's open chunk directly (see MessageSink); False: public API only


class MessageSink:
    """Queues (channel, log_time, data) and hands them to the mcap Writer in batches.

    ``Writer.add_message`` builds a Message object and packs it field by field (about 8 us a message,
    most of an archive's write time before this). When the Writer has the internals of mcap 1.x, a
    batch is appended to its open chunk at once: record headers packed by numpy, one bytes join,
    the same statistics, chunk message indexes and chunk-size rule as ``add_message``; otherwise
    (another mcap version) it falls back to ``add_message``. tests/test_archive.py checks that both
    paths write byte-identical files.
    """

    def __init__(self, writer: Any, fast: bool | None = None) -> None:
        fast = FAST_WRITES if fast is None else fast
        self.writer = writer
        self.pending: list[tuple[int, int, bytes]] = []
        self.append = self.pending.append
        names = ("_Writer__chunk_builder", "_Writer__statistics", "_Writer__chunk_size", "_Writer__finalize_chunk")
        cb = getattr(writer, names[0], None)
        self.fast = fast and all(hasattr(writer, n) for n in names) and cb is not None and all(
            hasattr(cb, n) for n in ("record_writer", "message_indices", "num_messages", "message_start_time",
                                     "message_end_time")) and hasattr(cb.record_writer, "_buffer")

    def flush(self) -> None:
        batch = self.pending[:]
        self.pending.clear()
        if not batch:
            return
        w = self.writer
        if not self.fast:
            for ch, t, data in batch:
                w.add_message(ch, t, data, t)
            return
        stats, limit = w._Writer__statistics, w._Writer__chunk_size
        cb = w._Writer__chunk_builder
        n = len(batch)
        chans, times, datas = zip(*batch)
        ch_arr = np.array(chans, dtype=np.int64)
        t_arr = np.array(times, dtype=np.uint64)
        sizes = np.fromiter(map(len, datas), np.int64, n)
        heads = np.zeros(n, dtype=_RECORD_HEAD)
        heads["opcode"], heads["length"], heads["channel"] = 0x05, 22 + sizes, ch_arr
        heads["log_time"] = heads["publish_time"] = t_arr
        raw = heads.tobytes()
        # Headers and payloads interleaved, built by slice assignment (C loops, not per-message Python).
        parts: list[bytes] = [b""] * (2 * n)
        parts[0::2] = map(raw.__getitem__, map(slice, range(0, 31 * n, 31), range(31, 31 * n + 1, 31)))
        parts[1::2] = datas
        ends = np.cumsum(31 + sizes)  # record ends relative to the batch start
        i = 0
        while i < n:
            buf = cb.record_writer._buffer
            start = buf.tell() - (int(ends[i - 1]) if i else 0)
            # Writer.__maybe_finalize_chunk closes the chunk after the first message that passes the limit.
            over = np.flatnonzero(start + ends[i:] > limit)
            j = i + int(over[0]) + 1 if over.size else n
            offsets = start + ends[i:j] - (31 + sizes[i:j])
            seg_ch, seg_t = ch_arr[i:j], t_arr[i:j]
            for ch in dict.fromkeys(chans[i:j]):  # first-seen order: the chunk's message indexes follow it
                mask = seg_ch == ch
                index = cb.message_indices.get(ch)
                if index is None:
                    index = cb.message_indices[ch] = FastMessageIndex(channel_id=ch, records=[])
                index.records.append(np.stack([seg_t[mask], offsets[mask].astype(np.uint64)], axis=1))
            buf.write(b"".join(parts[2 * i:2 * j]))
            lo, hi = int(seg_t.min()), int(seg_t.max())
            cb.message_start_time = lo if cb.num_messages == 0 else min(lo, cb.message_start_time)
            cb.message_end_time = max(hi, cb.message_end_time)
            cb.num_messages += j - i
            if over.size:
                w._Writer__finalize_chunk()
            i = j
        lo, hi = int(t_arr.min()), int(t_arr.max())
        stats.message_start_time = lo if stats.message_count == 0 else min(lo, stats.message_start_time)
        stats.message_end_time = max(hi, stats.message_end_time)
        stats.message_count += n
        for ch, count in collections.Counter(chans).items():  # first-seen order, as add_message keeps it
            stats.channel_message_counts[ch] += count


# A Message record's fixed part: opcode, record length, channel, sequence, log time, publish time.
_RECORD_HEAD = np.dtype([("opcode", "u1"), ("length", "<u8"), ("channel", "<u2"), ("sequence", "<u4"),
                         ("log_time", "<u8"), ("publish_time", "<u8")])  # packed: 31 bytes


class FastMessageIndex(MessageIndex):
    """mcap's MessageIndex holding its (log time, offset) pairs as (k, 2) uint64 arrays, one per
    batch, written in one buffer instead of two ``write8`` calls per message (identical bytes:
    little-endian u64 pairs)."""

    def write(self, stream: Any) -> None:
        pairs = np.concatenate(self.records) if self.records else np.zeros((0, 2), np.uint64)
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(pairs) * 16)
        stream.write(pairs.astype("<u8").tobytes())
        stream.finish_record()
