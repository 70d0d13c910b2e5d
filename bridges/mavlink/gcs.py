"""Ground-station MAVLink adapter: watches the vessel and the allocator, sends setpoints,
injects faults and sets parameters.

In (dispatch thread; sources filtered by ``vessel_ids`` / ``allocator_ids``):

* ``ODOMETRY`` (vessel) -> ``odometry: Mailbox[Odometry]``
* ``FTCAP_THRUST`` (allocator) -> ``thruster_commands: Mailbox[ThrusterCommand]``
  (the first ``n_thrusters`` forces, N; ACTUATOR_OUTPUT_STATUS carries them normalised)
* ``FTCAP_STATUS`` (allocator) -> ``allocator_status: Mailbox[AllocatorStatus]``
* ``FTCAP_ESC_STATUS`` (allocator) -> ``esc_status: Mailbox[EscReport]`` (rpm, current, age
  per thruster as the allocator sees its ESCs; NaN = unknown, inf age = never heard)
* ``HEARTBEAT`` (anyone) -> :meth:`heartbeat`; ``STATUSTEXT`` (anyone, chunks reassembled)
  -> ``statustexts`` queue; ``PARAM_VALUE`` -> :meth:`params_of`; ``COMMAND_ACK`` -> the
  waiting :meth:`inject_failure` / :meth:`command`.

Only the vehicle's systems (those of ``allocator_ids`` and ``vessel_ids``) are listened to.
Integer parameters are decoded byte-wise, as the components advertise
(:mod:`bridges.mavlink.params`), and set the same way.

Out: :meth:`send_wrench` (WRENCH_SETPOINT), :meth:`send_manual` (MANUAL_CONTROL),
:meth:`inject_failure` (COMMAND_LONG MAV_CMD_INJECT_FAILURE, waits for COMMAND_ACK),
:meth:`fetch_params` / :meth:`set_param` (parameter protocol, waits for PARAM_VALUE).
The blocking calls are for the ground-station script, never for a control loop.
"""

from __future__ import annotations

import math
import queue
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from bridges.mavlink.allocator_params import CODE_OF_MODE, MODE_CODES
from bridges.mavlink.codec import (
    Severity,
    SystemStatus,
    bits,
    odometry_from_message,
    status_from_message,
)
from bridges.mavlink.commands import MavResult
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint, default_gcs_endpoint
from bridges.mavlink.link import MavlinkPort, PortOwner, Route
from bridges.mavlink.params import int_from_either, int_to_wire
from bridges.mavlink.peers import TrafficLimits
from bridges.mavlink.vessel import (
    FAILURE_ENABLE_PARAM,
    FAILURE_TYPE_OF,
    FAILURE_UNIT_SYSTEM_MOTOR,
    HOLD_PARAM,
    MAV_CMD_INJECT_FAILURE,
)
from ftcap_hil.core.messages import FaultKind, Odometry, ThrusterCommand, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus, Mode
from ftcap_hil.ports.ground_link import ParamWrite, StatusText
from ftcap_hil.ports.mailbox import Mailbox, Stamped

Ids = tuple[int, int]
_MAV_PARAM_TYPE_REAL32 = 9
_MAV_PARAM_TYPE_INT32 = 6
_STARTING = (SystemStatus.UNINIT, SystemStatus.BOOT)


@dataclass(frozen=True)
class Heartbeat:
    """One HEARTBEAT's MAV_TYPE, MAV_AUTOPILOT and MAV_STATE (``system_status``)."""

    mav_type: int
    autopilot: int
    system_status: int


@dataclass(frozen=True)
class EscReport:
    """FTCAP_ESC_STATUS: per-thruster rpm, current (A), age (s) and the failed flags."""

    rpm: tuple[float, ...]
    current_a: tuple[float, ...]
    age_s: tuple[float, ...]
    failed: tuple[bool, ...]


