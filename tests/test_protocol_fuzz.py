"""Fuzzing the stream decoder: random bytes, bit flips, truncations, splices and garbage between frames.

Properties: no exception escapes; nothing is accepted that was not sent (no corrupted message accepted); every
frame whose own bytes were not touched is delivered, whatever happened to its neighbours.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.framing import encode_frame
from firmware_bridge.messages import (
    HEADER,
    Ack,
    Heartbeat,
    HostStatus,
    RelocPose,
    RelocRequest,
    WheelOdometry,
    encode_payload,
)
from firmware_bridge.protocol import StreamDecoder


def random_message(rng: np.random.Generator):
    k = int(rng.integers(6))
    f = lambda: float(rng.normal(0, 3))  # noqa: E731
    if k == 0:
        return Heartbeat(int(rng.integers(4)), 0, int(rng.integers(100)), int(rng.integers(1 << 32)),
                         int(rng.integers(1 << 62)), int(rng.integers(1 << 20)))
    if k == 1:
        return WheelOdometry(int(rng.integers(1 << 62)), f(), f(), f(), f(), f(), f(),
                             tuple(abs(f()) for _ in range(6)), int(rng.integers(3)), 0)
    if k == 2:
        return RelocRequest(int(rng.integers(1, 1 << 16)), int(rng.integers(5)))
    if k == 3:
        q = rng.normal(size=4)
        return RelocPose(int(rng.integers(1 << 16)), int(rng.integers(6)), 1, int(rng.integers(1 << 62)),
                         (f(), f(), f()), tuple(q / np.linalg.norm(q)), abs(f()), tuple(abs(f()) for _ in range(21)))
    if k == 4:
        return HostStatus(int(rng.integers(6)), 0, int(rng.integers(5)), int(rng.integers(1 << 32)), 3, 4,
                          "error text"[: int(rng.integers(11))])
    return Ack(int(rng.integers(1, 0x21)), int(rng.integers(4)), int(rng.integers(1 << 16)), int(rng.integers(9)))


def mutate(frame: bytes, rng: np.random.Generator) -> bytes:
    """One of several corruptions of a frame's own bytes (delimiters included)."""
    b = bytearray(frame)
    kind = int(rng.integers(7))
    if kind == 0:  # bit flips
        for bit in rng.choice(len(b) * 8, size=int(rng.integers(1, 6)), replace=False):
            b[bit // 8] ^= 1 << (bit % 8)
    elif kind == 1:  # truncated (the rest never arrives)
        b = b[: int(rng.integers(1, len(b) - 1))]
    elif kind == 2:  # head lost
        b = b[int(rng.integers(2, len(b) - 1)) :]
    elif kind == 3:  # bytes lost in the middle
        i = int(rng.integers(2, len(b) - 2))
        del b[i : i + int(rng.integers(1, 4))]
    elif kind == 4:  # random bytes inserted in the middle
        i = int(rng.integers(2, len(b) - 1))
        b[i:i] = rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8).tobytes()
    elif kind == 5:  # a byte replaced
        i = int(rng.integers(1, len(b) - 1))
        b[i] = (b[i] + int(rng.integers(1, 256))) % 256
    else:  # overwritten by noise of the same length
        b = bytearray(rng.integers(0, 256, len(b), dtype=np.uint8).tobytes())
    return bytes(b)


def run_fuzz(seed: int, n_frames: int = 40):
    rng = np.random.default_rng(seed)
    sent = {}
    chunks, intact = [], []
    spliced = False
    for seq in range(n_frames):
        msg = random_message(rng)
        stamp = int(rng.integers(1 << 62))
        frame = encode_frame(encode_payload(msg, seq=seq, stamp_ns=stamp))
        sent[seq] = (stamp, msg)
        if not spliced and rng.random() < 0.15:  # garbage between frames
            chunks.append(rng.integers(0, 256, int(rng.integers(1, 40)), dtype=np.uint8).tobytes())
        if not spliced and rng.random() < 0.4:  # (after a splice the next frame must bring its delimiter)
            chunks.append(mutate(frame, rng))
        elif not spliced and seq < n_frames - 1 and rng.random() < 0.1:
            # Spliced to the next frame (its trailing delimiter lost): still intact, the next frame's leading
            # delimiter closes it.
            chunks.append(frame[:-1])
            intact.append(seq)
            spliced = True
            continue
        else:
            chunks.append(frame)
            intact.append(seq)
        spliced = False
    stream = b"".join(chunks)
    dec = StreamDecoder(max_frame_bytes=int(rng.integers(150, 600)))
    out = []
    pos = 0
    while pos < len(stream):  # random chunking as a port delivers it
        n = int(rng.integers(1, 300))
        out += dec.feed(stream[pos : pos + n])
        pos += n
    return sent, intact, out, dec.stats


def test_fuzzed_streams_accept_nothing_corrupted_and_lose_nothing_intact():
    total_good = total_bad = 0
    for seed in range(150):
        sent, intact, out, stats = run_fuzz(seed)
        for p in out:
            assert p.seq in sent and sent[p.seq] == (p.stamp_ns, p.message), f"seed {seed}: corrupted frame accepted"
        delivered = [p.seq for p in out]
        assert len(set(delivered)) == len(delivered)
        missing = set(intact) - set(delivered)
        assert not missing, f"seed {seed}: intact frames {sorted(missing)} not delivered"
        total_good += stats.frames_good
        total_bad += stats.frames_bad
    assert total_bad > 500 and total_good > 3000  # the fuzzer did exercise both paths


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=2000), st.integers(1, 64))
def test_random_bytes_never_raise_and_never_decode(data, chunk):
    dec = StreamDecoder(max_frame_bytes=200)
    out = []
    for k in range(0, len(data), chunk):
        out += dec.feed(data[k : k + chunk])
    assert out == []  # a random frame passing COBS, CRC, version, type and length checks: ~1e-10
    assert dec.stats.bytes_in == len(data)


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=0, max_size=200), st.integers(0, 255), st.integers(0, 0xFFFF))
def test_valid_crc_with_arbitrary_content_is_rejected_by_header_or_length(body, msg_type, seq):
    # A frame with a correct CRC but arbitrary content: decoded only if its header and length make sense.
    payload = HEADER.pack(1, msg_type, seq, 0) + body
    dec = StreamDecoder(max_frame_bytes=1000)
    out = dec.feed(encode_frame(payload))
    assert len(out) + dec.stats.frames_bad == 1
    for p in out:
        assert encode_payload(p.message, seq=p.seq, stamp_ns=p.stamp_ns)[: HEADER.size] == payload[: HEADER.size]
