"""VesselClock and the estimation sampler: telemetry receipt stamps corrected for their
variable delay, commands averaged over the interval the states span (no processes)."""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.messages import Odometry
from ftcap_hil.runtime.estimation import EstimationSampler, VesselClock

MS = 1_000_000  # ns
OFFSET_NS = 7_000 * MS  # this clock minus the vessel's


def _delays(n: int, seed: int = 1) -> np.ndarray:
    """Delays of 5-150 ms, as seen in the qemu VM."""
    return np.random.default_rng(seed).uniform(5.0, 150.0, n) * MS


def test_the_least_delayed_offset_removes_the_jitter() -> None:
    clock = VesselClock(window=50)
    delays = _delays(200)
    errors = []
    for k, d in enumerate(delays):
        t_s = 0.1 * k
        mapped = clock.map(t_s, int(t_s * 1e9) + OFFSET_NS + int(d))
        errors.append(mapped - (int(t_s * 1e9) + OFFSET_NS))  # 0: the state's own time
    errors_ns = np.array(errors[50:])
    window_min = np.array([delays[max(0, k - 49) : k + 1].min() for k in range(50, 200)])
    np.testing.assert_allclose(errors_ns, window_min, atol=2)  # only the least delay is left
    assert errors_ns.max() < 20 * MS and np.ptp(errors_ns) < 0.1 * np.ptp(delays)


def test_vessel_time_going_back_restarts_the_filter() -> None:
    clock = VesselClock()
    clock.map(10.0, 10 * 10**9 + OFFSET_NS + 5 * MS)  # least delay 5 ms
    # the vessel restarted: its clock is back at 0, the offset to ours is another one
    rx = 20 * 10**9
    assert clock.map(0.0, rx) == rx
    assert clock.map(0.1, rx + 100 * MS + 40 * MS) == rx + 100 * MS  # the new least delay


def test_a_vessel_clock_running_slow_or_without_time_falls_back_to_receipt() -> None:
    clock = VesselClock(window=50, max_shift_s=0.25)
    shifts = []
    for k in range(50):  # vessel time at half rate (a sim below real time)
        rx = OFFSET_NS + k * 100 * MS
        shifts.append(rx - clock.map(0.05 * k, rx))
    assert max(shifts) <= 250 * MS and shifts[-1] == 0  # never moved back by more than 0.25 s
    assert clock.map(math.nan, 123) == 123


def _mean_command_error(vessel_clock: bool) -> float:
    """Largest error of the sampler's command average against the one over the interval
    the vessel's states really span (commands change every 0.1 s, telemetry every 0.1 s,
    a 0.3 s estimation period, 5-150 ms telemetry delay)."""
    d = EstimationSampler(period_s=0.2827, use_vessel_clock=vessel_clock)
    rng = np.random.default_rng(2)
    commands = rng.uniform(-0.1, 0.1, (400, 4))
    delays = _delays(300, seed=3)
    worst, prev_t = 0.0, None

    def send(j: int) -> None:  # command j goes out at 0.1 j + 0.05 s of our clock
        d.command_sent(OFFSET_NS + j * 100 * MS + 50 * MS, commands[j])

    send(0)
    send(1)
    for k in range(1, 300):
        send(k + 1)  # sent before telemetry k arrives (its delay is under 150 ms)
        t_s = 0.1 * k
        odom = Odometry.checked([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], t_s)
        rx = OFFSET_NS + k * 100 * MS + int(delays[k])
        got = d.sample(odom, rx)
        if got is None:
            continue
        u_mean = got.u_mean
        if prev_t is not None and k > 60:  # after the filter's window has filled
            want = d.history.mean(OFFSET_NS + int(prev_t * 1e9), OFFSET_NS + k * 100 * MS)
            worst = max(worst, float(np.abs(u_mean - want).max()))
        prev_t = t_s
    return worst


def test_the_sampler_averages_commands_over_the_interval_the_states_span() -> None:
    by_receipt, by_vessel = _mean_command_error(False), _mean_command_error(True)
    # Receipt stamps misplace the interval by up to the delay jitter: a large share of a
    # command change. The least-delay offset leaves the least delay (5 ms of 300).
    assert by_receipt > 0.02
    assert by_vessel < 0.2 * by_receipt
