"""The transport: a pyserial port, a reader thread that never dies, reconnection with backoff.

Any pyserial URL works the same (``/dev/ttyACM0``, a pseudo-terminal path, ``loop://``, ``socket://HOST:PORT``,
``rfc2217://...``). The reader thread owns the port's lifecycle: it opens it (retrying with the backoff schedule
while it is absent), sends a delimiter so the peer resynchronises at once, discards stale input, decodes what
arrives and hands packets to a callback. An unplugged device (pyserial's ``SerialException``, or ``OSError``) on
read or write is reported through the event callback, the port is closed, and the thread goes back to reopening it,
so the program carries on and the link returns when the device does. Every write is bounded by the write timeout.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Callable

from .messages import Message, Packet
from .protocol import StreamDecoder, StreamEncoder

__all__ = ["LinkEvent", "LinkStats", "SerialLink", "open_port"]


@dataclass(frozen=True)
class LinkEvent:
    """Something that happened to the link: ``kind`` in connected, disconnected, open_failed, write_timeout,
    write_failed, callback_error, closed."""

    kind: str
    detail: str
    stamp_ns: int


@dataclass
class LinkStats:
    connects: int = 0
    disconnects: int = 0
    open_failures: int = 0
    frames_sent: int = 0
    bytes_sent: int = 0
    write_timeouts: int = 0
    write_failures: int = 0
    send_while_down: int = 0
    callback_errors: int = 0


def open_port(url: str, *, baudrate: int, read_timeout_s: float, write_timeout_s: float):
    """Open any pyserial URL with the link's settings (the reader relies on the read timeout to stay responsive)."""
    import socket

    import serial

    port = serial.serial_for_url(url, baudrate=baudrate, timeout=read_timeout_s, write_timeout=write_timeout_s)
    sock = getattr(port, "_socket", None)  # socket:// keeps Nagle on: small frames would wait for the peer's ACK
    if sock is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass
    return port


