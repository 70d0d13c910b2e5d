"""The drives' telemetry (sim/feedback.py): rate, latency, quantisation, noise, drift,
per-seed calibration errors, silent drives."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ftcap_hil.core.faults import Cause, Truth
from sim.feedback import FeedbackConfig, FeedbackSensor
from sim.thrusters import ThrusterBank, ThrusterBankConfig

EXACT = FeedbackConfig(
    rate_hz=None, latency_s=0.0, speed_resolution=0.0, current_resolution_a=0.0,
    speed_noise_rel=0.0, current_noise_a=0.0, current_drift_a=0.0, current_scale_std=0.0,
)  # fmt: skip


def bank_out(u: float = 0.1, cause: Cause = Cause.HEALTHY, m: int = 2):  # type: ignore[no-untyped-def]
    bank = ThrusterBank(ThrusterBankConfig.ideal(m))
    return bank.step(np.full(m, u), Truth(np.ones(m), np.zeros(m), cause=(cause,) * m), 0.02)


def test_an_exact_sensor_reports_the_state_at_every_step() -> None:
    out = bank_out()
    [a, b] = FeedbackSensor(EXACT, 2).step(1.0, out)
    assert (a.index, b.index) == (0, 1) and a.t_delivered_s == 1.0
    assert a.speed == out.speed[0] and a.current_a == out.current_a[0]
    assert a.rpm == pytest.approx(1202.2, abs=0.05)


def test_rate_and_latency() -> None:
    cfg = FeedbackConfig(rate_hz=10.0, latency_s=0.03)
    sensor, out = FeedbackSensor(cfg, 2), bank_out()
    got = [s for k in range(100) for s in sensor.step(k * 0.01, out)]  # 1 s at 100 Hz
    measured = sorted({s.t_measured_s for s in got})
    np.testing.assert_allclose(np.diff(measured), 0.1, atol=1e-9)
    assert len(measured) == 10  # t = 0.0 .. 0.9, each delivered by 0.99
    assert all(s.t_delivered_s == pytest.approx(s.t_measured_s + 0.03) for s in got)


def test_quantised_to_one_rpm_and_ten_milliamps() -> None:
    cfg = FeedbackConfig(rate_hz=None, latency_s=0.0, speed_noise_rel=0.0, current_noise_a=0.0)
    [s, _] = FeedbackSensor(cfg, 2).step(0.0, bank_out())
    assert s.rpm == pytest.approx(round(s.rpm)) and s.current_a == pytest.approx(
        round(s.current_a, 2)
    )


def test_silent_drives_send_nothing() -> None:
    for cause in (Cause.POWER_LOST, Cause.TELEMETRY_LOST):
        assert FeedbackSensor(EXACT, 2).step(0.0, bank_out(cause=cause)) == []
    [s, _] = FeedbackSensor(EXACT, 2).step(0.0, bank_out(cause=Cause.DRIVE_DEAD))
    assert s.speed == 0.0


def test_calibration_errors_are_per_seed_and_drift_grows_like_a_random_walk() -> None:
    cfg = FeedbackConfig(current_scale_std=0.05, seed=1)
    a, b = FeedbackSensor(cfg, 400), FeedbackSensor(cfg, 400)
    np.testing.assert_array_equal(a.current_scale, b.current_scale)
    assert np.std(a.current_scale - 1.0) == pytest.approx(0.05, rel=0.15)
    c = FeedbackSensor(FeedbackConfig(current_scale_std=0.05, seed=2), 400)
    assert not np.array_equal(a.current_scale, c.current_scale)
    drift = FeedbackConfig(
        rate_hz=None, current_drift_a=0.01, current_noise_a=0.0, current_resolution_a=0.0,
        current_scale_std=0.0, seed=3,
    )  # fmt: skip
    sensor, out = FeedbackSensor(drift, 400), bank_out(10.0, m=400)  # ~10 A: no clip at 0
    for k in range(101):
        got = sensor.step(k * 1.0, out)
    offsets = np.array([s.current_a for s in got]) - out.current_a
    assert np.std(offsets) == pytest.approx(0.01 * math.sqrt(100), rel=0.15)  # 0.1 A at 100 s


def test_bad_settings_name_the_key() -> None:
    with pytest.raises(ValueError, match="feedback.latency_s"):
        FeedbackConfig(latency_s=-1.0)
    with pytest.raises(ValueError, match="feedback.rate_hz"):
        FeedbackConfig(rate_hz=0.0)
