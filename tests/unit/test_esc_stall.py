"""ESC telemetry as evidence (runtime/esc_watchdog.py, EscStallMonitor; FtcapCore's stalled)."""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.cycle import CoreConfig, FtcapCore
from ftcap_hil.core.effectiveness.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.estimation.config import Estimate
from ftcap_hil.core.estimation.decisions import Decision
from ftcap_hil.core.estimation.stages import StageOutput
from ftcap_hil.core.evidence import Evidence, apply_evidence
from ftcap_hil.core.status import Mode
from ftcap_hil.ports.transitions import TransitionLog
from ftcap_hil.runtime.esc_watchdog import EscStallMonitor

RANGE = np.full(4, 0.1)
FRESH = np.zeros(4)
MS = 1_000_000
S = 1_000_000_000


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


def test_one_status_repeated_by_a_starved_stream_is_not_a_stall() -> None:
    """The vessel's telemetry stalls after one low status (taken during a reversal): cycles
    keep reading that status, older every time but within the timeout. One status is one
    piece of evidence, however long it is read."""
    mon, said = monitor()
    u = np.full(4, 0.05)
    rpm = np.array([800.0, 0.0, 800.0, 800.0])
    for k in range(5):  # the same status, measured at 0 ms, read for 0.4 s
        ages = np.full(4, 0.1 * k)
        assert not mon.update(k * 100 * MS, u, rpm, ages, 0.5).any()
    for k in range(5, 15):  # then new ones again, all turning: never stalled
        rpm_now = np.full(4, 800.0)
        assert not mon.update(k * 100 * MS, u, rpm_now, FRESH, 0.5).any()
    assert not [s for s in said if "stalled" in s]


def test_a_status_is_judged_against_the_commands_it_could_show() -> None:
    """A thruster commanded from 0 to half its range: the statuses measured within lag_s of
    the step still show the stopped shaft, and do not count; a shaft that stays stopped
    under the command is a stall 1 s (and 3 statuses) later."""
    mon, _ = monitor()
    idle, on = np.zeros(4), np.full(4, 0.05)
    zero = np.zeros(4)
    for k in range(5):
        mon.update(k * 100 * MS, idle, zero, FRESH, 0.5)
    # the command steps at 500 ms; statuses come 50 ms late: the first one after the step
    # was measured before it, the second 50 ms after it (within lag_s = 0.1 s)
    late = np.full(4, 0.05)
    stalled_at = None
    for k in range(5, 30):
        out = mon.update(k * 100 * MS, on, zero, late, 0.5)
        if out.all() and stalled_at is None:
            stalled_at = k * 100
    # first status that counts: measured at 650 ms (the step at 500 ms + lag 100 ms); the
    # stall 1 s after it, judged when the status measured at 1650 ms arrives (1700 ms)
    assert stalled_at == 1700, stalled_at


def test_a_stalled_thruster_is_never_restored_when_the_demand_falls_short() -> None:
    """The stage removed thruster 2 at an estimate above the dead threshold (0.3) and its ESC
    shows no rpm: when the others cannot meet the demand, the removed thrusters may come back
    at their estimate, but not one the stall evidence takes out. CI's demo run of example 1
    commanded a stalled thruster at its -0.1 N limit through this path."""
    m = 4
    est = Estimate(np.array([1.0, 0.3, 1.0, 1.0]), np.zeros(3), np.zeros(m), delta_std=np.zeros(m))
    removed = np.array([False, True, False, False])
    dec = Decision(
        delta_alloc=np.where(removed, 0.0, 1.0), f_alloc=np.zeros(m), bf_alloc=np.zeros(3),
        in_use=removed, removed=removed, faulty=removed, bias_faulty=np.zeros(m, dtype=bool),
        observable=np.ones(m, dtype=bool),
    )  # fmt: skip
    out = StageOutput(est, dec.delta_alloc, dec.bf_alloc, dec.faulty, decision=dec)
    free = apply_evidence(Evidence.none(m), out, dead_threshold=0.1)
    assert free.restorable.tolist() == [False, True, False, False]
    seen = apply_evidence(Evidence.of(m, stalled=removed), out, dead_threshold=0.1)
    assert not seen.restorable.any()
    assert seen.estimate.delta_hat[1] == 0.0 and seen.delta[1] == 0.0


def test_the_bus_guard_holds_estimation_frozen_until_the_escs_settle() -> None:
    """A node-ID conflict seen from 1 s to 3 s: frozen from 1 s, and still for settle_s
    (5 s) after the detector last saw it, then over once (the ESCs judge the stranger by
    their own detectors and may refuse commands after the allocator's has cleared)."""
    from ftcap_hil.runtime.esc_watchdog import BusGuard

    said: list[str] = []
    guard = BusGuard(TransitionLog(lambda text, _sev: said.append(text)),
                     lambda now: 1 * S <= now <= 3 * S)  # fmt: skip
    states = [guard.attacked(int(t * 1e9)) for t in (0.5, 1.0, 3.0, 4.0, 7.9, 8.1, 9.0)]
    assert states == [(False, False), (True, False), (True, False), (True, False),
                      (True, False), (False, True), (False, False)]  # fmt: skip
    assert [t.split(":")[0] for t in said] == ["CAN node-ID conflict", "CAN node-ID conflict over"]
    assert guard.episodes == 1
