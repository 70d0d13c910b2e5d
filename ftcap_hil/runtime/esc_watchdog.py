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
from collections import deque
from collections.abc import Callable

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

    Only fresh telemetry counts (age below ``timeout_s``: a silent ESC is the watchdog's),
    and each status once: a status is judged when it is new (its measurement time, now minus
    its age, later than the last one judged), against the commands that were in force over
    the ``lag_s`` before it was measured (the ESC's and the vessel's response: a status taken
    just after a large command change still shows the previous one). A stall needs
    ``min_samples`` such statuses spanning ``stall_s``: a late or starved telemetry stream
    that repeats one old status, or a status compared with a command it could not yet show,
    is not a stall (the live loop on a loaded machine: tests/e2e/test_demo.py).
    """

    def __init__(
        self,
        transitions: TransitionLog,
        u_range: FloatArray,
        stall_rpm: float = 50.0,
        stall_s: float = 1.0,
        set_fraction: float = 0.1,
        clear_fraction: float = 0.02,
        lag_s: float = 0.1,
        min_samples: int = 3,
    ) -> None:
        self._transitions = transitions
        self._range = np.asarray(u_range, dtype=np.float64)
        self.stall_rpm, self.stall_s = stall_rpm, stall_s
        self.set_fraction, self.clear_fraction = set_fraction, clear_fraction
        self.lag_s, self.min_samples = lag_s, min_samples
        m = self._range.size
        self._since: list[int | None] = [None] * m  # measurement time of the first low status
        self._count = [0] * m  # low statuses under load since then
        self._judged: list[int | None] = [None] * m  # measurement time of the last status judged
        self._stalled = np.zeros(m, dtype=bool)
        self._history: deque[tuple[int, FloatArray]] = deque()  # (since, load) of the commands

    def _loads(self, t0_ns: int, t1_ns: int) -> tuple[FloatArray, FloatArray]:
        """(m,) smallest and largest load of the commands in force over [t0_ns, t1_ns]."""
        inside = [load for since, load in self._history if t0_ns < since <= t1_ns]
        before = [load for since, load in self._history if since <= t0_ns]
        loads = ([before[-1]] if before else []) + inside or [self._history[0][1]]
        stack = np.vstack(loads)
        return stack.min(axis=0), stack.max(axis=0)

    def update(
        self,
        now_ns: int,
        u: FloatArray,
        rpm: FloatArray,
        ages_s: FloatArray,
        timeout_s: float,
    ) -> BoolArray:
        """(m,) stalled thrusters after this cycle's command ``u`` (N, in force from
        ``now_ns``) and the latest ESC ``rpm`` with their ages (s; NaN rpm or an age beyond
        ``timeout_s``: no evidence)."""
        load = np.abs(np.asarray(u, dtype=np.float64)) / self._range
        self._history.append((now_ns, load))
        keep_ns = int((timeout_s + self.lag_s + 1.0) * 1e9)
        while len(self._history) > 1 and self._history[1][0] < now_ns - keep_ns:
            self._history.popleft()
        for i in range(self._range.size):
            fresh = bool(ages_s[i] <= timeout_s) and math.isfinite(float(rpm[i]))
            if not fresh:
                self._since[i], self._count[i] = None, 0
                continue
            measured = now_ns - int(float(ages_s[i]) * 1e9)
            judged = self._judged[i]
            if judged is not None and measured <= judged:
                continue  # the status judged already: no new evidence
            self._judged[i] = measured
            lo, hi = self._loads(measured - int(self.lag_s * 1e9), measured)
            turning = abs(float(rpm[i])) >= self.stall_rpm
            since = self._since[i]
            if turning and hi[i] >= self.clear_fraction:
                self._since[i], self._count[i], self._stalled[i] = None, 0, False
            elif not turning and lo[i] >= self.set_fraction:
                if since is None:
                    self._since[i], self._count[i] = measured, 1
                else:
                    self._count[i] += 1
                    lasted = measured - since >= self.stall_s * 1e9
                    if lasted and self._count[i] >= self.min_samples:
                        self._stalled[i] = True
            elif not self._stalled[i]:
                self._since[i], self._count[i] = None, 0  # not loaded: the stall must be seen again
            n = i + 1
            self._transitions.update(
                f"esc-stall{n}",
                bool(self._stalled[i]),
                f"ESC {n}: no rpm under command: thruster stalled",
                f"ESC {n}: turning again",
            )
        return self._stalled.copy()


class BusGuard:
    """A bus under attack: while ``in_conflict(now_ns)`` says a second node sends with the
    allocator's node ID (DroneCAN has no authentication), what the ESCs do and report may
    follow a stranger's commands, so neither the estimator nor the ESC evidence (silent,
    stalled) may judge the thrusters: estimation is frozen and the evidence ignored; the
    allocation goes on within its limits. Announced once when it starts and when it ends.

    It ends ``settle_s`` after the detector last said so: each ESC judges the stranger by
    its own detector and may go on refusing commands (zero) after the allocator's has
    cleared (its window and clear time, 2 s + 3 s by default); an estimator resumed then
    took every thruster for dead (seen in a loaded e2e run)."""

    def __init__(
        self,
        transitions: TransitionLog,
        in_conflict: Callable[[int], bool] | None,
        settle_s: float = 5.0,
    ) -> None:
        self._transitions = transitions
        self._in_conflict = in_conflict
        self._settle_ns = int(settle_s * 1e9)
        self._last_seen_ns: int | None = None
        self.episodes = 0

    def attacked(self, now_ns: int) -> tuple[bool, bool]:
        """(on now, just ended) at ``now_ns``."""
        if self._in_conflict is not None and self._in_conflict(now_ns):
            self._last_seen_ns = now_ns
        last = self._last_seen_ns
        on = last is not None and now_ns - last < self._settle_ns
        was = self._transitions["can_conflict"]
        self._transitions.update(
            "can_conflict",
            on,
            "CAN node-ID conflict: another node sends as the allocator; estimation frozen, "
            "ESC evidence ignored",
            "CAN node-ID conflict over: estimation and ESC evidence resume",
            Severity.ERROR,
        )
        self.episodes += on and not was
        return on, was and not on
