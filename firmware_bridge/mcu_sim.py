"""A simulated microcontroller that speaks the protocol, for tests, benchmarks and trying the host by hand.

It drives the base along a planar path (the ground truth ``T_map_base``), integrates wheel odometry with a
calibration error, a gyro bias and noise (so the odometry drifts as a real robot's does, with a covariance that
grows accordingly), keeps its own clock (offset from the host's and drifting by ``clock_drift_ppm``), sends
heartbeats with the clock echo, asks for relocalization (with retransmission until acknowledged) and checks every
pose it receives against its ground truth at the pose's stamp. Faults can be injected into what it sends.

It talks over an *endpoint*: a pseudo-terminal it creates (the host opens the slave path, optionally through a
stable symlink), a TCP server (the host connects with ``socket://HOST:PORT``), or any pyserial URL (a real serial
adapter looped to the host). ``reloc firmware-sim --port ...`` runs it by hand; tests run it in-process.
"""

from __future__ import annotations

import contextlib
import errno
import math
import os
import select
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from .framing import encode_frame
from .messages import (
    HEADER,
    PROTOCOL_VERSION,
    Ack,
    AckResult,
    Heartbeat,
    McuState,
    MsgType,
    OdometryFlags,
    Packet,
    PoseFlags,
    PoseStatus,
    RelocPose,
    RelocReason,
    RelocRequest,
    WheelOdometry,
)
from .protocol import StreamDecoder, StreamEncoder

__all__ = [
    "PlanarPath",
    "SampledPath",
    "OdometryModel",
    "FaultInjector",
    "McuClock",
    "PtyEndpoint",
    "TcpServerEndpoint",
    "SerialEndpoint",
    "open_endpoint",
    "McuSimulator",
    "PoseCheck",
]


# ---------------------------------------------------------------------------------------------------------------
# Ground truth and odometry
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlanarPath:
    """A smooth figure-eight through a room: ``x = cx + ax sin(w t)``, ``y = cy + ay sin(2 w t) / 2``, heading along
    the velocity. Never stops, so the heading is always defined. Map frame z up; the base stays at z = 0."""

    center_m: tuple[float, float] = (3.0, 2.0)
    amplitude_m: tuple[float, float] = (2.0, 1.5)
    period_s: float = 40.0

    def state(self, t_s: float) -> tuple[float, float, float, float, float]:
        """``(x_m, y_m, yaw_rad, v_mps, omega_radps)`` at time ``t_s``."""
        w = 2 * math.pi / self.period_s
        ax, ay = self.amplitude_m
        x = self.center_m[0] + ax * math.sin(w * t_s)
        y = self.center_m[1] + ay * math.sin(2 * w * t_s) / 2
        dx, dy = ax * w * math.cos(w * t_s), ay * w * math.cos(2 * w * t_s)
        ddx, ddy = -ax * w * w * math.sin(w * t_s), -2 * ay * w * w * math.sin(2 * w * t_s)
        v2 = dx * dx + dy * dy
        return x, y, math.atan2(dy, dx), math.sqrt(v2), (dx * ddy - dy * ddx) / v2

    def T_map_base(self, t_s: float) -> np.ndarray:
        from .host import planar_transform

        x, y, yaw, _, _ = self.state(t_s)
        return planar_transform(x, y, yaw)


class SampledPath:
    """A planar path given by samples ``(t_s, x_m, y_m, yaw_rad)``, linearly interpolated (heading unwrapped); the
    base stands still before the first and after the last sample. Same interface as :class:`PlanarPath`."""

    def __init__(self, t_s, x_m, y_m, yaw_rad):
        t = np.asarray(t_s, dtype=np.float64)
        if t.ndim != 1 or t.size < 2 or np.any(np.diff(t) <= 0):
            raise ValueError(f"t_s: expected >= 2 strictly increasing times, got shape {t.shape}")
        arrays = [np.asarray(a, dtype=np.float64) for a in (x_m, y_m, yaw_rad)]
        for name, a in zip(("x_m", "y_m", "yaw_rad"), arrays):
            if a.shape != t.shape or not np.all(np.isfinite(a)):
                raise ValueError(f"{name}: expected {t.shape} finite values, got shape {a.shape}")
        self.t, self.x, self.y = t, arrays[0], arrays[1]
        self.yaw = np.unwrap(arrays[2])

    @classmethod
    def from_T_world_cam(cls, T_world_cam, rate_hz: float, T_base_cam) -> "SampledPath":
        """From a camera trajectory ``(N, 4, 4) T_world_cam`` at ``rate_hz`` and the mounting ``T_base_cam``: the
        base is ``T_world_cam @ inv(T_base_cam)``, projected to the floor plane (x, y, heading of base x)."""
        from reloc.transforms import check_transform, invert

        T = np.asarray(T_world_cam, dtype=np.float64)
        if T.ndim != 3 or T.shape[1:] != (4, 4) or len(T) < 2:
            raise ValueError(f"T_world_cam: expected (N >= 2, 4, 4) poses, got shape {T.shape}")
        if not rate_hz > 0:
            raise ValueError(f"rate_hz: expected > 0, got {rate_hz}")
        T_cam_base = invert(check_transform(T_base_cam, "T_base_cam"))
        T_world_base = T @ T_cam_base
        yaw = np.arctan2(T_world_base[:, 1, 0], T_world_base[:, 0, 0])
        return cls(np.arange(len(T)) / rate_hz, T_world_base[:, 0, 3], T_world_base[:, 1, 3], yaw)

    def state(self, t_s: float) -> tuple[float, float, float, float, float]:
        """``(x_m, y_m, yaw_rad, v_mps, omega_radps)`` at time ``t_s``."""
        t = self.t
        if t_s <= t[0] or t_s >= t[-1]:
            i = 0 if t_s <= t[0] else len(t) - 1
            return float(self.x[i]), float(self.y[i]), math.remainder(float(self.yaw[i]), 2 * math.pi), 0.0, 0.0
        i = int(np.searchsorted(t, t_s)) - 1
        dt = t[i + 1] - t[i]
        w = (t_s - t[i]) / dt
        dx, dy, dyaw = self.x[i + 1] - self.x[i], self.y[i + 1] - self.y[i], self.yaw[i + 1] - self.yaw[i]
        yaw = self.yaw[i] + w * dyaw
        return (float(self.x[i] + w * dx), float(self.y[i] + w * dy), math.remainder(float(yaw), 2 * math.pi),
                float(math.hypot(dx, dy) / dt), float(dyaw / dt))

    def T_map_base(self, t_s: float) -> np.ndarray:
        from .host import planar_transform

        x, y, yaw, _, _ = self.state(t_s)
        return planar_transform(x, y, yaw)


