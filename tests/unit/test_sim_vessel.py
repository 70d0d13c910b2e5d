"""The pure simulated vessel: fault mapping, watchdog, ESC model, integration, config."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

from ftcap_hil.config.sim import load_config
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import FaultEvent, FaultSchedule, Truth
from ftcap_hil.core.messages import FaultInjection, FaultKind
from ftcap_hil.core.models.plants import SurfaceVessel
from ftcap_hil.runtime.vessel_process import MAX_CATCH_UP_STEPS, VesselProcess
from sim.esc_model import DEFAULT_ESC, EscModel
from sim.vessel import (
    Decimator,
    SilentWindow,
    VesselSim,
    VesselSimConfig,
    record_header,
    record_row,
)

THS = paper_four_thrusters(rate_limit=0.318359)
B = effectiveness(THS)
PLANT = SurfaceVessel()
SURGE = np.array([0.1, 0.1, -0.1, -0.1])  # pure +X for the paper layout: tau = [0.283, 0, 0]
DT = 0.02


def make_sim(**kw: object) -> VesselSim:
    return VesselSim(VesselSimConfig(plant=PLANT, thrusters=THS, B=B, **kw))  # type: ignore[arg-type]


def run_steps(sim: VesselSim, n: int, now0: float = 0.0, command: bool = True) -> None:
    for k in range(n):
        now = now0 + k * DT
        if command:
            sim.set_command(SURGE, now)
        sim.step(DT, now)


def test_surge_command_pushes_north_and_matches_rk4() -> None:
    sim = make_sim()
    sim.set_command(SURGE, 0.0)
    sample = sim.step(DT, 0.0)
    tau = B @ SURGE
    np.testing.assert_allclose(tau, [4 * 0.1 / math.sqrt(2), 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(sample.tau, tau)
    np.testing.assert_array_equal(sample.x, PLANT.step_rk4(np.zeros(6), tau, DT, 8))
    assert sample.t_s == pytest.approx(DT) and sample.command_fresh
    run_steps(sim, 100, now0=DT)
    x = sim.x
    assert x[3] > 0.3 and x[0] > 0.2  # moving forward, north at psi = 0
    assert abs(x[1]) < 1e-9 and abs(x[4]) < 1e-9 and abs(x[5]) < 1e-9


def test_a_command_takes_effect_when_received_mid_step() -> None:
    """Received 30 % into a step: the old command acts for the first 30 %, the new one for
    the rest (not the whole step, which made it act early); the sample's forces are means."""
    sim = make_sim()
    sim.set_command(SURGE, 0.0)
    sim.step(DT, 0.0)  # the step ending at now = 0: SURGE acting from here
    x0 = sim.x
    new = -SURGE
    sim.set_command(new, 0.3 * DT)
    sample = sim.step(DT, DT)
    x = PLANT.step_rk4(x0, B @ SURGE, 0.3 * DT, 8)
    x = PLANT.step_rk4(x, B @ new, 0.7 * DT, 8)
    np.testing.assert_allclose(sample.x, x, atol=1e-15)
    np.testing.assert_array_equal(sample.u, new)  # the command now applied, as sent
    np.testing.assert_allclose(sample.tau, B @ (0.3 * SURGE + 0.7 * new), atol=1e-15)
    # the next step runs on the new command alone
    x = PLANT.step_rk4(sample.x, B @ new, DT, 8)
    np.testing.assert_allclose(sim.step(DT, 2 * DT).x, x, atol=1e-15)


