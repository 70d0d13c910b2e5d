"""The allocator's status as ``diagnostic_msgs/DiagnosticArray``: one entry per thruster and
one for the allocator, as ``rqt_robot_monitor`` and Foxglove's diagnostics panels show them.

Per thruster ``i`` (1-based in the name, as on the ground station): name
``ftcap <vessel>: thruster i``, hardware id ``<vessel>/T<i>``, level ERROR when its ESC is
silent, WARN when the estimator flags it, else OK; the values (text, as the message type
has it) ``delta_hat``, ``delta_std``, ``delta_lower``, ``delta_upper`` (delta_hat -+ 2 std
within [0, 1]), ``observable``, ``faulty``, ``saturated``, ``esc_failed``, ``probing``,
``f_hat_N``, ``u_N``, ``esc_rpm``, ``esc_current_A``, ``drive`` (the drive's diagnosis): each
only where the status carries it. The allocator's entry (``ftcap <vessel>: allocator``) is
WARN when the last cycle was degraded or an input is stale, and carries mode, cycle,
overruns, malformed and the unallocated wrench (body FRD, as the project's JSON). Pure: no
zenoh import.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence

from bridges.zenoh_io.ros2.messages import Msg, delta_band, header
from ftcap_hil.core.status import AllocatorStatus


class Level(enum.IntEnum):
    """``diagnostic_msgs/DiagnosticStatus`` levels."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


def _text(value: float | bool | str) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "true" if value else "false"
    return "nan" if math.isnan(value) else f"{value:.6g}"


def _pairs(named: dict[str, Sequence[float] | Sequence[bool] | Sequence[str]], i: int) -> list[Msg]:
    return [
        {"key": key, "value": _text(values[i])} for key, values in named.items() if len(values) > i
    ]


def _thruster(st: AllocatorStatus, vessel: str, i: int, band: tuple[list[float], ...]) -> Msg:
    esc_failed = len(st.esc_failed) > i and st.esc_failed[i]
    faulty = len(st.faulty) > i and st.faulty[i]
    level = Level.ERROR if esc_failed else Level.WARN if faulty else Level.OK
    message = "ESC silent" if esc_failed else "fault flagged" if faulty else "healthy"
    named: dict[str, Sequence[float] | Sequence[bool] | Sequence[str]] = {
        "delta_hat": st.delta_hat,
        "delta_std": st.delta_std,
        "delta_lower": band[0],
        "delta_upper": band[1],
        "observable": st.observable,
        "faulty": st.faulty,
        "saturated": st.saturated,
        "esc_failed": st.esc_failed,
        "probing": st.probing,
        "f_hat_N": st.f_hat,
        "u_N": st.u,
        "esc_rpm": st.esc_rpm,
        "esc_current_A": st.esc_current_a,
        "drive": st.hypothesis,
    }
    return {
        "level": int(level),
        "name": f"ftcap {vessel}: thruster {i + 1}",
        "message": message,
        "hardware_id": f"{vessel}/T{i + 1}",
        "values": _pairs(named, i),
    }


def _allocator(st: AllocatorStatus, vessel: str) -> Msg:
    stale = st.setpoint_stale or st.telemetry_stale
    level = Level.WARN if st.degraded or stale else Level.OK
    message = "degraded (fallback)" if st.degraded else "inputs stale" if stale else "allocating"
    values = {
        "mode": "" if st.mode is None else st.mode.value,
        "cycle": str(st.cycle),
        "overruns": str(st.overruns),
        "malformed": str(st.malformed),
        "setpoint_stale": _text(st.setpoint_stale),
        "telemetry_stale": _text(st.telemetry_stale),
        "estimation_frozen": _text(st.estimation_frozen),
    }
    for key, v in zip(("X_N", "Y_N", "N_Nm"), st.unallocated, strict=False):
        values[f"unallocated_{key}"] = _text(float(v))
    return {
        "level": int(level),
        "name": f"ftcap {vessel}: allocator",
        "message": message,
        "hardware_id": vessel,
        "values": [{"key": k, "value": v} for k, v in values.items()],
    }


def diagnostic_array(st: AllocatorStatus, vessel: str, t_s: float) -> Msg:
    """The ``DiagnosticArray`` of a status stamped ``t_s`` (module docstring)."""
    band = delta_band(st.delta_hat, st.delta_std)
    entries = [_allocator(st, vessel)]
    entries += [_thruster(st, vessel, i, band) for i in range(st.m)]
    return {"header": header(t_s), "status": entries}
