"""Which telemetry the estimator may believe: sources bound to the vessel, and an alarm (not
a vote) when two sources disagree.

The allocator hears odometry on several ports (MAVLink, Zenoh, its ROS 2 mapping). A port is
**trusted** when its transport authenticates the sender as the vessel: MAVLink ODOMETRY is
accepted only from the vessel's inbox address (and signed, with a key file); Zenoh only with
access control (TLS identities). Untrusted ports (plain Zenoh: any local process may publish
on the key) are used only while no trusted port is fresh.

Two kinds of evidence that a second sender is on the air:

* **two senders on one port**: vessel time going back on a port is a restart once; three
  reversals within ``window_s`` are two interleaved streams (:class:`OdometryMailbox`
  counts them as samples arrive, every one, not only those a cycle happens to read);
* **two ports that disagree**: the latest samples of two fresh ports further apart than
  the vessel can move in the time between them
  (:func:`~ftcap_hil.runtime.estimation.track_jump`).

Either is an alarm for ``hold_s`` after its last evidence. Estimation is frozen (no sample
reaches it) while the alarm concerns a port the estimator would use; a disagreement of an
untrusted port with a trusted one only raises the alarm, since the trusted one is used.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

from ftcap_hil.config.daemon import OdometryLimits
from ftcap_hil.core.messages import Odometry
from ftcap_hil.core.status import Severity
from ftcap_hil.ports.mailbox import Mailbox, Stamped
from ftcap_hil.ports.transitions import TransitionLog
from ftcap_hil.runtime.estimation import (
    EstimationSample,
    EstimationSampler,
    newest_odometry,
    track_jump,
)

REVERSALS_FOR_CONFLICT = 3  # one is a restart; three within the window are two streams
# Two ports carry the same samples a few ms apart; a port may lag a sample period or two.
CLOCK_SLACK_S = 0.5


class OdometryMailbox(Mailbox[Odometry]):
    """A telemetry mailbox that also notes when vessel time goes back (or a stamped stream
    stops carrying vessel time): the sign of a second sender on the port; and keeps its last
    ``keep`` samples, so that the estimation sampler sees every one (:meth:`received_after`),
    not only the newest a cycle happens to read."""

    def __init__(self, name: str, keep: int = 64) -> None:
        super().__init__(name)
        self._last_time_s = math.nan
        self._reversals: deque[int] = deque(maxlen=keep)
        self._recent: deque[Stamped[Odometry]] = deque(maxlen=keep)
        self._rev_lock = threading.Lock()

    def put(self, value: Odometry, stamp_ns: int | None = None) -> None:
        """As :meth:`Mailbox.put`; a sample older (by vessel time) than the one before it,
        or without vessel time after one with it, is noted as a reversal."""
        t = value.time_s
        last, self._last_time_s = self._last_time_s, t
        super().put(value, stamp_ns)
        slot = self.latest()
        with self._rev_lock:
            if slot is not None:
                self._recent.append(slot)
            if math.isfinite(last) and not (math.isfinite(t) and t >= last):
                self._reversals.append(slot.stamp_ns if slot is not None else 0)

    def received_after(self, after_ns: int, upto_ns: int) -> list[Stamped[Odometry]]:
        """The samples kept that were received in (``after_ns``, ``upto_ns``], oldest first."""
        out: list[Stamped[Odometry]] = []
        with self._rev_lock:
            for s in reversed(self._recent):  # newest first: stop at the first one taken
                if s.stamp_ns <= after_ns:
                    break
                if s.stamp_ns <= upto_ns:
                    out.append(s)
        out.reverse()
        return out

    def reversals_since(self, since_ns: int) -> int:
        """Reversals noted at or after ``since_ns`` (monotonic ns)."""
        with self._rev_lock:
            return sum(1 for s in self._reversals if s >= since_ns)


@dataclass(frozen=True)
class TelemetryPort:
    """One telemetry mailbox and whether its transport authenticates the vessel."""

    mailbox: Mailbox[Odometry]
    trusted: bool


@dataclass(frozen=True)
class TelemetryChoice:
    """This cycle's sample for the estimator (None: none, or frozen) and the alarm text
    (None: no alarm); ``frozen``: the alarm concerns the source in use."""

    sample: Stamped[Odometry] | None
    alarm: str | None
    frozen: bool
    untrusted_only: bool


class TelemetryGuard:
    """The module docstring's policy over ``ports``; called from the loop thread."""

    def __init__(
        self,
        ports: Sequence[TelemetryPort],
        limits: OdometryLimits | None = None,
        window_s: float = 5.0,
        hold_s: float = 2.0,
    ) -> None:
        self.ports = list(ports)
        self.limits = limits or OdometryLimits()
        self.window_ns = int(window_s * 1e9)
        self.hold_ns = int(hold_s * 1e9)
        self.alarms = 0  # alarm episodes so far
        self._until_ns = -1
        self._frozen_until_ns = -1
        self._text: str | None = None

    def choose(self, now_ns: int, fresh_ns: int) -> TelemetryChoice:
        """The sample to use at ``now_ns`` among ports heard within ``fresh_ns``."""
        slots = [(p, p.mailbox.latest()) for p in self.ports]
        fresh = [(p, s) for p, s in slots if s is not None and now_ns - s.stamp_ns <= fresh_ns]
        trusted = [(p, s) for p, s in fresh if p.trusted]
        used = trusted or fresh
        chosen = newest_odometry([s for _, s in used], fresh_ns)
        text, frozen = self._evidence(now_ns, fresh, used, chosen)
        if text is not None:
            if now_ns > self._until_ns:
                self.alarms += 1
            self._until_ns, self._text = now_ns + self.hold_ns, text
            if frozen:
                self._frozen_until_ns = now_ns + self.hold_ns
        alarm = self._text if now_ns <= self._until_ns else None
        freeze = now_ns <= self._frozen_until_ns
        untrusted_only = bool(fresh) and not trusted and any(p.trusted for p in self.ports)
        return TelemetryChoice(None if freeze else chosen, alarm, freeze, untrusted_only)

    def _evidence(
        self,
        now_ns: int,
        fresh: list[tuple[TelemetryPort, Stamped[Odometry]]],
        used: list[tuple[TelemetryPort, Stamped[Odometry]]],
        chosen: Stamped[Odometry] | None,
    ) -> tuple[str | None, bool]:
        """(alarm text, whether it concerns a port in use) from this cycle's evidence."""
        since = now_ns - self.window_ns
        used_ids = {id(p) for p, _ in used}
        for p, _ in fresh:
            box = p.mailbox
            if isinstance(box, OdometryMailbox):
                n = box.reversals_since(since)
                if n >= REVERSALS_FOR_CONFLICT:
                    return f"two odometry senders on {box.name} ({n} time reversals)", (
                        id(p) in used_ids
                    )
        if chosen is None:
            return None, False
        for p, s in fresh:
            if s is chosen:
                continue
            why = self._disagreement(chosen, s)
            if why is not None:
                text = f"telemetry sources disagree ({p.mailbox.name}: {why})"
                return text, id(p) in used_ids
        return None, False

    def _disagreement(self, a: Stamped[Odometry], b: Stamped[Odometry]) -> str | None:
        """Why two ports' latest samples cannot both be the vessel's: vessel clocks that
        differ by more than their receipts do (plus ``CLOCK_SLACK_S``), or a distance the
        vessel cannot cover between the receipts (plus the slack; the vessel's clock is
        not used, so a forger cannot buy distance by claiming a later time)."""
        gap_s = abs(a.stamp_ns - b.stamp_ns) * 1e-9
        skew = abs(a.value.time_s - b.value.time_s)
        if math.isfinite(skew) and skew > gap_s + CLOCK_SLACK_S:
            return f"vessel times {skew:.3g} s apart, received {gap_s:.3g} s apart"
        slack_ns = int(CLOCK_SLACK_S * 1e9)
        untimed = Odometry(b.value.eta, b.value.nu)
        return track_jump(self.limits, (a.value, a.stamp_ns), untimed, b.stamp_ns + slack_ns)


