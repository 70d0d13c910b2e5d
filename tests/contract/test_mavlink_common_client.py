"""Interop: a ground station written against pymavlink's bundled common.xml only (no ftcap
dialect), doing what the MAVLink parameter and command protocols say a client should:
ask each component for AUTOPILOT_VERSION, decode integer parameters as its capabilities
say (byte-wise or C-cast), read and set every parameter of both components, and get a
COMMAND_ACK for every COMMAND_LONG it sends, supported or not."""

from __future__ import annotations

import importlib
import math
import struct
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink
from bridges.mavlink.allocator_params import allocator_param_specs
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint
from bridges.mavlink.vessel import MavlinkVesselLink
from ftcap_hil.core.cycle import CoreConfig
from tests.support.mavlink_peers import free_udp_ports, wait_until

pytestmark = [pytest.mark.timeout(90), pytest.mark.usefixtures("no_leaked_threads")]

COMMON = importlib.import_module("pymavlink.dialects.v20.common")
Ids = tuple[int, int]


class CommonClient:
    """pymavlink with common.xml only on the ground station's inbox; keeps every message."""

    def __init__(self, port: int) -> None:
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=255, source_component=190
        )
        self.conn.mav = COMMON.MAVLink(self.conn, srcSystem=255, srcComponent=190)
        self.conn.mav.robust_parsing = True
        self.mav = self.conn.mav
        self.msgs: list[Any] = []
        self.capabilities: dict[Ids, int] = {}

    def wait(self, mtype: str, src: Ids, pred: Any = lambda m: True, timeout_s: float = 3.0) -> Any:
        deadline = time.monotonic() + timeout_s
        seen = 0
        while time.monotonic() < deadline:
            for m in self.msgs[seen:]:
                if (m.get_type(), m.get_srcSystem(), m.get_srcComponent()) == (mtype, *src):
                    if pred(m):
                        self.msgs.remove(m)
                        return m
            seen = len(self.msgs)
            msg = self.conn.recv_msg()
            if msg is None:
                self.conn.select(0.01)
            else:
                self.msgs.append(msg)
        return None

    def decode(self, ids: Ids, msg: Any) -> float:
        """A PARAM_VALUE as the component's AUTOPILOT_VERSION capabilities say."""
        if msg.param_type == COMMON.MAV_PARAM_TYPE_REAL32:
            return float(msg.param_value)
        if self.capabilities[ids] & COMMON.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE:
            return float(struct.unpack("<i", struct.pack("<f", msg.param_value))[0])
        return float(msg.param_value)  # C-cast

    def encode(self, ids: Ids, value: float, ptype: int) -> float:
        caps = self.capabilities[ids]
        if ptype != COMMON.MAV_PARAM_TYPE_REAL32 and caps & (
            COMMON.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        ):
            return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
        return value

    def command(self, ids: Ids, command: int, *params: float) -> Any:
        args = [*params, *[0.0] * (7 - len(params))]
        self.mav.command_long_send(*ids, command, 0, *args)
        return self.wait("COMMAND_ACK", ids, lambda m: m.command == command)

    def close(self) -> None:
        self.conn.close()


@pytest.fixture
def rig() -> Iterator[tuple[CommonClient, MavlinkAllocatorLink, MavlinkVesselLink]]:
    gcs_port, a_port, v_port = free_udp_ports(3)
    a_ep = MavlinkEndpoint.inbox(a_port, ALLOCATOR_IDS, (gcs_port,))
    v_ep = MavlinkEndpoint.inbox(v_port, VESSEL_IDS, (a_port, gcs_port))
    specs = allocator_param_specs(CoreConfig(), 0.5, 1.0, 0.5, 20.0, 0.1)
    client = CommonClient(gcs_port)
    try:
        with (
            MavlinkAllocatorLink(AllocatorLinkConfig(4, (1.0, 1.0, 1.0)), a_ep, specs) as alloc,
            MavlinkVesselLink(4, v_ep) as vessel,
        ):
            yield client, alloc, vessel
    finally:
        client.close()


