"""The ground station's control loop: one :class:`Flight` of a :class:`FlightPlan`.

Every ``period_s`` on absolute deadlines (:class:`~ftcap_hil.runtime.loop.DeadlineLoop`),
at mission time t = (now - t0) s:

1. ``check()`` (raises to abort); the latest ODOMETRY -> x = [north, east, psi, u, v, r]
   (:class:`LinkLost` if it is older than ``odometry_timeout_s``);
2. the injections due by t handed to the :class:`Injector`;
3. the :class:`WrenchLaw` at (t, x), shrunk to ``wrench_limit`` -> WRENCH_SETPOINT;
4. the allocator's latest FTCAP_STATUS and ACTUATOR_OUTPUT_STATUS -> a recorder row and
   the status line; a new FTCAP_STATUS kept (``keep_statuses``);
5. injection outcomes and STATUSTEXTs drained and logged (STATUSTEXTs only with
   ``drain_texts``: a caller that reads the link's queue itself says False).

The flight ends at ``duration_s`` (never, if None) or at :meth:`Flight.request_exit`; the
injector is then given the time to finish what was submitted.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from types import TracebackType
from typing import Any

import numpy as np

from ftcap_hil.core.messages import FloatArray
from ftcap_hil.core.models.controllers import limit_wrench
from ftcap_hil.core.models.plants import wrap_angle
from ftcap_hil.core.status import AllocatorStatus, Severity
from ftcap_hil.ports.ground_link import GroundLink, StatusText
from ftcap_hil.ports.mailbox import Stamped
from ftcap_hil.ports.transitions import LOG_LEVEL, TransitionLog
from ftcap_hil.report.flight import FlightRecorder
from ftcap_hil.runtime.gcs_parts import (
    FlightPlan,
    InjectionOutcome,
    Injector,
    LinkLost,
    ProgressLine,
    StatusLine,
    state_of,
    status_text,
)
from ftcap_hil.runtime.loop import DeadlineLoop, LoopStats

log = logging.getLogger("ftcap_hil.gcs")

ALLOCATOR_SILENT_S = 2.0  # no FTCAP_STATUS for this long (once t > 2 s): a warning


class Flight:
    """One flight of ``plan`` on ``link`` from ``t0_ns`` (monotonic; default: now).

    Counters and what the flight kept (``outcomes``, ``texts``, ``statuses``) are read after
    :meth:`run`, or during it from another thread. ``max_position_error_m`` and
    ``max_heading_error_rad`` are the largest distances between x and the reference over
    the cycles that had both.
    """

    def __init__(
        self,
        link: GroundLink,
        plan: FlightPlan,
        t0_ns: int | None = None,
        *,
        recorder: FlightRecorder | None = None,
        line: StatusLine | None = None,
        check: Callable[[], None] | None = None,
        progress: ProgressLine | None = None,
    ) -> None:
        self.link, self.plan, self.progress = link, plan, progress
        self.loop = DeadlineLoop(int(round(plan.period_s / plan.time_scale * 1e9)))
        self.t0_ns = self.loop.clock() if t0_ns is None else t0_ns
        self.recorder, self.line, self._check = recorder, line, check
        self.cycles = self.sent = self.send_failures = self.limited_cycles = 0
        self.max_position_error_m = self.max_heading_error_rad = 0.0
        self.outcomes: list[InjectionOutcome] = []
        self.texts: list[Stamped[StatusText]] = []
        self.statuses: list[Stamped[AllocatorStatus]] = []
        self.error: BaseException | None = None  # what ended a background flight
        self._due = deque(plan.injections)
        self._injector: Injector | None = None
        self._transitions = TransitionLog(self._announce)
        self._thread: threading.Thread | None = None

    @property
    def overruns(self) -> int:
        """Deadlines missed because a cycle ran past them."""
        return self.loop.stats.overruns

    def request_exit(self, *_: object) -> None:
        """End after the current cycle (thread-safe, signal-handler safe)."""
        self.loop.request_exit()

    # --- running ---

    def run(self) -> LoopStats:
        """Fly in this thread until the end of the plan or :meth:`request_exit`; the
        exceptions of a cycle (:class:`LinkLost`, ``check``'s) end the flight and propagate."""
        if self._due:
            p = self.plan
            self._injector = Injector(self.link, self.t0_ns, p.inject_timeout_s, p.inject_attempts)
        try:
            return self.loop.run(self._tick, first_deadline_ns=self.t0_ns)
        finally:
            if self._injector is not None:
                self._injector.close()
            self.drain()
            if self.line is not None:
                self.line.clear()

    def start(self) -> Flight:
        """Fly on a thread of its own; :meth:`stop` (or leaving a ``with``) ends it."""
        self._thread = threading.Thread(target=self._background, name="gcs-flight", daemon=True)
        self._thread.start()
        return self

    def _background(self) -> None:
        try:
            self.run()
        except Exception as e:  # handed to the caller by stop()
            self.error = e
            log.error("flight ended: %s", e)

    def stop(self, timeout_s: float = 10.0) -> None:
        """End a background flight; re-raises what ended it early, if anything."""
        self.request_exit()
        if self._thread is not None:
            self._thread.join(timeout_s)
        if self.error is not None:
            raise self.error

    def __enter__(self) -> Flight:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()

    # --- one cycle ---

    def _tick(self, now_ns: int) -> None:
        t = (now_ns - self.t0_ns) * 1e-9 * self.plan.time_scale
        if self.plan.duration_s is not None and t >= self.plan.duration_s:
            self.loop.request_exit()
            return
        if self._check is not None:
            self._check()
        x = self._state(now_ns, t)
        self._submit_due(t)
        law = self.plan.law(t, x)
        ref, v = (None, None) if law is None else (law[0], self._send(law[1]))
        st, cmd = self.link.allocator_status.latest(), self.link.thruster_commands.latest()
        self._watch_allocator(now_ns, t, st)
        status = None if st is None else st.value
        u = None if cmd is None else cmd.value.u
        if x is not None and ref is not None:
            self._track_error(x, ref)
            if self.recorder is not None and v is not None:
                self.recorder.add(t, x, ref, v, status, u)
            if self.line is not None:
                self.line.show(status_text(t, x, ref, status, u, self.plan.duration_s))
        self.drain()
        if self.progress is not None and self.progress.due(t):
            if self.line is not None:
                self.line.clear()
            self.progress.show(t, x, ref, status, self.outcomes)
        self.cycles += 1

    def _state(self, now_ns: int, t: float) -> FloatArray | None:
        odom = self.link.odometry.latest()
        timeout_s = self.plan.odometry_timeout_s
        age_s = np.inf if odom is None else (now_ns - odom.stamp_ns) * 1e-9
        if timeout_s is not None and age_s > timeout_s:
            raise LinkLost(f"no ODOMETRY from the vessel for {age_s:.1f} s (t = {t:.1f} s)")
        return None if odom is None else state_of(odom.value)

    def _submit_due(self, t: float) -> None:
        due = []
        while self._due and self._due[0].at_s <= t:
            due.append(self._due.popleft())
        if due and self._injector is not None:
            self._injector.submit(due)

    def _send(self, v: FloatArray) -> FloatArray:
        if self.plan.wrench_limit is not None:
            limited = limit_wrench(v, self.plan.wrench_limit)
            self.limited_cycles += int(limited is not v)
            self._transition("limit", limited is not v, "demand beyond gcs.wrench_limit: shrunk")
            v = limited
        if self.link.send_wrench(v.tolist()):
            self.sent += 1
        else:
            self.send_failures += 1
        return v

    def _watch_allocator(self, now_ns: int, t: float, st: Stamped[AllocatorStatus] | None) -> None:
        silent = st is None or (now_ns - st.stamp_ns) * 1e-9 > ALLOCATOR_SILENT_S
        self._transition(
            "allocator", silent and t > ALLOCATOR_SILENT_S, "no FTCAP_STATUS from the allocator"
        )
        if self.plan.keep_statuses and st is not None:
            if not self.statuses or self.statuses[-1].stamp_ns != st.stamp_ns:
                self.statuses.append(st)

    def _track_error(self, x: FloatArray, ref: FloatArray) -> None:
        err = np.asarray(ref, dtype=np.float64) - x[:3]
        self.max_position_error_m = max(self.max_position_error_m, float(np.hypot(*err[:2])))
        heading = abs(float(wrap_angle(err[2])))
        self.max_heading_error_rad = max(self.max_heading_error_rad, heading)

    # --- what the cycle reports ---

    def _say(self, level: int, msg: str, *args: Any) -> None:
        if self.line is not None:
            self.line.clear()
        log.log(level, msg, *args)

    def _transition(self, name: str, on: bool, text: str) -> None:
        """Log a condition when it starts (a warning) and when it ends ("over: ", info), not
        every cycle."""
        self._transitions.update(name, on, text, f"over: {text}")

    def _announce(self, text: str, severity: Severity) -> None:
        self._say(LOG_LEVEL[severity], "%s", text)

    def drain(self) -> None:
        """Injection outcomes and (``drain_texts``) STATUSTEXTs received so far: kept, logged."""
        for out in [] if self._injector is None else self._injector.outcomes():
            self.outcomes.append(out)
            i = out.injection
            what = f"inject {i.kind.name} on thruster {i.thruster + 1} (value {i.value:g})"
            level = logging.INFO if out.ok else logging.ERROR
            self._say(level, "t = %.2f s: %s: %s", out.sent_at_s, what, out.result)
        if not self.plan.drain_texts:
            return
        for item in self.link.drain_statustexts():
            self.texts.append(item)
            text = item.value
            self._say(logging.INFO, "STATUSTEXT %d/%d: %s", text.system, text.component, text.text)
