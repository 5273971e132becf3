"""Fixed-shape CDR messages as numpy record templates (the archive's encoder).

ROS 2 serializes a message as CDR (little-endian, XCDR1): a 4-byte encapsulation header
``00 01 00 00``, then the fields in order, each primitive aligned to its size counted from the end
of that header, strings as a uint32 length (with the terminating NUL) plus the bytes, sequences as
a uint32 count plus the elements (https://design.ros2.org/articles/generated_interfaces_cpp.html,
OMG CDR; the rules @foxglove/cdr and mcap_ros2 read). A message whose strings and sequence lengths
are fixed is therefore one byte template with numeric slots at fixed offsets: a :class:`Layout`
describes it once, and :meth:`Layout.fill` writes ``n`` messages in one numpy pass (no Python per
message), each preceded by its MCAP Message record header (opcode, length, channel, sequence, log
and publish time: https://mcap.dev/spec#message-op0x05) so the rows are whole MCAP records.
"""

from __future__ import annotations

import struct

import numpy as np

RECORD_HEAD = (
    31  # MCAP Message record: opcode u8, length u64, channel u16, sequence u32, log_time u64, publish_time u64
)
ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR little-endian
_SIZES = {"u1": 1, "<u2": 2, "<u4": 4, "<i4": 4, "<u8": 8, "<f8": 8}


class Layout:
    """One message shape: constants written once, named slots filled per message.

    ``slot(name, fmt, count)`` reserves ``count`` consecutive primitives (a fixed part of a
    sequence or several scalars of one struct in a row); the names become fields of :attr:`dtype`
    (offsets into the whole record, header included)."""

    def __init__(self, channel: int) -> None:
        self.buf = bytearray(struct.pack("<BQHIQQ", 0x05, 0, channel, 0, 0, 0)) + ENCAPSULATION
        self.fields: dict[str, tuple[str, int, int]] = {
            "channel": ("<u2", 9, 1),
            "log_time": ("<u8", 15, 1),
            "publish_time": ("<u8", 23, 1),
        }
        self._dtype: np.dtype | None = None

    def _align(self, size: int) -> None:
        self.buf += b"\0" * (-(len(self.buf) - RECORD_HEAD - 4) % size)

    def const(self, fmt: str, *values: float) -> Layout:
        size = _SIZES[fmt]
        if size > 1:
            self._align(size)
        self.buf += np.array(values, dtype=fmt).tobytes()
        return self

    def f8(self, *values: float) -> Layout:
        return self.const("<f8", *values)

    def u4(self, *values: int) -> Layout:
        return self.const("<u4", *values)

    def u1(self, *values: int) -> Layout:
        return self.const("u1", *values)

    def string(self, text: str) -> Layout:
        data = text.encode() + b"\0"
        self.u4(len(data))
        self.buf += data
        return self

    def slot(self, name: str, fmt: str, count: int = 1) -> Layout:
        size = _SIZES[fmt]
        if size > 1:
            self._align(size)
        self.fields[name] = (fmt, len(self.buf), count)
        self.buf += b"\0" * (size * count)
        return self

    def text(self, name: str, width: int) -> Layout:
        """A string slot of exactly ``width`` bytes (the writer pads with spaces) plus its NUL."""
        self.u4(width + 1)
        self.fields[name] = (f"S{width}", len(self.buf), 1)
        self.buf += b" " * width + b"\0"
        return self

    @property
    def size(self) -> int:
        return len(self.buf)

    @property
    def dtype(self) -> np.dtype:
        if self._dtype is None:
            self.buf[1:9] = struct.pack("<Q", len(self.buf) - 9)  # the record's length field
            names = list(self.fields)
            formats = [f if c == 1 else (f, (c,)) for f, _, c in self.fields.values()]
            self._dtype = np.dtype(
                {
                    "names": names,
                    "formats": formats,
                    "offsets": [o for _, o, _ in self.fields.values()],
                    "itemsize": len(self.buf),
                }
            )
        return self._dtype

    def fill(self, n: int, **values: object) -> np.ndarray:
        """``n`` records: the template, then each named slot set from ``values`` (arrays or scalars)."""
        dt = self.dtype
        rows = np.empty(n, dt)
        rows.view(np.uint8).reshape(n, len(self.buf))[:] = np.frombuffer(bytes(self.buf), np.uint8)
        for name, value in values.items():
            rows[name] = value
        return rows

    def payload_dtype(self) -> np.dtype:
        """The same slots as offsets into the message data (no record header), for reading."""
        return _payload(self.dtype)

    def payload(self) -> bytes:
        """The message data of the template (for tests and the schema check)."""
        self.dtype  # noqa: B018 (the property fills in the record's length field on first use)
        return bytes(self.buf[RECORD_HEAD:])


def _payload(dt: np.dtype) -> np.dtype:
    names = [k for k in dt.names if k not in ("channel", "log_time", "publish_time")]
    return np.dtype(
        {
            "names": names,
            "formats": [dt.fields[k][0] for k in names],
            "offsets": [dt.fields[k][1] - RECORD_HEAD for k in names],
            "itemsize": dt.itemsize - RECORD_HEAD,
        }
    )
