"""The ROS 2 mapping on real loopback sessions: a plain Zenoh session acts as a ROS 2 node the
way rmw_zenoh does (its keys, tokens and attachments written here by hand from the design
document, its payloads by rosbags), against the allocator's router and a vessel client."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
import zenoh
from zenoh import ext

from bridges.zenoh_io.link import ZenohAllocatorLink, ZenohVesselLink, make_config
from bridges.zenoh_io.ros2.endpoints import Ros2Settings
from bridges.zenoh_io.ros2.graph import EntityKind, parse_token
from ftcap_hil.core.messages import FaultKind, Odometry, ThrusterCommand
from ftcap_hil.core.status import AllocatorStatus, Mode
from tests.support.ros2_reference import deserialize, serialize, typestore

pytestmark = pytest.mark.timeout(120)

VESSEL = "ship"
DOMAIN = 7
TIMEOUT_S = 10.0
STATUS = AllocatorStatus(
    mode=Mode.FTCAP,
    cycle=42,
    delta_hat=(1.0, 0.5, 0.9),
    delta_std=(0.01, 0.05, 0.2),
    observable=(True, True, False),
    f_hat=(0.0, 2.0, 0.0),
    bf_hat=(0.0, 2.0, -1.0),
    u=(10.0, -5.0, 2.5),
    tau_demand=(100.0, 10.0, -4.0),
    unallocated=(1.0, 0.0, 0.5),
    saturated=(False, True, False),
    faulty=(False, True, False),
)


def key(topic: str, type_name: str) -> str:
    """The data key as the design document writes it, with rosbags' type hash."""
    pkg, kind, name = type_name.split("/")
    rihs = typestore().hash_rihs01(type_name)
    return f"{DOMAIN}/{topic}/{pkg}::{kind}::dds_::{name}_/{rihs}"


def attachment(seq: int) -> bytes:
    gid = bytes(range(100, 116))
    return ext.z_serialize((ext.Int64(seq), ext.Int64(time.time_ns()), gid)).to_bytes()


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
def port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def allocator(port: int) -> Iterator[ZenohAllocatorLink]:
    ros2 = Ros2Settings(domain_id=DOMAIN)
    with ZenohAllocatorLink(VESSEL, make_config("router", port), ros2=ros2) as link:
        yield link


@pytest.fixture
def ros(allocator: ZenohAllocatorLink, port: int) -> Iterator[zenoh.Session]:
    """A plain Zenoh session: client of the allocator's router, multicast scouting off."""
    session = zenoh.open(make_config("client", port))
    yield session
    session.close()


def collect(session: zenoh.Session, key_expr: str) -> tuple[list[zenoh.Sample], Any]:
    got: list[zenoh.Sample] = []
    return got, session.declare_subscriber(key_expr, got.append)


def test_the_status_reaches_a_ros2_subscriber(
    allocator: ZenohAllocatorLink, ros: zenoh.Session
) -> None:
    got, _sub = collect(ros, key("ship/allocator/status", "ftcap_msgs/msg/AllocatorStatus"))
    assert wait_until(lambda: len(got) >= 2, retry=lambda: allocator.publish_status(STATUS))
    msg = deserialize("ftcap_msgs/msg/AllocatorStatus", got[-1].payload.to_bytes())
    assert (msg.mode, msg.cycle) == ("ftcap", 42)
    np.testing.assert_array_equal(msg.delta_hat, [1.0, 0.5, 0.9])
    np.testing.assert_allclose(msg.delta_lower, [0.98, 0.4, 0.5])
    assert msg.observable.tolist() == [True, True, False]
    assert (msg.demanded.force.x, msg.demanded.force.y, msg.demanded.torque.z) == (
        100.0,
        -10.0,
        4.0,
    )
    seqs = [ext.z_deserialize(tuple[ext.Int64, ext.Int64, bytes], s.attachment)[0] for s in got]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    _, stamp, gid = ext.z_deserialize(tuple[ext.Int64, ext.Int64, bytes], got[-1].attachment)
    assert abs(stamp - time.time_ns()) < 5e9 and gid == allocator.ros2_publishers["status"].gid


