"""The shared runtime plumbing: deadline loop, signal capture, transition log."""

from __future__ import annotations

import itertools
import os
import signal

import pytest

from ftcap_hil.core.status import Severity
from ftcap_hil.runtime.loop import DeadlineLoop
from ftcap_hil.runtime.signals import ForcedExit, capture_signals
from ftcap_hil.runtime.transitions import TransitionLog


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
