"""The shared runtime plumbing: deadline loop, signal capture, transition log."""

from __future__ import annotations

import itertools
import logging
import os
import signal
import sys
import threading

import pytest

from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import Mailbox
from ftcap_hil.ports.transitions import TransitionLog, log_to
from ftcap_hil.runtime.loop import DeadlineLoop, fast_thread_switch
from ftcap_hil.runtime.signals import ForcedExit, capture_signals


class FakeClock:
    """A clock that only moves when a tick says so (no sleeping in the loop's wait)."""

    def __init__(self) -> None:
        self.now = 0

    def __call__(self) -> int:
        return self.now


def test_deadlines_are_absolute_and_a_long_tick_counts_every_missed_deadline() -> None:
    clock = FakeClock()
    loop = DeadlineLoop(period_ns=100, clock=clock)
    starts: list[int] = []
    durations = iter([10, 10, 350, 10, 10])  # the third tick runs over 3 more deadlines

    def tick(now: int) -> None:
        starts.append(now)
        clock.now += next(durations)
        if len(starts) == 5:
            loop.request_exit()

    def wait(timeout_s: float | None = None) -> bool:  # the fake clock jumps to the deadline
        clock.now += max(0, round((timeout_s or 0.0) * 1e9))
        return False

    loop._event.wait = wait  # type: ignore[method-assign]
    stats = loop.run(tick)
    assert starts == [0, 100, 200, 600, 700]  # the phase is kept after the overrun
    assert stats.overruns == 3 and stats.ticks == 5 and stats.wake_ticks == 0


def test_wake_ticks_early_without_moving_the_deadlines() -> None:
    clock = FakeClock()
    loop = DeadlineLoop(period_ns=100, clock=clock)
    starts: list[int] = []
    woken = itertools.chain([True], itertools.repeat(False))

    def wait(timeout_s: float | None = None) -> bool:
        if next(woken):
            clock.now += 30  # something arrived 30 ns into the wait
            return True
        clock.now += max(0, round((timeout_s or 0.0) * 1e9))
        return False

    def tick(now: int) -> None:
        starts.append(now)
        if len(starts) == 4:
            loop.request_exit()

    loop._event.wait = wait  # type: ignore[method-assign]
    loop.run(tick, first_deadline_ns=100)
    assert starts == [30, 100, 200, 300]
    assert loop.stats.wake_ticks == 1 and loop.stats.ticks == 3


def test_a_bad_period_is_refused() -> None:
    with pytest.raises(ValueError, match="period_ns"):
        DeadlineLoop(period_ns=0)


def test_first_signal_stops_politely_a_second_forces_and_handlers_come_back() -> None:
    before = signal.getsignal(signal.SIGTERM)
    stops: list[str] = []
    with pytest.raises(ForcedExit), capture_signals(lambda: stops.append("stop")) as cap:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stops == ["stop"] and cap.stopping and cap.signal_name == "SIGTERM"
        os.kill(os.getpid(), signal.SIGINT)
    assert signal.getsignal(signal.SIGTERM) is before
    assert stops == ["stop"]


def test_transitions_are_announced_once_each_way() -> None:
    said: list[tuple[Severity, str]] = []
    log = TransitionLog(lambda text, sev: said.append((sev, text)))
    assert not log.update("stale", False, "stale!", "fresh")  # starts off: silent
    assert log.update("stale", True, "stale!", "fresh")
    assert not log.update("stale", True, "stale!", "fresh")
    assert log.update("stale", False, "stale!", "fresh")
    assert log.update("x", True, "x on", None, Severity.INFO)
    assert log.update("x", False, "x on")  # it changed, and says nothing (no off text)
    assert said == [
        (Severity.WARNING, "stale!"),
        (Severity.INFO, "fresh"),
        (Severity.INFO, "x on"),
    ]
    assert log["x"] is False and log["never"] is False