class MavlinkGcsLink(PortOwner):
    """The ground station's MAVLink port; see the module docstring."""

    def __init__(
        self,
        endpoint: MavlinkEndpoint | None = None,
        *,
        allocator_ids: Ids = ALLOCATOR_IDS,
        vessel_ids: Ids = VESSEL_IDS,
        poll_s: float = 0.05,
        heartbeat_period_s: float = 1.0,
        limits: TrafficLimits | None = None,
    ) -> None:
        self.allocator_ids = allocator_ids
        self.vessel_ids = vessel_ids
        self.odometry: Mailbox[Odometry] = Mailbox("mavlink.gcs.odometry")
        self.thruster_commands: Mailbox[ThrusterCommand] = Mailbox("mavlink.gcs.thrusters")
        self.allocator_status: Mailbox[AllocatorStatus] = Mailbox("mavlink.gcs.status")
        self.esc_status: Mailbox[EscReport] = Mailbox("mavlink.gcs.esc")
        self.statustexts: queue.Queue[Stamped[StatusText]] = queue.Queue(256)
        self._cond = threading.Condition()
        self._heartbeats: dict[Ids, Stamped[Heartbeat]] = {}
        self._params: dict[Ids, dict[str, tuple[float, int, int, int]]] = {}
        self._acks: dict[tuple[Ids, int], MavResult] = {}
        self._chunks: dict[tuple[int, int, int], list[str]] = {}
        self._command_lock = threading.Lock()
        routes = {
            "ODOMETRY": Route(self._on_odometry, self.odometry),
            "FTCAP_THRUST": Route(self._on_thrust, self.thruster_commands),
            "FTCAP_STATUS": Route(self._on_status, self.allocator_status),
            "FTCAP_ESC_STATUS": Route(self._on_esc, self.esc_status),
            "HEARTBEAT": Route(self._on_heartbeat),
            "STATUSTEXT": Route(self._on_statustext),
            "PARAM_VALUE": Route(self._on_param_value),
            "COMMAND_ACK": Route(self._on_command_ack),
        }
        self._port = MavlinkPort(
            endpoint or default_gcs_endpoint(),
            role="gcs",
            mav_type="MAV_TYPE_GCS",
            routes=routes,
            default_authorized=(allocator_ids[0], vessel_ids[0]),
            heartbeat_period_s=heartbeat_period_s,
            poll_s=poll_s,
            limits=limits,
        )

    # --- dispatch thread ---

    @staticmethod
    def _src(msg: Any) -> Ids:
        return msg.get_srcSystem(), msg.get_srcComponent()

    def _from(self, msg: Any, ids: Ids) -> bool:
        if self._src(msg) == ids:
            return True
        self._port.stats.ignored += 1
        return False

    def _on_odometry(self, msg: Any, now_ns: int) -> None:
        if self._from(msg, self.vessel_ids):
            self.odometry.put(odometry_from_message(msg, self._port.dialect))

    def _on_thrust(self, msg: Any, now_ns: int) -> None:
        if self._from(msg, self.allocator_ids):
            n = int(msg.n_thrusters)
            self.thruster_commands.put(ThrusterCommand.checked(msg.u[:n]))

    def _on_status(self, msg: Any, now_ns: int) -> None:
        if self._from(msg, self.allocator_ids):
            self.allocator_status.put(status_from_message(msg))

    def _on_esc(self, msg: Any, now_ns: int) -> None:
        if self._from(msg, self.allocator_ids):
            n = int(msg.n_thrusters)
            failed = bits(int(msg.failed), n)
            self.esc_status.put(
                EscReport(tuple(msg.rpm[:n]), tuple(msg.current[:n]), tuple(msg.age[:n]), failed)
            )

    def _on_heartbeat(self, msg: Any, now_ns: int) -> None:
        beat = Heartbeat(msg.type, msg.autopilot, msg.system_status)
        with self._cond:
            self._heartbeats[self._src(msg)] = Stamped(beat, now_ns)
            self._cond.notify_all()

    def _on_statustext(self, msg: Any, now_ns: int) -> None:
        system, component = self._src(msg)
        if msg.id == 0:
            text = msg.text
        else:  # MAVLink 2 chunked text: a chunk shorter than 50 characters ends it
            key = (system, component, msg.id)
            parts = self._chunks.setdefault(key, [])
            parts.append(msg.text)
            if len(msg.text) >= 50 and len(self._chunks) <= 16:
                return
            text = "".join(self._chunks.pop(key))
        item = StatusText(system, component, Severity(msg.severity), text)
        try:
            self.statustexts.put_nowait(Stamped(item, now_ns))
        except queue.Full:
            self._port.stats.ignored += 1

    def _on_param_value(self, msg: Any, now_ns: int) -> None:
        value = float(msg.param_value)
        if msg.param_type == _MAV_PARAM_TYPE_INT32:
            value = float(int_from_either(value))  # C-cast when it answers a C-cast set
        entry = (value, msg.param_type, msg.param_index, msg.param_count)
        with self._cond:
            self._params.setdefault(self._src(msg), {})[msg.param_id] = entry
            self._cond.notify_all()

    def _on_command_ack(self, msg: Any, now_ns: int) -> None:
        if not self._port.accepts(msg.target_system, msg.target_component):
            return
        with self._cond:
            self._acks[(self._src(msg), msg.command)] = MavResult(msg.result)
            self._cond.notify_all()

    # --- queries ---

    def heartbeat(self, ids: Ids) -> Stamped[Heartbeat] | None:
        """Latest HEARTBEAT from (system, component), stamped on receipt."""
        with self._cond:
            return self._heartbeats.get(ids)

    def params_of(self, ids: Ids) -> dict[str, float]:
        """Parameter values last reported by (system, component)."""
        with self._cond:
            return {name: entry[0] for name, entry in self._params.get(ids, {}).items()}

    def wait_heartbeat(self, ids: Ids, timeout_s: float = 3.0) -> bool:
        """Block until a HEARTBEAT from ``ids`` has been heard (True) or ``timeout_s`` passes."""
        with self._cond:
            return self._cond.wait_for(lambda: ids in self._heartbeats, timeout_s)

    def wait_ready(self, ids: Ids, timeout_s: float = 3.0) -> bool:
        """A HEARTBEAT from ``ids`` whose system_status is past start-up (not UNINIT/BOOT).

        The allocator's link heartbeats as BOOT until its control loop runs its first cycle.
        """

        def ready() -> bool:
            beat = self._heartbeats.get(ids)
            return beat is not None and beat.value.system_status not in _STARTING

        with self._cond:
            return self._cond.wait_for(ready, timeout_s)

    # --- sending ---

    def send_wrench(self, tau: Sequence[float], target: Ids | None = None) -> bool:
        """WRENCH_SETPOINT [X (N), Y (N), N (N*m)], body frame, to the allocator."""
        setpoint = WrenchSetpoint.checked(tau)  # refuse to send garbage
        system, component = target or self.allocator_ids
        x, y, n = (float(v) for v in setpoint.tau)
        stamp = self._port.time_boot_ms()
        return self._port.send(
            lambda mav: mav.wrench_setpoint_send(stamp, system, component, x, y, n)
        )

    def send_manual(self, x: int, y: int, r: int, target_system: int | None = None) -> bool:
        """MANUAL_CONTROL with normalized axes in [-1000, 1000] (z = 0, no buttons)."""
        if not all(-1000 <= a <= 1000 for a in (x, y, r)):
            raise ValueError(f"manual control axes must be in [-1000, 1000], got {(x, y, r)}")
        system = self.allocator_ids[0] if target_system is None else target_system
        return self._port.send(lambda mav: mav.manual_control_send(system, x, y, 0, r, 0))

    def inject_failure(
        self,
        kind: FaultKind,
        thruster: int | None,
        value: float = math.nan,
        *,
        timeout_s: float = 1.0,
        attempts: int = 3,
    ) -> MavResult | None:
        """MAV_CMD_INJECT_FAILURE on the vessel; ``thruster`` is 0-based, None = all.

        Returns the COMMAND_ACK result, or None if no ACK arrived after ``attempts`` sends.
        """
        instance = 0 if thruster is None else thruster + 1
        failure_type = int(FAILURE_TYPE_OF[kind])
        key = (self.vessel_ids, MAV_CMD_INJECT_FAILURE)
        system, component = self.vessel_ids
        with self._command_lock:
            with self._cond:
                self._acks.pop(key, None)
            for confirmation in range(attempts):

                def build(mav: Any, confirmation: int = confirmation) -> None:
                    mav.command_long_send(
                        system, component, MAV_CMD_INJECT_FAILURE, confirmation,
                        FAILURE_UNIT_SYSTEM_MOTOR, failure_type, instance, value, 0, 0, 0,
                    )  # fmt: skip

                self._port.send(build)
                with self._cond:
                    if self._cond.wait_for(lambda: key in self._acks, timeout_s):
                        return self._acks.pop(key)
        return None

    def request_params(self, ids: Ids) -> bool:
        """PARAM_REQUEST_LIST to ``ids``, not waiting (the answers reach :meth:`params_of`)."""
        return self._port.send(lambda mav: mav.param_request_list_send(ids[0], ids[1]))

    def fetch_params(self, ids: Ids, timeout_s: float = 2.0) -> dict[str, float]:
        """PARAM_REQUEST_LIST and wait until all ``param_count`` values arrived (or timeout)."""

        def complete() -> bool:
            entries = self._params.get(ids, {})
            counts = {e[3] for e in entries.values()}
            return len(counts) == 1 and len({e[2] for e in entries.values()}) >= counts.pop()

        with self._cond:
            self._params.pop(ids, None)
        self.request_params(ids)
        with self._cond:
            self._cond.wait_for(complete, timeout_s)
        return self.params_of(ids)

    def set_param(
        self, ids: Ids, name: str, value: float, *, timeout_s: float = 1.0, attempts: int = 3
    ) -> float | None:
        """PARAM_SET; returns the value the component reports back (unchanged if refused)."""
        with self._cond:
            known = self._params.get(ids, {}).pop(name, None)
        ptype = known[1] if known is not None else _MAV_PARAM_TYPE_REAL32
        wire = value
        if ptype == _MAV_PARAM_TYPE_INT32:
            if not float(value).is_integer():
                raise ValueError(f"{name} is an integer parameter, got {value!r}")
            wire = int_to_wire(int(value))
        raw = name.encode("ascii")
        for _ in range(attempts):
            self._port.send(lambda mav: mav.param_set_send(ids[0], ids[1], raw, wire, ptype))
            with self._cond:
                if self._cond.wait_for(lambda: name in self._params.get(ids, {}), timeout_s):
                    return self._params[ids][name][0]
        return None

    # --- in the project's terms (ftcap_hil.ports.ground_link.GroundLink) ---

    def allow_fault_injection(self, *, timeout_s: float = 1.0) -> ParamWrite:
        """SYS_FAILURE_EN = 1 on the vessel, and what it reports back."""
        name, value = FAILURE_ENABLE_PARAM, 1
        return ParamWrite(
            name, value, self.set_param(self.vessel_ids, name, value, timeout_s=timeout_s)
        )

    def release_vessel(self, *, timeout_s: float = 1.0) -> ParamWrite:
        """SIM_HOLD = 0 on the vessel (a held simulated vessel starts), and its answer."""
        name, value = HOLD_PARAM, 0
        return ParamWrite(
            name, value, self.set_param(self.vessel_ids, name, value, timeout_s=timeout_s)
        )

    def request_mode(self, mode: Mode, *, timeout_s: float = 1.0) -> ParamWrite:
        """FTC_MODE = ``mode``'s code on the allocator, and what it reports back."""
        ids, value = self.allocator_ids, CODE_OF_MODE[mode]
        return ParamWrite(
            "FTC_MODE", value, self.set_param(ids, "FTC_MODE", value, timeout_s=timeout_s)
        )

    def read_mode(self, *, timeout_s: float = 2.0) -> Mode | None:
        """The allocator's mode from its FTC_MODE (None: not reported within ``timeout_s``;
        KeyError: a code no mode has)."""
        params = self.fetch_params(self.allocator_ids, timeout_s=timeout_s)
        return MODE_CODES[int(params["FTC_MODE"])] if "FTC_MODE" in params else None

    def drain_statustexts(self) -> list[Stamped[StatusText]]:
        """Every STATUSTEXT received since the last drain, oldest first."""
        out: list[Stamped[StatusText]] = []
        while True:
            try:
                out.append(self.statustexts.get_nowait())
            except queue.Empty:
                return out
