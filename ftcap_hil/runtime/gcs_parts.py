"""The parts of the ground-station driver (:mod:`ftcap_hil.runtime.ground_station`).

* :class:`WrenchLaw`: what a flight sends each cycle: a constant wrench, or eq. (24) on the
  latest ODOMETRY toward a reference (a hold point is a constant reference);
* :class:`FlightPlan`: the law, the period, the duration, the injections and the limits;
* :class:`Injector`: MAV_CMD_INJECT_FAILURE sent in order from its own thread (it waits for
  the COMMAND_ACKs, the control loop never does); :class:`InjectionOutcome` per request;
* :class:`StatusLine`: one live line on a terminal; :class:`ProgressLine`: a line on stdout
  every few seconds of mission time (a log file or a pipe: ``--progress``);
* the driver's errors, each carrying its exit code of
  :class:`~ftcap_hil.core.errors.ExitCode`.
"""

from __future__ import annotations

import math
import queue
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ftcap_hil.core.errors import ExitCode, FtcapError
from ftcap_hil.core.faults import Injection
from ftcap_hil.core.messages import FloatArray, Odometry
from ftcap_hil.core.models.controllers import PoseController
from ftcap_hil.ports.ground_link import GroundLink

Controller = Callable[[FloatArray, FloatArray], FloatArray]
Reference = Callable[[float], FloatArray]


class GroundStationError(FtcapError):
    """The ground station could not start or finish its flight."""


class NoAnswer(GroundStationError):
    """The vessel or the allocator did not answer at start-up."""

    exit_code = ExitCode.NO_ANSWER


class LinkLost(GroundStationError):
    """The vessel went silent mid-flight (no ODOMETRY for ``odometry_timeout_s``)."""

    exit_code = ExitCode.LINK_LOST


class Refused(GroundStationError):
    """A parameter set was answered with another value than the one asked for."""

    exit_code = ExitCode.REFUSED


class Interrupted(GroundStationError):
    """A stop was requested (SIGINT / SIGTERM) before the flight started."""

    exit_code = ExitCode.INTERRUPTED


def state_of(odom: Odometry) -> FloatArray:
    """x = [north (m), east (m), psi (rad), u (m/s), v (m/s), r (rad/s)] of one ODOMETRY."""
    return np.concatenate([odom.eta, odom.nu])


@dataclass(frozen=True)
class WrenchLaw:
    """The wrench a flight sends: [X (N), Y (N), N (N*m)], body frame.

    Either a constant ``tau`` (needs no ODOMETRY), or ``controller(x, reference(t))`` on the
    latest state x = [north, east, psi, u, v, r] (eq. (24), the paper's gains by default).
    """

    tau: tuple[float, float, float] | None = None
    reference: Reference | None = None
    controller: Controller = field(default_factory=PoseController)

    def __post_init__(self) -> None:
        if (self.tau is None) == (self.reference is None):
            raise ValueError("a wrench law is a constant tau or a reference, exactly one")

    @classmethod
    def constant(cls, tau: Sequence[float]) -> WrenchLaw:
        x, y, n = (float(v) for v in tau)
        return cls(tau=(x, y, n))

    @classmethod
    def hold(cls, point: Sequence[float], controller: Controller | None = None) -> WrenchLaw:
        """Eq. (24) toward the fixed pose ``point`` = [north (m), east (m), psi (rad)]."""
        p = np.array(point, dtype=np.float64)
        return cls.track(lambda _t: p.copy(), controller)

    @classmethod
    def track(cls, reference: Reference, controller: Controller | None = None) -> WrenchLaw:
        """Eq. (24) (or ``controller``) toward ``reference(t)`` (mission time, s)."""
        return cls(reference=reference, controller=controller or PoseController())

    def __call__(
        self, t_s: float, x: FloatArray | None
    ) -> tuple[FloatArray | None, FloatArray] | None:
        """(reference or None, wrench) at mission time ``t_s``; None: no state yet."""
        if self.tau is not None:
            return None, np.array(self.tau, dtype=np.float64)
        if x is None or self.reference is None:
            return None
        ref = self.reference(t_s)
        return ref, self.controller(x, ref)


