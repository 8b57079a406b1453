"""Messages: round trips of every type (property tests), golden wire bytes (shared with docs/protocol.md), and the
stream decoder's handling of valid frames it cannot use."""

from __future__ import annotations

import math
import re
import struct
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.framing import cobs_encode, crc16, decode_frame, encode_frame
from firmware_bridge.messages import (
    HEADER,
    Ack,
    AckResult,
    BadLength,
    BadValue,
    Heartbeat,
    HostState,
    HostStatus,
    McuState,
    MsgType,
    PoseFlags,
    PoseStatus,
    RelocPose,
    RelocReason,
    RelocRequest,
    UnknownType,
    UnknownVersion,
    WheelOdometry,
    decode_payload,
    encode_payload,
)
from firmware_bridge.protocol import StreamDecoder, StreamEncoder

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"

u8 = st.integers(0, 255)
u16 = st.integers(0, 0xFFFF)
u32 = st.integers(0, 0xFFFFFFFF)
i64 = st.integers(-(2**63), 2**63 - 1)
f32 = st.floats(width=32, allow_nan=False, allow_infinity=False)
var32 = st.floats(min_value=0.0, max_value=2.0**100, width=32)


@st.composite
def unit_quaternions(draw):
    v = np.array(draw(st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4)))
    n = np.linalg.norm(v)
    if n < 1e-3:
        v, n = np.array([0.0, 0.0, 0.0, 1.0]), 1.0
    return tuple(v / n)


@st.composite
def upper_cov(draw, n):
    out = []
    for i in range(n):
        for j in range(i, n):
            out.append(draw(var32 if i == j else f32))
    return tuple(out)


heartbeats = st.builds(Heartbeat, u8, u8, u16, u32, i64, i64)
odometry = st.builds(WheelOdometry, i64, f32, f32, f32, f32, f32, f32, upper_cov(3), u16, u8)
requests = st.builds(RelocRequest, st.integers(1, 0xFFFF), u8, u8)
poses = st.builds(RelocPose, u16, u8, u8, i64, st.tuples(f32, f32, f32), unit_quaternions(), f32, upper_cov(6))
texts = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=40)
statuses = st.builds(HostStatus, u8, u8, u16, u32, u32, u32, texts)
acks = st.builds(Ack, u8, u8, u16, u16)
any_message = st.one_of(heartbeats, odometry, requests, poses, statuses, acks)


@settings(max_examples=150, deadline=None)
@given(msg=any_message, seq=u16, stamp=i64)
def test_round_trip_every_type(msg, seq, stamp):
    payload = encode_payload(msg, seq=seq, stamp_ns=stamp)
    assert len(payload) == HEADER.size + type(msg).BODY.size
    packet = decode_payload(decode_frame(encode_frame(payload)[1:-1]))
    assert packet.message == msg
    assert type(packet.message) is type(msg)
    assert (packet.seq, packet.stamp_ns, packet.msg_type) == (seq, stamp, msg.TYPE)


@settings(max_examples=60, deadline=None)
@given(msgs=st.lists(any_message, min_size=1, max_size=20), chunk=st.integers(1, 64))
def test_stream_round_trip_in_any_chunking(msgs, chunk):
    enc = StreamEncoder(first_seq=65530)  # crosses the sequence wrap
    wire = b"".join(enc.encode(m, 1000 + i)[1] for i, m in enumerate(msgs))
    dec = StreamDecoder()
    out = []
    for k in range(0, len(wire), chunk):
        out += dec.feed(wire[k : k + chunk])
    assert [p.message for p in out] == msgs
    assert [p.seq for p in out] == [(65530 + i) & 0xFFFF for i in range(len(msgs))]
    assert dec.stats.frames_good == len(msgs) and dec.stats.frames_bad == 0 and dec.stats.frames_lost == 0


def test_text_is_truncated_to_its_field_on_a_character_boundary():
    s = HostStatus(HostState.ERROR, last_error="é" * 20)  # 40 UTF-8 bytes
    assert s.last_error == "é" * 16
    assert decode_payload(encode_payload(s, seq=0, stamp_ns=0)).message == s


