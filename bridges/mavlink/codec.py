"""Wire conversions shared by the MAVLink roles (no I/O; the dialect module is passed in).

Frames: ODOMETRY pose is MAV_FRAME_LOCAL_NED, its twist MAV_FRAME_BODY_FRD; quaternions are
[w, x, y, z] (Hamilton), body FRD relative to NED. Only the planar part is used (3-DOF).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping
from types import ModuleType
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.estimation.shaft_types import HYPOTHESES_BY_CODE, HYPOTHESIS_CODES, Hypothesis
from ftcap_hil.core.messages import Odometry
from ftcap_hil.core.status import AllocatorStatus


class Severity(enum.IntEnum):
    """MAV_SEVERITY, for STATUSTEXT."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


class SystemStatus(enum.IntEnum):
    """MAV_STATE, reported in HEARTBEAT.system_status."""

    UNINIT = 0
    BOOT = 1
    STANDBY = 3
    ACTIVE = 4
    CRITICAL = 5
    EMERGENCY = 6
    POWEROFF = 7


def yaw_from_quaternion(q: Any) -> float:
    """Heading psi (rad) of the body-FRD frame in NED from q = [w, x, y, z] (Hamilton).

    Raises MalformedMessage for a non-finite or far-from-unit quaternion.
    """
    w, x, y, z = (float(c) for c in q)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    if not math.isfinite(norm) or abs(norm - 1.0) > 0.05:
        raise MalformedMessage(f"quaternion {[w, x, y, z]} is not a unit quaternion")
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(psi: float) -> list[float]:
    """q = [w, x, y, z] of a pure rotation by psi (rad) about NED down."""
    return [math.cos(psi / 2.0), 0.0, 0.0, math.sin(psi / 2.0)]


def odometry_from_message(msg: Any, dialect: ModuleType) -> Odometry:
    """Decode ODOMETRY (pose in MAV_FRAME_LOCAL_NED, twist in MAV_FRAME_BODY_FRD).

    eta = [x, y, yaw(q)], nu = [vx, vy, yawspeed]; z, roll and pitch are ignored (3-DOF).
    """
    if msg.frame_id != dialect.MAV_FRAME_LOCAL_NED:
        raise MalformedMessage(f"ODOMETRY frame_id {msg.frame_id}: expected MAV_FRAME_LOCAL_NED")
    if msg.child_frame_id != dialect.MAV_FRAME_BODY_FRD:
        raise MalformedMessage(
            f"ODOMETRY child_frame_id {msg.child_frame_id}: expected MAV_FRAME_BODY_FRD"
        )
    psi = yaw_from_quaternion(msg.q)
    return Odometry.checked(
        [msg.x, msg.y, psi], [msg.vx, msg.vy, msg.yawspeed], msg.time_usec * 1e-6
    )


def padded(values: Any, length: int, name: str) -> list[float]:
    """``values`` as a list of ``length`` floats, zero-padded (MAVLink arrays are fixed)."""
    arr = np.asarray(values, dtype=np.float64).ravel()
    if arr.shape[0] > length:
        raise ValueError(f"{name}: at most {length} values fit, got {arr.shape[0]}")
    return [*arr.tolist(), *([0.0] * (length - arr.shape[0]))]


MAX_THRUSTERS = 16  # per-thruster arrays and bit masks of the dialect


class StatusFlag(enum.IntFlag):
    """FTCAP_STATUS_FLAGS of the dialect."""

    NONE = 0
    DEGRADED = 1
    SETPOINT_STALE = 2
    TELEMETRY_STALE = 4
    FAULT_DETECTED = 8
    SATURATED = 16
    UNALLOCATED = 32


def status_flags(st: AllocatorStatus) -> StatusFlag:
    """The FTCAP_STATUS flag bits of a status."""
    flags = StatusFlag.NONE
    for on, flag in (
        (st.degraded, StatusFlag.DEGRADED),
        (st.setpoint_stale, StatusFlag.SETPOINT_STALE),
        (st.telemetry_stale, StatusFlag.TELEMETRY_STALE),
        (st.fault_detected, StatusFlag.FAULT_DETECTED),
        (any(st.saturated), StatusFlag.SATURATED),
        (st.has_unallocated, StatusFlag.UNALLOCATED),
    ):
        if on:
            flags |= flag
    return flags


def bitmask(flags: tuple[bool, ...]) -> int:
    """Bit i set where ``flags[i]`` is true."""
    return sum(1 << i for i, f in enumerate(flags) if f)


def bits(mask: int, n: int) -> tuple[bool, ...]:
    """The first ``n`` bits of ``mask`` as flags (the inverse of :func:`bitmask`)."""
    return tuple(bool(mask >> i & 1) for i in range(n))