def test_diagnostics_and_commands_decode(allocator: ZenohAllocatorLink, ros: zenoh.Session) -> None:
    diag, _a = collect(ros, key("diagnostics", "diagnostic_msgs/msg/DiagnosticArray"))
    cmd, _b = collect(ros, key("ship/thrusters/command", "std_msgs/msg/Float64MultiArray"))

    def publish() -> None:
        allocator.publish_status(STATUS)
        allocator.publish_thruster_command(ThrusterCommand.checked([1.0, -2.0, 3.5]))

    assert wait_until(lambda: bool(diag and cmd), retry=publish)
    array = deserialize("diagnostic_msgs/msg/DiagnosticArray", diag[-1].payload.to_bytes())
    second = array.status[2]  # [0] is the allocator
    assert (second.name, second.level, second.hardware_id) == (
        "ftcap ship: thruster 2",
        1,
        "ship/T2",
    )
    assert {kv.key: kv.value for kv in second.values}["delta_hat"] == "0.5"
    command = deserialize("std_msgs/msg/Float64MultiArray", cmd[-1].payload.to_bytes())
    assert command.data.tolist() == [1.0, -2.0, 3.5] and command.layout.dim[0].label == "thrusters"


def tokens(session: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in session.liveliness().get(f"@ros2_lv/{DOMAIN}/**") if r.ok]


def test_the_liveliness_tokens_parse(allocator: ZenohAllocatorLink, ros: zenoh.Session) -> None:
    assert wait_until(lambda: len(tokens(ros)) == 7)
    parsed = [parse_token(t) for t in tokens(ros)]
    router = str(ros.info.routers_zid()[0])
    assert {(p.domain_id, p.session_id, p.namespace, p.node) for p in parsed} == {
        (DOMAIN, router, "/ship", "ftcap_allocator")
    }
    endpoints = {(p.kind, p.topic, p.dds_type, p.type_hash) for p in parsed if p.topic}
    wrench = typestore().hash_rihs01("geometry_msgs/msg/WrenchStamped")
    assert (EntityKind.SUBSCRIPTION, "/ship/setpoint/wrench",
            "geometry_msgs::msg::dds_::WrenchStamped_", wrench) in endpoints  # fmt: skip
    kinds = sorted((p.kind.value, p.topic) for p in parsed)
    assert kinds == [
        ("MP", "/diagnostics"), ("MP", "/ship/allocator/status"), ("MP", "/ship/thrusters/command"),
        ("MS", "/ship/allocator/mode"), ("MS", "/ship/odometry"), ("MS", "/ship/setpoint/wrench"),
        ("NN", ""),
    ]  # fmt: skip
    assert all(p.qos == "::,10:,:,:,," for p in parsed if p.topic)


def test_the_tokens_go_when_the_node_does(port: int) -> None:
    link = ZenohAllocatorLink(VESSEL, make_config("router", port), ros2=Ros2Settings(DOMAIN))
    session = zenoh.open(make_config("client", port))
    try:
        gone: list[zenoh.Sample] = []
        sub = session.liveliness().declare_subscriber(f"@ros2_lv/{DOMAIN}/**", gone.append)
        assert wait_until(lambda: len(tokens(session)) == 7)
        link.shutdown()
        assert wait_until(lambda: sum(s.kind == zenoh.SampleKind.DELETE for s in gone) == 7)
        sub.undeclare()
    finally:
        link.shutdown()
        session.close()


WRENCH = {
    "header": {"stamp": {"sec": 1, "nanosec": 0}, "frame_id": "base_link"},
    "wrench": {
        "force": {"x": 120.0, "y": 30.0, "z": 0.0},
        "torque": {"x": 0.0, "y": 0.0, "z": 5.0},
    },
}


def publish_as_rmw_zenoh(
    session: zenoh.Session, key_expr: str, payload: bytes
) -> Callable[[], None]:
    """A publisher the way rmw_zenoh declares one, and a function that puts one sample."""
    zid = str(session.zid())
    session.liveliness().declare_token(f"@ros2_lv/{DOMAIN}/{zid}/0/0/NN/%/%/teleop")
    pub = session.declare_publisher(key_expr)
    seq = iter(range(1, 10_000))
    return lambda: pub.put(payload, attachment=attachment(next(seq)))