def test_a_repeated_command_feeds_the_watchdog_but_took_effect_when_it_first_came() -> None:
    """An ESC stream re-sends the command every 10 ms: the new one, first received 30 % into
    the step, still splits the step there, though its latest copy came at 80 %."""
    sim = make_sim(command_timeout_s=0.2)
    sim.set_command(SURGE, 0.0)
    sim.step(DT, 0.0)
    x0 = sim.x
    new = -SURGE
    for frac in (0.3, 0.55, 0.8):
        sim.set_command(new, frac * DT)
    sample = sim.step(DT, DT)
    x = PLANT.step_rk4(x0, B @ SURGE, 0.3 * DT, 8)
    x = PLANT.step_rk4(x, B @ new, 0.7 * DT, 8)
    np.testing.assert_allclose(sample.x, x, atol=1e-15)
    assert sample.command_age_s == pytest.approx(0.2 * DT)  # from the latest copy
    for k in range(1, 30):  # 0.58 s of repeats, beyond the 0.2 s timeout: still fresh
        sim.set_command(new, DT + k * 0.02)
        assert sim.step(DT, DT + k * 0.02).command_fresh
    # Only the latest copy handed over, with the first copy's stamp: cut at the first.
    sim.set_command(SURGE, DT + 29 * 0.02 + 0.8 * DT, first_s=DT + 29 * 0.02 + 0.3 * DT)
    x0 = sim.x
    sample = sim.step(DT, DT + 30 * 0.02)
    x = PLANT.step_rk4(x0, B @ new, 0.3 * DT, 8)
    np.testing.assert_allclose(sample.x, PLANT.step_rk4(x, B @ SURGE, 0.7 * DT, 8), atol=1e-15)
    sim.set_command(new, 1.0)
    # After a silence longer than the timeout the same value is a new command again.
    assert not sim.step(DT, 2.0).command_fresh
    sim.set_command(new, 2.0 + 0.5 * DT)
    x0 = sim.x
    sample = sim.step(DT, 2.0 + DT)
    x = PLANT.step_rk4(x0, B @ np.zeros(4), 0.5 * DT, 8)
    np.testing.assert_allclose(sample.x, PLANT.step_rk4(x, B @ new, 0.5 * DT, 8), atol=1e-15)


def test_yaw_spin_keeps_psi_wrapped_and_steps_match_rk4() -> None:
    yaw = np.array([-0.1, 0.1, 0.1, -0.1])  # pure +N on the paper layout
    np.testing.assert_allclose((B @ yaw)[:2], 0.0, atol=1e-12)
    sim = make_sim()
    x = np.zeros(6)
    for k in range(300):  # 30 s
        sim.set_command(yaw, k * 0.1)
        x = PLANT.step_rk4(x, B @ yaw, 0.1, 8)
        sample = sim.step(0.1, k * 0.1)
    assert sample.x[5] > 0.5 and abs(x[2]) > 2 * math.pi  # spun more than a turn
    assert -math.pi < sample.x[2] <= math.pi
    assert math.cos(sample.x[2]) == pytest.approx(math.cos(x[2]), abs=1e-9)
    np.testing.assert_allclose(np.delete(sample.x, 2), np.delete(x, 2), atol=1e-9)


def test_commands_are_clipped_to_the_thruster_limits() -> None:
    sim = make_sim()
    sim.set_command(np.array([1.0, -1.0, 0.05, 0.0]), 0.0)
    np.testing.assert_allclose(sim.step(DT, 0.0).u, [0.1, -0.1, 0.05, 0.0])


@pytest.mark.parametrize(
    ("kind", "value", "delta", "f"),
    [
        (FaultKind.OK, math.nan, 1.0, 0.0),
        (FaultKind.OFF, math.nan, 0.0, 0.0),
        (FaultKind.STUCK, 0.03, 0.0, 0.03),
        (FaultKind.WEAK, 0.25, 0.25, 0.0),
        (FaultKind.WEAK, math.nan, 0.5, 0.0),  # default_weak_delta
        (FaultKind.BIAS, -0.02, 1.0, -0.02),
        (FaultKind.BIAS, math.nan, 1.0, 0.08),  # default_bias_n
    ],
)
def test_injection_maps_to_delta_and_f(kind: FaultKind, value: float, delta: float, f: float):
    sim = make_sim()
    sim.inject(FaultInjection(2, kind, value))
    truth = sim.faults()
    assert (truth.delta[2], truth.f[2]) == (delta, f)
    np.testing.assert_array_equal(np.delete(truth.delta, 2), 1.0)
    np.testing.assert_array_equal(np.delete(truth.f, 2), 0.0)


