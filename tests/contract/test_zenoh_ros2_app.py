"""The allocator app with ``[zenoh] ros2 = true``, in-process (``apps.allocator.wire``, CAN on
python-can's virtual bus, MAVLink off): a plain Zenoh session publishing a WrenchStamped the
way rmw_zenoh does moves the daemon's demand, a mode request on ``allocator/mode`` switches
its mode, and its commands come back on the ROS 2 topic."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
import uuid
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import zenoh
from zenoh import ext

from bridges.zenoh_io.link import make_config
from ftcap_hil.apps.allocator import wire
from ftcap_hil.apps.demo import free_ports
from ftcap_hil.config.daemon import load_daemon_config
from ftcap_hil.core.status import Mode
from ftcap_hil.runtime.daemon import AllocatorDaemon
from tests.support.ros2_reference import deserialize, serialize, typestore

pytestmark = pytest.mark.timeout(60)
TIMEOUT_S = 15.0


def key(topic: str, type_name: str) -> str:
    pkg, kind, name = type_name.split("/")
    return f"3/{topic}/{pkg}::{kind}::dds_::{name}_/{typestore().hash_rihs01(type_name)}"


def wait_until(condition: Callable[[], bool], retry: Callable[[], object] | None = None) -> bool:
    deadline = time.monotonic() + TIMEOUT_S
    while time.monotonic() < deadline:
        if retry is not None:
            retry()
        if condition():
            return True
        time.sleep(0.1)
    return condition()


@pytest.fixture
def running() -> Iterator[tuple[AllocatorDaemon, int]]:
    (port,) = free_ports(socket.SOCK_STREAM, 1)
    listen = f'listen/endpoints:[\\"tcp/127.0.0.1:{port}\\"]'
    cfg = load_daemon_config(
        None,
        [
            'daemon.mode="cap"', "daemon.rate_hz=20.0", "daemon.status_period_s=0.05",
            'can.interface="virtual"', f'can.channel="ros2-{uuid.uuid4().hex}"',
            "can.esc_monitor=false", "mavlink.enabled=false", 'zenoh.vessel="ship"',
            f'zenoh.overrides=["{listen}"]', "zenoh.ros2=true", "zenoh.domain_id=3",
        ],
    )  # fmt: skip
    with contextlib.ExitStack() as stack:
        daemon = wire(cfg, stack, None)
        runner = threading.Thread(target=daemon.run, name="allocator-loop")
        runner.start()
        try:
            yield daemon, port
        finally:
            daemon.request_exit()
            runner.join(10.0)


def test_a_ros2_node_drives_the_allocator(running: tuple[AllocatorDaemon, int]) -> None:
    daemon, port = running
    session = zenoh.open(make_config("client", port))
    try:
        zid = str(session.zid())
        session.liveliness().declare_token(f"@ros2_lv/3/{zid}/0/0/NN/%/%/teleop")
        commands: list[zenoh.Sample] = []
        _sub = session.declare_subscriber(
            key("ship/thrusters/command", "std_msgs/msg/Float64MultiArray"), commands.append
        )
        wrench = {
            "header": {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": "base_link"},
            "wrench": {"force": {"x": 0.1, "y": 0.02, "z": 0.0},
                       "torque": {"x": 0.0, "y": 0.0, "z": 0.01}},
        }  # fmt: skip
        pub = session.declare_publisher(
            key("ship/setpoint/wrench", "geometry_msgs/msg/WrenchStamped")
        )
        payload = serialize("geometry_msgs/msg/WrenchStamped", wrench)
        seq = iter(range(1, 100_000))

        def put() -> None:
            att = ext.z_serialize((ext.Int64(next(seq)), ext.Int64(time.time_ns()), bytes(16)))
            pub.put(payload, attachment=att)

        def demand() -> tuple[float, ...]:
            st = daemon.last_status
            return () if st is None else tuple(st.tau_demand)

        assert wait_until(lambda: demand() == (0.1, -0.02, -0.01), retry=put)  # FLU -> FRD

        def last_command() -> list[float]:
            if not commands:
                return []
            msg = deserialize("std_msgs/msg/Float64MultiArray", commands[-1].payload.to_bytes())
            return list(msg.data)

        assert wait_until(lambda: np.any(np.abs(last_command()) > 1e-3), retry=put)
        assert len(last_command()) == daemon.config.thrusters.m

        mode = session.declare_publisher(key("ship/allocator/mode", "std_msgs/msg/String"))
        text = serialize("std_msgs/msg/String", {"data": "ftcap"})
        assert wait_until(
            lambda: daemon.config.core.mode is Mode.FTCAP, retry=lambda: mode.put(text)
        )
    finally:
        session.close()
