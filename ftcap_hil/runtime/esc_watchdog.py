"""The ESC watchdog: which thrusters the allocator treats as failed because their ESC is silent.

Each ESC's status age (seconds since its last ``esc.Status``, +inf if never heard) against
``timeout_s``:

* heard within ``timeout_s``: working;
* heard once, silent since for longer: **failed** (warning "ESC n silent: thruster failed");
* never heard: held at zero like a failed one, but announced as **waiting** (info "ESC n not
  heard yet") because at start-up the vessel may simply not be powered yet. It becomes a
  failure only once another ESC has been reporting for ``timeout_s`` (the *others-up* rule:
  the bus and the vessel are alive, this ESC is not).

Announcements go through a :class:`~ftcap_hil.ports.transitions.TransitionLog`, so each is
made once when it starts and once when it ends.
"""

from __future__ import annotations

import math

import numpy as np

from ftcap_hil.core.messages import BoolArray, FloatArray
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.transitions import TransitionLog


class EscWatchdog:
    """Failed/waiting policy over ESC status ages (module docstring)."""

    def __init__(self, transitions: TransitionLog) -> None:
        self._transitions = transitions
        self._bus_alive_ns: int | None = None  # when the first ESC was heard

    def failed(self, now_ns: int, ages_s: FloatArray, timeout_s: float) -> BoolArray:
        """(m,) True for every thruster to allocate as failed at ``now_ns``: silent for over
        ``timeout_s`` or never heard (announced as waiting or failed, module docstring)."""
        failed = ages_s > timeout_s  # never heard: age +inf, held at zero as well
        heard = np.isfinite(ages_s)
        if self._bus_alive_ns is None and heard.any():
            self._bus_alive_ns = now_ns
        others_up = self._bus_alive_ns is not None and now_ns - self._bus_alive_ns > timeout_s * 1e9
        for i in range(failed.size):
            n = i + 1
            self._transitions.update(
                f"esc-wait{n}",
                not heard[i],
                f"ESC {n} not heard yet: thruster held at 0",
                f"ESC {n} reporting",
                severity=Severity.INFO,
            )
            self._transitions.update(
                f"esc{n}",
                bool(failed[i]) and bool(heard[i] or others_up),
                f"ESC {n} silent: thruster failed",
                f"ESC {n} reporting again",
            )
        return failed


class EscStallMonitor:
    """ESC telemetry as evidence of its own: a thruster whose ESC keeps reporting a stalled
    shaft (|rpm| below ``stall_rpm``) while commanded at least ``set_fraction`` of its range
    for ``stall_s`` is **stalled** (warning "ESC n: no rpm under command: thruster stalled");
    the allocator then gives it no effort but its recovery probes. It clears as soon as the
    shaft turns (|rpm| >= stall_rpm) under a command of at least ``clear_fraction`` of the
    range: a probe is enough. A fouled or bladeless propeller still turns and is left to the
    motion-based estimate; a stuck one reports no rpm (sim/esc_model.py) like a dead one.

    Only fresh telemetry counts (age below ``timeout_s``: a silent ESC is the watchdog's).
    The command compared is the one the thrusters had when the status was measured: the
    last command sent at least one status age ago would be exact; the one sent now is used,
    and ``stall_s`` (default 1 s: several status periods and the thruster's lag) covers it.
    """

    def __init__(
        self,
        transitions: TransitionLog,
        u_range: FloatArray,
        stall_rpm: float = 50.0,
        stall_s: float = 1.0,
        set_fraction: float = 0.1,
        clear_fraction: float = 0.02,
    ) -> None:
        self._transitions = transitions
        self._range = np.asarray(u_range, dtype=np.float64)
        self.stall_rpm, self.stall_s = stall_rpm, stall_s
        self.set_fraction, self.clear_fraction = set_fraction, clear_fraction
        m = self._range.size
        self._since: list[int | None] = [None] * m
        self._stalled = np.zeros(m, dtype=bool)

    def update(
        self,
        now_ns: int,
        u: FloatArray,
        rpm: FloatArray,
        ages_s: FloatArray,
        timeout_s: float,
    ) -> BoolArray:
        """(m,) stalled thrusters after this cycle's command ``u`` (N) and the latest ESC
        ``rpm`` with their ages (s; NaN rpm or an age beyond ``timeout_s``: no evidence)."""
        load = np.abs(np.asarray(u, dtype=np.float64)) / self._range
        for i in range(self._range.size):
            fresh = bool(ages_s[i] <= timeout_s) and math.isfinite(float(rpm[i]))
            if not fresh:
                self._since[i] = None
                continue
            turning = abs(float(rpm[i])) >= self.stall_rpm
            if turning and load[i] >= self.clear_fraction:
                self._since[i], self._stalled[i] = None, False
            elif not turning and load[i] >= self.set_fraction:
                since = self._since[i]
                if since is None:
                    self._since[i] = now_ns
                elif now_ns - since >= self.stall_s * 1e9:
                    self._stalled[i] = True
            elif not self._stalled[i]:
                self._since[i] = None  # no longer loaded: the stall must be seen again
            n = i + 1
            self._transitions.update(
                f"esc-stall{n}",
                bool(self._stalled[i]),
                f"ESC {n}: no rpm under command: thruster stalled",
                f"ESC {n}: turning again",
            )
        return self._stalled.copy()