def test_stuck_without_value_holds_the_last_produced_force() -> None:
    sim = make_sim()
    sim.inject(FaultInjection(0, FaultKind.BIAS, 0.01))
    run_steps(sim, 3)  # produced T1 = 0.1 + 0.01
    sim.inject(FaultInjection(0, FaultKind.STUCK))
    sim.set_command(-SURGE, 3 * DT)
    s = sim.step(DT, 3 * DT)
    assert (s.delta[0], s.f[0]) == (0.0, pytest.approx(0.11))
    assert s.produced[0] == pytest.approx(0.11) and s.produced[1] == pytest.approx(-0.1)


def test_bias_keeps_an_injected_delta_and_ok_clears_both() -> None:
    sim = make_sim()
    sim.inject(FaultInjection(1, FaultKind.WEAK, 0.3))
    sim.inject(FaultInjection(1, FaultKind.BIAS, 0.02))
    assert (sim.faults().delta[1], sim.faults().f[1]) == (0.3, 0.02)
    sim.inject(FaultInjection(1, FaultKind.OK))
    assert (sim.faults().delta[1], sim.faults().f[1]) == (1.0, 0.0)


@pytest.mark.parametrize(
    "fault",
    [
        FaultInjection(4, FaultKind.OFF),
        FaultInjection(-1, FaultKind.OFF),
        FaultInjection(0, FaultKind.WEAK, 1.5),
        FaultInjection(0, FaultKind.BIAS, math.inf),
    ],
)
def test_bad_injections_are_refused_and_change_nothing(fault: FaultInjection) -> None:
    sim = make_sim()
    with pytest.raises(ValueError):
        sim.inject(fault)
    np.testing.assert_array_equal(sim.faults().delta, 1.0)
    np.testing.assert_array_equal(sim.faults().f, 0.0)


def test_schedule_by_sim_time_and_injection_overrides_it() -> None:
    event = FaultEvent(0.1, 0.2, 1, np.float64(0.0), np.float64(0.05))
    sim = make_sim(schedule=FaultSchedule(4, (event,)))
    assert sim.faults().delta[1] == 1.0
    run_steps(sim, 5)  # t = 0.1
    assert (sim.faults().delta[1], sim.faults().f[1]) == (0.0, 0.05)
    sim.inject(FaultInjection(1, FaultKind.BIAS, 0.01))  # f overridden, delta still scheduled
    assert (sim.faults().delta[1], sim.faults().f[1]) == (0.0, 0.01)
    run_steps(sim, 6, now0=0.1)  # t = 0.22: the scheduled delta ended, the injected bias stays
    assert (sim.faults().delta[1], sim.faults().f[1]) == (1.0, 0.01)


def test_a_scheduled_fault_acts_from_its_time_inside_a_step() -> None:
    """An onset 40 % into a step (and a command received 70 % into it): the step is cut at
    both, the fault acting from its scheduled time, not from the next step."""
    onset = 0.1 + 0.4 * DT
    event = FaultEvent(onset, math.inf, 1, np.float64(0.0), np.float64(0.08))
    sim = make_sim(schedule=FaultSchedule(4, (event,)))
    run_steps(sim, 5)  # t = 0.1, SURGE acting
    x0 = sim.x
    new = -SURGE
    sim.set_command(new, 4 * DT + 0.7 * DT)
    sample = sim.step(DT, 5 * DT)
    faulty = SURGE * [1.0, 0.0, 1.0, 1.0] + [0.0, 0.08, 0.0, 0.0]
    after = new * [1.0, 0.0, 1.0, 1.0] + [0.0, 0.08, 0.0, 0.0]
    x = PLANT.step_rk4(x0, B @ SURGE, 0.4 * DT, 8)
    x = PLANT.step_rk4(x, B @ faulty, 0.3 * DT, 8)
    x = PLANT.step_rk4(x, B @ after, 0.3 * DT, 8)
    np.testing.assert_allclose(sample.x, x, atol=1e-12)
    np.testing.assert_allclose(sample.produced, 0.4 * SURGE + 0.3 * faulty + 0.3 * after)
    assert (sample.delta[1], sample.f[1]) == (0.0, 0.08)  # the step's last part