def dialect_message(dialect: ModuleType, name: str, fields: Mapping[str, Any]) -> Any:
    """Message ``name`` (e.g. ``"FTCAP_STATUS"``) of ``dialect`` built from its fields by
    name, each array zero-padded to its length in the dialect (MAVLink arrays are fixed).
    ValueError naming the message for a field it does not have or lacks (extensions
    included), or an array longer than the dialect's."""
    cls = getattr(dialect, f"MAVLink_{name.lower()}_message")
    lengths: dict[str, int] = dict(zip(cls.fieldnames, cls.array_lengths, strict=True))
    if fields.keys() != lengths.keys():
        missing = sorted(lengths.keys() - fields.keys())
        unknown = sorted(fields.keys() - lengths.keys())
        raise ValueError(f"{name}: missing fields {missing}, unknown fields {unknown}")
    arrays = {k: padded(v, n, f"{name}.{k}") for k, v in fields.items() if (n := lengths[k])}
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    for k, v in arrays.items():
        if not types[k].startswith(("float", "double")):  # integer arrays: whole numbers
            arrays[k] = [round(x) for x in v]
    return cls(**{**fields, **arrays})


def message_fields(msg: Any) -> dict[str, Any]:
    """A received message's fields by name, as its dialect lists them."""
    return {name: getattr(msg, name) for name in msg.fieldnames}


def status_fields(st: AllocatorStatus, time_boot_ms: int) -> dict[str, Any]:
    """FTCAP_STATUS's fields of a status, by name (arrays unpadded: :func:`dialect_message`).

    ``n_thrusters`` is the status's m; ``faulty`` marks a thruster flagged by the estimator
    or failed by its ESC watchdog; a wrench the status does not carry is sent as zeros, a
    ``delta_std`` it does not carry as zeros ("known exactly", as the dialect says).
    """
    return {
        "time_boot_ms": time_boot_ms,
        "tau_demand": st.tau_demand or (0.0,) * 3,
        "tau_unallocated": st.unallocated or (0.0,) * 3,
        "delta_hat": st.delta_hat,
        "f_hat": st.f_hat,
        "flags": int(status_flags(st)),
        "n_thrusters": st.m,
        "faulty": bitmask(st.flagged),
        "saturated": bitmask(st.saturated),
        "probing": bitmask(st.probing),
        "delta_hat_std": st.delta_std,
        "hypothesis": tuple(HYPOTHESIS_CODES[Hypothesis(h)] for h in st.hypothesis),
    }


def status_from_message(msg: Any) -> AllocatorStatus:
    """FTCAP_STATUS -> AllocatorStatus (:func:`status_from_fields` of its fields by name)."""
    return status_from_fields(message_fields(msg))


def status_from_fields(fields: Mapping[str, Any]) -> AllocatorStatus:
    """FTCAP_STATUS's fields by name -> AllocatorStatus (fields it does not carry keep their
    defaults); built by :meth:`AllocatorStatus.checked`.

    A sender without the extension fields (masks read as 0, ``delta_hat_std`` as zeros)
    gives per-thruster ``faulty`` from FAULT_DETECTED alone: every thruster is then marked
    when any is. ``delta_std`` may hold NaN (unknown). Raises MalformedMessage for
    n_thrusters > 16 or non-finite values.
    """
    n = int(fields["n_thrusters"])
    if n > MAX_THRUSTERS:
        raise MalformedMessage(f"FTCAP_STATUS n_thrusters {n} > {MAX_THRUSTERS}")
    flags = StatusFlag(int(fields["flags"]) & sum(StatusFlag))
    faulty = bits(int(fields.get("faulty", 0)), n)
    if StatusFlag.FAULT_DETECTED in flags and not any(faulty):
        faulty = (True,) * n
    std = fields.get("delta_hat_std")
    codes = [int(c) for c in fields.get("hypothesis", ())[:n]]
    if any(c not in HYPOTHESES_BY_CODE for c in codes if c):
        raise MalformedMessage(f"FTCAP_STATUS hypothesis: unknown code in {codes}")
    hyps = () if not any(codes) else tuple(HYPOTHESES_BY_CODE[c].value for c in codes)
    return AllocatorStatus.checked(
        degraded=StatusFlag.DEGRADED in flags,
        setpoint_stale=StatusFlag.SETPOINT_STALE in flags,
        telemetry_stale=StatusFlag.TELEMETRY_STALE in flags,
        delta_hat=fields["delta_hat"][:n],
        delta_std=() if std is None else std[:n],
        f_hat=fields["f_hat"][:n],
        tau_demand=fields["tau_demand"],
        unallocated=fields["tau_unallocated"],
        saturated=bits(int(fields.get("saturated", 0)), n),
        faulty=faulty,
        probing=bits(int(fields.get("probing", 0)), n),
        hypothesis=hyps,
    )
