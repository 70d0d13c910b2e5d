"""True thruster faults over time: what the vessel's thrusters actually do.

A fault acts per thruster as ``F_i = delta_i u_i + f_i`` (eq. 23 of the paper): ``delta`` (m,)
in [0, 1] is the effectiveness, ``f`` (m,) the bias force in N; a thruster flagged ``stuck``
holds the force it produced at the onset whatever its command (the thruster bank of
``sim/thrusters.py`` does the holding: the schedule cannot know that force). A
:class:`FaultSchedule` says what holds when (``Truth`` at a time); its events have a time
profile (:class:`EventKind`): a step, a linear ramp, an intermittent on/off pattern, a stuck
output, a bias step. :func:`injection_plan` turns a schedule into the live fault injections
(MAV_CMD_INJECT_FAILURE, Zenoh ``fault/inject``) that reproduce it on a healthy vessel: exact
for steps, biases and stuck outputs; a ramp becomes steps to its values at the schedule's
change times (at least its end), and an intermittent
fault's edges arrive with the injection path's latency. Ramps and intermittent faults are
meant for the offline simulator and the sim process's own scenario schedule. Campaigns
draw their random faults as scenario ``[[fault]]`` tables
(:mod:`ftcap_hil.runtime.campaign_faults`). Pure: no I/O, no clock.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from ftcap_hil.core.messages import BoolArray, FaultKind, FloatArray


def _no_flags() -> BoolArray:
    return np.zeros(0, dtype=bool)


class Cause(enum.Enum):
    """What physically happened to a thruster: it decides what its shaft (or servo) and its
    telemetry show at a given ``delta`` (``sim/thrusters.py`` gives each its signature).
    ``delta`` keeps its meaning for every cause: the share of the healthy force at the
    same command that reaches the hull, in steady state."""

    HEALTHY = "healthy"
    WEAK_MOTOR = "weak-motor"  # the drive cannot give the torque: slower shaft
    LOST_BLADE = "lost-blade"  # thrust and torque down together at full speed
    FOULED = "fouled"  # rope or fouling: less thrust for more torque
    DRIVE_DEAD = "drive-dead"  # not driven: the shaft stops, the ESC reports 0 rpm, idle
    POWER_LOST = "power-lost"  # not driven and the ESC silent
    # the drive ignores its commands and holds a force (the fault's bias), reporting nothing:
    # a command link lost with hold-last, a drive switched to local control
    HELD = "held"
    JAMMED = "jammed"  # the shaft is blocked: 0 rpm, the drive at its current limit
    STUCK = "stuck"  # the output frozen at its onset value (see ``Truth.stuck``)
    TELEMETRY_LOST = "telemetry-lost"  # works as commanded, reports nothing
    VENTILATION = "ventilation"  # bursts of lost load in waves: transient, delta 1 between
    HULL_LOSS = "hull-loss"  # thruster-hull interaction: the shaft is clean, the hull is not


# The causes the shaft cannot see (its telemetry is that of a healthy thruster).
SHAFT_INVISIBLE = frozenset({Cause.HULL_LOSS})


def default_cause(delta: float, stuck: bool, bias: float = 0.0) -> Cause:
    """The cause of a fault that names none: STUCK if stuck, else at delta 0 HELD with a
    bias (a force that ignores the command: the paper's "stuck at a value") and POWER_LOST
    without, WEAK_MOTOR below 1, HEALTHY at 1 (a bias alone leaves the shaft healthy)."""
    if stuck:
        return Cause.STUCK
    if delta <= 0.0:
        return Cause.HELD if bias != 0.0 else Cause.POWER_LOST
    return Cause.WEAK_MOTOR if delta < 1.0 else Cause.HEALTHY


@dataclass(frozen=True)
class Truth:
    """The faults actually acting (for the oracle, for metrics and for the thruster bank).

    ``delta`` (m,) effectiveness in [0, 1], ``f`` (m,) bias force per thruster in N,
    ``stuck`` (m,) bool: the thruster holds its onset output (all False when not given),
    ``cause`` (m,) what happened physically (empty: :func:`default_cause` of each)."""

    delta: FloatArray
    f: FloatArray
    stuck: BoolArray = field(default_factory=_no_flags)
    cause: tuple[Cause, ...] = ()

    def __post_init__(self) -> None:
        if self.stuck.shape == (0,) and self.delta.shape != (0,):
            object.__setattr__(self, "stuck", np.zeros(self.delta.shape, dtype=bool))
        if self.cause and len(self.cause) != self.delta.shape[0]:
            raise ValueError(f"truth: {len(self.cause)} causes for {self.delta.shape[0]} thrusters")

    def causes(self) -> tuple[Cause, ...]:
        """(m,) each thruster's cause, the defaults filled in."""
        stuck = self.stuck.tolist()
        if self.cause:
            return tuple(Cause.STUCK if s else c for c, s in zip(self.cause, stuck, strict=True))
        return tuple(
            default_cause(d, s, f)
            for d, s, f in zip(self.delta.tolist(), stuck, self.f.tolist(), strict=True)
        )

    def effective(self, held: FloatArray) -> Truth:
        """(delta, f) seen from the command: a stuck thruster is ``delta = 0``, ``f = held``
        (the (m,) forces in N it holds, from the thruster bank); ``stuck`` is kept."""
        return Truth(
            np.where(self.stuck, 0.0, self.delta),
            np.where(self.stuck, held, self.f),
            self.stuck,
            self.cause,
        )


class EventKind(enum.Enum):
    """Time profile of a :class:`FaultEvent` (what it does between ``start`` and ``end``)."""

    STEP = "step"  # delta and/or bias take their values at start
    RAMP = "ramp"  # they move linearly from the earlier value to theirs over ramp_s
    INTERMITTENT = "intermittent"  # a step for on_s, nothing for off_s, repeating
    STUCK = "stuck"  # the thruster's output is frozen at its value at start
    BIAS = "bias"  # a step of the bias alone (delta untouched)


@dataclass(frozen=True)
class FaultEvent:
    """From ``start`` (inclusive) until ``end`` (exclusive; inf = forever, s): either one
    thruster (``thruster`` 0-based, scalar delta/bias) or all (``None``, (m,) vectors).
    Later events override earlier ones where they act.

    ``kind`` is the time profile (:class:`EventKind`): a RAMP reaches its delta/bias
    ``ramp_s`` after ``start``, starting from the value the earlier events give (healthy
    if none); an INTERMITTENT event acts for ``on_s``, then not for ``off_s``, and so on
    until ``end``, which must be finite; STUCK takes no delta or bias; BIAS takes a bias
    and no delta."""

    start: float
    end: float
    thruster: int | None
    delta: FloatArray | float | None
    bias: FloatArray | float | None
    kind: EventKind = EventKind.STEP
    ramp_s: float = 0.0
    on_s: float = 0.0
    off_s: float = 0.0
    cause: Cause | None = None  # what happened physically (None: ``default_cause``)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.start) and self.end > self.start):
            raise ValueError(f"fault event: need finite start < end, got {self.start}, {self.end}")
        need = {
            EventKind.RAMP: ("ramp_s",),
            EventKind.INTERMITTENT: ("on_s", "off_s"),
        }.get(self.kind, ())
        for name in need:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{self.kind.value} fault: {name} must be > 0, got {value}")
        if self.kind is EventKind.INTERMITTENT and not math.isfinite(self.end):
            raise ValueError("intermittent fault: needs a finite end")
        if self.kind is EventKind.STUCK and (self.delta is not None or self.bias is not None):
            raise ValueError("stuck fault: takes no delta or bias (the output is frozen)")
        if self.kind is EventKind.BIAS and (self.bias is None or self.delta is not None):
            raise ValueError("bias fault: needs a bias and no delta")

    def weight(self, t: float) -> float:
        """How far the event has taken its values at ``t``: 0 (not acting) .. 1 (fully)."""
        if not self.start <= t < self.end:
            return 0.0
        if self.kind is EventKind.RAMP:
            return min((t - self.start) / self.ramp_s, 1.0)
        if self.kind is EventKind.INTERMITTENT:
            period = self.on_s + self.off_s
            k = math.floor((t - self.start) / period + 1e-9)
            if t < self.start + k * period:  # the nudge above overshot: same edges as below
                k -= 1
            return 1.0 if t < self.start + k * period + self.on_s else 0.0
        return 1.0

    def edges(self) -> list[float]:
        """The times at which this event changes what acts (a ramp: its start and its end)."""
        out = [self.start]
        if self.kind is EventKind.RAMP:
            out.append(min(self.start + self.ramp_s, self.end))
        elif self.kind is EventKind.INTERMITTENT:
            period = self.on_s + self.off_s
            k = 0
            while (on := self.start + k * period) < self.end:
                out += [on, on + self.on_s]
                k += 1
        out.append(self.end)
        return [t for t in out if t <= self.end and math.isfinite(t)]


def _blend(old: FloatArray, target: FloatArray | float, w: float) -> FloatArray:
    """``old`` moved a fraction ``w`` towards ``target``; exactly ``target`` at w = 1."""
    return np.asarray(target if w >= 1.0 else old + w * (np.asarray(target) - old))


@dataclass(frozen=True)
class FaultSchedule:
    """The true faults of ``m`` thrusters over time: ``events`` in order, later ones win."""

    m: int
    events: tuple[FaultEvent, ...] = ()

    def at(self, t: float) -> Truth:
        """The (delta, f, stuck) acting at time ``t`` (s, or steps for a discrete plant),
        each (m,)."""
        delta, f = np.ones(self.m), np.zeros(self.m)
        stuck = np.zeros(self.m, dtype=bool)
        named: list[Cause | None] = [None] * self.m
        for ev in self.events:
            w = ev.weight(t)
            if w <= 0.0:
                continue
            sel = slice(None) if ev.thruster is None else ev.thruster
            if ev.kind is EventKind.STUCK:
                stuck[sel] = True
            if ev.delta is not None:
                delta[sel] = _blend(delta[sel], ev.delta, w)
            if ev.bias is not None:
                f[sel] = _blend(f[sel], ev.bias, w)
            if ev.cause is not None:
                for i in range(self.m) if ev.thruster is None else (ev.thruster,):
                    named[i] = ev.cause
        if all(c is None for c in named):
            return Truth(delta, f, stuck)
        cause = tuple(
            default_cause(d, s, b) if c is None else c
            for c, d, s, b in zip(named, delta.tolist(), stuck.tolist(), f.tolist(), strict=True)
        )
        return Truth(delta, f, stuck, cause)

    def change_times(self) -> list[float]:
        """Sorted times at which the truth changes or, for a ramp, starts or stops changing
        (finite ones only); between two of them a ramp moves linearly, all else is constant."""
        return sorted({t for ev in self.events for t in ev.edges()})


@dataclass(frozen=True)
class Injection:
    """One MAV_CMD_INJECT_FAILURE: at mission time ``at_s``, ``kind`` on ``thruster``
    (0-based) with ``value`` (delta for WEAK, N for BIAS / STUCK, NaN otherwise; a STUCK
    with NaN holds the force the thruster produces at that moment)."""

    at_s: float
    thruster: int
    kind: FaultKind
    value: float = math.nan


def _injections_for(
    i: int, at_s: float, before: tuple[float, float], after: tuple[float, float]
) -> list[Injection]:
    """Injections taking thruster i from (delta, f) ``before`` to ``after``. The vessel's
    WEAK clears the bias and BIAS keeps delta, so a weak and biased thruster is WEAK then
    BIAS; delta = 0 with a bias is STUCK at that force."""
    (d0, f0), (d1, f1) = before, after
    if (d1, f1) == (1.0, 0.0):
        return [Injection(at_s, i, FaultKind.OK)]
    if d1 == 0.0:
        return [Injection(at_s, i, FaultKind.OFF if f1 == 0.0 else FaultKind.STUCK,
                          math.nan if f1 == 0.0 else f1)]  # fmt: skip
    out: list[Injection] = []
    if d1 != d0:
        out.append(Injection(at_s, i, FaultKind.WEAK, d1))
    if f1 != 0.0 or (d1 == d0 and f0 != 0.0):
        out.append(Injection(at_s, i, FaultKind.BIAS, f1))
    return out


def _thruster_plan(i: int, t: float, prev: Truth, now: Truth) -> list[Injection]:
    """Injections for thruster i at ``t`` going from ``prev`` to ``now``. A stuck onset is
    a STUCK at the produced force (NaN); its end is OK, then whatever else acts."""
    if now.stuck[i]:
        return [] if prev.stuck[i] else [Injection(t, i, FaultKind.STUCK)]
    after = (float(now.delta[i]), float(now.f[i]))
    if prev.stuck[i]:
        rest = _injections_for(i, t, (1.0, 0.0), after) if after != (1.0, 0.0) else []
        return [Injection(t, i, FaultKind.OK), *rest]
    before = (float(prev.delta[i]), float(prev.f[i]))
    return _injections_for(i, t, before, after) if before != after else []


def injection_plan(schedule: FaultSchedule, duration_s: float) -> list[Injection]:
    """The injections that reproduce ``schedule`` on a healthy vessel, in time order;
    changes at or after ``duration_s`` are left out. The schedule is sampled at its change
    times only, so a ramp arrives as steps: to its value at any other change inside it, and
    to its target at its end."""
    m = schedule.m
    prev = Truth(np.ones(m), np.zeros(m))
    plan: list[Injection] = []
    for t in schedule.change_times():
        if t >= duration_s:
            break
        now = schedule.at(t)
        for i in range(m):
            plan += _thruster_plan(i, t, prev, now)
        prev = now
    return plan