class OdometryModel:
    """Wheel odometry integrated from true motion with systematic and random errors.

    Per step, the true displacement ``d`` in the previous base frame and the heading change ``dyaw`` are measured
    as ``d (1 + scale_error) + N(0, sigma_d^2 |d|)`` and ``dyaw (1 + yaw_scale_error) + bias dt + N(0, sigma_yaw^2
    |dyaw| + sigma_yaw_rate^2 dt)`` and integrated; the covariance of (x, y, yaw) is propagated with the Jacobians of
    the same step. With all errors zero it reproduces the true pose in the odometry frame exactly.
    """

    def __init__(self, *, seed: int = 0, scale_error: float | None = None, yaw_scale_error: float | None = None,
                 gyro_bias_radps: float = 0.002, sigma_d_m_per_sqrt_m: float = 0.01,
                 sigma_yaw_rad_per_sqrt_rad: float = 0.01, sigma_yaw_rate_rad_per_sqrt_s: float = 0.001,
                 slip_rate_hz: float = 0.0):
        self.rng = np.random.default_rng(seed)
        self.scale_error = float(self.rng.normal(0, 0.01) if scale_error is None else scale_error)
        self.yaw_scale_error = float(self.rng.normal(0, 0.01) if yaw_scale_error is None else yaw_scale_error)
        self.gyro_bias_radps = float(gyro_bias_radps)
        self.sigma_d = float(sigma_d_m_per_sqrt_m)
        self.sigma_yaw = float(sigma_yaw_rad_per_sqrt_rad)
        self.sigma_yaw_rate = float(sigma_yaw_rate_rad_per_sqrt_s)
        self.slip_rate_hz = float(slip_rate_hz)
        self.x = self.y = self.yaw = 0.0
        self.P = np.zeros((3, 3))
        self.vx = self.omega = 0.0
        self.slips = 0

    @classmethod
    def perfect(cls) -> "OdometryModel":
        return cls(scale_error=0.0, yaw_scale_error=0.0, gyro_bias_radps=0.0, sigma_d_m_per_sqrt_m=0.0,
                   sigma_yaw_rad_per_sqrt_rad=0.0, sigma_yaw_rate_rad_per_sqrt_s=0.0)

    def step(self, prev: tuple[float, float, float], now: tuple[float, float, float], dt_s: float) -> bool:
        """Advance by the true motion from ``prev`` to ``now`` ((x, y, yaw) in the map); True when a slip happened."""
        c, s = math.cos(prev[2]), math.sin(prev[2])
        ex, ey = now[0] - prev[0], now[1] - prev[1]
        dxb, dyb = c * ex + s * ey, -s * ex + c * ey
        dyaw = math.remainder(now[2] - prev[2], 2 * math.pi)
        ds = math.hypot(dxb, dyb)
        rng = self.rng
        k = 1 + self.scale_error
        var_d = self.sigma_d**2 * ds
        dxm = dxb * k + (rng.normal(0, math.sqrt(var_d)) if var_d > 0 else 0.0)
        dym = dyb * k + (rng.normal(0, math.sqrt(var_d)) if var_d > 0 else 0.0)
        var_yaw = self.sigma_yaw**2 * abs(dyaw) + self.sigma_yaw_rate**2 * dt_s
        dyawm = dyaw * (1 + self.yaw_scale_error) + self.gyro_bias_radps * dt_s
        if var_yaw > 0:
            dyawm += rng.normal(0, math.sqrt(var_yaw))
        slip = self.slip_rate_hz > 0 and rng.random() < self.slip_rate_hz * dt_s
        if slip:
            dxm += rng.normal(0, 0.05)
            dyawm += rng.normal(0, 0.02)
            self.slips += 1
        # Integrate in the previous heading (exact for the measured increments) and propagate the covariance.
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        F = np.array([[1.0, 0.0, -s * dxm - c * dym], [0.0, 1.0, c * dxm - s * dym], [0.0, 0.0, 1.0]])
        G = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        Q = np.diag([var_d + 1e-12, var_d + 1e-12, var_yaw + 1e-12])
        self.P = F @ self.P @ F.T + G @ Q @ G.T
        self.x += c * dxm - s * dym
        self.y += s * dxm + c * dym
        self.yaw = math.remainder(self.yaw + dyawm, 2 * math.pi)
        if dt_s > 0:
            self.vx, self.omega = dxm / dt_s, dyawm / dt_s
        return slip

    def covariance_upper(self) -> tuple[float, ...]:
        P = self.P
        return (P[0, 0], P[0, 1], P[0, 2], P[1, 1], P[1, 2], P[2, 2])


