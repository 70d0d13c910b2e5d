"""Allocator-side MAVLink adapter: setpoints and telemetry in, thruster commands and status out.

In (dispatch thread -> mailboxes; invalid input is counted in the mailbox and dropped):

* ``ODOMETRY`` from the vessel -> ``odometry: Mailbox[Odometry]`` (eta = [x, y, yaw(q)] in
  NED, nu = [vx, vy, yawspeed] in body FRD), only with the vessel's ids
  (``telemetry_source``) and from the vessel's inbox address (``telemetry_from``, default
  the endpoint's ``relay``; no address: no MAVLink telemetry). Anything else is counted in
  ``stats.ignored`` (wrong ids) or ``stats.wrong_source`` (wrong address): a process that
  claims the vessel's ids from another UDP port is not the vessel.
* ``WRENCH_SETPOINT`` -> ``setpoint: Mailbox[WrenchSetpoint]``; a component beyond
  ``wrench_limit`` counts as malformed.
* ``MANUAL_CONTROL`` -> ``manual: Mailbox[WrenchSetpoint]``, tau = [x, y, r] / 1000 *
  ``max_wrench``. x > 0 is surge ahead, y > 0 sway to starboard, r > 0 yaw to starboard
  (clockwise from above), as PX4, ArduPilot and QGroundControl read it (docs/decisions.md).
  An axis equal to INT16_MAX ("invalid") contributes 0; any other value outside
  [-1000, 1000] drops the message.
  Manual and automatic setpoints get separate mailboxes: the daemon decides who wins.
* ``PARAM_*``: the parameter protocol on the table given to the constructor
  (:mod:`bridges.mavlink.params`); ``COMMAND_LONG`` / ``COMMAND_INT``: every command
  addressed to this component is acknowledged (:mod:`bridges.mavlink.commands`; none but
  the AUTOPILOT_VERSION request is supported: UNSUPPORTED).
* Setpoints, parameters and commands are obeyed only from authorized systems
  (``MavlinkEndpoint.authorized_systems``, default the ground station 255); others are
  counted in ``stats.unauthorized`` (and a command gets DENIED).

Out (called from the loop thread; each returns False instead of raising on transport errors):

* ``HEARTBEAT`` at 1 Hz from the dispatch thread (MAV_TYPE_ONBOARD_CONTROLLER,
  MAV_AUTOPILOT_INVALID), status from :meth:`set_system_status`. It starts as
  ``MAV_STATE_BOOT``: the link (and the parameter protocol) is up before the control loop
  runs, and a ground station must not take the heartbeat alone for "allocating". The daemon
  reports ``STANDBY`` (setpoint stale: zero thrust) or ``ACTIVE`` (allocating) from its
  first cycle on.
* :meth:`send_thruster_commands` -> ``ACTUATOR_OUTPUT_STATUS`` with the normalised outputs
  ``actuator[i]`` = u_i / u_max_i clipped to [-1, 1] (0-based vessel-file order, bit i of
  ``active`` set for i < n_thrusters; not sent when ``u_max`` is not configured), and
  ``FTCAP_THRUST`` with u in N.
* :meth:`send_status` -> ``FTCAP_STATUS`` (our dialect): tau demand / unallocated and the
  per-thruster ``delta_hat`` (with ``delta_hat_std``) and ``f_hat`` (N) of one cycle, the
  :class:`StatusFlag` bits and per-thruster faulty / saturated / probing masks (MAVLink 2
  extension fields).
* :meth:`send_esc_status` -> ``FTCAP_ESC_STATUS`` and the standard ``ESC_STATUS`` (every
  call) and ``ESC_INFO`` (at most once a second), four ESCs per message.
* :meth:`send_statustext` -> ``STATUSTEXT``, for the daemon to call on transitions.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bridges.mavlink.codec import (
    MAX_THRUSTERS,
    SystemStatus,
    bitmask,
    dialect_message,
    odometry_from_message,
    padded,
    status_fields,
)
from bridges.mavlink.commands import CommandService
from bridges.mavlink.config import (
    VESSEL_IDS,
    MavlinkEndpoint,
    default_allocator_endpoint,
)
from bridges.mavlink.errors import LinkConfigError
from bridges.mavlink.esc import EscInfoClock, send_standard_esc
from bridges.mavlink.link import MavlinkPort, PortOwner, Route
from bridges.mavlink.params import ParamServer, ParamService, ParamSpec
from bridges.mavlink.peers import TrafficLimits
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import Odometry, ThrusterCommand, WrenchSetpoint
from ftcap_hil.core.status import AllocatorStatus
from ftcap_hil.ports.mailbox import Mailbox

MANUAL_FULL_SCALE = 1000
_INT16_MAX = 32767


def _positive_triple(key: str, value: object) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise LinkConfigError(f"{key}: expected 3 positive numbers, got {value!r}") from e
    if arr.shape != (3,) or not np.all(np.isfinite(arr)) or not np.all(arr > 0):
        raise LinkConfigError(f"{key}: expected 3 positive finite numbers, got {value!r}")
    return float(arr[0]), float(arr[1]), float(arr[2])


@dataclass(frozen=True)
class AllocatorLinkConfig:
    """Limits of the allocator link.

    max_wrench: tau for a full MANUAL_CONTROL deflection [X (N), Y (N), N (N*m)].
    wrench_limit: WRENCH_SETPOINT components beyond +-this are dropped as malformed
        (default 10 x max_wrench: a sanity bound, not the vessel's capability, since the
        allocator itself reports what it cannot meet).
    telemetry_source: (system, component) ODOMETRY is accepted from; None accepts any.
    telemetry_from: ``host:port`` inboxes ODOMETRY is accepted from (None: the endpoint's
        ``relay``, the vessel's inbox; empty: none).
    u_max: per-thruster force (N) that an ACTUATOR_OUTPUT_STATUS output of 1 stands for
        (the vessel file's u_max); None: ACTUATOR_OUTPUT_STATUS is not sent.
    """

    n_thrusters: int
    max_wrench: tuple[float, float, float]
    wrench_limit: tuple[float, float, float] | None = None
    telemetry_source: tuple[int, int] | None = VESSEL_IDS
    u_max: tuple[float, ...] | None = None
    telemetry_from: tuple[str, ...] | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.n_thrusters, int) or not 1 <= self.n_thrusters <= MAX_THRUSTERS:
            raise LinkConfigError(
                f"n_thrusters: expected an integer in 1..{MAX_THRUSTERS}, got {self.n_thrusters!r}"
            )
        object.__setattr__(self, "max_wrench", _positive_triple("max_wrench", self.max_wrench))
        limit: object = self.wrench_limit
        if limit is None:
            limit = [10.0 * w for w in self.max_wrench]
        object.__setattr__(self, "wrench_limit", _positive_triple("wrench_limit", limit))
        if self.u_max is not None:
            arr = np.asarray(self.u_max, dtype=np.float64)
            if arr.shape != (self.n_thrusters,) or not np.all(np.isfinite(arr) & (arr > 0)):
                raise LinkConfigError(
                    f"u_max: expected {self.n_thrusters} positive forces (N), got {self.u_max!r}"
                )
            object.__setattr__(self, "u_max", tuple(arr.tolist()))


def wrench_from_manual(msg: Any, max_wrench: Sequence[float]) -> WrenchSetpoint:
    """MANUAL_CONTROL (x, y, r in +-1000; INT16_MAX = axis invalid = 0) -> scaled wrench."""
    axes = []
    for name in ("x", "y", "r"):
        raw = int(getattr(msg, name))
        if raw == _INT16_MAX:
            raw = 0
        if not -MANUAL_FULL_SCALE <= raw <= MANUAL_FULL_SCALE:
            raise MalformedMessage(f"MANUAL_CONTROL {name}={raw} outside +-{MANUAL_FULL_SCALE}")
        axes.append(raw / MANUAL_FULL_SCALE)
    return WrenchSetpoint.checked(np.asarray(axes) * np.asarray(max_wrench))


def wrench_from_setpoint(msg: Any, limit: Sequence[float]) -> WrenchSetpoint:
    """WRENCH_SETPOINT -> WrenchSetpoint; non-finite or beyond +-limit raises MalformedMessage."""
    setpoint = WrenchSetpoint.checked([msg.surge, msg.sway, msg.yaw])
    if np.any(np.abs(setpoint.tau) > np.asarray(limit)):
        raise MalformedMessage(f"WRENCH_SETPOINT {setpoint.tau.tolist()} beyond +-{list(limit)}")
    return setpoint


class MavlinkAllocatorLink(PortOwner):
    """The allocator daemon's MAVLink port; see the module docstring.

    Mailboxes: ``odometry``, ``setpoint``, ``manual``. Parameters: ``params`` (a
    :class:`ParamServer` over ``param_specs``). Start-up errors raise ``LinkConfigError``.
    """

    def __init__(
        self,
        config: AllocatorLinkConfig,
        endpoint: MavlinkEndpoint | None = None,
        param_specs: Sequence[ParamSpec] = (),
        *,
        poll_s: float = 0.05,
        heartbeat_period_s: float = 1.0,
        limits: TrafficLimits | None = None,
        odometry: Mailbox[Odometry] | None = None,
    ) -> None:
        self.config = config
        self.odometry: Mailbox[Odometry] = odometry or Mailbox("mavlink.odometry")
        self.setpoint: Mailbox[WrenchSetpoint] = Mailbox("mavlink.wrench_setpoint")
        self.manual: Mailbox[WrenchSetpoint] = Mailbox("mavlink.manual_control")
        self.params = ParamServer(param_specs)
        self._param_service = ParamService(self.params)
        self.commands = CommandService()
        self._esc_info = EscInfoClock()
        routes = {
            "ODOMETRY": Route(self._on_odometry, self.odometry),
            "WRENCH_SETPOINT": Route(self._on_wrench, self.setpoint),
            "MANUAL_CONTROL": Route(self._on_manual, self.manual),
            **self._param_service.routes(),
            **self.commands.routes(),
        }
        self._port = MavlinkPort(
            endpoint or default_allocator_endpoint(),
            role="allocator",
            mav_type="MAV_TYPE_ONBOARD_CONTROLLER",
            routes=routes,
            status=SystemStatus.BOOT,
            heartbeat_period_s=heartbeat_period_s,
            poll_s=poll_s,
            limits=limits,
        )
        self._param_service.attach(self._port)
        self.commands.attach(self._port)
        inboxes = config.telemetry_from
        try:
            self._telemetry_from = frozenset(
                self._port.resolve("telemetry_from", self._port.endpoint.relay)
                if inboxes is None
                else self._port.resolve("telemetry_from", inboxes)
            )
        except LinkConfigError:
            self._port.shutdown()
            raise
        self._active_mask = (1 << config.n_thrusters) - 1

    @property
    def telemetry_from(self) -> frozenset[tuple[str, int]]:
        """The source addresses ODOMETRY is accepted from (empty: none)."""
        return self._telemetry_from

    # --- dispatch thread ---

    def _on_odometry(self, msg: Any, now_ns: int) -> None:
        source = self.config.telemetry_source
        if source is not None and (msg.get_srcSystem(), msg.get_srcComponent()) != source:
            self._port.stats.ignored += 1
            return
        if self._port.source not in self._telemetry_from:
            self._port.stats.wrong_source += 1
            return
        self.odometry.put(odometry_from_message(msg, self._port.dialect))

    def _on_wrench(self, msg: Any, now_ns: int) -> None:
        if not self._port.accepts(msg.target_system, msg.target_component):
            return
        if not self._port.authorized(msg):
            return
        assert self.config.wrench_limit is not None  # filled in by __post_init__
        self.setpoint.put(wrench_from_setpoint(msg, self.config.wrench_limit))

    def _on_manual(self, msg: Any, now_ns: int) -> None:
        if not self._port.accepts(msg.target):
            return
        if not self._port.authorized(msg):
            return
        self.manual.put(wrench_from_manual(msg, self.config.max_wrench))

    # --- loop thread ---

    def send_thruster_commands(self, command: ThrusterCommand) -> bool:
        """FTCAP_THRUST with u (N) and ACTUATOR_OUTPUT_STATUS with u / u_max in [-1, 1]."""
        u = np.asarray(command.u, dtype=np.float64)
        n = self.config.n_thrusters
        if u.shape != (n,):
            raise ValueError(f"thruster command: expected shape ({n},)")
        fields = {"time_boot_ms": self._port.time_boot_ms(), "u": u, "n_thrusters": n}
        thrust = dialect_message(self._port.dialect, "FTCAP_THRUST", fields)
        ok = self._port.send(lambda mav: mav.send(thrust))
        if self.config.u_max is None:
            return ok
        outputs = padded(np.clip(u / np.asarray(self.config.u_max), -1.0, 1.0), 32, "actuator")
        stamp = self._port.time_boot_us()
        mask = self._active_mask
        return (
            self._port.send(lambda mav: mav.actuator_output_status_send(stamp, mask, outputs))
            and ok
        )

    def send_status(self, status: AllocatorStatus) -> bool:
        """FTCAP_STATUS for one cycle (the daemon decimates): the status's fields by name
        (:func:`~bridges.mavlink.codec.status_fields`) as the dialect lays them out."""
        fields = status_fields(status, self._port.time_boot_ms())
        msg = dialect_message(self._port.dialect, "FTCAP_STATUS", fields)
        return self._port.send(lambda mav: mav.send(msg))

    def send_esc_status(
        self,
        rpm: Sequence[float],
        current: Sequence[float],
        age: Sequence[float],
        failed: Sequence[bool],
        voltage: Sequence[float] = (),
    ) -> bool:
        """FTCAP_ESC_STATUS: per-thruster ESC telemetry (NaN = unknown, +inf age = never),
        and the standard ESC_STATUS (with ``voltage`` in V) / ESC_INFO."""
        n = self.config.n_thrusters
        fields = {
            "time_boot_ms": self._port.time_boot_ms(),
            "rpm": rpm,
            "current": current,
            "age": age,
            "failed": bitmask(tuple(failed)),
            "n_thrusters": n,
        }
        msg = dialect_message(self._port.dialect, "FTCAP_ESC_STATUS", fields)
        ok = self._port.send(lambda mav: mav.send(msg))
        standard = send_standard_esc(
            self._port, rpm, current, age, failed, n, self._esc_info, voltage
        )
        return standard and ok

    def set_system_status(self, status: SystemStatus) -> None:
        """MAV_STATE reported by the HEARTBEAT from now on (a change is sent at once)."""
        self._port.set_system_status(status)
