"""Framing: CRC parameters, COBS against published examples and a byte-by-byte reference, the frame splitter."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.framing import (
    CrcError,
    FrameSplitter,
    FramingError,
    cobs_decode,
    cobs_encode,
    crc16,
    decode_frame,
    encode_frame,
    max_encoded_size,
)


def crc16_reference(data: bytes) -> int:
    """CRC-16/CCITT-FALSE bit by bit, straight from its parameters."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def cobs_encode_reference(data: bytes) -> bytes:
    """The byte loop of the widely copied C encoder (Wikipedia's listing), transcribed line by line."""
    buf = bytearray(2 * len(data) + 2)
    enc, codep, code = 1, 0, 1
    for i, b in enumerate(data):
        remaining = len(data) - i - 1
        if b:
            buf[enc] = b
            enc += 1
            code += 1
        if not b or code == 0xFF:
            buf[codep] = code
            code = 1
            codep = enc
            if not b or remaining:
                enc += 1
    buf[codep] = code
    return bytes(buf[:enc])


def test_crc_check_value_and_reference():
    assert crc16(b"123456789") == 0x29B1
    assert crc16(b"") == 0xFFFF
    for data in (b"\x00", b"\xff" * 7, bytes(range(256))):
        assert crc16(data) == crc16_reference(data)


# Published examples of the canonical encoding (Cheshire & Baker; the Wikipedia table).
COBS_EXAMPLES = [
    ("", "01"),
    ("00", "01 01"),
    ("00 00", "01 01 01"),
    ("00 11 00", "01 02 11 01"),
    ("11 22 00 33", "03 11 22 02 33"),
    ("11 22 33 44", "05 11 22 33 44"),
    ("11 00 00 00", "02 11 01 01 01"),
]


@pytest.mark.parametrize("raw,encoded", COBS_EXAMPLES)
def test_cobs_published_examples(raw, encoded):
    raw_b, enc_b = bytes.fromhex(raw), bytes.fromhex(encoded)
    assert cobs_encode(raw_b) == enc_b
    assert cobs_decode(enc_b) == raw_b


def test_cobs_long_runs():
    run254 = bytes(range(1, 255))
    assert cobs_encode(run254) == b"\xff" + run254  # no trailing 01 after a final full block
    assert cobs_encode(b"\x00" + run254) == b"\x01\xff" + run254
    assert cobs_encode(bytes(range(1, 256))) == b"\xff" + run254 + b"\x02\xff"
    assert cobs_encode(bytes(range(2, 256)) + b"\x00") == b"\xff" + bytes(range(2, 256)) + b"\x01\x01"
    assert cobs_encode(bytes(range(3, 256)) + b"\x00\x01") == b"\xfe" + bytes(range(3, 256)) + b"\x02\x01"


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=700))
def test_cobs_round_trip_and_reference(data):
    enc = cobs_encode(data)
    assert 0 not in enc
    assert enc == cobs_encode_reference(data)
    assert len(enc) <= len(data) + 1 + len(data) // 254
    assert cobs_decode(enc) == data


@pytest.mark.parametrize("bad", ["05 11 22", "02 11 00 01", "00"])
def test_cobs_rejects_invalid(bad):
    with pytest.raises(FramingError):
        cobs_decode(bytes.fromhex(bad))


def test_frame_layout_and_crc_check():
    payload = b"123456789"
    wire = encode_frame(payload)
    assert wire[0] == 0 and wire[-1] == 0 and 0 not in wire[1:-1]
    # The CRC 0x29B1 travels little-endian after the payload, inside the COBS encoding.
    assert cobs_decode(wire[1:-1]) == payload + b"\xb1\x29"
    assert decode_frame(wire[1:-1]) == payload
    assert len(wire) - 2 <= max_encoded_size(len(payload))
    assert encode_frame(payload, leading_delimiter=False) == wire[1:]
    corrupted = bytearray(cobs_decode(wire[1:-1]))
    corrupted[0] ^= 0x01
    with pytest.raises(CrcError):
        decode_frame(cobs_encode(bytes(corrupted)))
    with pytest.raises(FramingError):
        decode_frame(cobs_encode(b"\x01\x02"))  # too short for payload + CRC


def test_splitter_chunks_empty_frames_and_oversize():
    frames = [encode_frame(bytes([i + 1]) * (10 + i)) for i in range(5)]
    stream = b"".join(frames)
    for chunk in (1, 3, 7, len(stream)):
        sp = FrameSplitter(64)
        out = []
        for k in range(0, len(stream), chunk):
            out += sp.feed(stream[k : k + chunk])
        assert [decode_frame(f) for f in out] == [bytes([i + 1]) * (10 + i) for i in range(5)]
        assert sp.stats.oversize == 0

    sp = FrameSplitter(32)
    big = encode_frame(b"\x07" * 100)
    small = encode_frame(b"\x05" * 4)
    out = sp.feed(small + big + small)
    assert [decode_frame(f) for f in out] == [b"\x05" * 4, b"\x05" * 4]
    assert sp.stats.oversize == 1
    # An endless run without delimiter does not grow the buffer and counts once; the next frame gets through.
    for _ in range(50):
        assert sp.feed(b"\x11" * 100) == []
    assert sp.pending_bytes == 0 and sp.stats.oversize == 2
    assert [decode_frame(f) for f in sp.feed(small)] == [b"\x05" * 4]


def test_splitter_rejects_bad_limit():
    with pytest.raises(ValueError, match="max_frame_bytes"):
        FrameSplitter(0)