class TelemetryIntake:
    """The daemon's telemetry side, once per cycle: :class:`TelemetryGuard` -> the
    sampler's plausibility gate -> an estimation sample, with their announcements on
    ``transitions`` (a :class:`~ftcap_hil.ports.transitions.TransitionLog`)."""

    def __init__(
        self,
        guard: TelemetryGuard,
        sampler: EstimationSampler,
        transitions: TransitionLog,
        fresh_s: float,
    ) -> None:
        self.guard, self.sampler, self.transitions = guard, sampler, transitions
        self.fresh_ns = int(fresh_s * 1e9)
        self._fed_ns = -1  # samples received up to here were offered to the sampler (or not)

    def newest_stamp(self) -> int:
        """The latest receipt stamp over every telemetry port (-1: nothing yet)."""
        slots = [p.mailbox.latest() for p in self.guard.ports]
        return max((s.stamp_ns for s in slots if s is not None), default=-1)

    def _since(self, fed_ns: int, chosen: Stamped[Odometry]) -> list[Stamped[Odometry]]:
        """Every sample of the chosen sample's port received since the last cycle, up to and
        including it (a port that keeps none: the chosen sample alone)."""
        for p in self.guard.ports:
            box = p.mailbox
            if isinstance(box, OdometryMailbox):
                got = box.received_after(fed_ns, chosen.stamp_ns)
                if any(s is chosen for s in got):
                    return got
        return [chosen]

    def sample(self, now_ns: int, stale: bool) -> EstimationSample | None:
        """This cycle's estimation sample (None: none due, stale, frozen or dropped)."""
        choice = self.guard.choose(now_ns, self.fresh_ns)
        log = self.transitions
        log.update(
            "telemetry_conflict",
            choice.alarm is not None,
            f"telemetry alarm: {choice.alarm}"
            + ("; estimation frozen" if choice.frozen else "; the trusted source is used"),
            "telemetry alarm over: one consistent source",
            Severity.WARNING,
        )
        log.update(
            "telemetry_untrusted",
            choice.untrusted_only,
            "telemetry only from an unauthenticated source",
            "telemetry from the vessel's authenticated source again",
            Severity.WARNING,
        )
        fed, self._fed_ns = self._fed_ns, now_ns  # what came while frozen is never used
        if stale or choice.sample is None:
            return None
        for s in self._since(fed, choice.sample):
            self.sampler.observe(s.value, s.stamp_ns)
        got = self.sampler.take()
        gate = self.sampler.gate
        log.update(
            "telemetry_implausible",
            gate.reason is not None,
            f"telemetry implausible ({gate.reason}): dropped, estimation paused",
            "telemetry plausible again: estimation resumes",
        )
        return got