@dataclass
class McuClock:
    """The MCU's clock: starts at 0 when the simulator starts and runs ``drift_ppm`` fast against the host's."""

    drift_ppm: float = 30.0
    host_start_ns: int = field(default_factory=time.monotonic_ns)

    def mcu_from_host_ns(self, host_ns: int) -> int:
        return int(round((host_ns - self.host_start_ns) * (1 + self.drift_ppm * 1e-6)))

    def host_from_mcu_ns(self, mcu_ns: int) -> int:
        return int(round(mcu_ns / (1 + self.drift_ppm * 1e-6))) + self.host_start_ns


# ---------------------------------------------------------------------------------------------------------------
# Fault injection
# ---------------------------------------------------------------------------------------------------------------
class FaultInjector:
    """Corrupts outgoing frames, one frame at a time (seeded, reproducible).

    Parameters
    ----------
    bit_error_rate:
        Probability of each bit of a frame's wire bytes (delimiters included) being flipped.
    drop_rate:
        Probability of a frame not being sent at all.
    garbage_rate:
        Probability, per frame, of a burst of random bytes (1 to ``garbage_max_bytes``) sent just before it.
    unknown_rate:
        Probability, per frame, of an extra well-formed frame of an unknown type or a future protocol version before it.
    oversize_rate:
        Probability, per frame, of an extra run of non-zero bytes longer than any frame before it.
    """

    def __init__(self, *, seed: int = 0, bit_error_rate: float = 0.0, drop_rate: float = 0.0,
                 garbage_rate: float = 0.0, garbage_max_bytes: int = 64, unknown_rate: float = 0.0,
                 oversize_rate: float = 0.0, oversize_bytes: int = 2048):
        for name, v in (("bit_error_rate", bit_error_rate), ("drop_rate", drop_rate), ("garbage_rate", garbage_rate),
                        ("unknown_rate", unknown_rate), ("oversize_rate", oversize_rate)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{name}: expected a probability in [0, 1], got {v}")
        self.rng = np.random.default_rng(seed)
        self.bit_error_rate = bit_error_rate
        self.drop_rate = drop_rate
        self.garbage_rate = garbage_rate
        self.garbage_max_bytes = int(garbage_max_bytes)
        self.unknown_rate = unknown_rate
        self.oversize_rate = oversize_rate
        self.oversize_bytes = int(oversize_bytes)
        self.counts = {"frames": 0, "dropped": 0, "corrupted": 0, "bits_flipped": 0, "garbage_bursts": 0,
                       "garbage_bytes": 0, "unknown_frames": 0, "oversize_runs": 0}

    @property
    def active(self) -> bool:
        return any((self.bit_error_rate, self.drop_rate, self.garbage_rate, self.unknown_rate, self.oversize_rate))

    def apply(self, wire: bytes) -> tuple[bytes, str]:
        """``(bytes to send, fate)`` of one frame; fate is "intact", "dropped" or "corrupted"."""
        rng, c = self.rng, self.counts
        c["frames"] += 1
        prefix = b""
        if self.garbage_rate and rng.random() < self.garbage_rate:
            n = int(rng.integers(1, self.garbage_max_bytes + 1))
            prefix += rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            c["garbage_bursts"] += 1
            c["garbage_bytes"] += n
        if self.unknown_rate and rng.random() < self.unknown_rate:
            if rng.random() < 0.5:
                header = HEADER.pack(PROTOCOL_VERSION, 0x7E, 0, 0)  # a type this version does not define
            else:
                header = HEADER.pack(PROTOCOL_VERSION + 1, int(MsgType.HEARTBEAT), 0, 0)  # a future version
            prefix += encode_frame(header + rng.integers(0, 256, 24, dtype=np.uint8).tobytes())
            c["unknown_frames"] += 1
        if self.oversize_rate and rng.random() < self.oversize_rate:
            prefix += b"\x00" + rng.integers(1, 256, self.oversize_bytes, dtype=np.uint8).tobytes() + b"\x00"
            c["oversize_runs"] += 1
        if self.drop_rate and rng.random() < self.drop_rate:
            c["dropped"] += 1
            return prefix, "dropped"
        fate = "intact"
        if self.bit_error_rate:
            n_flips = int(rng.binomial(len(wire) * 8, self.bit_error_rate))
            if n_flips:
                buf = bytearray(wire)
                for bit in rng.choice(len(wire) * 8, size=n_flips, replace=False):
                    buf[bit // 8] ^= 1 << (bit % 8)
                wire = bytes(buf)
                c["corrupted"] += 1
                c["bits_flipped"] += n_flips
                fate = "corrupted"
        return prefix + wire, fate


# ---------------------------------------------------------------------------------------------------------------
# Endpoints: where the simulated firmware's bytes go
# ---------------------------------------------------------------------------------------------------------------
class PtyEndpoint:
    """A pseudo-terminal pair; the simulator holds the master, the host opens :attr:`path` (the slave, or the
    symlink ``link_path`` to it, which survives a close and reopen as a USB device's name does).

    The slave side is put in raw mode at once and kept open by this object, so data the simulator writes before the
    host opens the port is neither echoed nor altered, and the host may close and reopen the port at will.
    """

    def __init__(self, link_path: str | os.PathLike | None = None):
        import tty

        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.slave_path = os.ttyname(self.slave)
        self.link_path = None if link_path is None else os.fspath(link_path)
        if self.link_path is not None:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(self.link_path)
            os.symlink(self.slave_path, self.link_path)
        self.connections = 1
        self._closed = False

    @property
    def path(self) -> str:
        return self.link_path or self.slave_path

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        if self._closed:
            raise OSError(errno.EBADF, "endpoint closed")
        r, _, _ = select.select([self.master], [], [], max(0.0, timeout_s))
        if not r:
            return b""
        try:
            return os.read(self.master, max_bytes)
        except BlockingIOError:
            return b""

    def pending(self) -> int:
        """Bytes written and not yet read by the host (the slave's input queue; 0 once closed)."""
        import fcntl
        import struct
        import termios

        if self._closed:
            return 0
        try:
            return struct.unpack("i", fcntl.ioctl(self.slave, termios.FIONREAD, b"\0\0\0\0"))[0]
        except OSError:  # the slave side is gone: nothing more will be read
            return 0

    def write(self, data: bytes, timeout_s: float) -> bool:
        """Write all of ``data`` within ``timeout_s``; False (rest dropped) when the host does not read."""
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        while view:
            try:
                n = os.write(self.master, view)
                view = view[n:]
            except BlockingIOError:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                select.select([], [self.master], [], remaining)
        return True

    def close(self) -> None:
        """Unplug: remove the symlink and close both sides (the host's reads fail with an I/O error)."""
        if self._closed:
            return
        self._closed = True
        if self.link_path is not None:
            with contextlib.suppress(OSError):
                if os.readlink(self.link_path) == self.slave_path:
                    os.unlink(self.link_path)
        for fd in (self.master, self.slave):
            with contextlib.suppress(OSError):
                os.close(fd)


class TcpServerEndpoint:
    """A TCP server for one client at a time (the host connects with ``socket://HOST:PORT``).

    ``port=0`` picks a free port (see :attr:`port`). When the client goes away the next one is accepted;
    :attr:`connections` counts them so the simulator can restart its stream state.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0):
        self._server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._server.bind((host, port))
        self._server.listen(1)
        self._server.setblocking(False)
        self.host, self.port = self._server.getsockname()[:2]
        self._conn: socket.socket | None = None
        self.connections = 0
        self._closed = False

    @property
    def path(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def _drop_conn(self) -> None:
        if self._conn is not None:
            with contextlib.suppress(OSError):
                self._conn.close()
            self._conn = None

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        if self._closed:
            raise OSError(errno.EBADF, "endpoint closed")
        sock = self._conn or self._server
        r, _, _ = select.select([sock], [], [], max(0.0, timeout_s))
        if not r:
            return b""
        if self._conn is None:
            try:
                conn, _ = self._server.accept()
            except BlockingIOError:
                return b""
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.setblocking(False)
            self._conn = conn
            self.connections += 1
            return b""
        try:
            data = self._conn.recv(max_bytes)
        except BlockingIOError:
            return b""
        except OSError:
            data = b""
        if not data:
            self._drop_conn()  # client gone; wait for the next one
        return data

    def write(self, data: bytes, timeout_s: float) -> bool:
        if self._conn is None:
            return False
        view = memoryview(data)
        deadline = time.monotonic() + timeout_s
        try:
            while view:
                try:
                    n = self._conn.send(view)
                    view = view[n:]
                except BlockingIOError:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return False
                    select.select([], [self._conn], [], remaining)
        except OSError:
            self._drop_conn()
            return False
        return True

    def close(self) -> None:
        """The server goes away: the client's reads fail, its reconnects are refused until a new server binds."""
        if self._closed:
            return
        self._closed = True
        self._drop_conn()
        with contextlib.suppress(OSError):
            self._server.close()


class SerialEndpoint:
    """Any pyserial URL (e.g. a USB-serial adapter wired to the host's port); reopened after an error."""

    def __init__(self, url: str, *, baudrate: int = 921600, reopen_wait_s: float = 0.5):
        self.url = url
        self.baudrate = baudrate
        self.reopen_wait_s = reopen_wait_s
        self._port = None
        self._next_open = 0.0
        self.connections = 0

    @property
    def path(self) -> str:
        return self.url

    def _ensure(self) -> bool:
        import serial

        if self._port is not None:
            return True
        if time.monotonic() < self._next_open:
            return False
        try:
            self._port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.01, write_timeout=0.2)
            self.connections += 1
            return True
        except (serial.SerialException, OSError):
            self._next_open = time.monotonic() + self.reopen_wait_s
            return False

    def _fail(self) -> None:
        with contextlib.suppress(Exception):
            self._port.close()
        self._port = None
        self._next_open = time.monotonic() + self.reopen_wait_s

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        import serial

        if not self._ensure():
            time.sleep(min(timeout_s, 0.05))
            return b""
        try:
            self._port.timeout = max(0.0, timeout_s)
            waiting = self._port.in_waiting
            return self._port.read(min(max_bytes, waiting) if waiting else 1)
        except (serial.SerialException, OSError):
            self._fail()
            return b""

    def write(self, data: bytes, timeout_s: float) -> bool:
        import serial

        if self._port is None:
            return False
        try:
            self._port.write(data)
            return True
        except serial.SerialTimeoutException:
            return False
        except (serial.SerialException, OSError):
            self._fail()
            return False

    def close(self) -> None:
        if self._port is not None:
            with contextlib.suppress(Exception):
                self._port.close()
            self._port = None


def open_endpoint(spec: str, *, baudrate: int = 921600):
    """``pty`` | ``pty:LINK_PATH`` | ``tcp-listen:[HOST:]PORT`` | any pyserial URL or device path."""
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"port: expected 'pty', 'pty:PATH', 'tcp-listen:[HOST:]PORT' or a pyserial URL, got {spec!r}")
    if spec == "pty":
        return PtyEndpoint()
    if spec.startswith("pty:"):
        return PtyEndpoint(spec[4:])
    if spec.startswith("tcp-listen:"):
        rest = spec[len("tcp-listen:"):]
        host, _, port = rest.rpartition(":")
        try:
            return TcpServerEndpoint(host or "127.0.0.1", int(port))
        except ValueError:
            raise ValueError(f"port: expected tcp-listen:[HOST:]PORT with an integer PORT, got {spec!r}") from None
    return SerialEndpoint(spec, baudrate=baudrate)


