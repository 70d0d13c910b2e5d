"""The project's messages as ROS 2 message values (dicts for :mod:`~.cdr`) and back.

Frames follow REP-103, as ROS tools expect them: the world frame ``odom`` is ENU (x east,
y north, z up) and the body frame ``base_link`` is FLU (x forward, y port, z up); the
project is NED and FRD inside (Fossen). So a heading psi (from north, clockwise) is the
yaw ``pi/2 - psi`` about z, body ``v`` and ``r`` change sign, and a body wrench [X, Y, N]
is force (X, -Y, 0) and torque (0, 0, -N). A ``WrenchStamped`` whose ``frame_id`` is
``base_link_frd`` is read as FRD (no sign change); ``""`` or ``base_link``: FLU; any other
frame is refused (MalformedMessage: counted and dropped). Stamps: ``header.stamp`` of
odometry is the vessel's clock (``Odometry.time_s``), of everything else the sender's.
Pure: no zenoh import.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import (
    FaultInjection,
    FaultKind,
    Odometry,
    ThrusterCommand,
    WrenchSetpoint,
)
from ftcap_hil.core.status import AllocatorStatus, Mode

WORLD_FRAME = "odom"
BODY_FRAME = "base_link"
BODY_FRD_FRAME = "base_link_frd"
Msg = dict[str, Any]


def stamp(t_s: float) -> Msg:
    """``builtin_interfaces/Time`` of ``t_s`` seconds (NaN: zero)."""
    if not math.isfinite(t_s):
        return {"sec": 0, "nanosec": 0}
    ns = int(round(t_s * 1e9))
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def stamp_s(value: Msg) -> float:
    """Seconds of a ``builtin_interfaces/Time``."""
    return float(value["sec"]) + float(value["nanosec"]) * 1e-9


def header(t_s: float, frame_id: str = "") -> Msg:
    """``std_msgs/Header`` stamped ``t_s`` in ``frame_id``."""
    return {"stamp": stamp(t_s), "frame_id": frame_id}


def vector3(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> Msg:
    """``geometry_msgs/Vector3``."""
    return {"x": float(x), "y": float(y), "z": float(z)}


def wrench(tau: Sequence[float]) -> Msg:
    """A body wrench [X (N), Y (N), N (N*m)] (FRD) as ``geometry_msgs/Wrench`` (FLU)."""
    x, y, n = (float(v) for v in tau)
    return {"force": vector3(x, -y), "torque": vector3(0.0, 0.0, -n)}


def wrench_stamped(tau: Sequence[float], t_s: float) -> Msg:
    """``geometry_msgs/WrenchStamped`` in ``base_link`` (FLU)."""
    return {"header": header(t_s, BODY_FRAME), "wrench": wrench(tau)}


def setpoint_from(value: Msg, limit: tuple[float, float, float] | None = None) -> WrenchSetpoint:
    """The setpoint of a ``WrenchStamped`` (module docstring for frames); ``limit``: a
    component beyond +-it is refused, as on the JSON key."""
    frame = value["header"]["frame_id"]
    w = value["wrench"]
    x, y, n = w["force"]["x"], w["force"]["y"], w["torque"]["z"]
    if frame in ("", BODY_FRAME):
        y, n = -y, -n
    elif frame != BODY_FRD_FRAME:
        raise MalformedMessage(
            f"wrench frame_id {frame!r}: expected '{BODY_FRAME}' (FLU) or '{BODY_FRD_FRAME}'"
        )
    setpoint = WrenchSetpoint.checked([x, y, n])
    if limit is not None and np.any(np.abs(setpoint.tau) > np.asarray(limit)):
        raise MalformedMessage(f"wrench {setpoint.tau.tolist()} beyond the limit {limit}")
    return setpoint


def _quaternion_z(yaw: float) -> Msg:
    return {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)}


def odometry_msg(odom: Odometry) -> Msg:
    """``nav_msgs/Odometry``: pose in ``odom`` (ENU), twist in ``base_link`` (FLU)."""
    north, east, psi = (float(v) for v in odom.eta)
    u, v, r = (float(x) for x in odom.nu)
    pose = {"position": vector3(east, north), "orientation": _quaternion_z(math.pi / 2 - psi)}
    twist = {"linear": vector3(u, -v), "angular": vector3(0.0, 0.0, -r)}
    return {
        "header": header(odom.time_s, WORLD_FRAME),
        "child_frame_id": BODY_FRAME,
        "pose": {"pose": pose, "covariance": [0.0] * 36},
        "twist": {"twist": twist, "covariance": [0.0] * 36},
    }


def odometry_from(value: Msg) -> Odometry:
    """The Odometry of a ``nav_msgs/Odometry`` (ENU / FLU, module docstring); psi in
    (-pi, pi]; ``time_s`` from the stamp (None if zero: not stamped)."""
    pose, twist = value["pose"]["pose"], value["twist"]["twist"]
    q = pose["orientation"]
    sin_yaw = 2.0 * (q["w"] * q["z"] + q["x"] * q["y"])
    yaw = math.atan2(sin_yaw, 1.0 - 2.0 * (q["y"] ** 2 + q["z"] ** 2))
    psi = math.remainder(math.pi / 2 - yaw, 2 * math.pi)
    t_s = stamp_s(value["header"]["stamp"])
    eta = [pose["position"]["y"], pose["position"]["x"], psi]
    nu = [twist["linear"]["x"], -twist["linear"]["y"], -twist["angular"]["z"]]
    return Odometry.checked(eta, nu, t_s if t_s > 0.0 else math.nan)


def float64_array(values: Sequence[float], label: str) -> Msg:
    """``std_msgs/Float64MultiArray`` with one dimension named ``label``."""
    data = [float(v) for v in values]
    dim = {"label": label, "size": len(data), "stride": len(data)}
    return {"layout": {"dim": [dim], "data_offset": 0}, "data": data}


def thruster_command_from(value: Msg, m: int | None = None) -> ThrusterCommand:
    """The command (N) of a ``Float64MultiArray``; MalformedMessage unless m finite values."""
    return ThrusterCommand.checked(value["data"], m)


def fault_msg(fault: FaultInjection) -> Msg:
    """``ftcap_msgs/FaultInjection``."""
    return {"thruster": fault.index, "kind": fault.kind.value, "value": float(fault.value)}


def fault_from(value: Msg, m: int | None = None) -> FaultInjection:
    """The injection of an ``ftcap_msgs/FaultInjection``; MalformedMessage for an unknown
    kind, a thruster beyond ``m`` or a value out of range."""
    try:
        kind = FaultKind(value["kind"])
    except ValueError:
        known = [k.value for k in FaultKind]
        raise MalformedMessage(f"kind: {value['kind']!r:.40} is not one of {known}") from None
    index, number = int(value["thruster"]), float(value["value"])
    if m is not None and index >= m:
        raise MalformedMessage(f"thruster {index}: the vessel has {m} (0-based)")
    if math.isinf(number) or (kind is FaultKind.WEAK and not 0.0 <= number <= 1.0):
        raise MalformedMessage(f"{kind.value} value {number}: out of range")
    return FaultInjection(index, kind, number)


def mode_from(value: Msg) -> Mode:
    """The mode of a ``std_msgs/String`` (``none``, ``cap``, ``ftcap``, ``ftcap-literal``:
    what a running allocator may switch to, as FTC_MODE); MalformedMessage else."""
    known = [m.value for m in Mode if m is not Mode.ORACLE]
    text = value["data"].strip()
    if text not in known:
        raise MalformedMessage(f"mode {text!r:.40}: expected one of {known}")
    return Mode(text)


def delta_band(delta_hat: Sequence[float], delta_std: Sequence[float]) -> tuple[list[float], ...]:
    """(lower, upper): delta_hat -+ 2 std within [0, 1] (empty without a std)."""
    if len(delta_std) != len(delta_hat) or not delta_hat:
        return [], []
    dh, sd = np.asarray(delta_hat, dtype=float), np.asarray(delta_std, dtype=float)
    return np.clip(dh - 2 * sd, 0, 1).tolist(), np.clip(dh + 2 * sd, 0, 1).tolist()


def allocator_status_msg(st: AllocatorStatus, t_s: float, dead: Sequence[bool] = ()) -> Msg:
    """``ftcap_msgs/AllocatorStatus`` of a status stamped ``t_s`` (wrenches FLU)."""
    lower, upper = delta_band(st.delta_hat, st.delta_std)
    zero = (0.0, 0.0, 0.0)
    return {
        "header": header(t_s, BODY_FRAME),
        "mode": "" if st.mode is None else st.mode.value,
        "cycle": int(st.cycle),
        "overruns": int(st.overruns),
        "malformed": int(st.malformed),
        "degraded": bool(st.degraded),
        "estimation_frozen": bool(st.estimation_frozen),
        "setpoint_stale": bool(st.setpoint_stale),
        "telemetry_stale": bool(st.telemetry_stale),
        "demanded": wrench(st.tau_demand or zero),
        "unallocated": wrench(st.unallocated or zero),
        "bias": wrench(st.bf_hat or zero),
        "command": list(st.u),
        "delta_hat": list(st.delta_hat),
        "delta_std": list(st.delta_std),
        "delta_lower": lower,
        "delta_upper": upper,
        "f_hat": list(st.f_hat),
        "observable": [bool(b) for b in st.observable],
        "saturated": [bool(b) for b in st.saturated],
        "faulty": [bool(b) for b in st.faulty],
        "dead": [bool(b) for b in dead],
        "esc_failed": [bool(b) for b in st.esc_failed],
        "probing": [bool(b) for b in st.probing],
        "drive": [str(h) for h in st.hypothesis],
    }
