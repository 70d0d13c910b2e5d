"""The thruster bank: drives, propellers with in-flow, quantisation, dead band, asymmetry,
faults by cause and their signatures on the shaft."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bridges.can_io.force_map import ForceRawMap
from ftcap_hil.core.faults import Cause, EventKind, FaultEvent, FaultSchedule, Truth
from sim.esc_model import DEFAULT_ESC
from sim.shaft import DriveKind, Propeller, Servo
from sim.thrusters import (
    ThrusterBank,
    ThrusterBankConfig,
    Ventilation,
    esc_statuses,
    quantise,
    signature,
)

HEALTHY = Truth(np.ones(1), np.zeros(1))
K_T = 0.30 * 1025.0 * 0.03**4  # the default propeller's thrust per (rev/s)^2


def one(**kw: object) -> ThrusterBank:
    return ThrusterBank(ThrusterBankConfig.create(1, **kw))  # type: ignore[arg-type]


def run(bank: ThrusterBank, u: float, dt_s: float, steps: int, truth: Truth = HEALTHY) -> float:
    for _ in range(steps):
        out = bank.step(np.array([u]), truth, dt_s)
    return float(out.produced[0])


# --- the drive's lag acts on the shaft speed; thrust follows n|n| ---


def test_speed_reaches_63_2_percent_after_one_time_constant() -> None:
    bank = one(time_constant_s=0.5)
    thrust = run(bank, 0.1, 0.01, 50)
    n_ref = math.sqrt(0.1 / K_T)
    out = bank.step(np.array([0.1]), HEALTHY, 1e-9)
    assert out.speed[0] == pytest.approx(n_ref * (1 - math.exp(-1)), rel=1e-7)
    assert thrust == pytest.approx(0.1 * (1 - math.exp(-1)) ** 2, rel=1e-9)  # 0.03996 N


def test_lag_is_exact_whatever_the_step() -> None:
    coarse = run(one(time_constant_s=0.3), 0.08, 0.6, 1)
    fine = run(one(time_constant_s=0.3), 0.08, 0.001, 600)
    assert coarse == pytest.approx(0.08 * (1 - math.exp(-2)) ** 2, rel=1e-12)
    assert fine == pytest.approx(coarse, rel=1e-9)
    mixed = one(time_constant_s=0.3)
    for dt in (0.1, 0.2, 0.05, 0.25):  # the step may change between calls
        out = mixed.step(np.array([0.08]), HEALTHY, dt)
    assert out.produced[0] == pytest.approx(coarse, rel=1e-12)


def test_mean_force_over_a_step_is_the_integral() -> None:
    # mean of c (1 - exp(-t/T))^2 over [0, dt] = c (1 - 2a + b), with
    # a = T/dt (1 - exp(-dt/T)), b = T/(2 dt) (1 - exp(-2 dt/T)); Simpson on 3 points is
    # 0.3 % high at dt = T / 2 (the start of a spin-up, the worst case)
    tc, dt = 0.2, 0.1
    out = one(time_constant_s=tc).step(np.array([0.1]), HEALTHY, dt)
    a, b = tc / dt * (1 - math.exp(-dt / tc)), tc / (2 * dt) * (1 - math.exp(-2 * dt / tc))
    assert out.produced_mean[0] == pytest.approx(0.1 * (1 - 2 * a + b), rel=4e-3)


def test_no_lag_follows_within_the_step() -> None:
    assert run(one(), 0.07, 0.02, 1) == pytest.approx(0.07, rel=1e-12)


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
    assert run(one(u_max_abs=0.1), 0.05, 0.02, 1) == pytest.approx(4096 * 0.1 / 8191, rel=1e-12)


def test_dead_band() -> None:
    assert run(one(deadband_n=0.01), 0.0099, 0.02, 1) == 0.0
    assert run(one(deadband_n=0.01), -0.01, 0.02, 1) == 0.0
    assert run(one(deadband_n=0.01), 0.0101, 0.02, 1) == pytest.approx(0.0101, rel=1e-12)


def test_asymmetric_reverse() -> None:
    bank = one(reverse_gain=0.65)
    assert run(bank, 0.1, 0.02, 1) == pytest.approx(0.1, rel=1e-12)
    assert run(bank, -0.1, 0.02, 1) == pytest.approx(-0.065, rel=1e-15)


def test_ideal_bank_is_delta_u_plus_f() -> None:
    rng = np.random.default_rng(7)
    bank = ThrusterBank(ThrusterBankConfig.ideal(4))
    for _ in range(100):
        u = rng.uniform(-0.1, 0.1, 4)
        truth = Truth(rng.choice([0.0, 0.3, 0.9, 1.0], 4), rng.choice([0.0, 0.01, -0.02], 4))
        out = bank.step(u, truth, 0.02)
        np.testing.assert_allclose(out.produced, truth.delta * u + truth.f, rtol=1e-12, atol=1e-17)
        np.testing.assert_allclose(
            out.produced_mean, truth.delta * u + truth.f, rtol=1e-12, atol=1e-17
        )


# --- faults on the physical side ---


def test_stuck_holds_its_onset_speed_whatever_the_command() -> None:
    sched = FaultSchedule(1, (FaultEvent(1.0, 2.0, 0, None, None, EventKind.STUCK),))
    bank, dt = one(time_constant_s=0.2), 0.01
    produced, rpm = [], []
    for k in range(300):
        t = k * dt
        u = 0.1 if t < 1.0 else -0.1
        out = bank.step(np.array([u]), sched.at(t), dt)
        produced.append(out.produced[0])
        rpm.append(out.rpm[0])
    held = 0.1 * (1 - math.exp(-1.0 / 0.2)) ** 2  # the speed's value at the onset, 1.0 s
    np.testing.assert_allclose(produced[99:200], held, rtol=1e-9)
    assert rpm[150] == pytest.approx(60 * math.sqrt(held / K_T), rel=1e-9)  # the shaft shows it
    # after the end the speed resumes from the held value towards the reverse reference
    n0, n_ref = math.sqrt(held / K_T), -math.sqrt(0.1 / K_T)
    n = n_ref + (n0 - n_ref) * math.exp(-0.05)
    assert produced[200] == pytest.approx(K_T * n * abs(n), rel=1e-9)


def test_bias_adds_outside_the_propeller() -> None:
    out = one().step(np.array([0.05]), Truth(np.ones(1), np.array([0.01])), 0.02)
    assert out.produced[0] == pytest.approx(0.06)
    assert out.rpm[0] == pytest.approx(DEFAULT_ESC.k_rpm * math.sqrt(0.05), rel=1e-12)


def test_in_flow_takes_thrust_and_torque() -> None:
    """T = k_T (n^2 - n V_a (1 - w) / (J_T D)) at a forward speed of 0.2 m/s."""
    bank = one()
    still = bank.step(np.array([0.1]), HEALTHY, 0.02)
    moving = bank.step(np.array([0.1]), HEALTHY, 0.02, np.array([0.2]))
    n = math.sqrt(0.1 / K_T)
    assert moving.speed[0] == pytest.approx(n, rel=1e-12)  # a speed drive holds its speed
    assert moving.produced[0] == pytest.approx(K_T * (n * n - n * 0.2 * 0.9 / 0.03), rel=1e-12)
    assert moving.produced[0] < 0.75 * still.produced[0] and moving.torque[0] < still.torque[0]


def signed(cause: Cause, delta: float = 0.7, u: float = 0.1, steps: int = 1, **kw: object):  # type: ignore[no-untyped-def]
    bank = ThrusterBank(ThrusterBankConfig.create(1, **kw))  # type: ignore[arg-type]
    truth = Truth(np.array([delta]), np.zeros(1), cause=(cause,))
    for _ in range(steps):
        out = bank.step(np.array([u]), truth, 0.02)
    return out


def test_healthy_telemetry_equals_the_esc_model() -> None:
    u = np.array([0.1, -0.05, 0.0, 0.02])
    bank = ThrusterBank(ThrusterBankConfig.ideal(4))
    out = bank.step(u, Truth(np.ones(4), np.zeros(4)), 0.02)
    ok = np.ones(4, dtype=bool)
    np.testing.assert_allclose(out.rpm, DEFAULT_ESC.rpm(u, ok), rtol=1e-12)
    np.testing.assert_allclose(out.current_a, DEFAULT_ESC.current_a(u, ok), rtol=1e-12)
    # 60 / sqrt(0.30 * 1025 * 0.03^4) * sqrt(0.1): 3801.7 rpm/sqrt(N) * 0.31623
    assert out.rpm[0] == pytest.approx(1202.2, abs=0.05)


def test_fouled_draws_more_current_for_less_thrust() -> None:
    healthy, fouled = signed(Cause.HEALTHY, 1.0), signed(Cause.FOULED)
    assert fouled.produced[0] == pytest.approx(0.07)
    assert fouled.rpm[0] == pytest.approx(healthy.rpm[0], rel=1e-12)  # rpm-controlled drive
    idle = Propeller().idle_a
    # K_Q * (1 + 1.0 * 0.3): 30 % more shaft power at the same speed
    assert fouled.current_a[0] - idle == pytest.approx(1.3 * (healthy.current_a[0] - idle))


def test_lost_blade_keeps_rpm_loses_thrust_and_torque() -> None:
    healthy, lost = signed(Cause.HEALTHY, 1.0), signed(Cause.LOST_BLADE)
    assert lost.produced[0] == pytest.approx(0.07)
    assert lost.rpm[0] == pytest.approx(healthy.rpm[0], rel=1e-12)
    idle = Propeller().idle_a
    assert lost.current_a[0] - idle == pytest.approx(0.7 * (healthy.current_a[0] - idle))


def test_weak_motor_turns_slower() -> None:
    healthy, weak = signed(Cause.HEALTHY, 1.0), signed(Cause.WEAK_MOTOR)
    assert weak.produced[0] == pytest.approx(0.07)
    assert weak.rpm[0] == pytest.approx(math.sqrt(0.7) * healthy.rpm[0], rel=1e-12)
    assert weak.current_a[0] == pytest.approx(DEFAULT_ESC.current_a(np.array([0.07]), [True])[0])


TORQUE = Propeller(drive=DriveKind.TORQUE)


@pytest.mark.parametrize(
    ("cause", "rpm_ratio"),
    [
        (Cause.HEALTHY, 1.0),
        (Cause.WEAK_MOTOR, math.sqrt(0.7)),  # torque x 0.7 against the same load
        (Cause.LOST_BLADE, 1 / math.sqrt(0.7)),  # a lighter load: the shaft speeds up
        (Cause.FOULED, 1 / math.sqrt(1.3)),  # a heavier one: it slows down
    ],
)
def test_a_torque_drive_settles_at_delta_with_its_own_speed(cause: Cause, rpm_ratio: float) -> None:
    kw = {"actuator": TORQUE, "time_constant_s": 0.05, "full_force_n": 0.1}
    healthy = signed(Cause.HEALTHY, 1.0, steps=200, **kw)
    out = signed(cause, 0.7 if cause is not Cause.HEALTHY else 1.0, steps=200, **kw)
    delta = 1.0 if cause is Cause.HEALTHY else 0.7
    assert out.produced[0] == pytest.approx(0.1 * delta, rel=1e-3)
    assert out.rpm[0] == pytest.approx(rpm_ratio * healthy.rpm[0], rel=1e-3)


def test_a_torque_drive_has_its_time_constant_at_half_speed() -> None:
    kw = {"actuator": TORQUE, "time_constant_s": 0.1, "full_force_n": 0.4}
    bank = ThrusterBank(ThrusterBankConfig.create(1, **kw))  # type: ignore[arg-type]
    n_half = math.sqrt(0.1 / K_T)  # 0.1 N is half the top speed of 0.4 N
    bank.step(np.array([0.1]), HEALTHY, 5.0)  # settled
    nudge = bank.step(np.array([0.1 * 1.02**2]), HEALTHY, 0.1).speed[0]  # a 2 % speed step
    assert (nudge - n_half) / (0.02 * n_half) == pytest.approx(1 - math.exp(-1), abs=0.02)


def test_drive_dead_spins_down_and_reports_zero() -> None:
    bank = one(time_constant_s=0.1)
    run(bank, 0.1, 0.01, 200)
    dead = Truth(np.zeros(1), np.zeros(1), cause=(Cause.DRIVE_DEAD,))
    out = bank.step(np.array([0.1]), dead, 0.1)
    assert out.speed[0] == pytest.approx(math.sqrt(0.1 / K_T) * math.exp(-1), rel=1e-6)
    for _ in range(50):
        out = bank.step(np.array([0.1]), dead, 0.1)
    [status] = esc_statuses(out)
    assert abs(status.rpm) < 1e-6 and status.current_a == pytest.approx(Propeller().idle_a)


def test_power_lost_is_silent_telemetry_lost_works_silently() -> None:
    assert esc_statuses(signed(Cause.POWER_LOST, 0.0)) == []
    assert signed(Cause.POWER_LOST, 0.0).produced[0] == 0.0
    lost = signed(Cause.TELEMETRY_LOST, 1.0)
    assert esc_statuses(lost) == [] and lost.produced[0] == pytest.approx(0.1)


def test_a_jammed_shaft_stops_and_draws_its_current_limit() -> None:
    out = signed(Cause.JAMMED, 0.0, full_force_n=0.1)
    full = signed(Cause.HEALTHY, 1.0, full_force_n=0.1)
    assert out.rpm[0] == 0.0 and out.produced[0] == 0.0
    idle = Propeller().idle_a
    assert out.current_a[0] == pytest.approx(idle + 1.5 * (full.current_a[0] - idle) + 0.5 * idle)


def test_hull_loss_leaves_the_shaft_clean() -> None:
    healthy, hull = signed(Cause.HEALTHY, 1.0), signed(Cause.HULL_LOSS, 0.6)
    assert hull.produced[0] == pytest.approx(0.06)
    assert (hull.rpm[0], hull.current_a[0]) == (healthy.rpm[0], healthy.current_a[0])


def test_ventilation_bursts_are_transient_and_seeded() -> None:
    vent = Ventilation(rate_hz=1.0, mean_s=0.3, loss=0.6)
    truth = Truth(np.ones(1), np.zeros(1), cause=(Cause.VENTILATION,))

    def series(seed: int) -> np.ndarray:
        bank = one(ventilation=vent, seed=seed)
        return np.array([bank.step(np.array([0.1]), truth, 0.01).produced[0] for _ in range(6000)])

    a, b = series(1), series(1)
    np.testing.assert_array_equal(a, b)
    in_burst = a < 0.0999
    # share of time in a burst ~ rate x mean / (1 + rate x mean) = 0.23 over 60 s
    assert 0.12 < in_burst.mean() < 0.35 and a.min() == pytest.approx(0.04, rel=1e-9)
    assert a.max() == pytest.approx(0.1, rel=1e-12)


def test_a_servo_deflects_and_a_lost_rudder_blade_draws_less() -> None:
    kw = {"actuator": Servo(), "time_constant_s": 0.2, "full_force_n": 1.2}
    healthy = signed(Cause.HEALTHY, 1.0, 0.6, steps=200, **kw)
    lost = signed(Cause.LOST_BLADE, 0.5, 0.6, steps=200, **kw)
    assert healthy.speed[0] == pytest.approx(0.5) and healthy.produced[0] == pytest.approx(0.6)
    assert lost.speed[0] == pytest.approx(0.5) and lost.produced[0] == pytest.approx(0.3)
    assert lost.current_a[0] == pytest.approx(0.1 + 0.5 * 0.5)
    assert lost.current_a[0] < healthy.current_a[0]
    assert np.isnan(healthy.rpm[0]) and esc_statuses(healthy) == []


def test_default_causes_from_truth() -> None:
    bank = ThrusterBank(ThrusterBankConfig.ideal(3))
    out = bank.step(np.full(3, 0.1), Truth(np.array([1.0, 0.5, 0.0]), np.zeros(3)), 0.02)
    assert out.reports.tolist() == [True, True, False]  # delta 0 without a cause: power lost
    assert out.rpm[1] == pytest.approx(math.sqrt(0.5) * out.rpm[0], rel=1e-12)


def test_a_force_held_without_a_command_is_its_own_silent_cause() -> None:
    """delta 0 with a bias (the campaigns' "stuck" kind, the paper's stuck-at-a-value): the
    drive holds a force and reports nothing; it is not a power loss (no force left) and
    not a frozen shaft (whose drive reports its speed)."""
    truth = Truth(np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.05, 0.0]))
    assert truth.causes() == (Cause.HEALTHY, Cause.HELD, Cause.POWER_LOST)
    bank = ThrusterBank(ThrusterBankConfig.ideal(3))
    out = bank.step(np.full(3, 0.1), truth, 0.02)
    assert out.reports.tolist() == [True, False, False]
    assert out.produced[1] == pytest.approx(0.05) and out.produced[2] == 0.0


def test_reverse_asks_the_speed_of_the_command() -> None:
    # a fixed-pitch propeller in reverse: K_T * 0.65 at the speed of the healthy reverse thrust
    fwd = signed(Cause.HEALTHY, 1.0, 0.1)
    rev = signed(Cause.HEALTHY, 1.0, -0.1, reverse_gain=0.65)
    assert rev.produced[0] == pytest.approx(-0.065)
    assert rev.rpm[0] == pytest.approx(-math.sqrt(0.65) * fwd.rpm[0], rel=1e-12)


def test_signature_factors() -> None:
    causes = [Cause.FOULED, Cause.LOST_BLADE, Cause.WEAK_MOTOR, Cause.LOST_BLADE]
    shaft = np.ones(4, dtype=bool)
    torque = np.array([False, False, False, True])
    sig = signature(causes, np.full(4, 0.6), torque, shaft, fouled_torque_gain=0.5)
    np.testing.assert_allclose(sig.k_t, [0.6, 0.6, 1.0, 0.36])
    np.testing.assert_allclose(sig.k_q, [1.2, 0.6, 1.0, 0.6])
    np.testing.assert_allclose(sig.drive, [1.0, 1.0, math.sqrt(0.6), 1.0])
    assert sig.driven.all() and sig.reports.all()


@pytest.mark.parametrize(
    ("kw", "word"),
    [
        ({"time_constant_s": -0.1}, "time_constant_s"),
        ({"reverse_gain": 0.0}, "gains"),
        ({"u_max_abs": [0.1, 0.0]}, "u_max_abs"),
        ({"deadband_n": math.nan}, "deadband_n"),
        ({"actuator": [Propeller()]}, "actuator"),
        ({"full_force_n": 0.0}, "full_force_n"),
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