def test_pose_from_transform_and_back():
    rng = np.random.default_rng(3)
    from reloc.transforms import exp_se3, pose_error

    for _ in range(20):
        T = exp_se3(rng.normal(size=6) * np.array([3, 3, 0.5, 0.5, 0.5, 3]))
        C = np.diag(rng.uniform(1e-4, 1e-2, 6))
        C[0, 1] = C[1, 0] = 1e-5
        pose = RelocPose.from_transform(T, request_id=5, status=PoseStatus.OK, stamp_ns=77, score=2.0, covariance=C)
        back = decode_payload(encode_payload(pose, seq=1, stamp_ns=2)).message
        dt, dr = pose_error(back.transform(), T)
        assert dt < 1e-5 * (1 + np.linalg.norm(T[:3, 3])) and dr < 1e-3  # float32 on the wire
        np.testing.assert_allclose(back.covariance_matrix(), C, rtol=1e-6, atol=1e-12)
    with pytest.raises(ValueError, match="T_map_base"):
        RelocPose.from_transform(np.eye(3))
    with pytest.raises(ValueError, match="covariance"):
        RelocPose.from_transform(np.eye(4), covariance=np.eye(3))


@pytest.mark.parametrize(
    "build, match",
    [
        (lambda: Heartbeat(256), "state"),
        (lambda: Heartbeat(1, rx_errors=-1), "rx_errors"),
        (lambda: WheelOdometry(0, math.nan, 0.0, 0.0), "x_m"),
        (lambda: WheelOdometry(0, 0.0, 0.0, 0.0, cov=(-1.0, 0, 0, 0, 0, 0)), "cov"),
        (lambda: WheelOdometry(0, 1e39, 0.0, 0.0), "x_m"),
        (lambda: RelocRequest(0), "request_id"),
        (lambda: RelocPose(0, 0, 0, 0, (0, 0, 0), (0, 0, 0.5, 0.5)), "quat_xyzw"),
        (lambda: RelocPose(0, 0, 0, 0, (0, 0), (0, 0, 0, 1)), "position"),
        (lambda: HostStatus(1, last_error=5), "last_error"),
        (lambda: Ack(1, 0, 70000), "acked_seq"),
    ],
)
def test_invalid_fields_name_the_field(build, match):
    with pytest.raises(BadValue, match=match):
        build()


def test_decoder_skips_and_counts_unusable_frames():
    enc = StreamEncoder()
    good = enc.encode(Heartbeat(McuState.IDLE), 5)[1]
    unknown_type = encode_frame(HEADER.pack(1, 0x7E, 9, 0) + b"\x01\x02")
    future_version = encode_frame(HEADER.pack(2, int(MsgType.HEARTBEAT), 9, 0) + bytes(24))
    short_body = encode_frame(HEADER.pack(1, int(MsgType.HEARTBEAT), 9, 0) + bytes(23))
    nan_odometry = encode_frame(
        HEADER.pack(1, int(MsgType.WHEEL_ODOMETRY), 9, 0) + struct.pack("<q6f6fHBx", 0, math.nan, *[0.0] * 11, 0, 0)
    )
    runt = b"\x00" + cobs_encode(b"\x01") + b"\x00"
    bad_cobs = b"\x00\x05\x01\x02\x00"
    dec = StreamDecoder()
    out = dec.feed(good + unknown_type + future_version + short_body + nan_odometry + runt + bad_cobs + good)
    assert [p.message for p in out] == [Heartbeat(McuState.IDLE)] * 2
    s = dec.stats
    assert (s.unknown_types, s.unknown_versions, s.bad_lengths, s.bad_values, s.framing_errors) == (1, 1, 1, 1, 2)
    assert s.frames_good == 2 and s.resyncs == 1 and s.crc_errors == 0
    for raw, exc in ((HEADER.pack(1, 0x7E, 0, 0), UnknownType), (HEADER.pack(9, 1, 0, 0), UnknownVersion),
                     (b"\x01\x01", BadLength)):
        with pytest.raises(exc):
            decode_payload(raw)


def test_sequence_gaps_count_lost_frames():
    enc = StreamEncoder()
    frames = [enc.encode(RelocRequest(i + 1), i)[1] for i in range(10)]
    dec = StreamDecoder()
    out = dec.feed(b"".join(f for i, f in enumerate(frames) if i not in (3, 4, 7)))
    assert len(out) == 7 and dec.stats.frames_lost == 3
    dec.reset()  # a new connection: the numbering may start anywhere
    dec.feed(StreamEncoder(first_seq=40000).encode(RelocRequest(1), 0)[1])
    assert dec.stats.frames_lost == 3 and dec.stats.seq_restarts == 0