# ---------------------------------------------------------------------------------------------------------------
# The simulated firmware
# ---------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PoseCheck:
    """One received pose compared with the ground truth at its stamp."""

    request_id: int
    status: int
    stamp_mcu_ns: int
    position_error_m: float
    yaw_error_deg: float
    ok: bool
    latency_ns: int | None  # from the first transmission of the request to the pose's arrival (MCU clock)
    # False for a pose sent before the host's clock was synced (no STAMP_MCU_CLOCK flag): it is judged at its
    # arrival time, so its error includes the robot's motion during the pose's latency, not only the host's error.
    stamped: bool = True
    # sqrt of the trace of the pose covariance's translation block (m); NaN when the host sent none (all zeros).
    position_sigma_m: float = math.nan


class McuSimulator:
    """The simulated firmware (see the module docstring). ``start()``/``stop()`` run it in a thread.

    Parameters
    ----------
    endpoint:
        A :class:`PtyEndpoint`, :class:`TcpServerEndpoint` or :class:`SerialEndpoint` (closed by ``stop()`` only if
        ``close_endpoint``).
    path:
        Ground truth ``T_map_base`` over time (MCU clock, seconds since the simulator started): a
        :class:`PlanarPath` (default) or a :class:`SampledPath` (e.g. a simulator robot trajectory).
    odometry:
        The wheel odometry model (default: :class:`OdometryModel` seeded with ``seed``).
    odom_rate_hz, heartbeat_period_s:
        Odometry and heartbeat rates.
    reloc_period_s:
        A relocalization request this often once the host is alive (0 = only on :meth:`request_relocalization`).
    ack_timeout_s, max_retries, pose_timeout_s:
        A request is retransmitted (same id) until acknowledged, up to ``max_retries`` times; a pose that does not
        come within ``pose_timeout_s`` after the acknowledgement counts as unanswered.
    host_timeout_s:
        The host counts as gone after this long without a frame from it.
    clock_drift_ppm:
        The MCU clock's rate error against the host's.
    pose_tolerance_m, pose_tolerance_deg:
        A received OK/TRACKED pose within these of the ground truth at its stamp counts as correct.
    faults, silent_after_s, silent_for_s, flood_hz:
        Fault injection on what the simulator sends; a silent window (nothing sent, then resumes); odometry sent at
        ``flood_hz`` instead of ``odom_rate_hz``. :meth:`unplug` and :meth:`plug` pull and reconnect the cable
        (optionally in the middle of a frame).
    record_sent:
        Keep the last this many sent messages in :attr:`sent_log` (seq -> message), for tests that check that what
        the host accepted is exactly what was sent.
    """

    def __init__(self, endpoint, *, path: PlanarPath | SampledPath | None = None,
                 odometry: OdometryModel | None = None, odom_rate_hz: float = 50.0, heartbeat_period_s: float = 0.5,
                 reloc_period_s: float = 2.0,
                 ack_timeout_s: float = 0.25, max_retries: int = 4, pose_timeout_s: float = 2.0,
                 host_timeout_s: float = 1.5, clock_drift_ppm: float = 30.0, seed: int = 0,
                 pose_tolerance_m: float = 0.05, pose_tolerance_deg: float = 2.0, faults: FaultInjector | None = None,
                 silent_after_s: float | None = None, silent_for_s: float = 0.0, flood_hz: float = 0.0,
                 write_timeout_s: float = 0.05, close_endpoint: bool = True, record_sent: int = 0):
        if odom_rate_hz <= 0 or heartbeat_period_s <= 0:
            raise ValueError(
                f"odom_rate_hz, heartbeat_period_s: expected > 0, got {odom_rate_hz}, {heartbeat_period_s}"
            )
        self.endpoint = endpoint
        self.path = path or PlanarPath()
        self.odometry = odometry or OdometryModel(seed=seed)
        self.odom_period_ns = int(1e9 / (flood_hz if flood_hz > 0 else odom_rate_hz))
        self.heartbeat_period_ns = int(heartbeat_period_s * 1e9)
        self.reloc_period_ns = int(reloc_period_s * 1e9)
        self.ack_timeout_ns = int(ack_timeout_s * 1e9)
        self.max_retries = int(max_retries)
        self.pose_timeout_ns = int(pose_timeout_s * 1e9)
        self.host_timeout_ns = int(host_timeout_s * 1e9)
        self.clock = McuClock(clock_drift_ppm)
        self.pose_tolerance_m = pose_tolerance_m
        self.pose_tolerance_deg = pose_tolerance_deg
        self.faults = faults
        self.silent_window_ns = (
            None if silent_after_s is None else (int(silent_after_s * 1e9), int((silent_after_s + silent_for_s) * 1e9))
        )
        self.write_timeout_s = write_timeout_s
        self.close_endpoint = close_endpoint
        self.drain_result: str | None = None  # how stop() ended its wait for the host: empty, stalled or timeout
        self.decoder = StreamDecoder()
        self.encoder = StreamEncoder()
        self.state = McuState.BOOT
        self.counters = {
            "odometry_sent": 0, "heartbeats_sent": 0, "bytes_unread_at_stop": 0, "requests_sent": 0,
            "request_retransmissions": 0,
            "requests_acked": 0, "requests_failed": 0, "requests_unanswered": 0, "poses_received": 0,
            "poses_ok": 0, "poses_bad": 0, "poses_rejected": 0, "poses_unexpected": 0, "poses_unsynced": 0,
            "host_heartbeats": 0, "host_status": 0, "acks_received": 0, "write_failures": 0, "silent_frames": 0,
            "host_timeouts": 0, "connections": 0, "unplugs": 0, "half_frames_sent": 0,
        }
        self.pose_checks: deque[PoseCheck] = deque(maxlen=10_000)
        # seq -> message of the last ``record_sent`` frames sent (tests check what the host accepted against it).
        self.sent_log: dict[int, object] = {}
        self._record_sent = int(record_sent)
        self.host_state: int | None = None
        self.host_last_error = ""
        self._host_hb: tuple[int, int] | None = None  # (host stamp, our arrival time)
        self._host_last_rx: int | None = None
        self._next_request_id = 1
        self._request: dict | None = None  # the outstanding request
        self._request_first_sent: dict[int, int] = {}
        self._manual_requests: deque[int] = deque()
        self._lock = threading.Lock()
        self._cable_request: tuple[str, object] | None = None  # ("unplug", (mid_frame, hold_s)) | ("plug", endpoint)
        self._unplugged = False
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connections_seen = 0
        self.error: str | None = None

    # -- time --------------------------------------------------------------------------------------------------
    def now_mcu_ns(self) -> int:
        return self.clock.mcu_from_host_ns(time.monotonic_ns())

    def true_T_map_base_at_mcu(self, mcu_ns: int) -> np.ndarray:
        return self.path.T_map_base(mcu_ns * 1e-9)

    def true_T_map_base_at_host(self, host_ns: int) -> np.ndarray:
        """Ground truth for a host timestamp (what a perfect relocalizer would send)."""
        return self.true_T_map_base_at_mcu(self.clock.mcu_from_host_ns(host_ns))

    # -- control -----------------------------------------------------------------------------------------------
    def start(self) -> "McuSimulator":
        self._thread = threading.Thread(target=self._run_guarded, name="mcu-sim", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 2.0, drain_s: float = 1.0) -> None:
        """Stop sending; then, before closing the endpoint, give the host up to ``drain_s`` to read what is still on
        the line (a pseudo-terminal drops unread bytes when it closes, so a stop would otherwise lose the last
        messages unseen). The wait ends early once the host stops reading. :meth:`unplug` does not wait."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self.close_endpoint:
            pending = getattr(self.endpoint, "pending", None)
            if pending is not None:
                self.drain_result = self._drain(pending, drain_s)
                self.counters["bytes_unread_at_stop"] = pending()
            self.endpoint.close()

    @staticmethod
    def _drain(pending, drain_s: float, stalled_s: float = 0.25) -> str:
        """Wait until ``pending()`` has read 0 a few times in a row (the kernel moves written bytes to the reader's
        queue a moment after the write, so one 0 proves nothing): "empty"; until it stops changing for
        ``stalled_s``: "stalled"; or until ``drain_s`` has passed: "timeout"."""
        start = time.monotonic()
        last, last_change, zeros = -1, start, 0
        while (now := time.monotonic()) - start < drain_s:
            left = pending()
            zeros = zeros + 1 if left == 0 else 0
            if zeros >= 3:
                return "empty"
            if left != last:
                last, last_change = left, now
            elif now - last_change >= stalled_s:
                return "stalled"
            time.sleep(0.005)
        return "timeout"

    def __enter__(self) -> "McuSimulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    def run(self, duration_s: float | None = None) -> None:
        """Run in the calling thread for ``duration_s`` (None = until :meth:`stop` from another thread)."""
        end = None if duration_s is None else time.monotonic() + duration_s
        while not self._stop.is_set() and (end is None or time.monotonic() < end):
            self._step()

    def request_relocalization(self, reason: int = RelocReason.MANUAL) -> None:
        """Ask for a relocalization at the next loop turn (thread-safe)."""
        with self._lock:
            self._manual_requests.append(int(reason))

    def unplug(self, *, mid_frame: bool = True, hold_s: float = 0.1) -> None:
        """Fault: pull the cable (thread-safe; done at the next loop turn). With ``mid_frame`` the first half of a
        heartbeat frame goes out and stays on the line ``hold_s`` before the endpoint is closed, as when a cable is
        pulled during a write. The firmware keeps driving (its clock and odometry run on); it sends and reads
        nothing until :meth:`plug`."""
        with self._lock:
            self._cable_request = ("unplug", (bool(mid_frame), float(hold_s)))

    def plug(self, endpoint) -> None:
        """Fault: the cable is back, on ``endpoint`` (e.g. a new :class:`PtyEndpoint` at the same link path); the
        stream starts afresh as on any new connection (thread-safe)."""
        with self._lock:
            self._cable_request = ("plug", endpoint)

    @property
    def unplugged(self) -> bool:
        return self._unplugged

    def _cable(self) -> bool:
        """Carry out an unplug or plug request; True while unplugged."""
        with self._lock:
            request, self._cable_request = self._cable_request, None
        if request is not None and request[0] == "unplug" and not self._unplugged:
            mid_frame, hold_s = request[1]
            if mid_frame:
                _, wire = self.encoder.encode(Heartbeat(self.state, 0, 0, 0, 0, 0), self.now_mcu_ns())
                if self._send_raw(wire[: len(wire) // 2]):
                    self.counters["half_frames_sent"] += 1
                self._stop.wait(hold_s)
            with contextlib.suppress(OSError):
                self.endpoint.close()
            self._unplugged = True
            self.counters["unplugs"] += 1
        elif request is not None and request[0] == "plug":
            self.endpoint = request[1]
            self._unplugged = False
            self._connections_seen = -1  # a new connection: fresh decoder, a delimiter and a heartbeat at once
        if self._unplugged:
            self._stop.wait(0.01)
        return self._unplugged

    def stats(self) -> dict:
        with self._lock:
            out = dict(self.counters)
        out["decoder"] = self.decoder.stats.as_dict()
        if self.faults is not None:
            out["faults"] = dict(self.faults.counts)
        lat = [c.latency_ns for c in list(self.pose_checks) if c.latency_ns is not None]
        if lat:
            out["latency_ms_p50"] = float(np.percentile(lat, 50) / 1e6)
        errs = [c.position_error_m for c in list(self.pose_checks) if c.status in (PoseStatus.OK, PoseStatus.TRACKED)]
        if errs:
            out["pose_error_m_max"] = float(max(errs))
        return out

    # -- the firmware's main loop ------------------------------------------------------------------------------
    def _run_guarded(self) -> None:
        try:
            self.run()
        except Exception as exc:  # noqa: BLE001 - surfaced through .error for the test or the CLI to report
            self.error = repr(exc)
            raise

    def _step(self) -> None:
        if not hasattr(self, "_next_odom"):
            self._init_schedule()
        if self._cable():
            return
        now = self.now_mcu_ns()
        wait_ns = min(self._next_odom, self._next_hb) - now
        data = self.endpoint.read(4096, min(max(wait_ns, 0) / 1e9, 0.01))
        connections = getattr(self.endpoint, "connections", 1)
        if connections != self._connections_seen:
            # A new connection: the host starts a fresh stream, and so do we.
            self._connections_seen = connections
            self.decoder.reset()
            self.counters["connections"] += 1
            self._send_raw(b"\x00")
            self._next_hb = self.now_mcu_ns()  # a heartbeat right away (docs/protocol.md, 5.1)
        if data:
            rx = self.now_mcu_ns()
            for packet in self.decoder.feed(data):
                self._on_packet(packet, rx)
        now = self.now_mcu_ns()
        if now >= self._next_odom:
            self._send_odometry(now)
            self._next_odom += self.odom_period_ns
            if self._next_odom < now:  # fell behind (descheduled): skip rather than burst
                self._next_odom = now + self.odom_period_ns
        if now >= self._next_hb:
            self._send_heartbeat(now)
            self._next_hb = now + self.heartbeat_period_ns
        self._requests(now)

    def _init_schedule(self) -> None:
        now = self.now_mcu_ns()
        self._start_ns = now
        self._next_odom = now
        self._next_hb = now
        self._next_periodic_request = now + (self.reloc_period_ns if self.reloc_period_ns else 2**62)
        self._last_truth = self.path.state(now * 1e-9)[:3]
        self._last_truth_ns = now
        self.state = McuState.DRIVING

    def _host_alive(self, now: int) -> bool:
        return self._host_last_rx is not None and now - self._host_last_rx <= self.host_timeout_ns

    def _send(self, message, now: int) -> int | None:
        if self.silent_window_ns is not None:
            t = now - self._start_ns
            if self.silent_window_ns[0] <= t < self.silent_window_ns[1]:
                self.counters["silent_frames"] += 1
                return None
        seq, wire = self.encoder.encode(message, now)
        if self._record_sent:
            self.sent_log[seq] = message
            if len(self.sent_log) > self._record_sent:
                self.sent_log.pop(next(iter(self.sent_log)))
        if self.faults is not None and self.faults.active:
            wire, _ = self.faults.apply(wire)
        if not self._send_raw(wire):
            return None
        return seq

    def _send_raw(self, data: bytes) -> bool:
        if not data:
            return True
        try:
            ok = self.endpoint.write(data, self.write_timeout_s)
        except OSError:
            ok = False
        if not ok:
            self.counters["write_failures"] += 1
        return ok

    def _send_odometry(self, now: int) -> None:
        truth = self.path.state(now * 1e-9)[:3]
        slip = self.odometry.step(self._last_truth, truth, (now - self._last_truth_ns) * 1e-9)
        self._last_truth, self._last_truth_ns = truth, now
        o = self.odometry
        msg = WheelOdometry(now, o.x, o.y, o.yaw, o.vx, 0.0, o.omega, o.covariance_upper(), 0,
                            OdometryFlags.SLIP if slip else 0)
        if self._send(msg, now) is not None:
            self.counters["odometry_sent"] += 1

    def _send_heartbeat(self, now: int) -> None:
        echo, hold = (0, 0) if self._host_hb is None else (self._host_hb[0], now - self._host_hb[1])
        hb = Heartbeat(self.state, 0, min(self.decoder.stats.frames_bad, 0xFFFF), (now // 1_000_000) & 0xFFFFFFFF,
                       echo, hold)
        if self._send(hb, now) is not None:
            self.counters["heartbeats_sent"] += 1
        if self._host_last_rx is not None and not self._host_alive(now) and self._host_hb is not None:
            self.counters["host_timeouts"] += 1
            self._host_hb = None

    def _requests(self, now: int) -> None:
        req = self._request
        if req is not None:
            if not req["acked"] and now - req["sent"] >= self.ack_timeout_ns:
                if req["retries"] >= self.max_retries:
                    self.counters["requests_failed"] += 1
                    self._request = None
                else:
                    req["retries"] += 1
                    self.counters["request_retransmissions"] += 1
                    self._transmit_request(req, now)
            elif req["acked"] and now - req["acked_at"] >= self.pose_timeout_ns:
                self.counters["requests_unanswered"] += 1
                self._request = None
            return
        with self._lock:
            reason = self._manual_requests.popleft() if self._manual_requests else None
        if reason is None and now >= self._next_periodic_request and self._host_alive(now):
            reason = RelocReason.PERIODIC if self.counters["requests_sent"] else RelocReason.BOOT
            self._next_periodic_request = now + self.reloc_period_ns
        if reason is None:
            return
        rid = self._next_request_id
        self._next_request_id = rid % 0xFFFF + 1
        req = {"id": rid, "reason": reason, "sent": now, "retries": 0, "acked": False, "acked_at": 0, "seqs": set()}
        self._request = req
        self._request_first_sent[rid] = now
        if len(self._request_first_sent) > 1000:
            self._request_first_sent.pop(next(iter(self._request_first_sent)))
        self.counters["requests_sent"] += 1
        self._transmit_request(req, now)

    def _transmit_request(self, req: dict, now: int) -> None:
        req["sent"] = now
        seq = self._send(RelocRequest(req["id"], req["reason"]), now)
        if seq is not None:
            req["seqs"].add(seq)

    def _on_packet(self, packet: Packet, rx: int) -> None:
        msg = packet.message
        self._host_last_rx = rx
        t = msg.TYPE
        if t == MsgType.HEARTBEAT:
            self.counters["host_heartbeats"] += 1
            self._host_hb = (packet.stamp_ns, rx)
            self.host_state = msg.state
        elif t == MsgType.HOST_STATUS:
            self.counters["host_status"] += 1
            self.host_state = msg.state
            self.host_last_error = msg.last_error
        elif t == MsgType.ACK:
            self.counters["acks_received"] += 1
            req = self._request
            if (req is not None and msg.acked_type == MsgType.RELOC_REQUEST and msg.ref_id == req["id"]
                    and not req["acked"]):
                req["acked"], req["acked_at"] = True, rx
                self.counters["requests_acked"] += 1
        elif t == MsgType.RELOC_POSE:
            self._on_pose(packet, msg, rx)

    def _on_pose(self, packet: Packet, pose: RelocPose, rx: int) -> None:
        self.counters["poses_received"] += 1
        self._send(Ack(MsgType.RELOC_POSE, AckResult.ACCEPTED, packet.seq, pose.request_id), self.now_mcu_ns())
        req = self._request
        latency = None
        if pose.request_id:
            if req is not None and req["id"] == pose.request_id:
                self._request = None
            elif pose.request_id not in self._request_first_sent:
                self.counters["poses_unexpected"] += 1
            first = self._request_first_sent.pop(pose.request_id, None)
            latency = None if first is None else rx - first
        if pose.status not in (PoseStatus.OK, PoseStatus.TRACKED):
            self.counters["poses_rejected"] += 1
            self.pose_checks.append(PoseCheck(pose.request_id, pose.status, 0, math.nan, math.nan, False, latency))
            return
        stamped = bool(pose.flags & PoseFlags.STAMP_MCU_CLOCK)
        if stamped:
            stamp = pose.stamp_ns
        else:
            self.counters["poses_unsynced"] += 1
            stamp = rx
        x, y, yaw, _, _ = self.path.state(stamp * 1e-9)
        T = pose.transform()
        pos_err = math.sqrt((T[0, 3] - x) ** 2 + (T[1, 3] - y) ** 2 + T[2, 3] ** 2)
        yaw_err = math.degrees(abs(math.remainder(math.atan2(T[1, 0], T[0, 0]) - yaw, 2 * math.pi)))
        ok = pos_err <= self.pose_tolerance_m and yaw_err <= self.pose_tolerance_deg
        self.counters["poses_ok" if ok else "poses_bad"] += 1
        cov = pose.covariance_matrix()
        sigma = math.sqrt(max(float(np.trace(cov[:3, :3])), 0.0)) if np.any(cov) else math.nan
        self.pose_checks.append(PoseCheck(pose.request_id, pose.status, stamp, pos_err, yaw_err, ok, latency, stamped,
                                          sigma))
