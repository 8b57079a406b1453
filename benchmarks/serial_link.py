"""The serial link: decode throughput, request -> pose latency over a pseudo-terminal (and TCP side by side), the
effect of a corrupted line (intact frames delivered, corrupted frames accepted) and recovery after a reconnect.

    .venv/bin/python benchmarks/serial_link.py [--frames 20000] [--requests 300] [--outages 3] [--quick]

Prints tables and writes benchmarks/results/serial_link.json. Latency runs use the simulated firmware
(firmware_bridge/mcu_sim.py) on one end and HostBridge on the other, answering each request at once with the
simulator's ground truth (no relocalization work: this measures the link, not the matcher).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_results  # noqa: E402

from firmware_bridge import HostBridge, PoseStatus  # noqa: E402
from firmware_bridge.framing import FrameSplitter, decode_frame  # noqa: E402
from firmware_bridge.mcu_sim import (  # noqa: E402
    FaultInjector,
    McuSimulator,
    OdometryModel,
    PlanarPath,
    PtyEndpoint,
    TcpServerEndpoint,
)
from firmware_bridge.messages import (  # noqa: E402
    Heartbeat,
    HostState,
    HostStatus,
    McuState,
    RelocPose,
    RelocRequest,
    WheelOdometry,
)
from firmware_bridge.protocol import StreamDecoder, StreamEncoder  # noqa: E402

BAUD = 921600


def message_mix(n: int, seed: int = 0) -> list:
    """A realistic mix: mostly odometry, some heartbeats, a few requests, poses and status frames."""
    rng = np.random.default_rng(seed)
    path, odo = PlanarPath(), OdometryModel(seed=seed)
    prev = path.state(0.0)[:3]
    msgs = []
    for i in range(n):
        t = (i + 1) * 0.02
        r = rng.random()
        if r < 0.85:
            now = path.state(t)[:3]
            odo.step(prev, now, 0.02)
            prev = now
            msgs.append(WheelOdometry(int(t * 1e9), odo.x, odo.y, odo.yaw, odo.vx, 0.0, odo.omega,
                                      odo.covariance_upper()))
        elif r < 0.93:
            msgs.append(Heartbeat(McuState.DRIVING, 0, 0, int(t * 1e3), int(t * 1e9) - 7, 1234))
        elif r < 0.96:
            msgs.append(RelocRequest(int(rng.integers(1, 65535))))
        elif r < 0.99:
            msgs.append(RelocPose.from_transform(path.T_map_base(t), request_id=3, stamp_ns=int(t * 1e9), score=4.0,
                                                 covariance=np.eye(6) * 1e-3))
        else:
            msgs.append(HostStatus(HostState.LOCALIZED, 0, 0, i, 1, 0, "ok"))
    return msgs


def bench_decode(n_frames: int, repeats: int = 3) -> tuple[list, dict]:
    msgs = message_mix(n_frames)
    enc = StreamEncoder()
    t0 = time.perf_counter()
    frames = [enc.encode(m, 1000 + i)[1] for i, m in enumerate(msgs)]
    t_encode = time.perf_counter() - t0
    stream = b"".join(frames)
    chunks = [stream[k : k + 4096] for k in range(0, len(stream), 4096)]

    def best(fn):
        times = []
        for _ in range(repeats):
            t = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t)
        return min(times), out

    def split_only():
        sp = FrameSplitter(512)
        return sum(len(sp.feed(c)) for c in chunks)

    def split_crc():
        sp = FrameSplitter(512)
        return sum(len(decode_frame(f)) > 0 for c in chunks for f in sp.feed(c))

    def full():
        dec = StreamDecoder(512)
        return sum(len(dec.feed(c)) for c in chunks)

    def full_small_chunks():  # a port delivering 64 bytes at a time
        dec = StreamDecoder(512)
        return sum(len(dec.feed(stream[k : k + 64])) for k in range(0, len(stream), 64))

    rows, res = [], {}
    line_fps = BAUD / 10 / (len(stream) / n_frames)  # 8N1: 10 bits per byte
    stages = (("split at delimiters", split_only), ("+ COBS + CRC", split_crc),
              ("+ header/body decode (StreamDecoder)", full), ("StreamDecoder, 64-byte reads", full_small_chunks))
    for name, fn in stages:
        t, count = best(fn)
        assert count == n_frames, (name, count)
        fps = n_frames / t
        rows.append([name, fps, len(stream) / t / 1e6, fps / line_fps])
        res[name] = {"frames_per_s": fps, "MB_per_s": len(stream) / t / 1e6, "x_line_rate": fps / line_fps}
    enc_fps = n_frames / t_encode
    rows.append(["encode (StreamEncoder)", enc_fps, len(stream) / t_encode / 1e6, enc_fps / line_fps])
    res["encode"] = {"frames_per_s": n_frames / t_encode}
    res["mean_wire_bytes_per_frame"] = len(stream) / n_frames
    res["line_rate_frames_per_s_at_921600"] = line_fps
    return rows, res


def run_latency(kind: str, n_requests: int, odom_rate_hz: float) -> dict:
    """Sequential requests; each answered at once by the host. Latency measured by the simulator (its clock)."""
    tmp = tempfile.mkdtemp(prefix="serial-bench-")
    if kind == "pty":
        ep = PtyEndpoint(Path(tmp) / "tty")
        url = ep.path
    else:
        ep = TcpServerEndpoint("127.0.0.1", 0)
        url = ep.path
    sim = McuSimulator(ep, reloc_period_s=0.0, odom_rate_hz=odom_rate_hz, clock_drift_ppm=40.0, seed=1)
    holder = {}

    def answer(ev):
        b = holder["bridge"]
        b.send_pose(sim.true_T_map_base_at_host(ev.stamp_host_ns), ev.stamp_host_ns, status=PoseStatus.OK,
                    score=1.0, request_id=ev.request_id)

    bridge = HostBridge(url, on_reloc_request=answer, queue_odometry=False, heartbeat_period_s=0.1,
                        reconnect_backoff_s=(0.02,))
    holder["bridge"] = bridge
    sync_err = []
    with bridge, sim:
        deadline = time.monotonic() + 10
        while not (bridge.connected and bridge.clock_synced) and time.monotonic() < deadline:
            time.sleep(0.01)
        for i in range(n_requests):
            sim.request_relocalization()
            end = time.monotonic() + 2.0
            while len(sim.pose_checks) < i + 1 and time.monotonic() < end:
                time.sleep(0.0005)
            if i % 20 == 0:
                h = time.monotonic_ns()
                sync_err.append(abs(bridge.mcu_to_host_ns(sim.clock.mcu_from_host_ns(h)) - h))
        s = sim.stats()
        hb_rtt = bridge.clock.summary()["rtt_ns"]
    lat = np.array([c.latency_ns for c in sim.pose_checks if c.latency_ns is not None]) / 1e6
    return {
        "transport": kind, "odom_rate_hz": odom_rate_hz, "requests": n_requests, "answered": int(len(lat)),
        "p50_ms": float(np.percentile(lat, 50)), "p95_ms": float(np.percentile(lat, 95)),
        "p99_ms": float(np.percentile(lat, 99)), "max_ms": float(lat.max()),
        "poses_ok": s["poses_ok"], "poses_bad": s["poses_bad"],
        "heartbeat_min_rtt_ms": None if hb_rtt is None else hb_rtt / 1e6,
        "time_map_error_ms_max": float(max(sync_err) / 1e6) if sync_err else None,
    }


CORRUPTION_SETTINGS = [
    ("clean", {}),
    ("BER 1e-5", {"bit_error_rate": 1e-5}),
    ("BER 1e-4, drop 1%, garbage 1%", {"bit_error_rate": 1e-4, "drop_rate": 0.01, "garbage_rate": 0.01}),
    ("BER 1e-3, drop 5%, garbage 5%, unknown 1%, oversize 0.5%",
     {"bit_error_rate": 1e-3, "drop_rate": 0.05, "garbage_rate": 0.05, "unknown_rate": 0.01, "oversize_rate": 0.005}),
    ("BER 1e-2 (most frames hit), garbage 20%", {"bit_error_rate": 1e-2, "garbage_rate": 0.2}),
]


def bench_corruption(n_frames: int) -> tuple[list, list]:
    msgs = message_mix(n_frames, seed=7)
    rows, res = [], []
    for name, kw in CORRUPTION_SETTINGS:
        fi = FaultInjector(seed=11, **kw)
        enc = StreamEncoder()
        sent, fates, parts = {}, {}, []
        for i, m in enumerate(msgs):
            seq, wire = enc.encode(m, 1_000_000 + i)
            sent[seq] = (1_000_000 + i, m)
            out, fate = fi.apply(wire)
            fates[seq] = fate
            parts.append(out)
        stream = b"".join(parts)
        dec = StreamDecoder(512)
        got = []
        for k in range(0, len(stream), 1024):
            got += dec.feed(stream[k : k + 1024])
        intact = {s for s, f in fates.items() if f == "intact"}
        delivered_intact = sum(1 for p in got if p.seq in intact and sent[p.seq] == (p.stamp_ns, p.message))
        accepted_bad = sum(1 for p in got if p.seq not in sent or sent[p.seq] != (p.stamp_ns, p.message)
                           or fates[p.seq] != "intact")
        corrupted = sum(1 for f in fates.values() if f == "corrupted")
        st = dec.stats
        rows.append([name, n_frames, corrupted, len(intact), delivered_intact / max(1, len(intact)), accepted_bad,
                     st.crc_errors, st.framing_errors, st.oversize, st.unknown_types + st.unknown_versions,
                     st.frames_lost])
        res.append({"setting": name, "faults": kw, "frames_sent": n_frames, "frames_corrupted": corrupted,
                    "frames_dropped": fi.counts["dropped"], "frames_intact": len(intact),
                    "intact_delivered_fraction": delivered_intact / max(1, len(intact)),
                    "corrupted_accepted": accepted_bad, "decoder": st.as_dict(), "injected": dict(fi.counts)})
    return rows, res


def bench_recovery(outages_s: list[float], repeats: int, backoff: tuple[float, ...]) -> tuple[list, list]:
    """Unplug (pty closed, its name removed), wait, replug under the same name; time to the first good frame."""
    tmp = Path(tempfile.mkdtemp(prefix="serial-bench-"))
    link = tmp / "ttyMCU"
    first_rx = {}

    def on_odo(ev):
        first_rx.setdefault("t", time.monotonic_ns())

    bridge = HostBridge(str(link), on_odometry=on_odo, queue_odometry=False, reconnect_backoff_s=backoff)
    rows, res = [], []
    sim = McuSimulator(PtyEndpoint(link), reloc_period_s=0.0, seed=0).start()
    with bridge:
        t_end = time.monotonic() + 5
        while not bridge.connected and time.monotonic() < t_end:
            time.sleep(0.01)
        for outage in outages_s:
            times_frame = []
            for _ in range(repeats):
                sim.stop()
                t_unplug = time.monotonic()
                while bridge.connected and time.monotonic() < t_unplug + 5:
                    time.sleep(0.001)
                time.sleep(max(0.0, outage - (time.monotonic() - t_unplug)))
                first_rx.clear()
                clock = sim.clock
                t_replug = time.monotonic_ns()
                sim = McuSimulator(PtyEndpoint(link), reloc_period_s=0.0, seed=0)
                sim.clock = clock
                sim.start()
                while "t" not in first_rx and time.monotonic_ns() < t_replug + 10e9:
                    time.sleep(0.001)
                times_frame.append((first_rx.get("t", np.nan) - t_replug) / 1e6)
            rows.append([f"{outage:.1f} s", repeats, float(np.median(times_frame)), float(np.max(times_frame))])
            res.append({"outage_s": outage, "repeats": repeats, "backoff_s": list(backoff),
                        "replug_to_first_frame_ms": times_frame})
        stats = bridge.stats()
    sim.stop()
    for r in res:
        r["host_disconnects_total"] = stats["disconnects"]
        r["host_open_failures_total"] = stats["open_failures"]
    return rows, res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=20000, help="Frames in the decode and corruption streams.")
    ap.add_argument("--requests", type=int, default=300, help="Request -> pose round trips per latency run.")
    ap.add_argument("--outages", type=int, default=3, help="Unplug/replug repeats per outage length.")
    ap.add_argument("--quick", action="store_true", help="Small sizes (a smoke run).")
    args = ap.parse_args()
    if args.quick:
        args.frames, args.requests, args.outages = 3000, 50, 1

    rows, decode_res = bench_decode(args.frames)
    print_table(["decode stage", "frames/s", "MB/s", "x line rate"], rows, floatfmt=[None, ".0f", ".2f", ".1f"],
                title=f"Decode throughput ({args.frames} frames, mixed messages, "
                      f"{decode_res['mean_wire_bytes_per_frame']:.1f} wire bytes/frame; line rate = 921600 baud 8N1)")

    lat_res = []
    for kind, odo in (("pty", 50.0), ("pty", 0.001), ("tcp", 50.0)):
        lat_res.append(run_latency(kind, args.requests, odo))
    print_table(
        ["transport", "odometry Hz", "answered", "p50 ms", "p95 ms", "p99 ms", "max ms", "poses bad",
         "hb min RTT ms", "time map err ms"],
        [[r["transport"], r["odom_rate_hz"], f"{r['answered']}/{r['requests']}", r["p50_ms"], r["p95_ms"],
          r["p99_ms"], r["max_ms"], r["poses_bad"], r["heartbeat_min_rtt_ms"], r["time_map_error_ms_max"]]
         for r in lat_res],
        floatfmt=[None, ".0f", None, ".3f", ".3f", ".3f", ".3f", None, ".3f", ".3f"],
        title="Round trip: request written by the MCU -> pose decoded by the MCU (host answers at once)",
    )

    rows, corr_res = bench_corruption(args.frames)
    print_table(["line", "sent", "corrupted", "intact", "intact delivered", "corrupted accepted", "CRC err",
                 "framing err", "oversize", "unknown", "lost (seq)"], rows,
                floatfmt=[None, None, None, None, ".4f", None, None, None, None, None, None],
                title="Corrupted line (in-process stream, faults injected per frame)")

    rec_rows, rec_res = [], []
    for backoff in ((0.1, 0.2, 0.5, 1.0, 2.0), (0.02, 0.05, 0.1)):
        r, rr = bench_recovery([0.3, 1.5, 3.0] if not args.quick else [0.3], args.outages, backoff)
        rec_rows += [[f"{backoff}"] + x for x in r]
        rec_res += rr
    print_table(["backoff s", "outage", "n", "median ms", "max ms"], rec_rows,
                floatfmt=[None, None, None, ".1f", ".1f"],
                title="Recovery: replug (pty back under its name) -> first good odometry frame at the host")

    params = {"frames": args.frames, "requests": args.requests, "outage_repeats": args.outages, "baudrate": BAUD}
    path = write_results("serial_link", params=params, results={
        "decode": decode_res, "latency": lat_res, "corruption": corr_res, "recovery": rec_res})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
