"""ESC telemetry as evidence (runtime/esc_watchdog.py, EscStallMonitor; FtcapCore's stalled)."""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.cycle import CoreConfig, FtcapCore
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.evidence import Evidence
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.esc_watchdog import EscStallMonitor
from ftcap_hil.runtime.transitions import TransitionLog

RANGE = np.full(4, 0.1)
FRESH = np.zeros(4)
MS = 1_000_000


def monitor() -> tuple[EscStallMonitor, list[str]]:
    said: list[str] = []
    log = TransitionLog(lambda text, sev: said.append(text))
    return EscStallMonitor(log, RANGE, stall_rpm=50.0, stall_s=1.0), said


def run(mon: EscStallMonitor, u: np.ndarray, rpm: np.ndarray, t0_ms: int, n: int) -> np.ndarray:
    out = np.zeros(4, dtype=bool)
    for k in range(n):
        out = mon.update((t0_ms + 100 * k) * MS, u, rpm, FRESH, 0.5)
    return out


def test_no_rpm_under_command_for_the_stall_time_is_a_stall_then_a_turning_probe_clears() -> None:
    mon, said = monitor()
    u = np.array([0.05, 0.05, 0.05, 0.05])
    rpm = np.array([800.0, 0.0, 800.0, 800.0])
    assert not run(mon, u, rpm, 0, 10).any()  # 0.9 s: not yet
    assert run(mon, u, rpm, 1000, 1).tolist() == [False, True, False, False]
    assert "ESC 2: no rpm under command: thruster stalled" in said
    # allocated as dead it gets only probes: a small one that turns it clears the stall
    probe = np.array([0.05, 0.003, 0.05, 0.05])
    assert not run(mon, probe, np.array([800.0, 200.0, 800.0, 800.0]), 2000, 1).any()
    assert "ESC 2: turning again" in said


def test_no_evidence_without_command_or_fresh_telemetry() -> None:
    mon, _ = monitor()
    idle = np.array([0.005, 0.0, 0.0, 0.0])  # below 10 % of the range: a stopped shaft is fine
    assert not run(mon, idle, np.zeros(4), 0, 30).any()
    u = np.full(4, 0.05)
    for k in range(30):  # stale or missing telemetry: the watchdog's business, not a stall
        ages = np.array([5.0, 5.0, math.inf, 0.0])
        rpm = np.array([0.0, 0.0, math.nan, math.nan])
        assert not mon.update(k * 100 * MS, u, rpm, ages, 0.5).any()


def test_a_stall_must_last_under_load_to_count() -> None:
    mon, _ = monitor()
    u_on, u_off = np.full(4, 0.05), np.zeros(4)
    zero = np.zeros(4)
    for k in range(40):  # loaded 0.5 s, unloaded 0.5 s: never 1 s of load without rpm
        u = u_on if (k // 5) % 2 == 0 else u_off
        assert not mon.update(k * 100 * MS, u, zero, FRESH, 0.5).any()


def test_the_core_allocates_a_stalled_thruster_as_dead_and_reports_it() -> None:
    ths = paper_four_thrusters()
    core = FtcapCore(effectiveness(ths), ths, 0.2827, CoreConfig(mode=Mode.CAP))
    stalled = np.array([False, True, False, False])
    r = core.step(np.array([0.05, 0.0, 0.0]), None, evidence=Evidence.of(4, stalled=stalled))
    assert r.faulty.tolist() == [False, True, False, False]
    assert r.estimate.delta_hat[1] == 0.0 and r.allocation.dead[1]
    free = core.step(np.array([0.05, 0.0, 0.0]), None)
    assert not free.faulty.any() and not free.allocation.dead.any()
