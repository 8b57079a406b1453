"""Framing: bytes on the wire <-> payloads. No I/O here; the link and the simulator feed bytes in and take bytes out.

A frame on the wire is ``0x00 COBS(payload || crc16_le(payload)) 0x00``:

- COBS (Consistent Overhead Byte Stuffing) removes every zero byte from the encoded frame, so ``0x00`` only ever
  marks a frame boundary and a receiver that joins mid-stream, or loses bytes, is back in step at the next zero.
- The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor; check value
  ``crc16(b"123456789") == 0x29B1``), appended little-endian after the payload, inside the COBS encoding.
- Every frame is sent with a delimiter before and after it. Only the trailing one is required by the format; the
  leading one costs one byte and means garbage on the line before a frame (noise, a half-written frame after a write
  timeout, the tail of a stale buffer) can never spoil that frame. Empty frames (``00 00``) are ignored silently.

The byte-level specification, with worked examples, is docs/protocol.md.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass

__all__ = [
    "DELIMITER",
    "CRC_BYTES",
    "FramingError",
    "CrcError",
    "crc16",
    "cobs_encode",
    "cobs_decode",
    "max_encoded_size",
    "encode_frame",
    "decode_frame",
    "FrameSplitter",
    "SplitterStats",
]

DELIMITER = 0x00
CRC_BYTES = 2


class FramingError(ValueError):
    """A frame that is not valid COBS, or too short to hold a CRC."""


class CrcError(ValueError):
    """A frame whose CRC does not match its payload."""


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of ``data`` (poly 0x1021, init 0xFFFF, no reflection, xorout 0); 0x29B1 for b"123456789"."""
    return binascii.crc_hqx(data, 0xFFFF)


def cobs_encode(data: bytes) -> bytes:
    """COBS-encode ``data`` (any bytes) into bytes that contain no zero. Delimiters are not added.

    Canonical encoding as in Cheshire & Baker (1999): a block of 254 non-zero bytes gets code 0xFF and no implied
    zero; a run of 254 non-zero bytes at the very end of the data is not followed by an extra 0x01 block.
    """
    out = bytearray()
    segments = bytes(data).split(b"\x00")
    last = len(segments) - 1
    for k, seg in enumerate(segments):
        pos = 0
        while len(seg) - pos >= 254:
            out.append(0xFF)
            out += seg[pos : pos + 254]
            pos += 254
        rest = seg[pos:]
        # A short block (code < 0xFF) implies the zero that ended its segment; the last segment has no such zero.
        if rest or k != last or pos == 0:
            out.append(len(rest) + 1)
            out += rest
    return bytes(out)


def cobs_decode(encoded: bytes) -> bytes:
    """Invert :func:`cobs_encode`. Raises :class:`FramingError` on a zero byte or a block running past the end."""
    enc = bytes(encoded)
    n = len(enc)
    out = bytearray()
    i = 0
    while i < n:
        code = enc[i]
        if code == 0:
            raise FramingError(f"zero byte at offset {i} inside a COBS frame")
        end = i + code
        if end > n:
            raise FramingError(f"COBS block at offset {i} (code {code}) runs past the frame end ({n} bytes)")
        block = enc[i + 1 : end]
        if 0 in block:
            raise FramingError(f"zero byte inside the COBS block at offset {i}")
        out += block
        i = end
        if code != 0xFF and i < n:
            out.append(0)
    return bytes(out)


def max_encoded_size(payload_bytes: int) -> int:
    """Largest COBS encoding (without delimiters) of a payload of this many bytes plus its CRC."""
    n = payload_bytes + CRC_BYTES
    return n + 1 + n // 254


def encode_frame(payload: bytes, *, leading_delimiter: bool = True) -> bytes:
    """Wire bytes of one frame: ``[00] COBS(payload || crc16 little-endian) 00``."""
    body = bytes(payload)
    crc = crc16(body)
    encoded = cobs_encode(body + bytes((crc & 0xFF, crc >> 8)))
    return (b"\x00" if leading_delimiter else b"") + encoded + b"\x00"


def decode_frame(frame: bytes) -> bytes:
    """Payload of one frame given the bytes between two delimiters.

    Raises :class:`FramingError` (invalid COBS, too short) or :class:`CrcError`.
    """
    raw = cobs_decode(frame)
    if len(raw) < CRC_BYTES + 1:
        raise FramingError(f"frame of {len(raw)} decoded bytes is too short to hold a payload and a CRC")
    payload, crc_lo, crc_hi = raw[:-2], raw[-2], raw[-1]
    got = crc_lo | (crc_hi << 8)
    want = crc16(payload)
    if got != want:
        raise CrcError(f"CRC mismatch: frame carries 0x{got:04X}, payload gives 0x{want:04X}")
    return payload


@dataclass
class SplitterStats:
    """Counters of :class:`FrameSplitter` (monotonic, since construction)."""

    bytes_in: int = 0
    frames: int = 0  # non-empty frames handed out (not yet checked)
    oversize: int = 0  # frames longer than max_frame_bytes, discarded whole


class FrameSplitter:
    """Cuts a byte stream at 0x00 delimiters into encoded frames (still COBS, CRC unchecked).

    Frames longer than ``max_frame_bytes`` (encoded, without delimiters) are discarded as soon as they exceed it, so
    a stream that never sends a delimiter cannot grow memory; the rest of such a frame, up to the next delimiter, is
    thrown away too and the whole frame counts once in ``stats.oversize``.
    """

    def __init__(self, max_frame_bytes: int = 512):
        if not isinstance(max_frame_bytes, int) or max_frame_bytes < 4:
            raise ValueError(f"max_frame_bytes: expected an int >= 4, got {max_frame_bytes!r}")
        self.max_frame_bytes = max_frame_bytes
        self.stats = SplitterStats()
        self._buf = bytearray()
        self._discarding = False

    def reset(self) -> None:
        """Forget a partial frame (after a reconnect: whatever came before belongs to another connection)."""
        self._buf.clear()
        self._discarding = False

    @property
    def pending_bytes(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[bytes]:
        """Append ``data`` and return the complete non-empty frames it closed, oldest first."""
        self.stats.bytes_in += len(data)
        frames: list[bytes] = []
        start = 0
        n = len(data)
        while start < n:
            idx = data.find(b"\x00", start)
            if idx < 0:
                if not self._discarding:
                    self._buf += data[start:]
                    if len(self._buf) > self.max_frame_bytes:
                        self._buf.clear()
                        self._discarding = True
                        self.stats.oversize += 1
                break
            if self._discarding:
                self._discarding = False
            else:
                if self._buf:
                    self._buf += data[start:idx]
                    frame = bytes(self._buf)
                    self._buf.clear()
                else:
                    frame = bytes(data[start:idx])
                if len(frame) > self.max_frame_bytes:
                    self.stats.oversize += 1
                elif frame:
                    self.stats.frames += 1
                    frames.append(frame)
            start = idx + 1
        return frames