def _new_value(spec: Any, value: float) -> float:
    if spec.kind.value == "int":
        return spec.max if value != spec.max else spec.min
    hi = min(spec.max, spec.min + 1.0)
    return spec.min + 0.25 * (hi - spec.min)


@pytest.mark.parametrize("which", ["allocator", "vessel"])
def test_common_client_reads_and_sets_every_parameter(rig, which) -> None:
    client, alloc, vessel = rig
    link, ids = (alloc, ALLOCATOR_IDS) if which == "allocator" else (vessel, VESSEL_IDS)
    assert client.wait("HEARTBEAT", ids) is not None
    ack = client.command(
        ids, COMMON.MAV_CMD_REQUEST_MESSAGE, COMMON.MAVLINK_MSG_ID_AUTOPILOT_VERSION
    )
    assert ack.result == COMMON.MAV_RESULT_ACCEPTED
    client.capabilities[ids] = client.wait("AUTOPILOT_VERSION", ids).capabilities
    client.mav.param_request_list_send(*ids)
    count = len(link.params)
    values = {}
    for _ in range(count):
        msg = client.wait("PARAM_VALUE", ids)
        assert msg is not None and msg.param_count == count
        values[msg.param_id] = (client.decode(ids, msg), msg.param_type)
    assert {k: v for k, (v, _) in values.items()} == pytest.approx(link.params.values())
    for spec in link.params.specs:
        value, ptype = values[spec.name]
        new = _new_value(spec, value)
        wire = client.encode(ids, new, ptype)
        client.mav.param_set_send(*ids, spec.name.encode(), wire, ptype)
        echo = client.wait("PARAM_VALUE", ids, lambda m, n=spec.name: m.param_id == n)
        assert client.decode(ids, echo) == pytest.approx(new, rel=1e-6), spec.name
        assert link.params.get(spec.name) == pytest.approx(new, rel=1e-6), spec.name


@pytest.mark.parametrize("ids", [ALLOCATOR_IDS, VESSEL_IDS], ids=["allocator", "vessel"])
def test_every_command_long_to_either_component_is_acknowledged(rig, ids) -> None:
    client, alloc, vessel = rig
    assert client.wait("HEARTBEAT", ids) is not None
    commands = [
        (COMMON.MAV_CMD_REQUEST_MESSAGE, (COMMON.MAVLINK_MSG_ID_AUTOPILOT_VERSION,)),
        (COMMON.MAV_CMD_REQUEST_MESSAGE, (COMMON.MAVLINK_MSG_ID_BATTERY_STATUS,)),
        (COMMON.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, (1,)),
        (COMMON.MAV_CMD_INJECT_FAILURE, (101, 1, 1, math.nan)),  # vessel: DENIED (disabled)
        (COMMON.MAV_CMD_COMPONENT_ARM_DISARM, (1,)),
        (COMMON.MAV_CMD_DO_SET_MODE, (1, 4)),
        (COMMON.MAV_CMD_NAV_RETURN_TO_LAUNCH, ()),
        (COMMON.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, (0, 0)),
    ]
    results = {}
    for command, params in commands:
        ack = client.command(ids, command, *params)
        assert ack is not None, f"no COMMAND_ACK for {command} from {ids}"
        assert (ack.target_system, ack.target_component) == (255, 190)
        results[command] = ack.result
    assert results[COMMON.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES] == COMMON.MAV_RESULT_ACCEPTED
    assert results[COMMON.MAV_CMD_COMPONENT_ARM_DISARM] == COMMON.MAV_RESULT_UNSUPPORTED
    expected = COMMON.MAV_RESULT_DENIED if ids == VESSEL_IDS else COMMON.MAV_RESULT_UNSUPPORTED
    assert results[COMMON.MAV_CMD_INJECT_FAILURE] == expected
    link = alloc if ids == ALLOCATOR_IDS else vessel
    assert wait_until(lambda: link.commands.acked == len(commands))  # counted after sending
