"""sim.sampling.RateSchedule: which simulator steps a sensor at rate_hz samples."""

from __future__ import annotations

import pytest

from sim.sampling import RateSchedule


def test_a_10_hz_sensor_on_a_0_03_s_step_samples_at_t0_plus_k_tenths() -> None:
    sched = RateSchedule(10.0)
    steps = [round(0.03 * k, 2) for k in range(20)]
    assert [t for t in steps if sched.due(t)] == [0.0, 0.12, 0.21, 0.3, 0.42, 0.51]


def test_a_late_step_takes_one_sample_and_skips_the_missed_ones() -> None:
    sched = RateSchedule(2.0)
    assert sched.due(1.0) and not sched.due(1.4) and sched.due(1.5)
    assert sched.due(3.2)  # samples due at 2.0, 2.5, 3.0: one taken
    assert not sched.due(3.4) and sched.due(3.5)


def test_no_rate_samples_every_step_and_a_bad_rate_is_refused() -> None:
    sched = RateSchedule(None)
    assert all(sched.due(t) for t in (0.0, 0.0, 0.001))
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="rate_hz"):
            RateSchedule(bad)
