"""The firmware bridge: the serial protocol with the robot's microcontroller and the link that carries it.

Data flow, one module per step (specification: docs/protocol.md):

- ``framing``  bytes <-> frames: COBS, 0x00 delimiters, CRC-16/CCITT-FALSE, maximum frame size.
- ``messages`` frames <-> messages: the header and the fixed little-endian layout of every message type.
- ``protocol`` a byte stream <-> packets, with the counters a link reports (no I/O).
- ``timesync`` the MCU clock mapped to the host clock (minimum-delay filter over the heartbeat exchange).
- ``link``     the transport: any pyserial URL, a reader thread, write timeouts, reconnection with backoff.
- ``host``     ``HostBridge``: the host's half of the protocol, as the live loop uses it.
- ``mcu_sim``  a simulated microcontroller (pty, TCP or serial) with ground truth and fault injection.
"""

from .host import BridgeEvent, HostBridge, OdometryEvent, RelocRequestEvent, SendResult
from .messages import (
    Ack,
    AckResult,
    Heartbeat,
    HostState,
    HostStatus,
    McuState,
    MsgType,
    PoseStatus,
    RelocPose,
    RelocReason,
    RelocRequest,
    WheelOdometry,
)

__all__ = [
    "HostBridge", "OdometryEvent", "RelocRequestEvent", "BridgeEvent", "SendResult",
    "Heartbeat", "WheelOdometry", "RelocRequest", "RelocPose", "HostStatus", "Ack",
    "MsgType", "McuState", "HostState", "PoseStatus", "RelocReason", "AckResult",
]
