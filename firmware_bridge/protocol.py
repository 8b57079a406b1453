"""Byte stream <-> packets for one direction of one connection, with the counters a live link reports.

:class:`StreamDecoder` turns any byte chunks (as they arrive from a port) into :class:`~firmware_bridge.messages.Packet`
objects; every bad frame is counted by kind and skipped, nothing raises. :class:`StreamEncoder` numbers and frames
outgoing messages. Neither does I/O, so both are tested without a port and shared by the host link and the
simulated firmware.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from .framing import CrcError, FrameSplitter, FramingError, decode_frame, encode_frame
from .messages import (
    BadLength,
    BadValue,
    Message,
    Packet,
    ProtocolError,
    UnknownType,
    UnknownVersion,
    decode_payload,
    encode_payload,
)

__all__ = ["DecoderStats", "StreamDecoder", "StreamEncoder"]


@dataclass
class DecoderStats:
    """Counters of a :class:`StreamDecoder`, monotonic since construction (not reset on reconnect)."""

    bytes_in: int = 0
    frames_good: int = 0  # CRC ok, header and body valid: handed out
    crc_errors: int = 0
    framing_errors: int = 0  # invalid COBS, or too short for a payload and CRC
    oversize: int = 0  # longer than max_frame_bytes, discarded
    resyncs: int = 0  # a good frame after one or more bad ones: the stream lost and found its step
    unknown_versions: int = 0
    unknown_types: int = 0
    bad_lengths: int = 0  # known type, body of the wrong size
    bad_values: int = 0  # known type, a field out of range (NaN, bad quaternion, ...)
    frames_lost: int = 0  # frames missing according to the sender's sequence numbers
    seq_restarts: int = 0  # a sequence jump too large to be losses (sender rebooted or reconnected)
    truncated: int = 0  # a partial frame pending when the connection ended (reset()), discarded

    @property
    def frames_bad(self) -> int:
        """Frames that reached the receiver but were not accepted."""
        return (
            self.crc_errors + self.framing_errors + self.oversize + self.unknown_versions + self.unknown_types
            + self.bad_lengths + self.bad_values + self.truncated
        )

    def as_dict(self) -> dict:
        out = asdict(self)
        out["frames_bad"] = self.frames_bad
        return out


class StreamDecoder:
    """Incremental decoder of one incoming byte stream.

    Parameters
    ----------
    max_frame_bytes:
        Longest encoded frame accepted (bytes between delimiters); longer ones are dropped and counted.
    max_seq_gap:
        Sequence jumps up to this many frames count as losses; larger jumps (and going backwards) count as a restart
        of the sender's numbering.
    """

    def __init__(self, max_frame_bytes: int = 512, *, max_seq_gap: int = 1000):
        self._splitter = FrameSplitter(max_frame_bytes)
        self.max_seq_gap = int(max_seq_gap)
        self.stats = DecoderStats()
        self._last_seq: int | None = None
        self._bad_since_good = False

    def reset(self) -> None:
        """Start of a new connection: drop a partial frame (counted as truncated: it is never joined to the next
        connection's bytes) and forget the sender's sequence numbering."""
        if self._splitter.pending_bytes:
            self.stats.truncated += 1
            self._bad_since_good = True
        self._splitter.reset()
        self._last_seq = None

    def feed(self, data: bytes) -> list[Packet]:
        """Decode the packets completed by ``data``; bad frames are counted in :attr:`stats` and skipped."""
        s = self.stats
        s.bytes_in += len(data)
        oversize_before = self._splitter.stats.oversize
        frames = self._splitter.feed(data)
        if self._splitter.stats.oversize != oversize_before:
            s.oversize += self._splitter.stats.oversize - oversize_before
            self._bad_since_good = True
        packets = []
        for frame in frames:
            try:
                packet = decode_payload(decode_frame(frame))
            except CrcError:
                s.crc_errors += 1
            except FramingError:
                s.framing_errors += 1
            except UnknownVersion:
                s.unknown_versions += 1
            except UnknownType:
                s.unknown_types += 1
            except BadLength:
                s.bad_lengths += 1
            except (BadValue, ProtocolError):
                s.bad_values += 1
            else:
                s.frames_good += 1
                if self._bad_since_good:
                    s.resyncs += 1
                    self._bad_since_good = False
                self._track_seq(packet.seq)
                packets.append(packet)
                continue
            self._bad_since_good = True
        return packets

    def _track_seq(self, seq: int) -> None:
        if self._last_seq is not None:
            gap = (seq - self._last_seq - 1) & 0xFFFF
            if 0 < gap <= self.max_seq_gap:
                self.stats.frames_lost += gap
            elif gap > self.max_seq_gap:
                self.stats.seq_restarts += 1
        self._last_seq = seq


class StreamEncoder:
    """Numbers (seq +1 per frame, wrapping at 65536) and frames outgoing messages."""

    def __init__(self, first_seq: int = 0):
        self._seq = int(first_seq) & 0xFFFF
        self.frames_out = 0

    @property
    def next_seq(self) -> int:
        return self._seq

    def encode(self, message: Message, stamp_ns: int) -> tuple[int, bytes]:
        """``(seq, wire_bytes)`` of ``message`` stamped ``stamp_ns`` (the sender's clock, ns)."""
        seq = self._seq
        wire = encode_frame(encode_payload(message, seq=seq, stamp_ns=stamp_ns))
        self._seq = (seq + 1) & 0xFFFF
        self.frames_out += 1
        return seq, wire
