"""What the allocator reports: its status assembled from one cycle, and its announcements.

* :func:`assemble_status` builds the one :class:`~ftcap_hil.core.status.AllocatorStatus`
  from the inputs' freshness, the last cycle's result and the ESC telemetry.
* :func:`announce_cycle` logs a cycle's estimator flags and a fallback allocation on their
  transitions.
* :class:`MalformedNotice` turns the growing count of malformed inputs into at most one
  announcement per ``min_interval_s``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.core.allocation.allocator import AllocationStatus
from ftcap_hil.core.cycle import CycleResult
from ftcap_hil.core.messages import BoolArray, EscStatus, FloatArray
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.runtime.transitions import TransitionLog


@dataclass(frozen=True)
class Freshness:
    """The inputs of one cycle as the watchdogs judged them: ages in s (+inf: never heard),
    stale flags, ``esc_failed`` (m,) from the ESC watchdog and the ESC status ages it judged
    (s; None: no ESC monitor)."""

    setpoint_age_s: float
    telemetry_age_s: float
    setpoint_stale: bool
    telemetry_stale: bool
    esc_failed: BoolArray | None = None
    esc_ages_s: FloatArray | None = None


@dataclass(frozen=True)
class EscReport:
    """ESC telemetry per thruster: the latest status (None: never heard) and its age (s)."""

    latest: Sequence[EscStatus | None]
    ages_s: FloatArray


@dataclass(frozen=True)
class LoopCounts:
    """The loop's counters at the status: cycles run, deadlines missed, malformed inputs
    dropped on every port."""

    cycle: int
    overruns: int
    malformed: int


def _flags(a: BoolArray | None, m: int) -> BoolArray:
    return np.zeros(m, dtype=bool) if a is None else a


def _esc_fields(esc: EscReport | None) -> dict[str, Any]:
    if esc is None:
        return {}
    return {
        "esc_rpm": [math.nan if e is None else e.rpm for e in esc.latest],
        "esc_current_a": [math.nan if e is None else e.current_a for e in esc.latest],
        "esc_age_s": esc.ages_s,
    }


def _uncertainty_fields(last: CycleResult | None) -> dict[str, Any]:
    """delta_std and observable when the estimator gives them (the Kalman stage)."""
    if last is None:
        return {}
    fields: dict[str, Any] = {}
    if last.estimate.delta_std is not None:
        fields["delta_std"] = last.estimate.delta_std
    if last.decision is not None:
        fields["observable"] = last.decision.observable
    if last.shaft is not None:
        fields["hypothesis"] = tuple(h.value for h in last.shaft.hypothesis)
    return fields


def assemble_status(
    *,
    mode: Mode,
    counts: LoopCounts,
    fresh: Freshness,
    last: CycleResult | None,
    u: FloatArray,
    tau_demand: FloatArray,
    degraded: bool,
    esc: EscReport | None = None,
) -> AllocatorStatus:
    """The status after a cycle (:meth:`AllocatorStatus.checked`: MalformedMessage if the
    cycle left something it refuses, a non-finite estimate). ``last`` is the latest cycle
    that allocated (None before the first: no estimate yet, delta_hat 1, nothing
    saturated); ``u`` (m,) the command on the thrusters (N), ``tau_demand`` (k,) the demand
    of this cycle (zero while stale)."""
    m, k = u.size, tau_demand.size
    est = last.estimate if last is not None else None
    return AllocatorStatus.checked(
        mode=mode,
        cycle=counts.cycle,
        overruns=counts.overruns,
        degraded=degraded,
        setpoint_stale=fresh.setpoint_stale,
        telemetry_stale=fresh.telemetry_stale,
        estimation_frozen=fresh.telemetry_stale and mode.estimates,
        delta_hat=est.delta_hat if est else np.ones(m),
        f_hat=est.f_hat if est else np.zeros(m),
        bf_hat=est.bf_hat if est else np.zeros(k),
        u=u,
        tau_demand=tau_demand,
        unallocated=last.allocation.unallocated if last else np.zeros(k),
        saturated=_flags(last.allocation.saturated if last else None, m),
        faulty=_flags(last.faulty if last else None, m),
        esc_failed=_flags(fresh.esc_failed, m),
        probing=_flags(last.probing if last else None, m),
        **_uncertainty_fields(last),
        setpoint_age_s=fresh.setpoint_age_s,
        telemetry_age_s=fresh.telemetry_age_s,
        malformed=counts.malformed,
        **_esc_fields(esc),
    )


def announce_cycle(transitions: TransitionLog, result: CycleResult) -> None:
    """Estimator flags (``fault<n>``) and a fallback allocation (``degraded``), on change."""
    for i, faulty in enumerate(result.faulty):
        d = result.estimate.delta_hat[i]
        transitions.update(
            f"fault{i + 1}",
            bool(faulty),
            f"thruster {i + 1} fault detected: delta_hat {d:.2f}",
            f"thruster {i + 1} fault cleared: delta_hat {d:.2f}",
        )
    status = result.allocation.status
    transitions.update(
        "degraded",
        status is not AllocationStatus.OK,
        f"allocation degraded: {status.value}",
        "allocation nominal",
    )


class MalformedNotice:
    """At most one "malformed input dropped" announcement per ``min_interval_s``."""

    def __init__(self, min_interval_s: float = 5.0) -> None:
        self._min_interval_ns = int(min_interval_s * 1e9)
        self._seen = 0
        self._said_ns: int | None = None

    def update(self, now_ns: int, malformed: int) -> str | None:
        """The text to announce for the running count ``malformed`` at ``now_ns``, or None
        (nothing new, or said less than ``min_interval_s`` ago)."""
        if malformed <= self._seen:
            return None
        self._seen = malformed
        if self._said_ns is not None and now_ns - self._said_ns < self._min_interval_ns:
            return None
        self._said_ns = now_ns
        return f"malformed input dropped: {malformed} so far"