def test_watchdog_zeroes_stale_commands_but_a_stuck_bias_stays() -> None:
    sim = make_sim(command_timeout_s=0.5)
    assert not sim.step(DT, 0.0).command_fresh  # never commanded: zero
    sim.set_command(SURGE, 1.0)
    assert sim.step(DT, 1.5).command_fresh
    sim.inject(FaultInjection(3, FaultKind.STUCK, -0.07))
    s = sim.step(DT, 1.51)
    assert not s.command_fresh and s.command_age_s == pytest.approx(0.51)
    np.testing.assert_array_equal(s.u, 0.0)
    np.testing.assert_allclose(s.produced, [0.0, 0.0, 0.0, -0.07])
    np.testing.assert_allclose(s.tau, B[:, 3] * -0.07)


def test_velocity_decays_after_commands_stop() -> None:
    sim = make_sim()
    run_steps(sim, 100)
    u_moving = sim.x[3]
    for k in range(100):
        sim.step(DT, 100 * DT + 1.0 + k * DT)  # last command is > 0.5 s old
    assert 0.0 < sim.x[3] < u_moving - 0.01


def test_esc_model_formula_and_stalled_thrusters() -> None:
    esc = EscModel(k_rpm=1000.0, k_i=2.0, idle_a=0.1, voltage_v=12.0)
    force = np.array([0.04, -0.09, 0.05, 0.0])
    responding = np.array([True, True, False, True])
    np.testing.assert_allclose(esc.rpm(force, responding), [200.0, -300.0, 0.0, 0.0])
    np.testing.assert_allclose(
        esc.current_a(force, responding), [2 * 0.04**1.5 + 0.1, 2 * 0.09**1.5 + 0.1, 0.1, 0.1]
    )
    report = np.array([True, False, True, True])
    assert [s.index for s in esc.statuses(force, responding, report)] == [0, 2, 3]


def test_default_esc_constants_from_the_propeller() -> None:
    k_rpm = 60.0 / math.sqrt(0.30 * 1025.0 * 0.03**4)
    assert DEFAULT_ESC.k_rpm == pytest.approx(k_rpm) and 3700 < k_rpm < 3900
    assert DEFAULT_ESC.rpm(np.array([0.1]), np.array([True]))[0] == pytest.approx(1202.2, abs=0.1)
    with pytest.raises(ValueError, match="k_rpm"):
        EscModel(k_rpm=-1.0, k_i=0.0)


def test_esc_status_signs_off_thruster_and_silence() -> None:
    sim = make_sim(silent=(SilentWindow(2, 0.0, 0.05),))
    sim.inject(FaultInjection(1, FaultKind.OFF))
    run_steps(sim, 1)
    statuses = sim.esc_statuses()
    assert [s.index for s in statuses] == [0, 1, 3]  # ESC 3 silent until t = 0.05
    rpm = {s.index: s.rpm for s in statuses}
    assert rpm[0] > 1000 and rpm[1] == 0.0 and rpm[3] < -1000
    run_steps(sim, 2, now0=DT)  # t = 0.06
    assert [s.index for s in sim.esc_statuses()] == [0, 1, 2, 3]
    sim.set_silent(0, True)
    assert [s.index for s in sim.esc_statuses()] == [1, 2, 3]
    assert sim.silent().tolist() == [True, False, False, False]


