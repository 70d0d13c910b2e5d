"""The thruster bank: lag, quantisation, dead band, asymmetry, faults and ESC signatures."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridges.can_io.force_map import ForceRawMap
from ftcap_hil.core.faults import EventKind, FaultEvent, FaultSchedule, Truth
from sim.esc_model import DEFAULT_ESC
from sim.thrusters import (
    DeadEsc,
    Propeller,
    ThrusterBank,
    ThrusterBankConfig,
    ThrusterFault,
    esc_statuses,
    quantise,
    signature,
)

HEALTHY = Truth(np.ones(1), np.zeros(1))


def one(**kw: object) -> ThrusterBank:
    return ThrusterBank(ThrusterBankConfig.create(1, **kw))  # type: ignore[arg-type]


def run(bank: ThrusterBank, u: float, dt_s: float, steps: int, truth: Truth = HEALTHY) -> float:
    for _ in range(steps):
        out = bank.step(np.array([u]), truth, dt_s)
    return float(out.produced[0])


# --- lag ---


def test_lag_reaches_63_2_percent_after_one_time_constant() -> None:
    assert run(one(time_constant_s=0.5), 0.1, 0.01, 50) == pytest.approx(
        0.1 * (1 - math.exp(-1)), rel=1e-12
    )  # 0.063212 N


def test_lag_is_exact_whatever_the_step() -> None:
    coarse = run(one(time_constant_s=0.3), 0.08, 0.6, 1)
    fine = run(one(time_constant_s=0.3), 0.08, 0.001, 600)
    assert coarse == pytest.approx(0.08 * (1 - math.exp(-2)), rel=1e-12)
    assert fine == pytest.approx(coarse, rel=1e-9)
    mixed = one(time_constant_s=0.3)
    for dt in (0.1, 0.2, 0.05, 0.25):  # the step may change between calls
        out = mixed.step(np.array([0.08]), HEALTHY, dt)
    assert out.produced[0] == pytest.approx(coarse, rel=1e-12)


def test_lag_mean_over_a_step_is_the_integral() -> None:
    # mean of c (1 - exp(-t/T)) over [0, dt]: c (1 - T/dt (1 - exp(-dt/T)))
    out = one(time_constant_s=0.2).step(np.array([0.1]), HEALTHY, 0.4)
    assert out.produced_mean[0] == pytest.approx(0.1 * (1 - 0.5 * (1 - math.exp(-2))), rel=1e-12)
    assert out.produced[0] == pytest.approx(0.1 * (1 - math.exp(-2)), rel=1e-12)


def test_no_lag_follows_within_the_step() -> None:
    assert run(one(), 0.07, 0.02, 1) == 0.07


# --- command path ---


def test_quantisation_nearest_of_16383_levels() -> None:
    u_max = np.array([0.1])
    sweep = np.linspace(-0.1, 0.1, 200_001)
    q = np.array([quantise(np.array([u]), u_max)[0] for u in sweep[::7]])
    quantum = 0.1 / 8191
    assert np.max(np.abs(q - sweep[::7])) <= quantum / 2 + 1e-15
    levels = np.unique(np.rint(quantise(sweep, np.full_like(sweep, 0.1)) / quantum))
    assert levels.size == 16383 and levels[0] == -8191 and levels[-1] == 8191


def test_quantisation_matches_the_can_force_map() -> None:
    rng = np.random.default_rng(3)
    fmap = ForceRawMap.create([0.1, 0.2, 5.0])
    for _ in range(50):
        u = rng.uniform(-1, 1, 3) * fmap.u_max_abs
        np.testing.assert_array_equal(quantise(u, fmap.u_max_abs), fmap.to_force(fmap.to_raw(u)))


def test_quantised_bank_output() -> None:
    # 0.05 N on a 0.1 N range: raw rint(4095.5) = 4096 (half to even), 4096 * 0.1 / 8191
    assert run(one(u_max_abs=0.1), 0.05, 0.02, 1) == 4096 * 0.1 / 8191


def test_dead_band() -> None:
    assert run(one(deadband_n=0.01), 0.0099, 0.02, 1) == 0.0
    assert run(one(deadband_n=0.01), -0.01, 0.02, 1) == 0.0
    assert run(one(deadband_n=0.01), 0.0101, 0.02, 1) == 0.0101


def test_asymmetric_reverse() -> None:
    bank = one(reverse_gain=0.65)
    assert run(bank, 0.1, 0.02, 1) == 0.1
    assert run(bank, -0.1, 0.02, 1) == pytest.approx(-0.065, rel=1e-15)


def test_ideal_bank_is_delta_u_plus_f_exactly() -> None:
    rng = np.random.default_rng(7)
    bank = ThrusterBank(ThrusterBankConfig.ideal(4))
    for _ in range(100):
        u = rng.uniform(-0.1, 0.1, 4)
        truth = Truth(rng.choice([0.0, 0.3, 0.9, 1.0], 4), rng.choice([0.0, 0.01, -0.02], 4))
        out = bank.step(u, truth, 0.02)
        np.testing.assert_array_equal(out.produced, truth.delta * u + truth.f)
        np.testing.assert_array_equal(out.produced_mean, truth.delta * u + truth.f)


# --- faults on the physical side ---


def test_stuck_holds_its_onset_output_whatever_the_command() -> None:
    sched = FaultSchedule(1, (FaultEvent(1.0, 2.0, 0, None, None, EventKind.STUCK),))
    bank, dt = one(time_constant_s=0.2), 0.01
    produced = []
    for k in range(300):
        t = k * dt
        u = 0.1 if t < 1.0 else -0.1
        produced.append(bank.step(np.array([u]), sched.at(t), dt).produced[0])
    held = 0.1 * (1 - math.exp(-1.0 / 0.2))  # the lag's value at the onset, 1.0 s
    np.testing.assert_allclose(produced[99:200], held, rtol=1e-9)
    # after the end the lag resumes from the held value towards -0.1
    assert produced[200] == pytest.approx(-0.1 + (held + 0.1) * math.exp(-0.05), rel=1e-9)


def test_stuck_reports_the_rpm_of_the_force_it_holds() -> None:
    bank = one()
    bank.step(np.array([0.04]), HEALTHY, 0.02)
    out = bank.step(np.array([0.1]), Truth(np.ones(1), np.zeros(1), np.array([True])), 0.02)
    assert out.produced[0] == 0.04 and out.reports[0]
    assert out.rpm[0] == pytest.approx(DEFAULT_ESC.k_rpm * math.sqrt(0.04), rel=1e-12)


def test_bias_adds_outside_the_propeller() -> None:
    out = one().step(np.array([0.05]), Truth(np.ones(1), np.array([0.01])), 0.02)
    assert out.produced[0] == pytest.approx(0.06)
    assert out.rpm[0] == pytest.approx(DEFAULT_ESC.k_rpm * math.sqrt(0.05), rel=1e-12)


def test_dead_esc_spins_down_through_the_lag() -> None:
    bank = one(time_constant_s=0.1)
    spun_up = run(bank, 0.1, 0.01, 200)  # 20 time constants
    assert spun_up == pytest.approx(0.1 * (1 - math.exp(-20)), rel=1e-12)
    out = bank.step(np.array([0.1]), HEALTHY, 0.1, causes=[ThrusterFault.DEAD_ESC])
    assert out.produced[0] == pytest.approx(spun_up * math.exp(-1), rel=1e-12)
    assert not out.reports[0] and out.rpm[0] == 0.0


# --- ESC telemetry and fault signatures ---


def test_healthy_telemetry_equals_the_esc_model() -> None:
    u = np.array([0.1, -0.05, 0.0, 0.02])
    bank = ThrusterBank(ThrusterBankConfig.ideal(4))
    out = bank.step(u, Truth(np.ones(4), np.zeros(4)), 0.02)
    ok = np.ones(4, dtype=bool)
    np.testing.assert_allclose(out.rpm, DEFAULT_ESC.rpm(u, ok), rtol=1e-12)
    np.testing.assert_allclose(out.current_a, DEFAULT_ESC.current_a(u, ok), rtol=1e-12)
    # 60 / sqrt(0.30 * 1025 * 0.03^4) * sqrt(0.1): 3801.7 rpm/sqrt(N) * 0.31623
    assert out.rpm[0] == pytest.approx(1202.2, abs=0.05)


def signed(cause: ThrusterFault, delta: float = 0.7, u: float = 0.1, **kw: object):  # type: ignore[no-untyped-def]
    bank = ThrusterBank(ThrusterBankConfig.create(1, **kw))  # type: ignore[arg-type]
    truth = Truth(np.array([delta]), np.zeros(1))
    return bank.step(np.array([u]), truth, 0.02, causes=[cause])


def test_fouled_draws_more_current_for_less_thrust() -> None:
    healthy, fouled = signed(ThrusterFault.HEALTHY, 1.0), signed(ThrusterFault.FOULED)
    assert fouled.produced[0] == pytest.approx(0.07)
    assert fouled.rpm[0] == pytest.approx(healthy.rpm[0], rel=1e-12)  # rpm-controlled ESC
    idle = Propeller().idle_a
    # K_Q * (1 + 1.0 * 0.3): 30 % more shaft power at the same speed
    assert fouled.current_a[0] - idle == pytest.approx(1.3 * (healthy.current_a[0] - idle))
    assert fouled.current_a[0] > healthy.current_a[0]


def test_lost_blade_keeps_rpm_loses_thrust_and_torque() -> None:
    healthy, lost = signed(ThrusterFault.HEALTHY, 1.0), signed(ThrusterFault.LOST_BLADE)
    assert lost.produced[0] == pytest.approx(0.07)
    assert lost.rpm[0] == pytest.approx(healthy.rpm[0], rel=1e-12)
    idle = Propeller().idle_a
    assert lost.current_a[0] - idle == pytest.approx(0.7 * (healthy.current_a[0] - idle))


def test_weak_motor_turns_slower() -> None:
    healthy, weak = signed(ThrusterFault.HEALTHY, 1.0), signed(ThrusterFault.WEAK_MOTOR)
    assert weak.produced[0] == pytest.approx(0.07)
    assert weak.rpm[0] == pytest.approx(math.sqrt(0.7) * healthy.rpm[0], rel=1e-12)
    # same propeller at the speed of 0.07 N: exactly the ESC model's current at 0.07 N
    assert weak.current_a[0] == pytest.approx(DEFAULT_ESC.current_a(np.array([0.07]), [True])[0])


def test_dead_esc_reports_nothing_or_zero() -> None:
    silent = signed(ThrusterFault.DEAD_ESC, 0.0)
    assert esc_statuses(silent) == []
    zero = signed(ThrusterFault.DEAD_ESC, 0.0, dead_esc=DeadEsc.ZERO)
    [status] = esc_statuses(zero)
    assert (status.rpm, status.current_a) == (0.0, Propeller().idle_a)


def test_default_causes_from_truth() -> None:
    bank = ThrusterBank(ThrusterBankConfig.ideal(3))
    out = bank.step(np.full(3, 0.1), Truth(np.array([1.0, 0.5, 0.0]), np.zeros(3)), 0.02)
    assert out.reports.tolist() == [True, True, False]  # delta 0: a dead ESC, silent
    assert out.rpm[1] == pytest.approx(math.sqrt(0.5) * out.rpm[0], rel=1e-12)


def test_reverse_asks_the_speed_of_the_command() -> None:
    # a fixed-pitch propeller in reverse: same shaft speed, K_T * 0.65
    fwd, rev = (
        signed(ThrusterFault.HEALTHY, 1.0, 0.1),
        signed(ThrusterFault.HEALTHY, 1.0, -0.1, reverse_gain=0.65),
    )
    assert rev.produced[0] == pytest.approx(-0.065)
    assert rev.rpm[0] == pytest.approx(-fwd.rpm[0], rel=1e-12)


def test_signature_factors() -> None:
    causes = [ThrusterFault.FOULED, ThrusterFault.LOST_BLADE, ThrusterFault.WEAK_MOTOR]
    sig = signature(causes, np.array([0.6, 0.6, 0.6]), fouled_torque_gain=0.5)
    np.testing.assert_allclose(sig.thrust_factor, [0.6, 0.6, 0.6])
    np.testing.assert_allclose(sig.torque_factor, [1.2, 0.6, 0.6])
    assert sig.responds.all() and sig.reports.all()


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"time_constant_s": -0.1}, "time_constant_s"),
        ({"reverse_gain": 0.0}, "gains"),
        ({"u_max_abs": [0.1, 0.0]}, "u_max_abs"),
        ({"deadband_n": math.nan}, "deadband_n"),
        ({"propeller": [Propeller()]}, "propeller"),
    ],
)
def test_bad_config_names_the_field(kw: dict[str, object], word: str) -> None:
    with pytest.raises(ValueError, match=word):
        ThrusterBankConfig.create(2, **kw)  # type: ignore[arg-type]


def test_bad_command_or_step() -> None:
    bank = one()
    with pytest.raises(ValueError, match="finite"):
        bank.step(np.array([math.nan]), HEALTHY, 0.02)
    with pytest.raises(ValueError, match="dt_s"):
        bank.step(np.array([0.0]), HEALTHY, 0.0)
