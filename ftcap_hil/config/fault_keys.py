"""A scenario's ``[[fault]]`` entries -> :class:`~ftcap_hil.core.faults.FaultSchedule`.

Each entry: ``from``, optional ``until`` (s, or steps for the linear plant; absent:
forever), and ``delta`` / ``bias`` for all m thrusters (vectors) or for ``thruster``
(1-based) alone (scalars); its time profile is ``kind``: ``step`` (default), ``ramp``,
``intermittent``, ``stuck``, ``bias`` (:class:`~ftcap_hil.core.faults.EventKind`).
``ramp_s`` (s, > 0) belongs to a ramp, ``on_s`` and ``off_s`` (s, > 0) to an intermittent
fault, which also needs ``until`` (see ``docs/scenarios.md``). ``cause`` (optional) names
what happened physically (:class:`~ftcap_hil.core.faults.Cause`: ``lost-blade``,
``jammed``, ...): it decides what the thruster's drive and telemetry show.
"""

from __future__ import annotations

import math

from ftcap_hil.config.table_dataclass import defaults_of
from ftcap_hil.config.tables import Table
from ftcap_hil.core.faults import Cause, EventKind, FaultEvent, FaultSchedule
from ftcap_hil.core.messages import FloatArray

PROFILE_KEYS = {EventKind.RAMP: ("ramp_s",), EventKind.INTERMITTENT: ("on_s", "off_s")}
ALL_PROFILE_KEYS = tuple(key for keys in PROFILE_KEYS.values() for key in keys)


def _owner(key: str) -> str:
    return next(k.value for k, keys in PROFILE_KEYS.items() if key in keys)


def fault_event(
    t: Table,
    start: float,
    end: float,
    thruster: int | None,
    delta: FloatArray | float | None,
    bias: FloatArray | float | None,
) -> FaultEvent:
    """The :class:`FaultEvent` of the entry ``t``, its time profile read from ``kind`` and
    the profile keys (a key of another kind's profile is refused)."""
    kind = t.enum("kind", EventKind, EventKind.STEP)
    own = PROFILE_KEYS.get(kind, ())
    for other in ALL_PROFILE_KEYS:
        if other not in own and t.has(other):
            raise t.error(other, f"only for kind = {_owner(other)!r}")
    t.allow(*ALL_PROFILE_KEYS)
    base = defaults_of(FaultEvent)
    ramp_s, on_s, off_s = (
        t.number(k) if k in own else base[k] for k in ("ramp_s", "on_s", "off_s")
    )
    cause = t.enum("cause", Cause) if t.has("cause") else base["cause"]
    try:
        return FaultEvent(start, end, thruster, delta, bias, kind, ramp_s, on_s, off_s, cause)
    except ValueError as e:
        raise t.error(None, str(e)) from None


def fault_event_from(t: Table, m: int) -> FaultEvent:
    """One ``[[fault]]`` entry of a schedule for m thrusters (module docstring)."""
    start = t.number("from")
    end = t.number("until", math.inf)
    if end <= start:
        raise t.error("until", f"expected a time after from = {start:g}, got {end:g}")
    thruster = t.integer("thruster", None, lo=1, hi=m)
    t.allow("delta", "bias")
    if thruster is None:
        delta = t.vector("delta", m, lo=0.0, hi=1.0) if t.has("delta") else None
        bias = t.vector("bias", m) if t.has("bias") else None
        return fault_event(t, start, end, None, delta, bias)
    d, b = t.number("delta", None, lo=0.0, hi=1.0), t.number("bias", None)
    return fault_event(t, start, end, thruster - 1, d, b)


def fault_schedule_from(tables: list[Table], m: int) -> FaultSchedule:
    """The ``[[fault]]`` entries of a file, in order (later ones win where they act)."""
    return FaultSchedule(m, tuple(fault_event_from(t, m) for t in tables))
