"""Vessel-side MAVLink adapter: odometry and the standard position messages out, fault
injection in.

Out (:meth:`MavlinkVesselLink.send_odometry`, at the sim rate): ``ODOMETRY`` (for the
allocator), and for a ground station's map and instruments ``ATTITUDE`` (roll = pitch = 0,
yaw = psi), ``LOCAL_POSITION_NED`` (x = north, y = east, NED velocities) and, when a
``geodetic_origin`` is configured, ``GLOBAL_POSITION_INT`` (flat-earth conversion around
it, :mod:`bridges.mavlink.geodesy`; heading = psi). A 1 Hz ``HEARTBEAT``
(MAV_TYPE_SURFACE_BOAT, MAV_AUTOPILOT_GENERIC).

In: commands through :class:`~bridges.mavlink.commands.CommandService` (every command
addressed to this component is acknowledged; AUTOPILOT_VERSION on request):
``MAV_CMD_INJECT_FAILURE`` -> ``faults`` (a queue, not a latest-value mailbox: two
injections in a row must both arrive). Only authorized systems may inject or set
parameters (others: DENIED). The parameter protocol serves ``SYS_FAILURE_EN`` (int, 0/1,
default 0, as in PX4) plus any extra parameters given.

MAV_CMD_INJECT_FAILURE, as interpreted here:

* param1 failure unit: only ``FAILURE_UNIT_SYSTEM_MOTOR`` (101); others -> UNSUPPORTED.
* param3 instance: 0 = all thrusters (one FaultInjection per thruster), 1..m = thruster
  instance - 1 (MAVLink instances are 1-based, :class:`FaultInjection.index` is 0-based);
  anything else -> DENIED.
* param4 value (our extension; MAVLink leaves it unused). **0 or NaN means the default**:
  standard clients send 0 for an unused parameter (MAVProxy's ``long INJECT_FAILURE 101 2
  1`` does), and 0 is never a useful value here: a 0 N bias changes nothing, a thruster stuck
  at 0 N is OFF, a WEAK thruster with delta 0 is OFF. The defaults are the simulator's
  (FaultInjection value NaN): STUCK holds the force the thruster produced at that moment,
  WRONG adds ``sim.default_bias_n``, SLOW scales by ``sim.default_weak_delta``.
* param2 failure type -> FaultKind:

  ======================= =========== ================================================
  FAILURE_TYPE            FaultKind   param4 (value; 0 or NaN: the default above)
  ======================= =========== ================================================
  OK (0)                  OK          ignored (clears the fault)
  OFF (1)                 OFF         ignored
  STUCK (2)               STUCK       force held (N)
  WRONG (4)               BIAS        additive force (N)
  SLOW (5)                WEAK        effectiveness delta in (0, 1], else DENIED
  GARBAGE (3), DELAYED    --          UNSUPPORTED
  (6), INTERMITTENT (7)
  ======================= =========== ================================================

Result order (as PX4): not an authorized system -> DENIED; SYS_FAILURE_EN == 0 -> DENIED;
unsupported unit or type -> UNSUPPORTED; bad instance or value -> DENIED; fault queue full
-> TEMPORARILY_REJECTED; otherwise ACCEPTED.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from bridges.mavlink.codec import Severity, SystemStatus, quaternion_from_yaw
from bridges.mavlink.commands import CommandService, MavResult
from bridges.mavlink.config import MavlinkEndpoint, default_vessel_endpoint
from bridges.mavlink.geodesy import GeodeticOrigin
from bridges.mavlink.link import MavlinkPort, PortOwner
from bridges.mavlink.params import ParamServer, ParamService, ParamSpec, ParamType
from bridges.mavlink.peers import TrafficLimits
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry
from ftcap_hil.ports.mailbox import EventQueue, Stamped

MAV_CMD_INJECT_FAILURE = 420
FAILURE_UNIT_SYSTEM_MOTOR = 101
FAILURE_ENABLE_PARAM = "SYS_FAILURE_EN"
HOLD_PARAM = "SIM_HOLD"  # a simulated vessel's: 1 waits at sim time 0, 0 starts it (sim.hold)


class FailureType(enum.IntEnum):
    """FAILURE_TYPE of MAV_CMD_INJECT_FAILURE (param2)."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


