"""The ESC watchdog's announcements: waiting at start-up vs failed (no processes)."""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.status import Severity
from ftcap_hil.ports.transitions import TransitionLog
from ftcap_hil.runtime.esc_watchdog import EscWatchdog

S = 1_000_000_000  # ns
TIMEOUT_S = 0.5


class Texts:
    def __init__(self) -> None:
        self.got: list[tuple[str, str]] = []

    def announce(self, text: str, severity: Severity) -> None:
        self.got.append((severity.value, text))


def watchdog() -> tuple[EscWatchdog, Texts]:
    texts = Texts()
    return EscWatchdog(TransitionLog(texts.announce)), texts


def test_start_up_is_waiting_not_failure_then_a_mute_esc_fails() -> None:
    inf = math.inf
    w, texts = watchdog()
    assert w.failed(0, np.array([inf, inf, inf, inf]), TIMEOUT_S).all()  # held at zero
    assert texts.got == [
        ("info", f"ESC {n} not heard yet: thruster held at 0") for n in (1, 2, 3, 4)
    ]
    texts.got.clear()
    ages = np.array([0.01, 0.01, inf, 0.01])  # the vessel powers up, ESC 3 stays mute
    assert w.failed(1 * S, ages, TIMEOUT_S).tolist() == [False, False, True, False]
    assert texts.got == [("info", f"ESC {n} reporting") for n in (1, 2, 4)]
    texts.got.clear()
    w.failed(1 * S + S // 4, ages, TIMEOUT_S)  # the others have reported for 0.25 s: waiting
    assert texts.got == []
    w.failed(1 * S + S * 6 // 10, ages, TIMEOUT_S)  # 0.6 s > the timeout: ESC 3 is failed
    assert texts.got == [("warning", "ESC 3 silent: thruster failed")]
    texts.got.clear()
    ages = np.array([0.01, 0.01, 0.01, 0.9])  # ESC 3 shows up; ESC 4 goes quiet
    assert w.failed(3 * S, ages, TIMEOUT_S).tolist() == [False, False, False, True]
    assert texts.got == [
        ("info", "ESC 3 reporting"),
        ("info", "ESC 3 reporting again"),
        ("warning", "ESC 4 silent: thruster failed"),
    ]


def test_the_timeout_is_read_at_each_call() -> None:
    """A live FTC_ESC_TMO change acts at the next cycle."""
    w, texts = watchdog()
    ages = np.array([0.01, 0.3, 0.01, 0.01])
    assert not w.failed(0, ages, TIMEOUT_S).any()
    assert w.failed(1, ages, 0.2).tolist() == [False, True, False, False]
    assert texts.got[-1] == ("warning", "ESC 2 silent: thruster failed")