@dataclass(frozen=True)
class FlightPlan:
    """What a :class:`Flight` does (module docstring); times in s, mission time."""

    law: WrenchLaw
    period_s: float
    duration_s: float | None = None  # None: until request_exit
    injections: tuple[Injection, ...] = ()
    wrench_limit: tuple[float, float, float] | None = None
    odometry_timeout_s: float | None = None  # None: fly without ODOMETRY if need be
    drain_texts: bool = True
    keep_statuses: bool = False
    inject_timeout_s: float = 1.0  # per attempt, waiting for the COMMAND_ACK
    inject_attempts: int = 3
    time_scale: float = 1.0  # mission (vessel) seconds per wall second


# --- fault injection off the loop thread ---


@dataclass(frozen=True)
class InjectionOutcome:
    """One injection as sent: mission time and wall clock of the send, the ACK's result
    (the reply's name, ``"ACCEPTED"`` when carried out, or ``"NO_ACK"``)."""

    injection: Injection
    sent_at_s: float
    sent_wall_s: float
    result: str

    @property
    def ok(self) -> bool:
        return self.result == "ACCEPTED"

    def as_dict(self) -> dict[str, Any]:
        """results.json form: thruster 1-based, value None for NaN."""
        i = self.injection
        value = None if math.isnan(i.value) else i.value
        keys = ("at_s", "sent_at_s", "thruster", "kind", "value", "result")
        row = (i.at_s, self.sent_at_s, i.thruster + 1, i.kind.name, value, self.result)
        return dict(zip(keys, row, strict=True))


class Injector:
    """Sends injections in order on its own thread; :meth:`outcomes` drains the results."""

    def __init__(self, link: GroundLink, t0_ns: int, timeout_s: float, attempts: int) -> None:
        self._link, self._t0_ns = link, t0_ns
        self._timeout_s, self._attempts = timeout_s, attempts
        self._todo: queue.Queue[Injection | None] = queue.Queue()
        self._done: queue.Queue[InjectionOutcome] = queue.Queue()
        self._thread = threading.Thread(target=self._run, name="gcs-injector", daemon=True)
        self._thread.start()

    def submit(self, items: Sequence[Injection]) -> None:
        for item in items:
            self._todo.put(item)

    def _run(self) -> None:
        while (item := self._todo.get()) is not None:
            sent, wall = (time.monotonic_ns() - self._t0_ns) * 1e-9, time.time()
            result = self._link.inject_failure(
                item.kind, item.thruster, item.value,
                timeout_s=self._timeout_s, attempts=self._attempts,
            )  # fmt: skip
            name = "NO_ACK" if result is None else result.name
            self._done.put(InjectionOutcome(item, sent, wall, name))

    def outcomes(self) -> list[InjectionOutcome]:
        out = []
        while not self._done.empty():
            out.append(self._done.get_nowait())
        return out

    def close(self) -> None:
        """Let the queued injections finish (every attempt of each), then end the thread."""
        self._todo.put(None)
        self._thread.join(self._timeout_s * self._attempts * (self._todo.qsize() + 2) + 5.0)


# --- live status on a terminal ---


