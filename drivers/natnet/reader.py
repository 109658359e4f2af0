"""Bounds-checked little-endian cursor over a NatNet payload, shared by the frame and model-definition parsers.

Every read checks the remaining length first and raises :class:`~drivers.errors.ProtocolError` on a short
packet, so a parser never returns half-parsed data. Strings are searched in one bytes copy of the payload
made once, so reading N strings costs O(total length), not O(N x length).
"""

from __future__ import annotations

import struct
from typing import Any

from drivers.errors import ProtocolError

DEVICE = "natnet"
I32 = struct.Struct("<i")


class Reader:
    """A cursor over ``data``; ``offset`` is the next byte to read."""

    def __init__(self, data: bytes | memoryview) -> None:
        self.raw = bytes(data)
        self.data = memoryview(self.raw)
        self.offset = 0

    @property
    def remaining(self) -> int:
        """Bytes left after the cursor."""
        return len(self.raw) - self.offset

    def take(self, n: int, what: str) -> memoryview:
        """The next ``n`` bytes; raises ProtocolError when fewer are left."""
        if n < 0 or n > self.remaining:
            raise ProtocolError(DEVICE, f"truncated packet: {what} needs {n} bytes at offset {self.offset}, "
                                        f"{self.remaining} left")
        chunk = self.data[self.offset:self.offset + n]
        self.offset += n
        return chunk

    def unpack(self, fmt: struct.Struct, what: str) -> tuple[Any, ...]:
        """Unpack ``fmt`` at the cursor."""
        return fmt.unpack(self.take(fmt.size, what))

    def i32(self, what: str) -> int:
        """One little-endian ``int32``."""
        value: int = self.unpack(I32, what)[0]
        return value

    def count(self, what: str, min_item_size: int) -> int:
        """An ``int32`` item count, rejected when negative or when its items cannot fit in what is left."""
        n = self.i32(what)
        if n < 0 or n * min_item_size > self.remaining:
            raise ProtocolError(DEVICE, f"bad {what} {n} at offset {self.offset - 4}")
        return n

    def cstring(self, what: str) -> str:
        """A NUL-terminated UTF-8 string (invalid bytes replaced)."""
        end = self.raw.find(b"\0", self.offset)
        if end < 0:
            raise ProtocolError(DEVICE, f"truncated packet: unterminated {what} at offset {self.offset}")
        text = self.raw[self.offset:end].decode("utf-8", errors="replace")
        self.offset = end + 1
        return text

    def expect_consumed(self, start: int, size: int, what: str) -> None:
        """Check that exactly ``size`` bytes were read since ``start`` (4.1+ byte counts)."""
        if self.offset - start != size:
            raise ProtocolError(DEVICE, f"{what} byte count says {size}, parsed {self.offset - start}")
