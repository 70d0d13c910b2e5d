"""CDR of every ROS 2 message the bridge and the recordings write, byte for byte against
rosbags' serializer, and the decoder against rosbags' bytes and against bad payloads."""

from __future__ import annotations

import math
from typing import Any

import pytest

from bridges.zenoh_io.ros2 import cdr
from bridges.zenoh_io.ros2 import messages as m
from bridges.zenoh_io.ros2.diagnostics import diagnostic_array
from bridges.zenoh_io.ros2.std_types import registry
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import FaultInjection, FaultKind, Odometry
from ftcap_hil.core.status import AllocatorStatus, Mode
from tests.support.ros2_reference import deserialize, plain, serialize

STATUS = AllocatorStatus(
    mode=Mode.FTCAP,
    cycle=1234,
    overruns=2,
    degraded=True,
    delta_hat=(1.0, 0.42, 0.97),
    delta_std=(0.01, 0.08, 0.3),
    observable=(True, True, False),
    f_hat=(0.0, 1.5, -0.25),
    bf_hat=(1.0, -2.0, 0.5),
    u=(10.0, -20.0, 30.5),
    tau_demand=(12.0, 3.0, -1.0),
    unallocated=(0.5, 0.0, -0.125),
    saturated=(False, True, False),
    faulty=(False, True, False),
    esc_failed=(False, False, True),
    probing=(True, False, False),
    malformed=7,
    esc_rpm=(1200.0, math.nan, 0.0),
)

VALUES: dict[str, Any] = {
    "geometry_msgs/msg/WrenchStamped": m.wrench_stamped([120.0, -35.5, 7.25], 1.5),
    "nav_msgs/msg/Odometry": m.odometry_msg(
        Odometry.checked([10.0, -4.0, 0.3], [0.5, 0.05, -0.01], 12.345)
    ),
    "std_msgs/msg/Float64MultiArray": m.float64_array([1.0, -2.5, 3.75, 0.0], "thrusters"),
    "std_msgs/msg/String": {"data": "ftcap-literal"},
    "ftcap_msgs/msg/AllocatorStatus": m.allocator_status_msg(STATUS, 99.5, dead=(False,) * 3),
    "ftcap_msgs/msg/FaultInjection": m.fault_msg(FaultInjection(2, FaultKind.WEAK, 0.6)),
    "diagnostic_msgs/msg/DiagnosticArray": diagnostic_array(STATUS, "ship", 3.0),
    "rcl_interfaces/msg/Log": {
        "stamp": m.stamp(4.5),
        "level": 30,
        "name": "ftcap",
        "msg": "thruster 2 flagged",
        "file": "",
        "function": "",
        "line": 0,
    },  # fmt: skip
    "nav_msgs/msg/Path": {
        "header": m.header(2.0, "odom"),
        "poses": [
            {
                "header": m.header(t, "odom"),
                "pose": {
                    "position": m.vector3(t, 2 * t),
                    "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                },
            }
            for t in (0.0, 0.5, 1.0)
        ],
    },  # fmt: skip
}


@pytest.mark.parametrize("name", sorted(VALUES))
def test_encoding_equals_rosbags_byte_for_byte(name: str) -> None:
    ours = cdr.encode(registry(), name, VALUES[name])
    assert ours[:4] == b"\x00\x01\x00\x00"
    assert ours == serialize(name, VALUES[name])


@pytest.mark.parametrize("name", sorted(VALUES))
def test_decoding_rosbags_bytes_gives_the_value(name: str) -> None:
    got = cdr.decode(registry(), name, serialize(name, VALUES[name]))
    assert got == plain(deserialize(name, serialize(name, VALUES[name])))
    assert cdr.encode(registry(), name, got) == serialize(name, VALUES[name])


def test_a_known_wrench_stamped() -> None:
    # header {stamp 12 s 345 ns, "base_link"}, force (1.5, -2, 0), torque (0, 0, 3.25)
    value = {
        "header": {"stamp": {"sec": 12, "nanosec": 345}, "frame_id": "base_link"},
        "wrench": {"force": m.vector3(1.5, -2.0), "torque": m.vector3(0.0, 0.0, 3.25)},
    }
    expected = bytes.fromhex(
        "00010000" "0c000000" "59010000" "0a000000" "626173655f6c696e6b00" "0000"
        "000000000000f83f" "00000000000000c0" "0000000000000000"
        "0000000000000000" "0000000000000000" "0000000000000a40"
    )  # fmt: skip
    assert cdr.encode(registry(), "geometry_msgs/msg/WrenchStamped", value) == expected
    assert cdr.decode(registry(), "geometry_msgs/msg/WrenchStamped", expected) == value


def test_big_endian_payloads_decode() -> None:
    be = bytes.fromhex("000000000000000c000001590000000100")
    got = cdr.decode(registry(), "std_msgs/msg/Header", be)
    assert got == {"stamp": {"sec": 12, "nanosec": 345}, "frame_id": ""}


WRENCH = "geometry_msgs/msg/WrenchStamped"


def _good() -> bytes:
    return cdr.encode(registry(), WRENCH, VALUES[WRENCH])


@pytest.mark.parametrize(
    "bad",
    [
        lambda b: b"\x00\x02" + b[2:],  # another encapsulation (PL_CDR_BE)
        lambda b: b"\x00\x01",  # the header only, cut
        lambda b: b[:-1],  # one byte short
        lambda b: b[:12] + b"\xff\xff\xff\x7f" + b[16:],  # a frame_id longer than the payload
        lambda b: b[:25] + b"\x01" + b[26:],  # frame_id's NUL is not one
        lambda b: b[:16] + b"\xff" + b[17:],  # frame_id not UTF-8
        lambda b: b + bytes(cdr.MAX_PAYLOAD_BYTES),  # too long
    ],
)
def test_a_bad_payload_is_malformed(bad: Any) -> None:
    with pytest.raises(MalformedMessage):
        cdr.decode(registry(), WRENCH, bad(_good()))


def test_a_wrong_length_or_range_is_a_value_error() -> None:
    with pytest.raises(ValueError, match="36 elements"):
        cdr.encode(registry(), "geometry_msgs/msg/PoseWithCovariance", {"covariance": [0.0]})
    with pytest.raises(ValueError):
        cdr.encode(registry(), "ftcap_msgs/msg/FaultInjection", {"thruster": 70000})


def test_missing_fields_are_zero() -> None:
    got = cdr.decode(registry(), WRENCH, cdr.encode(registry(), WRENCH, {}))
    assert got["header"] == {"stamp": {"sec": 0, "nanosec": 0}, "frame_id": ""}
    assert got["wrench"]["torque"] == m.vector3()