def test_forced_exit_is_raised_once_and_never_inside_a_shield() -> None:
    stops: list[str] = []
    with capture_signals(lambda: stops.append("stop")) as cap:
        os.kill(os.getpid(), signal.SIGTERM)
        with cap.shielded():  # the final zero going out: a second signal does not cut it
            os.kill(os.getpid(), signal.SIGINT)
        assert len(cap.received) == 2 and not cap.forced
    with pytest.raises(ForcedExit), capture_signals(lambda: None) as cap:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            os.kill(os.getpid(), signal.SIGTERM)
        finally:
            os.kill(os.getpid(), signal.SIGTERM)  # while forcing: counted, not raised again
            assert cap.forced and len(cap.received) == 3
    assert stops == ["stop"]


def test_on_force_is_called_instead_of_raising() -> None:
    calls: list[str] = []
    with capture_signals(lambda: calls.append("stop"), on_force=lambda: calls.append("force")):
        for _ in range(3):
            os.kill(os.getpid(), signal.SIGINT)
    assert calls == ["stop", "force"]


def test_no_capture_outside_the_main_thread() -> None:
    before = signal.getsignal(signal.SIGINT)
    seen: list[object] = []

    def other() -> None:
        with capture_signals(lambda: None) as cap:
            seen.append(signal.getsignal(signal.SIGINT))
            seen.append(cap.stopping)

    t = threading.Thread(target=other)
    t.start()
    t.join()
    assert seen == [before, False]


def test_a_mailbox_handed_the_wake_event_wakes_a_real_loop() -> None:
    loop = DeadlineLoop(period_ns=10 * 10**9)  # a 10 s period: only a wake-up ticks again
    box: Mailbox[int] = Mailbox("x", notify=loop.wake_event)
    ticks: list[int] = []

    def tick(now: int) -> None:
        ticks.append(now)
        if len(ticks) == 2:
            loop.request_exit()

    t = threading.Thread(target=loop.run, args=(tick,))
    t.start()
    box.put(1)
    t.join(5.0)
    assert not t.is_alive() and len(ticks) == 2
    assert loop.stats.ticks == 1 and loop.stats.wake_ticks == 1


def test_fast_thread_switch_restores_the_interval() -> None:
    before = sys.getswitchinterval()
    with pytest.raises(RuntimeError), fast_thread_switch(1e-4):
        assert sys.getswitchinterval() == pytest.approx(1e-4)
        raise RuntimeError
    assert sys.getswitchinterval() == before


def test_off_severity_and_the_logger_announce(caplog: pytest.LogCaptureFixture) -> None:
    log = TransitionLog(log_to(logging.getLogger("t")))
    with caplog.at_level(logging.INFO, logger="t"):
        log.update("silent", True, "ESC 1 silent")
        log.update("silent", False, "ESC 1 silent", "ESC 1 back", off_severity=Severity.WARNING)
    assert [(r.levelno, r.message) for r in caplog.records] == [
        (logging.WARNING, "ESC 1 silent"),
        (logging.WARNING, "ESC 1 back"),
    ]


def test_a_key_that_keeps_flipping_is_announced_once_per_interval() -> None:
    clock = FakeClock()
    said: list[str] = []
    held: list[str] = []
    log = TransitionLog(
        lambda text, _sev: said.append(text),
        min_interval_s=5.0,
        quiet=lambda text, _sev: held.append(text),
        clock=clock,
    )
    assert log.update("port", True, "failing", "working")  # t = 0: said
    clock.now = 1_000_000_000
    assert log.update("port", False, "failing", "working")  # 1 s later: held back
    clock.now = 2_000_000_000
    assert log.update("port", True, "failing", "working")  # held back
    assert log.update("other", True, "other failing")  # another key has its own interval
    clock.now = 5_000_000_000
    assert log.update("port", False, "failing", "working")  # 5 s after the last line: said
    assert said == [
        "failing",
        "other failing",
        "working (2 changes not logged since the last line)",
    ]
    assert held == ["working", "failing"]
    assert log["port"] is False and log["other"] is True