FAULT_KIND_OF: dict[FailureType, FaultKind] = {
    FailureType.OK: FaultKind.OK,
    FailureType.OFF: FaultKind.OFF,
    FailureType.STUCK: FaultKind.STUCK,
    FailureType.WRONG: FaultKind.BIAS,
    FailureType.SLOW: FaultKind.WEAK,
}
FAILURE_TYPE_OF: dict[FaultKind, FailureType] = {k: t for t, k in FAULT_KIND_OF.items()}


@dataclass(frozen=True)
class InjectDecision:
    """How to answer one MAV_CMD_INJECT_FAILURE: the result, the faults to apply if
    ACCEPTED, and the reason if not."""

    result: MavResult
    faults: tuple[FaultInjection, ...] = ()
    reason: str = ""


def decode_inject_failure(
    unit: float, failure_type: float, instance: float, value: float, n_thrusters: int
) -> InjectDecision:
    """Map MAV_CMD_INJECT_FAILURE params 1-4 to FaultInjections (see the module table)."""
    unit, failure_type, instance, value = (float(p) for p in (unit, failure_type, instance, value))
    if unit != FAILURE_UNIT_SYSTEM_MOTOR:
        return InjectDecision(MavResult.UNSUPPORTED, reason=f"failure unit {unit:g}")
    try:
        if not failure_type.is_integer():
            raise ValueError(failure_type)
        kind = FAULT_KIND_OF[FailureType(int(failure_type))]
    except (ValueError, KeyError, OverflowError):
        return InjectDecision(MavResult.UNSUPPORTED, reason=f"failure type {failure_type:g}")
    if not (math.isfinite(instance) and instance.is_integer() and 0 <= instance <= n_thrusters):
        return InjectDecision(
            MavResult.DENIED, reason=f"instance {instance:g} not in 0..{n_thrusters}"
        )
    if kind is FaultKind.WEAK and not (math.isnan(value) or 0.0 <= value <= 1.0):
        return InjectDecision(MavResult.DENIED, reason=f"delta {value:g} not in (0, 1]")
    if math.isinf(value):
        return InjectDecision(MavResult.DENIED, reason="value is infinite")
    if kind in (FaultKind.OK, FaultKind.OFF) or value == 0.0:
        value = math.nan  # ignored, or the default (module docstring)
    indices = range(n_thrusters) if instance == 0 else (int(instance) - 1,)
    faults = tuple(FaultInjection(i, kind, value) for i in indices)
    return InjectDecision(MavResult.ACCEPTED, faults)


