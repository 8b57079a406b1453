"""The live loop (``reloc run``): frames from a camera, the simulator or a recording become planes, submaps and
relocalized poses in real time, with the firmware bridge carrying odometry in and poses out.

One module per step: ``frame_queue`` (the bounded capture queue), ``submap`` (the sliding window of frames fused
with odometry), ``tracking`` (odometry jumps, agreement of the current planes with the map), ``loop`` (the
threads and the triggers), ``factory`` (parts built from the config), ``params`` (plain parameters), ``cli``
(the command).
"""

from reloc.live.frame_queue import DropOldestQueue
from reloc.live.loop import LiveLoop, LiveSummary, RelocRecord
from reloc.live.params import LiveParams
from reloc.live.submap import SubmapWindow

__all__ = ["DropOldestQueue", "LiveLoop", "LiveParams", "LiveSummary", "RelocRecord", "SubmapWindow"]
