"""A run's record as an MCAP file that Foxglove (and ``ros2 bag``) opens: ROS 2 messages in CDR.

:func:`write_mcap` writes one message per record row (``timeseries.csv``'s rows, the same
values) on the channels of :data:`CHANNELS`, stamped with the row's time ``t`` (s of the
run; ``start_ns`` is the epoch time of t = 0, 0 by default). Schemas are the ``ros2msg``
text of each type (its ``.msg`` and its dependencies), messages the CDR that the ROS 2
bridge sends (:mod:`bridges.zenoh_io.ros2`), frames REP-103 (``odom`` ENU, ``base_link``
FLU), so a wrench's Y and N and a yaw rate change sign against the CSV, and the heading is
the yaw ``pi/2 - psi``. Channels whose columns a record lacks (the linear plant has no
pose, a run without an estimator no ``delta_std``) are left out or hold empty arrays.

Derived, not per row: the path (every :data:`PATH_PERIOD_S`, poses every
:data:`PATH_POSE_S`), the diagnostics (every :data:`DIAGNOSTICS_PERIOD_S`), the faults of
the scenario's schedule as the injections that reproduce it (``core.faults.injection_plan``)
and the log lines: each injection, each flag that rises or falls (``faulty_i``, ``dead_i``,
``fallback``), and the ``logs`` handed in. The layout in ``docs/foxglove-layout.json``
shows them (docs/ros2-and-foxglove.md).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bridges.zenoh_io.ros2 import cdr
from bridges.zenoh_io.ros2 import messages as ros2
from bridges.zenoh_io.ros2.diagnostics import diagnostic_array
from bridges.zenoh_io.ros2.std_types import registry
from ftcap_hil.core.estimation.shaft_types import HYPOTHESES_BY_CODE
from ftcap_hil.core.faults import injection_plan
from ftcap_hil.core.messages import FaultInjection, FloatArray, Odometry
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.report.records import RunRecord

NS = "/ftcap"
PATH_PERIOD_S = 2.0
PATH_POSE_S = 1.0
DIAGNOSTICS_PERIOD_S = 1.0
CHANNELS: dict[str, str] = {
    f"{NS}/odometry": "nav_msgs/msg/Odometry",
    "/tf": "tf2_msgs/msg/TFMessage",
    f"{NS}/path": "nav_msgs/msg/Path",
    f"{NS}/reference": "geometry_msgs/msg/PoseStamped",
    f"{NS}/wrench/demanded": "geometry_msgs/msg/WrenchStamped",
    f"{NS}/wrench/allocated": "geometry_msgs/msg/WrenchStamped",
    f"{NS}/wrench/unallocated": "geometry_msgs/msg/WrenchStamped",
    f"{NS}/thrusters/command": "std_msgs/msg/Float64MultiArray",
    f"{NS}/thrusters/produced": "std_msgs/msg/Float64MultiArray",
    f"{NS}/truth/delta": "std_msgs/msg/Float64MultiArray",
    f"{NS}/truth/bias": "std_msgs/msg/Float64MultiArray",
    f"{NS}/allocator/status": "ftcap_msgs/msg/AllocatorStatus",
    "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    f"{NS}/fault/inject": "ftcap_msgs/msg/FaultInjection",
    "/rosout": "rcl_interfaces/msg/Log",
}
LOG_INFO, LOG_WARN = 20, 30


@dataclass(frozen=True)
class LogLine:
    """A line for ``/rosout`` at run time ``t_s``: ``level`` as rcl_interfaces/Log (20 info,
    30 warn, 40 error), the logger ``name``."""

    t_s: float
    text: str
    level: int = LOG_INFO
    name: str = "ftcap"


class _Columns:
    """A record's columns by name, per row; per-thruster groups as (m,) vectors."""

    def __init__(self, rec: RunRecord) -> None:
        self.c = rec.columns
        self.m = rec.scenario.thrusters.m
        self.k = rec.scenario.B.shape[0]
        step = rec.scenario.time_unit == "step"
        self.t_s: FloatArray = rec.t * rec.scenario.dt_s if step else rec.t

    def has(self, *names: str) -> bool:
        return all(n in self.c for n in names)

    def group(self, prefix: str, row: int, n: int | None = None) -> list[float]:
        names = [f"{prefix}_{i}" for i in range(1, (n or self.m) + 1)]
        if not self.has(*names):
            return []
        return [float(self.c[name][row]) for name in names]

    def flags(self, prefix: str, row: int) -> list[bool]:
        return [bool(v == 1.0) for v in self.group(prefix, row)]

    def scalar(self, name: str, row: int, default: float = math.nan) -> float:
        return float(self.c[name][row]) if name in self.c else default


def _finite(values: list[float]) -> list[float]:
    """``values``, or nothing if any is NaN (a column the run did not measure)."""
    return values if values and all(math.isfinite(v) for v in values) else []


def _drives(codes: list[float]) -> tuple[str, ...]:
    """The drives' hypotheses of a row's ``drive_i`` codes (none if a code is NaN)."""
    if not _finite(codes):
        return ()
    return tuple(HYPOTHESES_BY_CODE[int(c)].value for c in codes)