def test_faults_is_a_truth() -> None:
    assert isinstance(make_sim().faults(), Truth)


def test_decimator_rates() -> None:
    d = Decimator(50.0, 20.0)
    assert sum(d.due() for _ in range(500)) == 200
    d = Decimator(50.0, 10.0)
    assert [d.due() for _ in range(6)] == [True, False, False, False, False, True]


def test_record_columns_line_up_with_the_row() -> None:
    header = record_header(["A", "B"])
    assert header[8:12] == ["command_fresh", "command_age_s", "u_A_N", "u_B_N"]
    assert header[12:20] == ["F_A_N", "F_B_N", "delta_A", "delta_B", "f_A_N", "f_B_N",
                             "silent_A", "silent_B"]  # fmt: skip
    sim = make_sim()
    sim.inject(FaultInjection(3, FaultKind.BIAS, 0.01))
    sim.set_command(SURGE, 0.0)
    row = dict(zip(record_header(THS.names), record_row(sim.step(DT, 0.0), 12.5), strict=True))
    assert (row["time_s"], row["monotonic_s"], row["command_fresh"]) == ("0.020000", "12.500000", 1)
    assert (row["u_T4_N"], row["f_T4_N"], row["silent_T4"]) == (-0.1, 0.01, 0)
    assert row["F_T4_N"] == pytest.approx(-0.09)
    assert row["tau_X_N"] == pytest.approx(0.4 / math.sqrt(2) - 0.01 / math.sqrt(2))


def test_shipped_config_loads() -> None:
    cfg = load_config(None, [])
    assert cfg.shell.rate_hz == 50.0 and cfg.shell.realtime_factor == 1.0
    assert not cfg.shell.fault_injection_enabled
    assert cfg.sim.thrusters.m == 4 and cfg.sim.command_timeout_s == 0.5
    np.testing.assert_allclose(cfg.sim.B, B)
    assert cfg.raw["can"]["channel"] == "127.0.0.1:29536"


def test_overrides_silence_and_scenario() -> None:
    cfg = load_config(
        None,
        ["sim.silent_thrusters=[2]", "sim.silent=[{thruster=4, from=1.0, until=2.0}]",
         "sim.x0=[1, 2, 0.5, 0, 0, 0]"],
        scenario="paper-4.2-ex2-bias008",
    )  # fmt: skip
    assert cfg.sim.silent == (SilentWindow(1), SilentWindow(3, 1.0, 2.0))
    np.testing.assert_allclose(cfg.sim.x0, [1, 2, 0.5, 0, 0, 0])
    assert cfg.sim.schedule is not None
    truth = cfg.sim.schedule.at(20.0)
    assert truth.delta.tolist() == [1.0, 0.0, 1.0, 1.0] and truth.f[1] == 0.08


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("sim.rate_hz=-1", "[sim] rate_hz: expected a finite number > 0, got -1"),
        ("sim.command_timeout_s=0", "[sim] command_timeout_s: expected a finite number > 0"),
        ("sim.realtime_factor='fast'", "[sim] realtime_factor: expected a finite number"),
        ("sim.silent_thrusters=[5]", "[sim] silent_thrusters: expected a list of integers in 1..4"),
        ("sim.x0=[0, 0]", "[sim] x0: expected 6 finite numbers, got [0, 0]"),
        ("sim.default_weak_delta=2", "[sim] default_weak_delta: expected a finite number in 0..1"),
        ("sim.fault_injection_enabled=1", "[sim] fault_injection_enabled: expected true or false"),
        ("sim.typo=1", "[sim] unknown key 'typo'"),
        ("esc.k_rpm=-3", "[esc] k_rpm: expected a finite number >= 0, got -3"),
        ("sim.silent=[{thruster=2, untill=3.0}]", "[[sim.silent]][0] unknown key 'untill'"),
        ("can.start_hub=1", "[can] start_hub: expected true or false, got 1"),
        ("zenoh.overrides=['nocolon']", "[zenoh] overrides: --cfg 'nocolon': expected KEY:VALUE"),
    ],
)
def test_config_errors_name_the_key(override: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(f"vessel.toml: {message}")):
        load_config(None, [override])


