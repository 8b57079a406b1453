"""Messages of the host <-> microcontroller protocol: fixed little-endian layouts, packed and unpacked with ``struct``.

A payload is a 12-byte header followed by the body of one message type::

    offset size type  field
    0      1    u8    version    PROTOCOL_VERSION (1)
    1      1    u8    msg_type   MsgType
    2      2    u16   seq        per-sender frame counter, +1 per frame, wraps at 65536
    4      8    i64   stamp_ns   sender's monotonic clock when the frame was built, nanoseconds

Every body layout is given byte by byte in docs/protocol.md (and in each class's docstring). Message objects are
frozen dataclasses whose constructor validates and normalises their fields exactly as the wire will carry them
(floats rounded to float32, text truncated to its field), so ``decode_payload(encode_payload(m, ...)).message == m``
for every valid ``m``. Decoding raises a subclass of :class:`ProtocolError`; nothing else escapes it.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields
from enum import IntEnum
from typing import ClassVar, Union

import numpy as np

__all__ = [
    "PROTOCOL_VERSION",
    "HEADER",
    "MsgType",
    "McuState",
    "HostState",
    "PoseStatus",
    "RelocReason",
    "AckResult",
    "HeartbeatFlags",
    "OdometryFlags",
    "PoseFlags",
    "ProtocolError",
    "UnknownVersion",
    "UnknownType",
    "BadLength",
    "BadValue",
    "Heartbeat",
    "WheelOdometry",
    "RelocRequest",
    "RelocPose",
    "HostStatus",
    "Ack",
    "Message",
    "Packet",
    "MESSAGE_CLASSES",
    "encode_payload",
    "decode_payload",
]

PROTOCOL_VERSION = 1
HEADER = struct.Struct("<BBHq")  # version, msg_type, seq, stamp_ns


class MsgType(IntEnum):
    HEARTBEAT = 0x01  # both ways
    WHEEL_ODOMETRY = 0x02  # MCU -> host
    RELOC_REQUEST = 0x03  # MCU -> host, acknowledged by the host
    RELOC_POSE = 0x10  # host -> MCU, acknowledged by the MCU
    HOST_STATUS = 0x11  # host -> MCU
    ACK = 0x20  # both ways


class McuState(IntEnum):
    """``Heartbeat.state`` sent by the microcontroller."""

    BOOT = 0
    IDLE = 1
    DRIVING = 2
    FAULT = 3


class HostState(IntEnum):
    """``Heartbeat.state`` and ``HostStatus.state`` sent by the host (the live loop)."""

    STARTING = 0
    WAITING = 1  # no map loaded or no camera frames yet
    LOCALIZED = 2  # poses are being sent
    SEARCHING = 3  # lost, relocalizing
    ERROR = 4  # see HostStatus.error_code / last_error
    STOPPING = 5


class PoseStatus(IntEnum):
    """``RelocPose.status``. Only OK and TRACKED carry a usable pose; the others are rejections with a reason."""

    OK = 0  # relocalized from this frame
    TRACKED = 1  # propagated from the last relocalization with odometry
    NO_MATCH = 2
    AMBIGUOUS = 3  # several poses fit (symmetric scene)
    TOO_FEW_PLANES = 4
    NOT_READY = 5  # no map / no camera frame yet


class RelocReason(IntEnum):
    """``RelocRequest.reason``."""

    BOOT = 0
    LOST = 1
    PERIODIC = 2
    MANUAL = 3
    KIDNAPPED = 4  # wheels lifted, bumped, slipped


class AckResult(IntEnum):
    ACCEPTED = 0
    DUPLICATE = 1  # this request_id is already being handled; no second answer will come
    BUSY = 2
    UNSUPPORTED = 3


class HeartbeatFlags(IntEnum):
    CLOCK_SYNCED = 0x01  # the sender maps the peer's clock to its own


class OdometryFlags(IntEnum):
    SLIP = 0x01  # the firmware saw wheel slip during this interval


class PoseFlags(IntEnum):
    STAMP_MCU_CLOCK = 0x01  # stamp_ns is in the MCU's clock (else in the host's: time not synced yet)


class ProtocolError(ValueError):
    """A payload that cannot be accepted. Subclasses say why; the stream decoder counts each kind."""


class UnknownVersion(ProtocolError):
    pass


class UnknownType(ProtocolError):
    pass


class BadLength(ProtocolError):
    pass


class BadValue(ProtocolError):
    pass


_I64 = (-(2**63), 2**63 - 1)
_F32_MAX = 3.4028234663852886e38
_TEXT_BYTES = 32


def _int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise BadValue(f"{name}: expected an int in [{lo}, {hi}], got {value!r}")
    v = int(value)
    if not lo <= v <= hi:
        raise BadValue(f"{name}: expected an int in [{lo}, {hi}], got {v}")
    return v


def _f32(name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BadValue(f"{name}: expected a finite float, got {value!r}") from None
    if not math.isfinite(v) or abs(v) > _F32_MAX:
        raise BadValue(f"{name}: expected a finite float32, got {v!r}")
    return struct.unpack("<f", struct.pack("<f", v))[0]


def _f32_tuple(name: str, values, n: int) -> tuple[float, ...]:
    try:
        items = tuple(np.asarray(values, dtype=np.float64).reshape(-1).tolist())
    except (TypeError, ValueError):
        raise BadValue(f"{name}: expected {n} floats, got {values!r}") from None
    if len(items) != n:
        raise BadValue(f"{name}: expected {n} floats, got {len(items)}")
    return tuple(_f32(f"{name}[{i}]", v) for i, v in enumerate(items))


def _text(name: str, value) -> str:
    if not isinstance(value, str):
        raise BadValue(f"{name}: expected a str, got {type(value).__name__}")
    raw = value.replace("\x00", "").encode("utf-8")[:_TEXT_BYTES]
    return raw.decode("utf-8", errors="ignore")  # drops a character cut in half by the truncation


def _upper_triangle_indices(n: int) -> list[tuple[int, int]]:
    return [(i, j) for i in range(n) for j in range(i, n)]


def _sym_from_upper(values: tuple[float, ...], n: int) -> np.ndarray:
    out = np.zeros((n, n))
    for k, (i, j) in enumerate(_upper_triangle_indices(n)):
        out[i, j] = out[j, i] = values[k]
    return out


def _upper_from_sym(name: str, matrix, n: int) -> tuple[float, ...]:
    m = np.asarray(matrix, dtype=np.float64)
    if m.shape != (n, n):
        raise ValueError(f"{name}: expected shape ({n}, {n}), got {m.shape}")
    if not np.allclose(m, m.T, rtol=1e-6, atol=1e-12):
        raise ValueError(f"{name}: expected a symmetric matrix")
    return tuple(float(m[i, j]) for i, j in _upper_triangle_indices(n))


class _Message:
    """Base of the message dataclasses: one wire type, one ``struct`` layout."""

    TYPE: ClassVar[MsgType]
    BODY: ClassVar[struct.Struct]

    def _set(self, name: str, value) -> None:
        object.__setattr__(self, name, value)

    def pack_body(self) -> bytes:
        raise NotImplementedError

    @classmethod
    def unpack_body(cls, body: bytes) -> "_Message":
        raise NotImplementedError


@dataclass(frozen=True)
class Heartbeat(_Message):
    """Liveness, state and the two-way clock exchange; sent by both sides every heartbeat period. Body 24 bytes::

        0  u8   state          McuState (from the MCU) or HostState (from the host)
        1  u8   flags          HeartbeatFlags
        2  u16  rx_errors      bad frames the sender has received on this connection (saturates at 65535)
        4  u32  uptime_ms      sender's time since boot (or program start), ms
        8  i64  echo_stamp_ns  header stamp_ns of the last heartbeat received from the peer (0 = none yet)
        16 i64  echo_hold_ns   time from receiving that heartbeat to building this one, sender's clock, ns
    """

    TYPE: ClassVar[MsgType] = MsgType.HEARTBEAT
    BODY: ClassVar[struct.Struct] = struct.Struct("<BBHIqq")

    state: int
    flags: int = 0
    rx_errors: int = 0
    uptime_ms: int = 0
    echo_stamp_ns: int = 0
    echo_hold_ns: int = 0

    def __post_init__(self):
        self._set("state", _int("state", self.state, 0, 255))
        self._set("flags", _int("flags", self.flags, 0, 255))
        self._set("rx_errors", _int("rx_errors", self.rx_errors, 0, 0xFFFF))
        self._set("uptime_ms", _int("uptime_ms", self.uptime_ms, 0, 0xFFFFFFFF))
        self._set("echo_stamp_ns", _int("echo_stamp_ns", self.echo_stamp_ns, *_I64))
        self._set("echo_hold_ns", _int("echo_hold_ns", self.echo_hold_ns, *_I64))

    def pack_body(self) -> bytes:
        return self.BODY.pack(
            self.state, self.flags, self.rx_errors, self.uptime_ms, self.echo_stamp_ns, self.echo_hold_ns
        )

    @classmethod
    def unpack_body(cls, body: bytes) -> "Heartbeat":
        return cls(*cls.BODY.unpack(body))


@dataclass(frozen=True)
class WheelOdometry(_Message):
    """Planar wheel odometry of the base in the odometry frame (z up), MCU -> host. Body 60 bytes::

        0  i64  stamp_ns      when the wheels were read, MCU clock, ns
        8  f32  x_m           position of the base in the odometry frame
        12 f32  y_m
        16 f32  yaw_rad       heading, counter-clockwise from odometry x
        20 f32  vx_mps        velocity in the base frame (forward)
        24 f32  vy_mps        velocity in the base frame (left; 0 for a differential drive)
        28 f32  omega_radps   yaw rate
        32 f32  cov[6]        covariance of (x, y, yaw): xx, xy, xyaw, yy, yyaw, yawyaw (m^2, m rad, rad^2)
        56 u16  reset_count   +1 each time the firmware resets its odometry origin
        58 u8   flags         OdometryFlags
        59 u8   reserved      0
    """

    TYPE: ClassVar[MsgType] = MsgType.WHEEL_ODOMETRY
    BODY: ClassVar[struct.Struct] = struct.Struct("<q6f6fHBx")

    stamp_ns: int
    x_m: float
    y_m: float
    yaw_rad: float
    vx_mps: float = 0.0
    vy_mps: float = 0.0
    omega_radps: float = 0.0
    cov: tuple = (0.0,) * 6
    reset_count: int = 0
    flags: int = 0

    def __post_init__(self):
        self._set("stamp_ns", _int("stamp_ns", self.stamp_ns, *_I64))
        for name in ("x_m", "y_m", "yaw_rad", "vx_mps", "vy_mps", "omega_radps"):
            self._set(name, _f32(name, getattr(self, name)))
        cov = _f32_tuple("cov", self.cov, 6)
        if min(cov[0], cov[3], cov[5]) < 0:
            raise BadValue(f"cov: variances (xx, yy, yawyaw) must be >= 0, got {cov[0]}, {cov[3]}, {cov[5]}")
        self._set("cov", cov)
        self._set("reset_count", _int("reset_count", self.reset_count, 0, 0xFFFF))
        self._set("flags", _int("flags", self.flags, 0, 255))

    def covariance_matrix(self) -> np.ndarray:
        """(3, 3) float64 covariance of (x_m, y_m, yaw_rad)."""
        return _sym_from_upper(self.cov, 3)

    def pack_body(self) -> bytes:
        return self.BODY.pack(
            self.stamp_ns, self.x_m, self.y_m, self.yaw_rad, self.vx_mps, self.vy_mps, self.omega_radps,
            *self.cov, self.reset_count, self.flags,
        )

    @classmethod
    def unpack_body(cls, body: bytes) -> "WheelOdometry":
        v = cls.BODY.unpack(body)
        return cls(v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7:13], v[13], v[14])


@dataclass(frozen=True)
class RelocRequest(_Message):
    """The MCU asks for a relocalization; the host acknowledges, then answers with a RelocPose. Body 4 bytes::

        0  u16  request_id   chosen by the MCU, non-zero; a retransmission keeps the same id
        2  u8   reason       RelocReason
        3  u8   flags        0
    """

    TYPE: ClassVar[MsgType] = MsgType.RELOC_REQUEST
    BODY: ClassVar[struct.Struct] = struct.Struct("<HBB")

    request_id: int
    reason: int = RelocReason.MANUAL
    flags: int = 0

    def __post_init__(self):
        self._set("request_id", _int("request_id", self.request_id, 1, 0xFFFF))
        self._set("reason", _int("reason", self.reason, 0, 255))
        self._set("flags", _int("flags", self.flags, 0, 255))

    def pack_body(self) -> bytes:
        return self.BODY.pack(self.request_id, self.reason, self.flags)

    @classmethod
    def unpack_body(cls, body: bytes) -> "RelocRequest":
        return cls(*cls.BODY.unpack(body))


@dataclass(frozen=True)
class RelocPose(_Message):
    """Relocalized pose of the base in the map, host -> MCU (acknowledged by the MCU). Body 128 bytes::

        0   u16  request_id     the RelocRequest answered, 0 = sent on the host's own initiative
        2   u8   status         PoseStatus (only OK and TRACKED carry a usable pose)
        3   u8   flags          PoseFlags
        4   i64  stamp_ns       time the pose holds for (camera frame time), MCU clock if STAMP_MCU_CLOCK
        12  f32  position[3]    translation of T_map_base, metres (x, y, z in the map, z up)
        24  f32  quat_xyzw[4]   rotation of T_map_base, unit quaternion (x, y, z, w)
        40  f32  score          matcher confidence (>= 0, larger is better)
        44  f32  cov[21]        6x6 covariance, upper triangle row by row, of the left perturbation
                                (dx, dy, dz, drx, dry, drz) in the map frame: T_true = exp(delta) T_map_base
    """

    TYPE: ClassVar[MsgType] = MsgType.RELOC_POSE
    BODY: ClassVar[struct.Struct] = struct.Struct("<HBBq3f4ff21f")

    request_id: int
    status: int
    flags: int
    stamp_ns: int
    position: tuple
    quat_xyzw: tuple
    score: float = 0.0
    cov: tuple = (0.0,) * 21

    def __post_init__(self):
        self._set("request_id", _int("request_id", self.request_id, 0, 0xFFFF))
        self._set("status", _int("status", self.status, 0, 255))
        self._set("flags", _int("flags", self.flags, 0, 255))
        self._set("stamp_ns", _int("stamp_ns", self.stamp_ns, *_I64))
        self._set("position", _f32_tuple("position", self.position, 3))
        q = _f32_tuple("quat_xyzw", self.quat_xyzw, 4)
        norm = math.sqrt(sum(c * c for c in q))
        if abs(norm - 1.0) > 1e-3:
            raise BadValue(f"quat_xyzw: expected a unit quaternion (norm 1 +- 1e-3), got norm {norm:.6g}")
        self._set("quat_xyzw", q)
        self._set("score", _f32("score", self.score))
        cov = _f32_tuple("cov", self.cov, 21)
        diag = [cov[k] for k, (i, j) in enumerate(_upper_triangle_indices(6)) if i == j]
        if min(diag) < 0:
            raise BadValue(f"cov: variances on the diagonal must be >= 0, got {diag}")
        self._set("cov", cov)

    @classmethod
    def from_transform(
        cls, T_map_base, *, request_id: int = 0, status: int = PoseStatus.OK, flags: int = 0, stamp_ns: int = 0,
        score: float = 0.0, covariance=None,
    ) -> "RelocPose":
        """Build from a 4x4 ``T_map_base`` and an optional (6, 6) covariance (see the class docstring)."""
        from reloc.transforms import check_transform, quaternion_from_rotation

        T = check_transform(np.asarray(T_map_base, dtype=np.float64), "T_map_base")
        q = np.asarray(quaternion_from_rotation(T[:3, :3]), dtype=np.float64)
        cov = (0.0,) * 21 if covariance is None else _upper_from_sym("covariance", covariance, 6)
        return cls(request_id, int(status), flags, stamp_ns, tuple(T[:3, 3]), tuple(q / np.linalg.norm(q)), score, cov)

    def transform(self) -> np.ndarray:
        """(4, 4) float64 ``T_map_base`` (the quaternion renormalised after its float32 trip)."""
        from reloc.transforms import rotation_from_quaternion, transform_from_rotation_translation

        q = np.asarray(self.quat_xyzw, dtype=np.float64)
        return transform_from_rotation_translation(rotation_from_quaternion(q / np.linalg.norm(q)), self.position)

    def covariance_matrix(self) -> np.ndarray:
        """(6, 6) float64 covariance (translation first, then rotation), see the class docstring."""
        return _sym_from_upper(self.cov, 6)

    def pack_body(self) -> bytes:
        return self.BODY.pack(
            self.request_id, self.status, self.flags, self.stamp_ns, *self.position, *self.quat_xyzw, self.score,
            *self.cov,
        )

    @classmethod
    def unpack_body(cls, body: bytes) -> "RelocPose":
        v = cls.BODY.unpack(body)
        return cls(v[0], v[1], v[2], v[3], v[4:7], v[7:11], v[11], v[12:33])


@dataclass(frozen=True)
class HostStatus(_Message):
    """State of the live loop, host -> MCU, on every change and about once a second. Body 48 bytes::

        0  u8   state              HostState
        1  u8   flags              0
        2  u16  error_code         0 = none; otherwise the live loop's error number
        4  u32  frames_processed   camera frames processed since start
        8  u32  relocs_ok          relocalizations that produced a pose
        12 u32  relocs_failed      relocalizations rejected
        16 char last_error[32]     UTF-8, zero-padded, not necessarily zero-terminated
    """

    TYPE: ClassVar[MsgType] = MsgType.HOST_STATUS
    BODY: ClassVar[struct.Struct] = struct.Struct("<BBHIII32s")

    state: int
    flags: int = 0
    error_code: int = 0
    frames_processed: int = 0
    relocs_ok: int = 0
    relocs_failed: int = 0
    last_error: str = ""

    def __post_init__(self):
        self._set("state", _int("state", self.state, 0, 255))
        self._set("flags", _int("flags", self.flags, 0, 255))
        self._set("error_code", _int("error_code", self.error_code, 0, 0xFFFF))
        for name in ("frames_processed", "relocs_ok", "relocs_failed"):
            self._set(name, _int(name, getattr(self, name), 0, 0xFFFFFFFF))
        self._set("last_error", _text("last_error", self.last_error))

    def pack_body(self) -> bytes:
        return self.BODY.pack(
            self.state, self.flags, self.error_code, self.frames_processed, self.relocs_ok, self.relocs_failed,
            self.last_error.encode("utf-8"),
        )

    @classmethod
    def unpack_body(cls, body: bytes) -> "HostStatus":
        v = cls.BODY.unpack(body)
        text = v[6].split(b"\x00", 1)[0].decode("utf-8", errors="replace")
        return cls(*v[:6], text)


@dataclass(frozen=True)
class Ack(_Message):
    """Acknowledges one frame, both ways (RelocRequest by the host, RelocPose by the MCU). Body 6 bytes::

        0  u8   acked_type   MsgType of the acknowledged frame
        1  u8   result       AckResult
        2  u16  acked_seq    header seq of the acknowledged frame
        4  u16  ref_id       request_id of the acknowledged RelocRequest / RelocPose
    """

    TYPE: ClassVar[MsgType] = MsgType.ACK
    BODY: ClassVar[struct.Struct] = struct.Struct("<BBHH")

    acked_type: int
    result: int
    acked_seq: int
    ref_id: int = 0

    def __post_init__(self):
        self._set("acked_type", _int("acked_type", self.acked_type, 0, 255))
        self._set("result", _int("result", self.result, 0, 255))
        self._set("acked_seq", _int("acked_seq", self.acked_seq, 0, 0xFFFF))
        self._set("ref_id", _int("ref_id", self.ref_id, 0, 0xFFFF))

    def pack_body(self) -> bytes:
        return self.BODY.pack(self.acked_type, self.result, self.acked_seq, self.ref_id)

    @classmethod
    def unpack_body(cls, body: bytes) -> "Ack":
        return cls(*cls.BODY.unpack(body))


Message = Union[Heartbeat, WheelOdometry, RelocRequest, RelocPose, HostStatus, Ack]
MESSAGE_CLASSES: dict[int, type] = {
    cls.TYPE: cls for cls in (Heartbeat, WheelOdometry, RelocRequest, RelocPose, HostStatus, Ack)
}


@dataclass(frozen=True)
class Packet:
    """One decoded payload: the header fields and the message."""

    seq: int
    stamp_ns: int
    message: Message

    @property
    def msg_type(self) -> MsgType:
        return self.message.TYPE


def encode_payload(message: Message, *, seq: int, stamp_ns: int) -> bytes:
    """Header + body bytes of ``message`` (not yet framed; see :func:`firmware_bridge.framing.encode_frame`)."""
    if type(message) not in MESSAGE_CLASSES.values():
        raise ValueError(f"message: expected one of {[c.__name__ for c in MESSAGE_CLASSES.values()]}, "
                         f"got {type(message).__name__}")
    seq = _int("seq", seq, 0, 0xFFFF)
    stamp_ns = _int("stamp_ns", stamp_ns, *_I64)
    return HEADER.pack(PROTOCOL_VERSION, int(message.TYPE), seq, stamp_ns) + message.pack_body()


def decode_payload(payload: bytes) -> Packet:
    """Parse header + body. Raises :class:`UnknownVersion`, :class:`UnknownType`, :class:`BadLength` or
    :class:`BadValue` (all :class:`ProtocolError`); never anything else."""
    if len(payload) < HEADER.size:
        raise BadLength(f"payload of {len(payload)} bytes is shorter than the {HEADER.size}-byte header")
    version, msg_type, seq, stamp_ns = HEADER.unpack_from(payload)
    if version != PROTOCOL_VERSION:
        raise UnknownVersion(f"protocol version {version} (this side speaks {PROTOCOL_VERSION})")
    cls = MESSAGE_CLASSES.get(msg_type)
    if cls is None:
        raise UnknownType(f"message type 0x{msg_type:02X}")
    body = payload[HEADER.size :]
    if len(body) != cls.BODY.size:
        raise BadLength(f"{cls.__name__} body of {len(body)} bytes, expected {cls.BODY.size}")
    try:
        message = cls.unpack_body(body)
    except ProtocolError:
        raise
    except (ValueError, struct.error, UnicodeDecodeError) as exc:  # defensive: layouts are fixed, values validated
        raise BadValue(f"{cls.__name__}: {exc}") from None
    return Packet(seq, stamp_ns, message)


def message_fields(message: Message) -> dict:
    """Field name -> value of a message (for logs and JSON)."""
    return {f.name: getattr(message, f.name) for f in fields(message)}
