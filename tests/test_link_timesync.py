"""Clock mapping: the minimum-delay filter against a simulated MCU clock with offset, drift and delay spikes."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_bridge.timesync import ClockSync


def simulate(sync: ClockSync, *, seconds: float, drift_ppm: float, seed: int, spike_rate: float = 0.3,
             period_s: float = 0.5, base_delay_ns: int = 300_000):
    """Heartbeat exchanges every period; each direction has a base delay plus jitter and, sometimes, a spike."""
    rng = np.random.default_rng(seed)
    offset0 = 987_654_321_000  # host - mcu at t = 0
    k = 1 + drift_ppm * 1e-6

    def mcu(host_ns):  # the true MCU clock
        return int((host_ns - offset0) * k)

    naive = []
    t = 5_000_000_000
    while t < seconds * 1e9:
        d_up, d_down = (base_delay_ns + rng.exponential(50_000, 2)).astype(int)
        if rng.random() < spike_rate:  # one direction stalls (USB, scheduling)
            if rng.random() < 0.5:
                d_up += int(rng.uniform(2e6, 40e6))
            else:
                d_down += int(rng.uniform(2e6, 40e6))
        hold = int(rng.uniform(0, 400e6))
        t1 = t
        t2 = mcu(t1 + d_up)
        t3 = t2 + hold
        t4 = int(t3 / k) + offset0 + d_down
        sync.add_two_way(t1, t2, t3, t4)
        naive.append(((t1 - t2) + (t4 - t3)) / 2)
        t += int(period_s * 1e9)
    return mcu, t, np.array(naive)


def test_min_delay_filter_rejects_spikes_and_follows_drift():
    sync = ClockSync(window_s=20.0)
    mcu, t_end, naive = simulate(sync, seconds=120, drift_ppm=80.0, seed=1)
    assert sync.synced
    errors = []
    for host_ns in np.linspace(t_end - 5e9, t_end, 20).astype(np.int64):
        mcu_ns = mcu(int(host_ns))
        errors.append(sync.mcu_to_host_ns(mcu_ns) - int(host_ns))
        assert abs(sync.host_to_mcu_ns(int(host_ns)) - mcu_ns) < 100_000
    assert np.max(np.abs(errors)) < 100_000  # 0.1 ms, with 30 % of exchanges delayed by 2-40 ms one way
    # The plain average of the same samples is far off (delay spikes and 80 ppm drift over 2 minutes).
    assert np.std(naive) > 1e6
    assert sync.summary()["drift_ppm"] == pytest.approx(-80.0, abs=10.0)


def test_without_drift_model_a_long_run_would_drift_away():
    # Same data; evaluating the best sample's offset without drift extrapolation at the end is worse than with it.
    sync = ClockSync(window_s=20.0)
    mcu, t_end, _ = simulate(sync, seconds=120, drift_ppm=80.0, seed=2)
    best = sync.offset_ns()
    extrapolated = sync.offset_ns(t_end)
    true_offset = t_end - mcu(t_end)
    assert abs(extrapolated - true_offset) < abs(best - true_offset)


def test_one_way_bound_before_the_first_echo_and_reset():
    sync = ClockSync()
    assert sync.mcu_to_host_ns(0) is None and not sync.synced
    offset = 5_000_000_000
    for mcu_tx, delay in ((1_000_000, 900_000), (2_000_000, 300_000), (3_000_000, 2_000_000)):
        sync.add_one_way(mcu_tx, mcu_tx + offset + delay)
    assert sync.offset_ns() == offset + 300_000  # the smallest delay seen
    assert sync.uncertainty_ns() is None and not sync.synced
    sync.reset()
    assert sync.offset_ns() is None


def test_implausible_round_trips_are_rejected():
    sync = ClockSync(max_rtt_ns=100_000_000)
    assert sync.add_two_way(0, 10, 5, 100) is None  # the MCU replied before it received
    assert sync.add_two_way(0, 0, 0, 2_000_000_000) is None  # a stale echo after a reconnect
    assert sync.summary()["rejected_samples"] == 2
    with pytest.raises(ValueError, match="window_s"):
        ClockSync(window_s=0)


def test_conversions_are_exact_on_an_epoch_clock():
    """A host clock in epoch nanoseconds (``clock_ns=time.time_ns``, 1.7e18) has no exact float: the conversions
    summed in floats were off by tens of nanoseconds with no drift at all. Integer nanoseconds throughout."""
    sync = ClockSync()
    host0 = 1_732_000_000_123_456_789
    off = host0 - 5_000_000_001  # the MCU booted 5 s before
    for k in range(3):
        t1 = host0 + k * 500_000_000
        sync.add_two_way(t1, t1 - off + 100_000, t1 - off + 100_000, t1 + 200_000)
    offset = sync.offset_ns()
    assert isinstance(offset, int) and sync.offset_ns(host0) == offset
    mcu = 6_000_000_008
    assert sync.mcu_to_host_ns(mcu) == mcu + offset and sync.host_to_mcu_ns(mcu + offset) == mcu
