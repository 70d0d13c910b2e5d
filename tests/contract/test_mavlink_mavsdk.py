"""Interop: MAVSDK (the ``mavsdk`` wheel, MAVSDK's C++ library in-process through ctypes,
no server process) as the ground station on the ground station's inbox, as QGroundControl
sits on 14550: ``udpin://127.0.0.1:PORT``, which binds loopback only (checked from /proc).
MAVSDK's ``udpout://`` would bind an ephemeral port on all interfaces, so it is not used.

It discovers both components (the vessel as the autopilot, the allocator as a companion
computer), reads and sets every parameter of both with its own encoding rules (byte-wise
integers for a vehicle that is not ArduPilot), and receives the vessel's position and
attitude. MAVSDK's default system id (245) is authorized through ``authorized_systems``.
Skipped when ``mavsdk`` is not installed.
"""

from __future__ import annotations

import math
import os
import re
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

mavsdk = pytest.importorskip("mavsdk")

from mavsdk import ComponentType, Configuration, Mavsdk  # noqa: E402
from mavsdk.plugins.param import Param, ParamError, ParamResult, ProtocolVersion  # noqa: E402
from mavsdk.plugins.telemetry import Telemetry  # noqa: E402

from bridges.mavlink.allocator import AllocatorLinkConfig, MavlinkAllocatorLink  # noqa: E402
from bridges.mavlink.allocator_params import allocator_param_specs  # noqa: E402
from bridges.mavlink.config import ALLOCATOR_IDS, VESSEL_IDS, MavlinkEndpoint  # noqa: E402
from bridges.mavlink.geodesy import GeodeticOrigin  # noqa: E402
from bridges.mavlink.vessel import FAILURE_ENABLE_PARAM, MavlinkVesselLink  # noqa: E402
from ftcap_hil.core.cycle import CoreConfig  # noqa: E402
from ftcap_hil.core.messages import Odometry  # noqa: E402
from tests.support.mavlink_peers import free_udp_ports, wait_until  # noqa: E402

pytestmark = [pytest.mark.timeout(120)]
MAVSDK_SYSTEM = 245


def own_udp_binds() -> list[str]:
    """Local addresses of the UDP sockets this process holds (from /proc)."""
    inodes = set()
    for fd in Path("/proc/self/fd").iterdir():
        m = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(fd)) if fd.is_symlink() else None
        if m:
            inodes.add(m.group(1))
    binds = []
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[9] in inodes:
                binds.append(cols[1].split(":")[0])
    return binds


@pytest.fixture
def vehicle() -> Iterator[tuple[MavlinkAllocatorLink, MavlinkVesselLink, int]]:
    gcs_port, a_port, v_port = free_udp_ports(3)
    authorized = (MAVSDK_SYSTEM,)
    a_ep = MavlinkEndpoint(
        f"udpin:127.0.0.1:{a_port}", *ALLOCATOR_IDS, (f"127.0.0.1:{gcs_port}",),
        authorized_systems=authorized,
    )  # fmt: skip
    v_ep = MavlinkEndpoint(
        f"udpin:127.0.0.1:{v_port}", *VESSEL_IDS,
        (f"127.0.0.1:{a_port}", f"127.0.0.1:{gcs_port}"),
        authorized_systems=authorized, geodetic_origin=(63.43, 10.39, 0.0),
    )  # fmt: skip
    specs = allocator_param_specs(CoreConfig(), 0.5, 1.0, 0.5, 20.0, 0.1)
    config = AllocatorLinkConfig(4, (1.0, 1.0, 1.0))
    with (
        MavlinkAllocatorLink(config, a_ep, specs) as allocator,
        MavlinkVesselLink(4, v_ep) as vessel,
    ):
        assert vessel.geodetic_origin == GeodeticOrigin(63.43, 10.39, 0.0)
        yield allocator, vessel, gcs_port


@pytest.fixture
def ground_station(vehicle) -> Iterator[tuple[Any, MavlinkAllocatorLink, MavlinkVesselLink]]:
    allocator, vessel, gcs_port = vehicle
    stop = threading.Event()

    def odometry() -> None:
        t = 0.0
        while not stop.wait(0.05):
            vessel.send_odometry(Odometry.checked([10.0, 5.0, 0.3], [1.0, 0.0, 0.0], t))
            t += 0.05

    feeder = threading.Thread(target=odometry, daemon=True)
    feeder.start()
    sdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    try:
        assert int(sdk.add_any_connection(f"udpin://127.0.0.1:{gcs_port}")) == 0  # SUCCESS
        system = sdk.first_autopilot(15.0)
        assert system is not None
        yield system, allocator, vessel
    finally:
        stop.set()
        feeder.join()
        sdk.destroy()


def _select(param: Any, component: int) -> None:
    # MAVSDK 4.1.0's C wrapper reports UNKNOWN from select_component although the selection
    # takes effect (the reads below come from that component): tolerate that one result.
    try:
        param.select_component(component, ProtocolVersion.V1)
    except ParamError as e:
        if e.result is not ParamResult.UNKNOWN:
            raise


def _all(param: Any) -> dict[str, float]:
    params = param.get_all_params()
    return {p.name: p.value for p in [*params.int_params, *params.float_params]}


def test_mavsdk_reads_and_sets_every_parameter_of_both_components(ground_station) -> None:
    system, allocator, vessel = ground_station
    assert sorted(system.component_ids()) == [VESSEL_IDS[1], ALLOCATOR_IDS[1]]
    binds = own_udp_binds()  # ours and MAVSDK's: 127.0.0.1 only
    assert binds and set(binds) == {"0100007F"}, binds
    param = Param(system)
    assert _all(param) == {FAILURE_ENABLE_PARAM: 0}  # the autopilot component: the vessel
    param.set_param_int(FAILURE_ENABLE_PARAM, 1)
    assert vessel.fault_injection_enabled
    _select(param, ALLOCATOR_IDS[1])
    want = allocator.params.values()
    got = _all(param)
    assert set(got) == set(want)
    for name, value in want.items():
        assert got[name] == pytest.approx(value, rel=1e-6), name  # FTC_MODE is 2, not 2**30
    for spec in allocator.params.specs:  # the daemon is not running: every one is settable
        if spec.kind.value == "int":
            new = int(spec.max) if spec.default != spec.max else int(spec.min)
            param.set_param_int(spec.name, new)
        else:
            new = (
                0.99
                if spec.name == "FTC_DEAD_THR"
                else spec.min + 0.5 * (min(spec.max, spec.min + 1.0) - spec.min)
            )
            param.set_param_float(spec.name, new)
        assert allocator.params.get(spec.name) == pytest.approx(new, rel=1e-6), spec.name


def test_mavsdk_receives_position_and_attitude(ground_station) -> None:
    system, _, _ = ground_station
    telemetry = Telemetry(system)
    assert wait_until(lambda: not math.isnan(telemetry.position().latitude_deg), 5.0)
    time.sleep(0.3)
    pos, att = telemetry.position(), telemetry.attitude_euler()
    lat, lon = GeodeticOrigin(63.43, 10.39).to_geodetic(10.0, 5.0)
    assert pos.latitude_deg == pytest.approx(lat, abs=1e-6)
    assert pos.longitude_deg == pytest.approx(lon, abs=1e-6)
    assert att.yaw_deg == pytest.approx(math.degrees(0.3), abs=1e-3)