def test_missing_config_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "nope.toml", [])


def test_cli_module_imports_no_transport() -> None:
    """``ftcap-hil`` imports every subcommand module to build its parser: the sim's must not
    pull in the networking stacks (the bridges are imported when the process starts)."""
    code = "import json, sys, ftcap_hil.apps.sim; print(json.dumps(sorted(sys.modules)))"
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60
    )
    modules = json.loads(out.stdout)
    assert "sim.vessel" in modules
    forbidden = ("can", "zenoh", "pymavlink", "dronecan", "bridges")
    assert [m for m in modules if m.split(".")[0] in forbidden] == []


class _NoPorts:
    """A VesselIO with nothing connected: no command, no fault, outputs dropped."""

    def latest_command(self) -> None:
        return None

    def drain_faults(self) -> list[object]:
        return []

    def send_odometry(self, odom: object) -> None:
        pass

    def send_esc(self, statuses: object, reporting: object, now_ns: int) -> None:
        pass


def test_a_late_step_integrates_the_steps_it_missed_up_to_the_cap() -> None:
    cfg = load_config(None, ["sim.rate_hz=10.0", "sim.realtime_factor=2.0"])
    proc = VesselProcess(cfg, _NoPorts())  # type: ignore[arg-type]
    nominal = 2.0 / 10.0  # sim seconds per step: realtime_factor / rate_hz
    ms = 1_000_000
    proc.step(1000 * ms)
    assert proc.sim.t_s == pytest.approx(nominal)  # first step: the nominal one
    proc.step(1100 * ms)  # on time
    assert proc.sim.t_s == pytest.approx(2 * nominal)
    proc.step(1305 * ms)  # one deadline missed (woken 5 ms late): two nominal steps
    assert proc.sim.t_s == pytest.approx(4 * nominal)
    assert proc.lost_s == 0.0
    proc.step(4305 * ms)  # a 3 s stall: MAX_CATCH_UP_STEPS nominal steps, the rest lost
    assert proc.sim.t_s == pytest.approx((4 + MAX_CATCH_UP_STEPS) * nominal)
    assert proc.lost_s == pytest.approx((30 - MAX_CATCH_UP_STEPS) * nominal)


class _CountingPorts(_NoPorts):
    def __init__(self) -> None:
        self.odometry = 0

    def send_odometry(self, odom: object) -> None:
        self.odometry += 1


def test_the_process_loop_runs_for_its_sim_duration() -> None:
    cfg = load_config(None, ["sim.rate_hz=100.0", "sim.realtime_factor=10.0"])
    ports = _CountingPorts()
    proc = VesselProcess(cfg, ports, duration_s=2.0)  # type: ignore[arg-type]
    assert proc.run() == 0
    nominal = 10.0 / 100.0
    t_s = proc.sim.t_s  # about 0.2 s of wall time; a late last step may overshoot
    assert 2.0 - 1e-9 <= t_s < 2.0 + MAX_CATCH_UP_STEPS * nominal
    assert t_s / nominal == pytest.approx(round(t_s / nominal), abs=1e-6)  # on the grid
    assert proc.steps <= 20 and ports.odometry > 0  # late steps integrate several nominal ones


def test_sigterm_ends_the_process_loop_and_restores_the_handler() -> None:
    cfg = load_config(None, ["sim.rate_hz=50.0"])
    proc = VesselProcess(cfg, _NoPorts())  # type: ignore[arg-type]
    before = signal.getsignal(signal.SIGTERM)
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGTERM))
    timer.start()
    try:
        assert proc.run() == 0
    finally:
        timer.cancel()
    assert proc.loop.should_exit and proc.steps > 0
    assert signal.getsignal(signal.SIGTERM) is before
