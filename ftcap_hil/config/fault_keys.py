"""The time-profile keys of a scenario's ``[[fault]]`` entry: ``kind``, ``ramp_s``, ``on_s``,
``off_s`` (see ``docs/scenarios.md``); the rest of the entry is read by ``scenario.py``.

``kind`` is one of ``step`` (default), ``ramp``, ``intermittent``, ``stuck``, ``bias``
(:class:`~ftcap_hil.core.faults.EventKind`); ``ramp_s`` (s, > 0) belongs to a ramp,
``on_s`` and ``off_s`` (s, > 0) to an intermittent fault, which also needs ``until``.
"""

from __future__ import annotations

from typing import Any

from ftcap_hil.config.tables import number
from ftcap_hil.core.errors import ConfigError
from ftcap_hil.core.faults import EventKind, FaultEvent
from ftcap_hil.core.messages import FloatArray

PROFILE_KEYS = {EventKind.RAMP: ("ramp_s",), EventKind.INTERMITTENT: ("on_s", "off_s")}


def _kind(entry: dict[str, Any], where: str) -> EventKind:
    name = entry.get("kind", EventKind.STEP.value)
    try:
        return EventKind(name)
    except ValueError:
        known = [k.value for k in EventKind]
        raise ConfigError(f"{where}.kind: {name!r} not one of {known}") from None


def fault_event(
    entry: dict[str, Any],
    where: str,
    start: float,
    end: float,
    thruster: int | None,
    delta: FloatArray | float | None,
    bias: FloatArray | float | None,
) -> FaultEvent:
    """The :class:`FaultEvent` of one ``[[fault]]`` ``entry`` (``where`` names it in
    errors), its time profile read from the entry's profile keys."""
    kind = _kind(entry, where)
    own = PROFILE_KEYS.get(kind, ())
    for other in {key for keys in PROFILE_KEYS.values() for key in keys} - set(own):
        if other in entry:
            raise ConfigError(f"{where}.{other}: only for kind = {_owner(other)!r}")
    times = {key: number(entry, key, where) for key in own}
    try:
        return FaultEvent(start, end, thruster, delta, bias, kind, **times)
    except ValueError as e:
        raise ConfigError(f"{where}: {e}") from None


def _owner(key: str) -> str:
    return next(k.value for k, keys in PROFILE_KEYS.items() if key in keys)