class StatusLine:
    """One line on stderr rewritten every cycle (a terminal only); cleared before logging."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled
        self._shown = False

    def show(self, text: str) -> None:
        if self.enabled:
            sys.stderr.write("\r" + text + "\x1b[K")
            sys.stderr.flush()
            self._shown = True

    def clear(self) -> None:
        if self._shown:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()
            self._shown = False


def status_text(
    t: float, x: FloatArray, ref: FloatArray, st: Any, u: Any, duration_s: float | None = None
) -> str:
    """The status line: mission time, pose, distance to the reference, delta_hat, u."""
    err = math.hypot(x[0] - ref[0], x[1] - ref[1])
    of = "" if duration_s is None else f"/{duration_s:.0f}"
    dh = " ".join(f"{d:.2f}" for d in st.delta_hat) if st is not None else "-"
    thrust = " ".join(f"{v:+.3f}" for v in u) if u is not None else "-"
    return (
        f"t {t:6.1f}{of} s  N {x[0]:+6.2f} E {x[1]:+6.2f} m  psi {math.degrees(x[2]):+7.1f} deg"
        f"  |e| {err:5.2f} m  dhat {dh}  u {thrust} N"
    )


class ProgressLine:
    """A progress line every ``every_s`` of mission time, written whole (``write``: stdout,
    flushed, by default) so that a log file or a pipe shows it: time flown, the fault phase,
    the injections carried out so far, the distance to the reference and the allocator's
    current verdict (mode, flagged thrusters, delta_hat). ``phases``: the mission's fault
    phases [start, end) s; ``mode``: the allocator's mode as read at connection, for a status
    that does not carry it (FTCAP_STATUS)."""

    PREFIX = "progress:"

    def __init__(
        self,
        every_s: float,
        phases: Sequence[tuple[float, float]],
        duration_s: float | None,
        write: Callable[[str], None] | None = None,
        mode: str | None = None,
    ) -> None:
        if not every_s > 0:
            raise ValueError(f"progress every_s: must be > 0, got {every_s}")
        self.every_s, self.phases, self.duration_s = every_s, list(phases), duration_s
        self._write = write or (lambda text: print(text, flush=True))
        self._next_s, self.mode = 0.0, mode

    def due(self, t: float) -> bool:
        """Whether a line is due at mission time ``t`` (then the next one is ``every_s`` on)."""
        if t < self._next_s:
            return False
        self._next_s = (math.floor(t / self.every_s) + 1) * self.every_s
        return True

    def show(
        self, t: float, x: FloatArray | None, ref: FloatArray | None, st: Any,
        outcomes: Sequence[InjectionOutcome],
    ) -> None:  # fmt: skip
        """Write the line for mission time ``t`` (:meth:`due` decides when)."""
        self._write(self.text(t, x, ref, st, outcomes))

    def text(
        self, t: float, x: FloatArray | None, ref: FloatArray | None, st: Any,
        outcomes: Sequence[InjectionOutcome],
    ) -> str:  # fmt: skip
        """The line (class docstring); ``st``: the latest AllocatorStatus or None."""
        of = "" if self.duration_s is None else f"/{self.duration_s:.0f}"
        parts = [f"{self.PREFIX} t {t:.0f}{of} s"]
        j = next((k for k, (a, b) in enumerate(self.phases) if a <= t < b), None)
        if j is not None:
            a, b = self.phases[j]
            parts.append(f"phase {j + 1}/{len(self.phases)} [{a:g}, {b:g}) s")
        done = [
            f"{o.injection.kind.name} thruster {o.injection.thruster + 1} at "
            f"{o.sent_at_s:.1f} s ({o.result})"
            for o in outcomes
        ]
        parts.append("injected: " + (", ".join(done) if done else "nothing yet"))
        if x is not None and ref is not None:
            parts.append(f"|e| {math.hypot(x[0] - ref[0], x[1] - ref[1]):.3f} m")
        parts.append(_verdict_text(st, self.mode))
        return "; ".join(parts)


def _verdict_text(st: Any, mode: str | None) -> str:
    """The allocator's verdict in a few words (no status yet: says so); ``mode``: the one
    to name when the status does not carry it."""
    if st is None:
        return "allocator: no status yet"
    mode = st.mode.value if st.mode is not None else mode or "?"
    flagged = [str(i + 1) for i, f in enumerate(st.faulty) if f]
    dh = " ".join(f"{d:.2f}" for d in st.delta_hat)
    return f"allocator {mode}: flagged {', '.join(flagged) or 'none'}, delta_hat {dh}"
