"""The simulated vessel's ports opened from its configuration and handed to its loop
(:class:`~ftcap_hil.runtime.vessel_process.VesselPorts`): CAN (commands in, ESC telemetry
out; the CAN hub too with ``[can] start_hub``), MAVLink and Zenoh (odometry out, fault
injections in).

The bridges are imported here, lazily, so that building the ``ftcap-hil`` parser does not
import the networking stacks.
"""

from __future__ import annotations

import contextlib
import logging
from typing import Any

import numpy as np

from ftcap_hil.config.bridges import CanSettings, MavlinkSettings, PortSettings, ZenohSettings
from ftcap_hil.core.effectiveness.geometry import ThrusterSet
from ftcap_hil.core.errors import ConfigError, PortError
from ftcap_hil.core.messages import BoolArray, EscStatus, FaultInjection, Odometry, ThrusterCommand
from ftcap_hil.ports.mailbox import Stamped

log = logging.getLogger(__name__)


class VesselPorts:
    """CAN (commands in, ESC telemetry out), MAVLink and Zenoh (odometry out, faults in):
    the loop's :class:`~ftcap_hil.runtime.vessel_process.VesselIO`. ``shutdown()`` closes
    everything opened, in reverse."""

    def __init__(self, injection_enabled: bool, hold: bool = False) -> None:
        self._stack = contextlib.ExitStack()
        self._injection_enabled = injection_enabled
        self._hold = hold
        self.commands: Any = None  # Mailbox[ThrusterCommand] of the CanCommandSource
        self.changes: Any = None  # its changes only (stamped at a value's first arrival)
        self.esc_sink: Any = None
        self.mavlink: Any = None
        self.zenoh: Any = None

    @classmethod
    def open(
        cls, settings: PortSettings, ths: ThrusterSet, injection_enabled: bool, hold: bool = False
    ) -> VesselPorts:
        """Open every port of ``settings`` (validated by ``config.bridges``) or none;
        ``hold``: the vessel waits at t = 0 until its parameter SIM_HOLD is set to 0 (needs
        MAVLink)."""
        if hold and settings.mavlink is None:
            raise ConfigError("sim.hold = true needs [mavlink]: SIM_HOLD releases the vessel")
        ports = cls(injection_enabled, hold)
        try:
            ports._open_can(settings.can, ths)
            if settings.mavlink is not None:
                ports._open_mavlink(settings.mavlink, ths.m)
            if settings.zenoh is not None:
                ports._open_zenoh(settings.zenoh, ths.m)
        except BaseException:
            ports.shutdown()
            raise
        return ports

    def _open_can(self, c: CanSettings, ths: ThrusterSet) -> None:
        from bridges.can_io.adapters import CanCommandSource, CanEscStatusSink
        from bridges.can_io.bus import CanBusError, open_can_bus
        from bridges.can_io.force_map import CurveForceMap, ForceRawMap
        from bridges.can_io.hub import CanHub, parse_channel
        from bridges.can_io.node import CanNodeServer, sim_esc_node

        ids = c.esc_node_ids if c.esc_node_ids is not None else [20 + i for i in range(ths.m)]
        try:
            if c.start_hub:
                host, port = parse_channel(c.channel)
                self._stack.callback(CanHub(host, port).start().shutdown)
            bus = open_can_bus(c.interface, c.channel)
            self._stack.callback(bus.shutdown)
            force_map: Any = (  # the physical curves: a wrong map in the allocator shows
                ForceRawMap.from_limits(ths.u_min, ths.u_max, c.deadband_n)
                if c.curves is None
                else CurveForceMap.create(c.curves, c.deadband_n)
            )
            source = CanCommandSource(bus, force_map, allocator_node_id=c.node_id)
            self._stack.callback(source.shutdown)
            self.esc_sink = CanEscStatusSink(bus, ids)
            self._stack.callback(self.esc_sink.shutdown)
            escs = {n: sim_esc_node(i, n, ths.thrusters[i]) for i, n in enumerate(ids)}
            server = CanNodeServer(
                bus, {n: info for n, (info, _) in escs.items()}, self.esc_sink.current_status,
                notifier=source.notifier, params={n: ps for n, (_, ps) in escs.items()},
            )  # fmt: skip
            self._stack.callback(server.shutdown)
        except (CanBusError, OSError) as e:
            raise PortError(f"can: {e}") from e
        except (ValueError, TypeError) as e:
            raise ConfigError(f"can: {e}") from e
        self.commands, self.changes = source.commands, source.changes

    def _open_mavlink(self, c: MavlinkSettings, m: int) -> None:
        from bridges.mavlink.params import ParamSpec, ParamType
        from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, HOLD_PARAM, MavlinkVesselLink

        if c.warning is not None:
            log.warning("%s", c.warning)
        hold = ParamSpec(
            HOLD_PARAM, int(self._hold), ParamType.INT, 0, 1,
            description="1: the vessel waits at sim time 0 (0 starts it)",
        )  # fmt: skip
        try:
            self.mavlink = MavlinkVesselLink(m, c.endpoint, extra_params=[hold])
        except ConfigError as e:  # the endpoint cannot be opened (port taken, bad device)
            raise PortError(f"mavlink: {e}") from e
        self._stack.callback(self.mavlink.shutdown)
        self.mavlink.params.set(FAILURE_ENABLE_PARAM, int(self._injection_enabled))

    def _open_zenoh(self, c: ZenohSettings, m: int) -> None:
        from bridges.zenoh_io.link import ZenohLinkError, ZenohVesselLink, load_config
        from bridges.zenoh_io.ros2.endpoints import Ros2Settings

        # ZenohConfigError: a ConfigError
        conf = load_config(c.config, list(c.overrides), c.allow_unauthenticated)
        try:
            ros2 = Ros2Settings(c.domain_id, c.namespace) if c.ros2 else None
            self.zenoh = ZenohVesselLink(c.vessel, conf, n_thrusters=m, ros2=ros2)
        except ZenohLinkError as e:
            raise PortError(f"zenoh: {e}") from e
        self._stack.callback(self.zenoh.shutdown)

    def latest_command(self) -> Stamped[ThrusterCommand] | None:
        return None if self.commands is None else self.commands.latest()

    def first_arrival_ns(self, command: Stamped[ThrusterCommand]) -> int:
        """When ``command``'s value first arrived (before the ESC stream's repeats of it):
        its own stamp unless the latest change is that value and not newer."""
        change = None if self.changes is None else self.changes.latest()
        if change is None or change.stamp_ns > command.stamp_ns:
            return command.stamp_ns
        same = np.array_equal(change.value.u, command.value.u)
        return change.stamp_ns if same else command.stamp_ns

    def drain_faults(self) -> list[tuple[str, Stamped[FaultInjection]]]:
        """Injections from every source, oldest first, as (source name, injection)."""
        out = [("mavlink", f) for f in self.mavlink.drain_faults()] if self.mavlink else []
        if self.zenoh is not None:
            out += [("zenoh", f) for f in self.zenoh.faults.drain()]
        return sorted(out, key=lambda item: item[1].stamp_ns)

    def injection_enabled(self) -> bool:
        """SYS_FAILURE_EN (live over MAVLink; the config value without MAVLink)."""
        if self.mavlink is not None:
            return bool(self.mavlink.fault_injection_enabled)
        return self._injection_enabled

    def held(self) -> bool:
        """SIM_HOLD is 1 (the vessel waits at t = 0); False without MAVLink."""
        from bridges.mavlink.vessel import HOLD_PARAM

        return self.mavlink is not None and self.mavlink.params.get(HOLD_PARAM) == 1

    def send_odometry(self, odom: Odometry) -> None:
        if self.mavlink is not None:
            self.mavlink.send_odometry(odom)
        if self.zenoh is not None:
            self.zenoh.publish_odometry(odom)

    def send_esc(self, statuses: list[EscStatus], reporting: BoolArray, now_ns: int) -> None:
        if self.esc_sink is not None:
            self.esc_sink.send_all(statuses)
            self.esc_sink.tick(now_ns, np.flatnonzero(reporting).tolist())

    def shutdown(self) -> None:
        """Close every port opened, newest first. Idempotent."""
        self._stack.close()
