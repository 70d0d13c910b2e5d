"""The allocator's status: one type, built by the daemon, encoded and decoded by each bridge.

:class:`AllocatorStatus` is what ``ftcap-hil allocator`` publishes (decimated, on MAVLink
``FTCAP_STATUS`` / ``ACTUATOR_OUTPUT_STATUS`` / ``FTCAP_ESC_STATUS`` and Zenoh
``allocator/status``) and answers to queries. A transport that does not carry a field
decodes it as its default (``mode`` None, ages +inf, empty per-thruster tuples), so every
consumer reads the same names whatever the wire was. SI units, body frame; per-thruster
tuples have one entry per thruster in vessel-file order.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields


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
    (+inf: never). ``degraded``: the last cycle used the fallback allocation.
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