class MavlinkVesselLink(PortOwner):
    """The simulated vessel's MAVLink port; see the module docstring.

    ``faults``: queue of ``Stamped[FaultInjection]``, drained by the sim loop
    (:meth:`drain_faults`). ``params``: SYS_FAILURE_EN plus ``extra_params``.
    ``geodetic_origin``: where NED (0, 0) is on the Earth (default: the endpoint's
    ``geodetic_origin``; None: no GLOBAL_POSITION_INT).
    """

    def __init__(
        self,
        n_thrusters: int,
        endpoint: MavlinkEndpoint | None = None,
        extra_params: Sequence[ParamSpec] = (),
        *,
        geodetic_origin: GeodeticOrigin | None = None,
        fault_queue_size: int = 64,
        poll_s: float = 0.05,
        heartbeat_period_s: float = 1.0,
        limits: TrafficLimits | None = None,
    ) -> None:
        if not isinstance(n_thrusters, int) or n_thrusters < 1:
            raise ValueError(f"n_thrusters: expected a positive integer, got {n_thrusters!r}")
        self.n_thrusters = n_thrusters
        endpoint = endpoint or default_vessel_endpoint()
        self.geodetic_origin = geodetic_origin or GeodeticOrigin.from_value(
            endpoint.geodetic_origin
        )
        self.faults: EventQueue[FaultInjection] = EventQueue("mavlink.fault", fault_queue_size)
        enable = ParamSpec(
            FAILURE_ENABLE_PARAM, 0, ParamType.INT, 0, 1, description="allow fault injection"
        )
        self.params = ParamServer([enable, *extra_params])
        self._param_service = ParamService(self.params)
        self.commands = CommandService({MAV_CMD_INJECT_FAILURE: self._on_inject})
        routes = {**self.commands.routes(), **self._param_service.routes()}
        self._port = MavlinkPort(
            endpoint,
            role="vessel",
            mav_type="MAV_TYPE_SURFACE_BOAT",
            autopilot="MAV_AUTOPILOT_GENERIC",
            status=SystemStatus.ACTIVE,
            routes=routes,
            heartbeat_period_s=heartbeat_period_s,
            poll_s=poll_s,
            limits=limits,
        )
        self._param_service.attach(self._port)
        self.commands.attach(self._port)

    @property
    def fault_injection_enabled(self) -> bool:
        return self.params.get(FAILURE_ENABLE_PARAM) == 1

    # --- dispatch thread ---

    def _on_inject(self, msg: Any) -> MavResult:
        decision = self._decide(msg)
        if decision.result is not MavResult.ACCEPTED:
            self._port.send_statustext(
                f"fault injection refused: {decision.reason}", Severity.WARNING
            )
        return decision.result

    def _decide(self, msg: Any) -> InjectDecision:
        if not self.fault_injection_enabled:
            return InjectDecision(MavResult.DENIED, reason=f"{FAILURE_ENABLE_PARAM} is 0")
        decision = decode_inject_failure(
            msg.param1, msg.param2, msg.param3, msg.param4, self.n_thrusters
        )
        if decision.result is not MavResult.ACCEPTED:
            return decision
        if self.faults.room() < len(decision.faults):
            return InjectDecision(MavResult.TEMPORARILY_REJECTED, reason="fault queue full")
        for fault in decision.faults:  # only this thread puts: the room checked above stays
            self.faults.put(fault)
        return decision

    # --- sim thread ---

    def send_odometry(self, odometry: Odometry) -> bool:
        """ODOMETRY (pose in MAV_FRAME_LOCAL_NED, twist in MAV_FRAME_BODY_FRD, 3-DOF) and the
        standard position messages (module docstring). True if all went out.

        ODOMETRY's time_usec is the sim time ``odometry.time_s`` (uptime of the link if NaN).
        """
        eta, nu = odometry.eta, odometry.nu
        t_s = odometry.time_s
        time_usec = int(t_s * 1e6) if math.isfinite(t_s) and t_s >= 0 else self._port.time_boot_us()
        unknown = [math.nan] + [0.0] * 20  # covariance unknown: NaN first element
        d = self._port.dialect
        fields = (
            time_usec, d.MAV_FRAME_LOCAL_NED, d.MAV_FRAME_BODY_FRD,
            float(eta[0]), float(eta[1]), 0.0, quaternion_from_yaw(float(eta[2])),
            float(nu[0]), float(nu[1]), 0.0, 0.0, 0.0, float(nu[2]),
            unknown, unknown,
        )  # fmt: skip
        ok = self._port.send(lambda mav: mav.odometry_send(*fields))
        return self._send_position(odometry) and ok

    def _send_position(self, odometry: Odometry) -> bool:
        north, east, psi = (float(v) for v in odometry.eta)
        u, v, r = (float(x) for x in odometry.nu)
        psi = math.atan2(math.sin(psi), math.cos(psi))
        v_n = u * math.cos(psi) - v * math.sin(psi)
        v_e = u * math.sin(psi) + v * math.cos(psi)
        t_ms = self._port.time_boot_ms()
        port = self._port
        ok = port.send(lambda mav: mav.attitude_send(t_ms, 0.0, 0.0, psi, 0.0, 0.0, r))
        ok = (
            port.send(
                lambda mav: mav.local_position_ned_send(t_ms, north, east, 0.0, v_n, v_e, 0.0)
            )
            and ok
        )
        origin = self.geodetic_origin
        if origin is None:
            return ok
        lat, lon = origin.to_geodetic(north, east)
        fields = (
            t_ms, round(lat * 1e7), round(lon * 1e7), round(origin.alt_m * 1000), 0,
            round(v_n * 100), round(v_e * 100), 0, round(math.degrees(psi) * 100) % 36000,
        )  # fmt: skip
        return port.send(lambda mav: mav.global_position_int_send(*fields)) and ok

    def drain_faults(self) -> list[Stamped[FaultInjection]]:
        """All queued fault injections, oldest first."""
        return self.faults.drain()
