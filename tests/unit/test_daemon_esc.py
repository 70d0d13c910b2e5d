"""The daemon's ESC watchdog announcements: waiting at start-up vs failed (no processes)."""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.cycle import CoreConfig
from ftcap_hil.core.geometry import effectiveness, paper_four_thrusters
from ftcap_hil.core.plants import SurfaceVessel
from ftcap_hil.core.status import Severity
from ftcap_hil.runtime.daemon import AllocatorDaemon, DaemonConfig, Ports

S = 1_000_000_000  # ns


class NullSink:
    def send(self, u: np.ndarray) -> bool:
        return True

    def send_zero(self) -> bool:
        return True

    def tick(self, now_ns: int | None = None) -> None:
        return None


class Texts:
    def __init__(self) -> None:
        self.got: list[tuple[str, str]] = []

    def publish(self, status: object) -> None:
        pass

    def announce(self, text: str, severity: Severity) -> None:
        self.got.append((severity.value, text))


def daemon(ages: dict[str, np.ndarray]) -> tuple[AllocatorDaemon, Texts]:
    ths = paper_four_thrusters()
    texts = Texts()
    ports = Ports([], [], NullSink(), [texts], esc_ages=lambda now: ages["now"])
    cfg = DaemonConfig(ths, effectiveness(ths), SurfaceVessel(), CoreConfig(), esc_timeout_s=0.5)
    return AllocatorDaemon(cfg, ports), texts


def test_start_up_is_waiting_not_failure_then_a_mute_esc_fails() -> None:
    inf = math.inf
    ages = {"now": np.array([inf, inf, inf, inf])}
    d, texts = daemon(ages)
    assert d._esc_failed(0).all()  # not heard yet: held at zero, like a failed one
    assert texts.got == [
        ("info", f"ESC {n} not heard yet: thruster held at 0") for n in (1, 2, 3, 4)
    ]
    texts.got.clear()
    ages["now"] = np.array([0.01, 0.01, inf, 0.01])  # the vessel powers up, ESC 3 stays mute
    assert d._esc_failed(1 * S).tolist() == [False, False, True, False]
    assert texts.got == [("info", f"ESC {n} reporting") for n in (1, 2, 4)]
    texts.got.clear()
    d._esc_failed(1 * S + S // 4)  # the others have reported for 0.25 s: still waiting
    assert texts.got == []
    d._esc_failed(1 * S + S * 6 // 10)  # 0.6 s > esc_timeout_s: ESC 3 is failed
    assert texts.got == [("warning", "ESC 3 silent: thruster failed")]
    texts.got.clear()
    ages["now"] = np.array([0.01, 0.01, 0.01, 0.9])  # ESC 3 shows up; ESC 4 goes quiet
    assert d._esc_failed(3 * S).tolist() == [False, False, False, True]
    assert texts.got == [
        ("info", "ESC 3 reporting"),
        ("info", "ESC 3 reporting again"),
        ("warning", "ESC 4 silent: thruster failed"),
    ]
