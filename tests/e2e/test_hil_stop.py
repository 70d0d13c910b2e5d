"""The allocator stopping: SIGTERM sends a zero command last and exits 0; SIGKILL sends
nothing, and the sim's command watchdog zeroes the thrust after ``command_timeout_s``.

Both tests stream a surge + sway setpoint at 10 Hz from the test (MAVLink) into hub + sim +
allocator processes and watch the bus (CAN tap), the allocator's command log and the sim's
``--record`` CSV. All clocks are CLOCK_MONOTONIC of the one machine.
"""

from __future__ import annotations

import re
import signal
import time

import pytest

from bridges.mavlink.gcs import MavlinkGcsLink
from ftcap_hil.runtime.processes import Child, wait_until
from tests.e2e.rig import BusTap, Rig, record_raw, setpoints

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(180)]

TAU = [0.1, 0.05, 0.0]
COMMAND_TIMEOUT_S = 0.5  # vessel.toml sim.command_timeout_s
ZERO = (0, 0, 0, 0)


def _u(row: dict[str, str]) -> list[float]:
    return [float(row[f"u_T{i}_N"]) for i in range(1, 5)]


def _running_rig(hil: Rig) -> tuple[MavlinkGcsLink, Child, BusTap]:
    gcs = hil.gcs()
    alloc = hil.start_allocator()
    hil.start_sim()
    tap = hil.tap()
    assert wait_until(lambda: gcs.odometry.latest() is not None, 20.0), hil.logs()
    return gcs, alloc, tap


def test_sigterm_sends_zero_last_and_exits_0(hil: Rig) -> None:
    gcs, alloc, tap = _running_rig(hil)
    with setpoints(gcs, tau=TAU):
        assert wait_until(lambda: all(v != 0 for v in tap.rpm()), 10.0), tap.rpm()
        time.sleep(1.0)
        t_term = time.monotonic_ns()
        alloc.send(signal.SIGTERM)  # while setpoints keep coming
        code = alloc.wait(15.0)
    time.sleep(1.0)  # the tap keeps listening after the process is gone
    assert code == 0, alloc.output()
    frames = tap.commands()
    before = [f.raw for f in frames if f.stamp_ns < t_term]
    assert before and ZERO not in before[-5:], before[-5:]  # it was thrusting
    assert frames[-1].raw == ZERO, [f.raw for f in frames[-5:]]
    t_zero = next(f.stamp_ns for f in frames if f.stamp_ns >= t_term and f.raw == ZERO)
    assert all(f.raw == ZERO for f in frames if f.stamp_ns >= t_zero), frames[-5:]
    logged = hil.command_log_rows()
    assert logged[-1][1:] == [0.0] * 4 and any(r[1:] != [0.0] * 4 for r in logged[-5:]), logged[-5:]
    # the sim got the zero as a command (fresh), not from its watchdog 0.5 s later (judged
    # on the sim's own record: its rows and the tap's frames are stamped by two processes)
    rows = [r for r in hil.record_rows() if float(r["monotonic_s"]) > t_term * 1e-9]
    first_zero = next((r for r in rows if _u(r) == [0.0] * 4), None)
    assert first_zero is not None and first_zero["command_fresh"] == "1", first_zero
    assert float(first_zero["command_age_s"]) < COMMAND_TIMEOUT_S, first_zero
    summary = re.search(r"stopped after (\d+) cycles, (\d+) overruns", alloc.output())
    assert summary is not None, alloc.output()
    print(
        f"\nSIGTERM -> first zero frame {(t_zero - t_term) * 1e-6:.1f} ms, exit 0; last frame "
        f"{frames[-1].raw}, last command-log row {logged[-1][1:]}; {summary.group(0)}"
    )


def test_sigkill_leaves_the_sim_watchdog_to_stop_the_thrusters(hil: Rig) -> None:
    gcs, alloc, tap = _running_rig(hil)
    with setpoints(gcs, tau=TAU):
        assert wait_until(lambda: all(v != 0 for v in tap.rpm()), 10.0), tap.rpm()
        time.sleep(1.0)
        alloc.send(signal.SIGKILL)
        assert alloc.wait(10.0) == -signal.SIGKILL
    time.sleep(1.5)
    frames = tap.commands()
    last = frames[-1]
    assert last.raw != ZERO and ZERO not in [f.raw for f in frames[-10:]], frames[-10:]
    # Timing on the sim's own clock: the last command's receive time is a fresh row's stamp
    # minus its command age (the tap's frames are stamped by another process).
    rows = hil.record_rows()
    last_fresh = [r for r in rows if r["command_fresh"] == "1"][-1]
    t_rx = float(last_fresh["monotonic_s"]) - float(last_fresh["command_age_s"])
    after = [r for r in rows if float(r["monotonic_s"]) > t_rx + 0.05]
    # the last command on the bus keeps acting until the watchdog fires ...
    held = [r for r in after if float(r["monotonic_s"]) < t_rx + COMMAND_TIMEOUT_S - 0.05]
    assert held and all(_u(r) == _u(held[0]) for r in held), held
    raw = record_raw(held[0])
    assert all(abs(a - b) <= 1 for a, b in zip(raw, last.raw, strict=True)), (raw, last.raw)
    # ... then the thrusters give zero, and keep giving zero
    first_zero = next(r for r in after if _u(r) == [0.0] * 4)
    stopped_after = float(first_zero["monotonic_s"]) - t_rx
    assert COMMAND_TIMEOUT_S <= stopped_after < COMMAND_TIMEOUT_S + 0.4, stopped_after
    tail = [r for r in after if float(r["monotonic_s"]) >= float(first_zero["monotonic_s"])]
    assert all(_u(r) == [0.0] * 4 and r["command_fresh"] == "0" for r in tail), tail[:3]
    assert float(tail[-1]["command_age_s"]) > 1.0, tail[-1]
    assert tap.rpm() == [0.0] * 4  # the ESCs report standstill
    sim = hil.procs["sim"]
    assert sim.running() and "thrusters at zero" in sim.output(), sim.output()
    print(
        f"\nSIGKILL: last command {last.raw}, thrust zeroed by the sim watchdog "
        f"{stopped_after:.3f} s after it (command_timeout_s {COMMAND_TIMEOUT_S})"
    )