def test_a_ros2_wrench_moves_the_setpoint(
    allocator: ZenohAllocatorLink, ros: zenoh.Session
) -> None:
    put = publish_as_rmw_zenoh(ros, key("ship/setpoint/wrench", "geometry_msgs/msg/WrenchStamped"),
                               serialize("geometry_msgs/msg/WrenchStamped", WRENCH))  # fmt: skip
    assert wait_until(lambda: allocator.ros2_setpoints.latest() is not None, retry=put)
    slot = allocator.ros2_setpoints.latest()
    assert slot is not None
    np.testing.assert_array_equal(slot.value.tau, [120.0, -30.0, -5.0])  # FLU -> FRD
    assert allocator.setpoints.latest() is None  # the JSON port stays its own


@pytest.mark.parametrize(
    "wrong",
    [
        lambda b: b"\x00\x02" + b[2:],
        lambda b: b[:-1],
        lambda b: b[:12] + b"\x00\x00\x00\x7f" + b[16:],
    ],
    ids=["encapsulation", "one byte short", "frame_id length"],
)
def test_a_wrong_byte_is_counted_not_used(
    allocator: ZenohAllocatorLink, ros: zenoh.Session, wrong: Any
) -> None:
    payload = wrong(serialize("geometry_msgs/msg/WrenchStamped", WRENCH))
    put = publish_as_rmw_zenoh(
        ros, key("ship/setpoint/wrench", "geometry_msgs/msg/WrenchStamped"), payload
    )
    assert wait_until(lambda: allocator.ros2_setpoints.malformed > 0, retry=put)
    assert allocator.ros2_setpoints.latest() is None


def test_another_type_hash_never_arrives(allocator: ZenohAllocatorLink, ros: zenoh.Session) -> None:
    other = key("ship/setpoint/wrench", "geometry_msgs/msg/WrenchStamped")[:-1] + "0"
    put = publish_as_rmw_zenoh(ros, other, serialize("geometry_msgs/msg/WrenchStamped", WRENCH))
    good = publish_as_rmw_zenoh(ros, key("ship/allocator/mode", "std_msgs/msg/String"),
                                serialize("std_msgs/msg/String", {"data": "cap"}))  # fmt: skip
    assert wait_until(lambda: allocator.modes.received > 0, retry=lambda: (put(), good()))
    assert [item.value for item in allocator.modes.drain()][0] is Mode.CAP
    assert allocator.ros2_setpoints.latest() is None and allocator.ros2_setpoints.malformed == 0


@pytest.fixture
def vessel(allocator: ZenohAllocatorLink, port: int) -> Iterator[ZenohVesselLink]:
    ros2 = Ros2Settings(domain_id=DOMAIN)
    with ZenohVesselLink(VESSEL, make_config("client", port), n_thrusters=3, ros2=ros2) as link:
        yield link


def test_the_vessel_takes_ros2_faults_and_sends_odometry(
    vessel: ZenohVesselLink, ros: zenoh.Session
) -> None:
    fault = {"thruster": 1, "kind": "weak", "value": 0.25}
    put = publish_as_rmw_zenoh(ros, key("ship/fault/inject", "ftcap_msgs/msg/FaultInjection"),
                               serialize("ftcap_msgs/msg/FaultInjection", fault))  # fmt: skip
    assert wait_until(lambda: vessel.faults.received > 0, retry=put)
    got = vessel.faults.drain()[0].value
    assert (got.index, got.kind, got.value) == (1, FaultKind.WEAK, 0.25)
    odom, _sub = collect(ros, key("ship/odometry", "nav_msgs/msg/Odometry"))
    sample = Odometry.checked([3.0, 4.0, 0.0], [1.0, 0.0, 0.2], 9.5)
    assert wait_until(lambda: bool(odom), retry=lambda: vessel.publish_odometry(sample))
    msg = deserialize("nav_msgs/msg/Odometry", odom[-1].payload.to_bytes())
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y) == (4.0, 3.0)  # ENU
    assert msg.pose.pose.orientation.z == pytest.approx(math.sin(math.pi / 4))
    assert msg.twist.twist.angular.z == -0.2 and msg.header.stamp.sec == 9
