"""Wire conversions shared by the MAVLink roles (no I/O; the dialect module is passed in).

Frames: ODOMETRY pose is MAV_FRAME_LOCAL_NED, its twist MAV_FRAME_BODY_FRD; quaternions are
[w, x, y, z] (Hamilton), body FRD relative to NED. Only the planar part is used (3-DOF).
"""

from __future__ import annotations

import enum
import math
from types import ModuleType
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
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


def status_from_message(msg: Any) -> AllocatorStatus:
    """FTCAP_STATUS -> AllocatorStatus (fields it does not carry keep their defaults).

    A sender without the extension fields (masks read as 0, ``delta_hat_std`` as zeros)
    gives per-thruster ``faulty`` from FAULT_DETECTED alone: every thruster is then marked
    when any is. ``delta_std`` may hold NaN (unknown). Raises
    MalformedMessage for n_thrusters > 16 or non-finite values.
    """
    n = int(msg.n_thrusters)
    if n > MAX_THRUSTERS:
        raise MalformedMessage(f"FTCAP_STATUS n_thrusters {n} > {MAX_THRUSTERS}")
    arrays = [np.asarray(a, dtype=np.float64) for a in (msg.tau_demand, msg.tau_unallocated)]
    arrays += [np.asarray(a[:n], dtype=np.float64) for a in (msg.delta_hat, msg.f_hat)]
    if not all(np.all(np.isfinite(a)) for a in arrays):
        raise MalformedMessage("FTCAP_STATUS: non-finite values")
    flags = StatusFlag(int(msg.flags) & sum(StatusFlag))
    faulty = bits(int(getattr(msg, "faulty", 0)), n)
    if StatusFlag.FAULT_DETECTED in flags and not any(faulty):
        faulty = (True,) * n
    tau, unallocated, delta_hat, f_hat = (tuple(a.tolist()) for a in arrays)
    std = getattr(msg, "delta_hat_std", None)
    delta_std = () if std is None else tuple(float(v) for v in std[:n])
    return AllocatorStatus(
        degraded=StatusFlag.DEGRADED in flags,
        setpoint_stale=StatusFlag.SETPOINT_STALE in flags,
        telemetry_stale=StatusFlag.TELEMETRY_STALE in flags,
        delta_hat=delta_hat,
        delta_std=delta_std,
        f_hat=f_hat,
        tau_demand=tau,
        unallocated=unallocated,
        saturated=bits(int(getattr(msg, "saturated", 0)), n),
        faulty=faulty,
        probing=bits(int(getattr(msg, "probing", 0)), n),
    )
