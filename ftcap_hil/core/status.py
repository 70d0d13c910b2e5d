"""The allocator's status: one type, built by the daemon, encoded and decoded by each bridge.

:class:`AllocatorStatus` is what ``ftcap-hil allocator`` publishes (decimated, on MAVLink
``FTCAP_STATUS`` / ``ACTUATOR_OUTPUT_STATUS`` / ``FTCAP_ESC_STATUS`` and Zenoh
``allocator/status``) and answers to queries. A transport that does not carry a field
decodes it as its default (``mode`` None, ages +inf, empty per-thruster tuples), so every
consumer reads the same names whatever the wire was. SI units, body frame; per-thruster
tuples have one entry per thruster in vessel-file order.

Build a status with :meth:`AllocatorStatus.checked` (the daemon from its cycle, every
decoder from its wire): it is validated there, once, and every encoder and reader trusts it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.estimation.shaft_types import Hypothesis
from ftcap_hil.core.messages import ThrusterCommand


class Mode(enum.Enum):
    """How the allocator core treats faults (its estimator, or none); values as in config."""

    NONE = "none"  # reference run: no faults injected, allocator as CAP
    CAP = "cap"  # allocation without estimation (Delta_hat = I, f_hat = 0)
    FTCAP = "ftcap"  # windowed joint estimation (default)
    FTCAP_LITERAL = "ftcap-literal"  # the paper's eqs. (9)-(11) read literally
    ORACLE = "oracle"  # the true Delta and f handed to the allocator

    @property
    def estimates(self) -> bool:
        """The mode runs a fault estimator."""
        return self in (Mode.FTCAP, Mode.FTCAP_LITERAL)


class Severity(enum.Enum):
    """How an announcement (a transition: fault detected, watchdog fired) is to be shown."""

    INFO = "info"
    WARNING = "warning"
    ERROR = "error"


@dataclass(frozen=True)
class AllocatorStatus:
    """One decimated status of the allocator (module docstring).

    Wrenches (3,) are [X (N), Y (N), N (N*m)]: ``tau_demand`` the demand, ``unallocated``
    the demand minus what the allocation plans to produce, ``bf_hat`` the estimated bias
    B f_hat. Per thruster (m,): ``delta_hat`` effectiveness in [0, 1] with its standard
    deviation ``delta_std`` and whether the recent data determine it (``observable``),
    ``f_hat`` bias (N),
    ``u`` last command (N), flags ``saturated`` (at an amplitude or rate limit), ``faulty``
    (flagged by the estimator), ``esc_failed`` (ESC silent), ``probing`` (recovery probe),
    ESC telemetry ``esc_rpm``, ``esc_current_a`` (NaN: never reported), ``esc_age_s``
    (+inf: never), ``hypothesis`` what its drive shows (:class:`Hypothesis` values:
    ``healthy``, ``drive-dead``, ``telemetry-lost``, ...; empty: no drive diagnosis).
    ``degraded``: the last cycle used the fallback allocation.
    """

    mode: Mode | None = None
    cycle: int = 0
    overruns: int = 0
    degraded: bool = False
    setpoint_stale: bool = False
    telemetry_stale: bool = False
    estimation_frozen: bool = False
    delta_hat: tuple[float, ...] = ()
    delta_std: tuple[float, ...] = ()  # standard deviation of delta_hat (0: the truth/CAP)
    observable: tuple[bool, ...] = ()  # the recent data determine delta_i
    f_hat: tuple[float, ...] = ()
    bf_hat: tuple[float, ...] = ()
    u: tuple[float, ...] = ()
    tau_demand: tuple[float, ...] = ()
    unallocated: tuple[float, ...] = ()
    saturated: tuple[bool, ...] = ()
    faulty: tuple[bool, ...] = ()
    esc_failed: tuple[bool, ...] = ()
    probing: tuple[bool, ...] = ()
    setpoint_age_s: float = math.inf
    telemetry_age_s: float = math.inf
    malformed: int = 0  # malformed messages dropped, all ports
    esc_rpm: tuple[float, ...] = ()
    esc_current_a: tuple[float, ...] = ()
    esc_age_s: tuple[float, ...] = ()
    # the drives' diagnosis per thruster: a Hypothesis value (core/estimation/shaft_types.py)
    hypothesis: tuple[str, ...] = ()

    @classmethod
    def checked(cls, **values: Any) -> AllocatorStatus:
        """The status of ``values`` (fields by name; vectors as any sequence or array),
        normalised to tuples of float / bool, or MalformedMessage naming the first field
        that breaks the rules (TypeError for a name that is not a field):

        * every per-thruster field has m = len(delta_hat) entries, or none (not carried);
        * every wrench (``tau_demand``, ``unallocated``, ``bf_hat``) has 3 entries, or none;
        * ``delta_hat``, ``f_hat``, ``u`` and the wrenches are finite (``delta_std``, the
          ESC telemetry and the ages may hold NaN / +inf as the class docstring says);
        * ``mode`` is a :class:`Mode` or None.
        """
        st = cls(**values)
        norm: dict[str, Any] = {n: _floats(n, getattr(st, n)) for n in _FLOATS}
        norm |= {n: tuple(bool(v) for v in getattr(st, n)) for n in _BOOLS}
        m = len(norm["delta_hat"])
        for name in (*_FLOATS, *_BOOLS):
            want = (0, 3) if name in _WRENCHES else (0, m)
            if len(norm[name]) not in want:
                raise MalformedMessage(
                    f"status {name}: expected {' or '.join(map(str, want))} entries, "
                    f"got {len(norm[name])}"
                )
        for name in _FINITE:
            if not all(map(math.isfinite, norm[name])):
                raise MalformedMessage(f"status {name}: non-finite value in {norm[name]}")
        if st.mode is not None and not isinstance(st.mode, Mode):
            raise MalformedMessage(f"status mode: {st.mode!r:.40} is not a Mode")
        norm["hypothesis"] = _hypotheses(st.hypothesis, m)
        norm |= {n: int(getattr(st, n)) for n in ("cycle", "overruns", "malformed")}
        norm |= {n: bool(getattr(st, n)) for n in _FLAGS}
        norm |= {n: float(getattr(st, n)) for n in ("setpoint_age_s", "telemetry_age_s")}
        return cls(mode=st.mode, **norm)

    @property
    def command(self) -> ThrusterCommand:
        """The last command ``u`` (m,) in N as a message."""
        return ThrusterCommand(np.array(self.u, dtype=np.float64))

    @property
    def flagged(self) -> tuple[bool, ...]:
        """Per thruster: flagged by the estimator or failed by its ESC watchdog (empty when
        the status carries neither)."""
        faulty = self.faulty or (False,) * len(self.esc_failed)
        failed = self.esc_failed or (False,) * len(faulty)
        return tuple(a or b for a, b in zip(faulty, failed, strict=True))

    @property
    def m(self) -> int:
        """Number of thrusters the status describes."""
        return len(self.delta_hat)

    @property
    def fault_detected(self) -> bool:
        """Any thruster flagged by the estimator or failed by its ESC watchdog."""
        return any(self.faulty) or any(self.esc_failed)

    @property
    def has_unallocated(self) -> bool:
        """Some of the demand cannot be met (1e-6 N or N*m on some axis)."""
        return max(map(abs, self.unallocated), default=0.0) > 1e-6

    def as_dict(self) -> dict[str, object]:
        """The fields by name (``mode`` as its value string)."""
        out = {f.name: getattr(self, f.name) for f in fields(self)}
        out["mode"] = None if self.mode is None else self.mode.value
        return out


_WRENCHES = ("tau_demand", "unallocated", "bf_hat")
_FINITE = ("delta_hat", "f_hat", "u", *_WRENCHES)
_FLOATS = (*_FINITE, "delta_std", "esc_rpm", "esc_current_a", "esc_age_s")
_BOOLS = ("observable", "saturated", "faulty", "esc_failed", "probing")
_FLAGS = ("degraded", "setpoint_stale", "telemetry_stale", "estimation_frozen")


def _floats(name: str, value: object) -> tuple[float, ...]:
    """``value`` (a sequence or a 1-D array of numbers) as a tuple of floats."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise MalformedMessage(f"status {name}: not a numeric vector: {e}") from e
    if arr.ndim != 1:
        raise MalformedMessage(f"status {name}: expected a vector, got shape {arr.shape}")
    # Every NaN as the one ``math.nan``: tuples compare items by identity first, so two
    # statuses with the same unknowns (an ESC never heard) compare equal.
    return tuple(math.nan if v != v else v for v in arr.tolist())


_HYPOTHESES = frozenset(h.value for h in Hypothesis)


def _hypotheses(values: object, m: int) -> tuple[str, ...]:
    """The per-thruster hypotheses, each a :class:`Hypothesis` value, m of them or none."""
    out = tuple(str(v) for v in values) if isinstance(values, tuple | list) else ()
    if not isinstance(values, tuple | list) or len(out) not in (0, m):
        raise MalformedMessage(f"status hypothesis: expected 0 or {m} entries, got {values!r:.60}")
    bad = [v for v in out if v not in _HYPOTHESES]
    if bad:
        raise MalformedMessage(f"status hypothesis: unknown {bad[0]!r:.40}")
    return out