class SerialLink:
    """One end of the framed link over a pyserial URL.

    Parameters
    ----------
    url:
        pyserial URL or device path.
    baudrate, read_timeout_s, write_timeout_s:
        Port settings; a read returns after at most ``read_timeout_s`` so the thread notices ``close()`` quickly.
    reconnect_backoff_s:
        Waits between reopen attempts while the port is absent; the last value repeats.
    max_frame_bytes:
        Longer incoming frames are dropped and counted.
    on_packet:
        ``f(packet, rx_ns)`` called in the reader thread for every good packet, with the host clock at arrival.
        Exceptions are caught, counted and reported; they never stop the thread.
    on_event:
        ``f(LinkEvent)`` called (from the reader or the sending thread) on connect, disconnect and errors.
    on_connect:
        ``f()`` called in the reader thread right after each (re)connection, before any packet is delivered.
    clock_ns:
        Host clock for arrival stamps and outgoing headers (default ``time.monotonic_ns``).
    opener:
        ``f() -> port`` replacing :func:`open_port` (tests, exotic transports). The port needs ``read``, ``write``,
        ``close`` and optionally ``in_waiting``, ``reset_input_buffer``, ``cancel_read``.
    """

    def __init__(
        self,
        url: str,
        *,
        baudrate: int = 921600,
        read_timeout_s: float = 0.05,
        write_timeout_s: float = 0.2,
        reconnect_backoff_s=(0.1, 0.2, 0.5, 1.0, 2.0),
        max_frame_bytes: int = 512,
        on_packet: Callable[[Packet, int], None] | None = None,
        on_event: Callable[[LinkEvent], None] | None = None,
        on_connect: Callable[[], None] | None = None,
        clock_ns: Callable[[], int] = time.monotonic_ns,
        opener: Callable[[], object] | None = None,
        name: str = "serial-link",
    ):
        if not isinstance(url, str) or not url:
            raise ValueError(f"url: expected a pyserial URL or device path, got {url!r}")
        if "://" in url and opener is None:
            import importlib.util

            scheme = url.split("://", 1)[0].lower().replace("-", "_")
            if not scheme.isidentifier() or importlib.util.find_spec(f"serial.urlhandler.protocol_{scheme}") is None:
                raise ValueError(f"url: pyserial has no handler for {scheme!r} in {url!r} "
                                 "(expected a device path, loop://, socket://HOST:PORT, rfc2217://, ...)")
        if read_timeout_s <= 0 or write_timeout_s <= 0:
            raise ValueError(f"read_timeout_s, write_timeout_s: expected > 0, got {read_timeout_s}, {write_timeout_s}")
        backoff = tuple(float(b) for b in reconnect_backoff_s)
        if not backoff or min(backoff) < 0:
            raise ValueError(f"reconnect_backoff_s: expected a non-empty list of waits >= 0, got {reconnect_backoff_s}")
        self.url = url
        self.baudrate = int(baudrate)
        self.read_timeout_s = float(read_timeout_s)
        self.write_timeout_s = float(write_timeout_s)
        self.reconnect_backoff_s = backoff
        self.on_packet = on_packet
        self.on_event = on_event
        self.on_connect = on_connect
        self.clock_ns = clock_ns
        self._opener = opener or (
            lambda: open_port(url, baudrate=self.baudrate, read_timeout_s=self.read_timeout_s,
                              write_timeout_s=self.write_timeout_s)
        )
        self.decoder = StreamDecoder(max_frame_bytes)
        self.encoder = StreamEncoder()
        self.stats = LinkStats()
        self.last_error: str = ""
        self._port = None
        self._broken = False
        self._write_lock = threading.Lock()
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._started = False

    # -- lifecycle ---------------------------------------------------------------------------------------------
    def start(self) -> "SerialLink":
        if not self._started:
            self._started = True
            self._thread.start()
        return self

    def close(self, timeout_s: float = 2.0) -> None:
        """Stop the reader thread, close the port and join the thread."""
        self._stop.set()
        port = self._port
        if port is not None and hasattr(port, "cancel_read"):
            try:
                port.cancel_read()
            except Exception:  # noqa: BLE001 - best effort: the read timeout ends the read anyway
                pass
        if self._started:
            self._thread.join(timeout_s)
        self._close_port()
        self._emit("closed", "")

    def __enter__(self) -> "SerialLink":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def wait_connected(self, timeout_s: float) -> bool:
        return self._connected.wait(timeout_s)

    @property
    def alive(self) -> bool:
        """The reader thread is running."""
        return self._thread.is_alive()

    # -- sending -----------------------------------------------------------------------------------------------
    def send(self, message: Message, stamp_ns: int | None = None) -> int | None:
        """Frame and write ``message``; returns its seq, or None when the link is down or the write failed.

        Thread-safe. A write blocked longer than the write timeout is abandoned and counted (the receiver drops the
        partial frame: the next frame starts with a delimiter).
        """
        import serial

        stamp = self.clock_ns() if stamp_ns is None else stamp_ns
        with self._write_lock:
            port = self._port
            if port is None or self._broken:
                self.stats.send_while_down += 1
                return None
            seq, wire = self.encoder.encode(message, stamp)
            try:
                written = port.write(wire)
            except serial.SerialTimeoutException as exc:
                self.stats.write_timeouts += 1
                self._emit("write_timeout", str(exc))
                return None
            except (serial.SerialException, OSError) as exc:
                self.stats.write_failures += 1
                self._mark_broken(f"write failed: {exc}")
                return None
            if written is not None and written != len(wire):
                self.stats.write_timeouts += 1
                self._emit("write_timeout", f"wrote {written} of {len(wire)} bytes")
                return None
            self.stats.frames_sent += 1
            self.stats.bytes_sent += len(wire)
            return seq

    def send_raw(self, data: bytes) -> bool:
        """Write bytes as they are (fault injection in tests and benchmarks)."""
        import serial

        with self._write_lock:
            port = self._port
            if port is None or self._broken:
                return False
            try:
                port.write(data)
                return True
            except (serial.SerialException, OSError) as exc:
                self._mark_broken(f"write failed: {exc}")
                return False

    # -- internals ---------------------------------------------------------------------------------------------
    def _emit(self, kind: str, detail: str) -> None:
        if kind in ("disconnected", "open_failed", "write_failed"):
            self.last_error = detail
        if self.on_event is not None:
            try:
                self.on_event(LinkEvent(kind, detail, self.clock_ns()))
            except Exception:  # noqa: BLE001 - a faulty observer must not take the link down
                self.stats.callback_errors += 1

    def _mark_broken(self, detail: str) -> None:
        # Called with the write lock held or from the reader; the reader closes and reopens the port.
        if not self._broken:
            self._broken = True
            self._emit("write_failed", detail)
            port = self._port
            if port is not None and hasattr(port, "cancel_read"):
                try:
                    port.cancel_read()
                except Exception:  # noqa: BLE001
                    pass

    def _close_port(self) -> None:
        with self._write_lock:
            port, self._port = self._port, None
            self._connected.clear()
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - closing a vanished device may fail; it is gone either way
                pass

    def _try_open(self) -> bool:
        import serial

        port = None
        try:
            port = self._opener()
            if hasattr(port, "reset_input_buffer"):
                port.reset_input_buffer()  # bytes from before this connection are stale
            try:
                port.write(b"\x00")  # the peer drops any partial frame and is in step from our first byte
            except serial.SerialTimeoutException as exc:
                # Open, but the peer is not reading: a write that timed out, as later ones may; the port is kept
                # (the peer's frames still come in) and the next frame's leading delimiter resyncs it.
                self.stats.write_timeouts += 1
                self._emit("write_timeout", f"{self.url}: resync byte: {exc}")
        except (serial.SerialException, OSError, ValueError) as exc:
            if port is not None:
                try:
                    port.close()  # opened, then failed: not left for the garbage collector to close
                except Exception:  # noqa: BLE001 - it failed already; closing is best effort
                    pass
            self.stats.open_failures += 1
            if self.stats.open_failures == 1 or self._connected_once:
                self._emit("open_failed", f"{self.url}: {exc}")
            self._connected_once = False
            return False
        self.decoder.reset()
        with self._write_lock:
            self._port = port
            self._broken = False
        self.stats.connects += 1
        self._connected_once = True
        if self.on_connect is not None:
            try:
                self.on_connect()
            except Exception as exc:  # noqa: BLE001
                self.stats.callback_errors += 1
                self._emit("callback_error", f"on_connect: {exc!r}")
        self._connected.set()
        self._emit("connected", self.url)
        return True

    def _run(self) -> None:
        import serial

        self._connected_once = False
        attempt = 0
        while not self._stop.is_set():
            if self._port is None:
                if self._try_open():
                    attempt = 0
                    continue
                wait = self.reconnect_backoff_s[min(attempt, len(self.reconnect_backoff_s) - 1)]
                attempt += 1
                self._stop.wait(wait)
                continue
            port = self._port
            try:
                if self._broken:
                    raise serial.SerialException(self.last_error or "port marked broken by a failed write")
                waiting = getattr(port, "in_waiting", 0)
                data = port.read(waiting if waiting > 0 else 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                # TypeError/AttributeError: pyserial's posix read on a port closed under it by close().
                if self._stop.is_set():
                    break
                self.stats.disconnects += 1
                self._close_port()
                self._emit("disconnected", f"{self.url}: {exc}")
                continue
            if not data:
                continue
            rx_ns = self.clock_ns()
            for packet in self.decoder.feed(data):
                if self.on_packet is None:
                    continue
                try:
                    self.on_packet(packet, rx_ns)
                except Exception as exc:  # noqa: BLE001 - one bad handler call must not end the link
                    self.stats.callback_errors += 1
                    self._emit("callback_error", f"on_packet: {exc!r}")
        self._close_port()

    def stats_dict(self) -> dict:
        """Link and decoder counters together (a snapshot)."""
        out = dict(self.stats.__dict__)
        out.update(self.decoder.stats.as_dict())
        out["connected"] = self.connected
        out["last_error"] = self.last_error
        return out