def _status(cols: _Columns, row: int, mode: str) -> tuple[AllocatorStatus, list[bool]]:
    """The allocator's status of a row, and its ``dead`` flags."""
    dem, ach = cols.group("v_dem", row, cols.k), cols.group("v_ach", row, cols.k)
    status = AllocatorStatus(
        mode=Mode(mode) if mode in {m.value for m in Mode} else None,
        cycle=row,
        degraded=cols.scalar("fallback", row, 0.0) == 1.0,
        delta_hat=tuple(cols.group("delta_hat", row)),
        delta_std=tuple(_finite(cols.group("delta_std", row))),
        observable=tuple(cols.flags("observable", row))
        if _finite(cols.group("observable", row))
        else (),
        f_hat=tuple(cols.group("f_hat", row)),
        bf_hat=tuple(cols.group("bf_hat", row, cols.k)) if cols.k == 3 else (),
        u=tuple(cols.group("u", row)),
        tau_demand=tuple(dem) if cols.k == 3 else (),
        unallocated=tuple(np.subtract(dem, ach).tolist()) if cols.k == 3 else (),
        faulty=tuple(cols.flags("faulty", row)),
        hypothesis=_drives(cols.group("drive", row)),
    )
    return status, cols.flags("dead", row)


def _pose(north: float, east: float, psi: float) -> dict[str, Any]:
    yaw = math.pi / 2 - psi
    orientation = {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2), "w": math.cos(yaw / 2)}
    return {"position": ros2.vector3(east, north), "orientation": orientation}


def _vessel_messages(cols: _Columns, row: int, t: float) -> Iterator[tuple[str, dict[str, Any]]]:
    c = cols.c
    if cols.has("north", "east", "psi"):
        eta = [c["north"][row], c["east"][row], c["psi"][row]]
        nu = [c[n][row] for n in ("u", "v", "r")] if cols.has("u", "v", "r") else [0.0] * 3
        odom = ros2.odometry_msg(Odometry(np.asarray(eta), np.asarray(nu), t))
        yield f"{NS}/odometry", odom
        pose = odom["pose"]["pose"]
        transform = {"translation": pose["position"], "rotation": pose["orientation"]}
        tf = {"header": odom["header"], "child_frame_id": ros2.BODY_FRAME, "transform": transform}
        yield "/tf", {"transforms": [tf]}
    if cols.has("ref_north", "ref_east", "ref_psi"):
        ref = _pose(c["ref_north"][row], c["ref_east"][row], c["ref_psi"][row])
        yield f"{NS}/reference", {"header": ros2.header(t, ros2.WORLD_FRAME), "pose": ref}
    if cols.k == 3 and cols.has("v_dem_1", "v_ach_1"):
        dem, ach = cols.group("v_dem", row, 3), cols.group("v_ach", row, 3)
        yield f"{NS}/wrench/demanded", ros2.wrench_stamped(dem, t)
        yield f"{NS}/wrench/allocated", ros2.wrench_stamped(ach, t)
        yield f"{NS}/wrench/unallocated", ros2.wrench_stamped(np.subtract(dem, ach).tolist(), t)


def _row_messages(cols: _Columns, row: int, mode: str) -> Iterator[tuple[str, dict[str, Any]]]:
    t = float(cols.t_s[row])
    yield from _vessel_messages(cols, row, t)
    for topic, prefix in (("thrusters/command", "u"), ("thrusters/produced", "tau"),
                          ("truth/delta", "delta"), ("truth/bias", "f")):  # fmt: skip
        yield f"{NS}/{topic}", ros2.float64_array(cols.group(prefix, row), "thrusters")
    status, dead = _status(cols, row, mode)
    yield f"{NS}/allocator/status", ros2.allocator_status_msg(status, t, dead)


def _path_messages(cols: _Columns) -> Iterator[tuple[float, dict[str, Any]]]:
    if not cols.has("north", "east", "psi") or not len(cols.t_s):
        return
    poses: list[dict[str, Any]] = []
    next_pose, next_path = -math.inf, 0.0
    c = cols.c
    for row, t in enumerate(cols.t_s.tolist()):
        if t >= next_pose:
            pose = _pose(c["north"][row], c["east"][row], c["psi"][row])
            poses.append({"header": ros2.header(t, ros2.WORLD_FRAME), "pose": pose})
            next_pose = t + PATH_POSE_S
        if t >= next_path or row == len(cols.t_s) - 1:
            yield t, {"header": ros2.header(t, ros2.WORLD_FRAME), "poses": list(poses)}
            next_path = t + PATH_PERIOD_S


def _diagnostics(cols: _Columns, mode: str, vessel: str) -> Iterator[tuple[float, dict[str, Any]]]:
    due = -math.inf
    for row, t in enumerate(cols.t_s.tolist()):
        if t >= due:
            yield t, diagnostic_array(_status(cols, row, mode)[0], vessel, t)
            due = t + DIAGNOSTICS_PERIOD_S


