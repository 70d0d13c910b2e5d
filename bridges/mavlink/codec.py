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

from ftcap_hil.core.messages import MalformedMessage, Odometry


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
