"""The telemetry sources' guard (runtime/telemetry_guard.py, issue 22 item 1): a trusted port
wins over an untrusted one, two senders on one port or two ports that disagree are an alarm,
and estimation freezes only when the alarm concerns the source in use."""

from __future__ import annotations

import numpy as np

from ftcap_hil.core.messages import Odometry
from ftcap_hil.ports.mailbox import Mailbox
from ftcap_hil.ports.transitions import TransitionLog
from ftcap_hil.runtime.estimation import EstimationSampler
from ftcap_hil.runtime.telemetry_guard import (
    OdometryMailbox,
    TelemetryGuard,
    TelemetryIntake,
    TelemetryPort,
)

S = 1_000_000_000


def odo(t: float, north: float = 0.0) -> Odometry:
    return Odometry(np.array([north, 0.0, 0.0]), np.zeros(3), t)


def test_the_trusted_port_is_used_and_an_untrusted_forger_only_raises_the_alarm() -> None:
    mav, zen = OdometryMailbox("mavlink.odometry"), OdometryMailbox("zenoh.odometry")
    guard = TelemetryGuard([TelemetryPort(mav, True), TelemetryPort(zen, False)])
    mav.put(odo(1.0), 10 * S)
    zen.put(odo(99.0, north=40.0), 10 * S + 1000)  # newer vessel time, 40 m away
    got = guard.choose(10 * S + 2000, S)
    assert got.sample is not None and got.sample.value.eta[0] == 0.0
    assert got.alarm is not None and "disagree" in got.alarm and not got.frozen


def test_an_untrusted_port_alone_is_used_and_said_so() -> None:
    mav, zen = OdometryMailbox("mavlink.odometry"), OdometryMailbox("zenoh.odometry")
    guard = TelemetryGuard([TelemetryPort(mav, True), TelemetryPort(zen, False)])
    zen.put(odo(1.0), 10 * S)
    got = guard.choose(10 * S, S)
    assert got.sample is not None and got.untrusted_only and got.alarm is None


def test_two_senders_on_the_port_in_use_freeze_estimation_for_the_hold_time() -> None:
    zen = OdometryMailbox("zenoh.odometry")
    guard = TelemetryGuard([TelemetryPort(zen, False)], hold_s=2.0)
    for k in range(10):  # the vessel at 0.1 k s, a forger at 100 + k s, interleaved
        zen.put(odo(0.1 * k), 10 * S + k * 100_000_000)
        zen.put(odo(100.0 + k), 10 * S + k * 100_000_000 + 1000)
    got = guard.choose(11 * S, S)
    assert got.frozen and got.sample is None
    assert got.alarm is not None and "two odometry senders" in got.alarm
    zen.put(odo(200.0), 18 * S)  # the forger gone for longer than the window and the hold
    later = guard.choose(18 * S, S)
    assert not later.frozen and later.sample is not None and later.alarm is None


def test_one_restart_is_not_a_second_sender() -> None:
    box = OdometryMailbox("zenoh.odometry")
    guard = TelemetryGuard([TelemetryPort(box, True)])
    for t in (5.0, 5.1, 0.0, 0.1, 0.2):  # vessel time goes back once
        box.put(odo(t), 10 * S)
    got = guard.choose(10 * S, S)
    assert got.alarm is None and got.sample is not None


def test_plain_mailboxes_are_judged_on_agreement_only() -> None:
    a, b = Mailbox[Odometry]("a"), Mailbox[Odometry]("b")
    guard = TelemetryGuard([TelemetryPort(a, True), TelemetryPort(b, True)])
    a.put(odo(1.0), 10 * S)
    b.put(odo(1.0, north=0.5), 10 * S)  # within the 2 m margin
    assert guard.choose(10 * S, S).alarm is None
    b.put(odo(1.0, north=30.0), 10 * S)
    got = guard.choose(10 * S, S)
    assert got.alarm is not None and got.frozen  # both trusted: nothing to prefer


def test_the_exit_line_counts_the_gates_drops_with_the_malformed(caplog) -> None:  # type: ignore[no-untyped-def]
    """Issue 22, item 8: the exit line's malformed count left out the gate's drops."""
    import logging

    from ftcap_hil.apps.allocator import _log_summary
    from tests.unit.test_daemon_parts import _daemon

    daemon, _, _ = _daemon()
    box = daemon.ports.telemetry[0]
    box.count_malformed()  # one undecodable sample on the port
    box.put(Odometry(np.zeros(3), np.array([1e6, 0.0, 0.0]), 1.0))  # one absurd one
    daemon.cycle(daemon.loop.clock())
    assert daemon.sampler.gate.rejected == 1 and daemon.malformed == 2
    with caplog.at_level(logging.INFO, logger="ftcap_hil.apps.allocator"):
        _log_summary(daemon)
    assert "2 malformed inputs dropped (1 of them implausible telemetry)" in caplog.text


def test_the_intake_hands_the_sampler_every_sample_since_the_last_cycle() -> None:
    """A cycle every 0.25 s reads the newest sample; the grid's ends are the samples at or
    after each 0.2827 s, which a cycle rarely reads: the intake hands over every sample of
    the port in use received since the last cycle. (The newest sample alone gave intervals
    of 0.5 s here: 0.25 s is under 0.9 periods.)"""
    mav, zen = OdometryMailbox("mavlink.odometry"), OdometryMailbox("zenoh.odometry")
    guard = TelemetryGuard([TelemetryPort(mav, True), TelemetryPort(zen, False)])
    sampler = EstimationSampler(period_s=0.2827, use_vessel_clock=False)
    sampler.command_sent(0, np.ones(4))
    intake = TelemetryIntake(guard, sampler, TransitionLog(lambda *_: None), fresh_s=1.0)
    ends = []
    for k in range(1, 61):  # 20 Hz on both ports (Zenoh's copy 1 ms later)
        mav.put(odo(0.05 * k), 10 * S + k * 50_000_000)
        zen.put(odo(0.05 * k), 10 * S + k * 50_000_000 + 1_000_000)
        if k % 5 == 0:  # a cycle every 0.25 s, just after the sample at 0.25 j s
            got = intake.sample(10 * S + k * 50_000_000 + 2_000_000, stale=False)
            if got is not None:
                ends.append(round(got.observation.dt_s, 6))
    # ends at 0.3, 0.6, 0.85 (>= 0.848), 1.15, 1.45, 1.7, ...: dt 0.30 or 0.25, never 0.6
    assert len(ends) >= 9 and set(ends) == {0.25, 0.3}, ends
    box = mav.received_after(10 * S + 55 * 50_000_000, 10 * S + 58 * 50_000_000)
    assert [round(s.value.time_s, 6) for s in box] == [2.8, 2.85, 2.9]