# --- golden vectors: the same hex is in docs/protocol.md; a C implementation must produce exactly these bytes ----
GOLDEN = [
    (
        Heartbeat(McuState.DRIVING, 0, 3, 1500, 123_456_789_000, 250_000), 1, 1_500_000_000,
        "00 04 01 01 01 01 04 2f 68 59 01 01 01 02 02 02 03 03 dc 05 01 06 08 1a 99 be 1c 01 01 04 90 d0 03 01 01 01"
        " 01 03 6a dc 00",
    ),
    (
        WheelOdometry(1_519_000_000, 1.5, -0.25, 0.5, 0.375, 0.0, -0.125, (2**-10, 0.0, 0.0, 2**-10, 0.0, 2**-12), 1, 0),
        2, 1_520_000_000,
        "00 04 01 02 02 01 04 5c 99 5a 01 01 01 05 c0 19 8a 5a 01 01 01 01 01 03 c0 3f 01 03 80 be 01 01 02 3f 01 03"
        " c0 3e 01 01 01 01 01 01 02 be 01 03 80 3a 01 01 01 01 01 01 01 01 01 03 80 3a 01 01 01 01 01 04 80 39 01 01"
        " 01 03 cc f7 00",
    ),
    (
        RelocRequest(42, RelocReason.BOOT, 0), 3, 1_530_000_000,
        "00 04 01 03 03 05 80 f2 31 5b 01 01 01 02 2a 01 01 03 25 01 00",
    ),
    (
        RelocPose(42, PoseStatus.OK, PoseFlags.STAMP_MCU_CLOCK, 1_510_000_000, (1.5, -0.25, 0.0), (0.0, 0.0, 1.0, 0.0),
                  12.5, tuple(2**-8 if i == j < 3 else 2**-12 if i == j else 0.0 for i in range(6) for j in range(i, 6))),
        8, 123_457_000_000,
        "00 04 01 10 08 06 40 52 9c be 1c 01 01 02 2a 01 04 01 80 c5 02 5a 01 01 01 01 01 03 c0 3f 01 03 80 be 01 01"
        " 01 01 01 01 01 01 01 01 01 01 01 03 80 3f 01 01 01 01 01 03 48 41 01 03 80 3b 01 01 01 01 01 01 01 01 01 01"
        " 01 01 01 01 01 01 01 01 01 01 01 03 80 3b 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 03 80 3b 01 01"
        " 01 01 01 01 01 01 01 01 01 01 01 03 80 39 01 01 01 01 01 01 01 01 01 03 80 39 01 01 01 01 01 05 80 39 6a 24"
        " 00",
    ),
    (
        HostStatus(HostState.LOCALIZED, 0, 0, 1234, 10, 2, "map office"), 9, 123_458_000_000,
        "00 04 01 11 09 06 80 94 ab be 1c 01 01 02 02 01 01 03 d2 04 01 02 0a 01 01 02 02 01 01 0b 6d 61 70 20 6f 66"
        " 66 69 63 65 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 01 03 81 aa 00",
    ),
    (
        Ack(MsgType.RELOC_REQUEST, AckResult.ACCEPTED, 3, 42), 10, 123_459_000_000,
        "00 04 01 20 0a 06 c0 d6 ba be 1c 01 01 02 03 02 03 02 2a 03 67 d6 00",
    ),
]


@pytest.mark.parametrize("msg, seq, stamp, wire_hex", GOLDEN, ids=[type(g[0]).__name__ for g in GOLDEN])
def test_golden_vectors(msg, seq, stamp, wire_hex):
    wire = bytes.fromhex(wire_hex)
    assert encode_frame(encode_payload(msg, seq=seq, stamp_ns=stamp)) == wire
    packet = decode_payload(decode_frame(wire[1:-1]))
    assert (packet.message, packet.seq, packet.stamp_ns) == (msg, seq, stamp)


def test_golden_vectors_cover_every_type_and_match_the_document():
    assert {type(g[0]).TYPE for g in GOLDEN} == set(MsgType)
    text = DOC.read_text(encoding="utf-8")
    doc_wires = [" ".join(m.split()).lower() for m in re.findall(r"^wire:\s*((?:[0-9a-fA-F]{2}\s*)+)$", text, re.M)]
    assert doc_wires == [g[3] for g in GOLDEN]
    # The document's CRC check value and payload CRCs agree with the code.
    assert "0x29B1" in text
    for msg, seq, stamp, _ in GOLDEN:
        assert f"0x{crc16(encode_payload(msg, seq=seq, stamp_ns=stamp)):04X}" in text