def _edges(cols: _Columns, name: str) -> Iterator[tuple[int, bool]]:
    values = cols.c[name] == 1.0
    for row in np.flatnonzero(np.diff(values.astype(np.int8))) + 1:
        yield int(row), bool(values[row])


def flag_lines(cols: _Columns) -> list[LogLine]:
    """A line per rise and fall of ``faulty_i``, ``dead_i`` and ``fallback``."""
    lines = []
    for i in range(1, cols.m + 1):
        for prefix, what in (("faulty", "flagged faulty"), ("dead", "taken out of the allocation")):
            if cols.has(f"{prefix}_{i}"):
                for row, up in _edges(cols, f"{prefix}_{i}"):
                    text = f"thruster {i} {what}" if up else f"thruster {i} {what}: cleared"
                    lines.append(LogLine(float(cols.t_s[row]), text, LOG_WARN if up else LOG_INFO))
    if cols.has("fallback"):
        for row, up in _edges(cols, "fallback"):
            text = "allocation degraded (fallback)" if up else "allocation back to the QP"
            lines.append(LogLine(float(cols.t_s[row]), text, LOG_WARN if up else LOG_INFO))
    return lines


def _log(line: LogLine) -> dict[str, Any]:
    return {"stamp": ros2.stamp(line.t_s), "level": line.level, "name": line.name,
            "msg": line.text, "file": "", "function": "", "line": 0}  # fmt: skip


def fault_messages(rec: RunRecord) -> list[tuple[float, FaultInjection, LogLine]]:
    """The scenario's faults as injections (and their log lines), by run time; none for the
    ``none`` reference run, which flies without them."""
    sc = rec.scenario
    if rec.mode == Mode.NONE.value:
        return []
    scale = sc.dt_s if sc.time_unit == "step" else 1.0
    out = []
    for inj in injection_plan(sc.faults, sc.duration_s):
        t = inj.at_s * scale
        value = "" if math.isnan(inj.value) else f" {inj.value:g}"
        line = LogLine(
            t, f"fault injected: thruster {inj.thruster + 1} {inj.kind.value}{value}", LOG_WARN
        )
        out.append((t, FaultInjection(inj.thruster, inj.kind, inj.value), line))
    return out


def timeline(
    rec: RunRecord, vessel: str = "ftcap", logs: Iterable[LogLine] = ()
) -> list[tuple[float, str, dict[str, Any]]]:
    """Every message of the recording as (run time s, topic, value), in time order."""
    cols = _Columns(rec)
    items = [
        (float(cols.t_s[row]), topic, value)
        for row in range(len(cols.t_s))
        for topic, value in _row_messages(cols, row, rec.mode)
    ]
    items += [(t, f"{NS}/path", v) for t, v in _path_messages(cols)]
    items += [(t, "/diagnostics", v) for t, v in _diagnostics(cols, rec.mode, vessel)]
    lines = [*flag_lines(cols), *logs]
    for t, fault, line in fault_messages(rec):
        items.append((t, f"{NS}/fault/inject", ros2.fault_msg(fault)))
        lines.append(line)
    items += [(line.t_s, "/rosout", _log(line)) for line in lines]
    items.sort(key=lambda item: item[0])  # stable: a row's messages keep their order
    return items


def write_mcap(
    rec: RunRecord,
    path: Path,
    *,
    vessel: str = "ftcap",
    logs: Iterable[LogLine] = (),
    start_ns: int = 0,
) -> dict[str, int]:
    """Write the recording of ``rec`` to ``path``; returns the message count per topic."""
    from mcap.writer import Writer  # the mcap package, only for recordings

    path.parent.mkdir(parents=True, exist_ok=True)
    reg = registry()
    counts = dict.fromkeys(CHANNELS, 0)
    with open(path, "wb") as fh:
        writer = Writer(fh, enable_data_crcs=True)
        writer.start(profile="ros2", library="ftcap-hil")
        channels = {}
        for topic, type_name in CHANNELS.items():
            schema = writer.register_schema(
                type_name, "ros2msg", reg.schema_text(type_name).encode()
            )
            channels[topic] = writer.register_channel(topic, "cdr", schema)
        for t, topic, value in timeline(rec, vessel, logs):
            stamp = start_ns + int(round(t * 1e9))
            counts[topic] += 1
            writer.add_message(
                channels[topic],
                stamp,
                cdr.encode(reg, CHANNELS[topic], value),
                stamp,
                counts[topic],
            )
        writer.finish()
    return counts


MCAP_NAME = "run.mcap"


def write_recordings(
    records: dict[str, RunRecord], out_dir: Path, vessel: str = "ftcap"
) -> list[Path]:
    """``out_dir/<mode>/run.mcap`` beside each record's ``timeseries.csv``; their paths."""
    paths = []
    for mode, rec in records.items():
        path = out_dir / mode / MCAP_NAME
        write_mcap(rec, path, vessel=vessel)
        paths.append(path)
    return paths
