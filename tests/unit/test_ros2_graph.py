"""rmw_zenoh's names, against the examples of its design document (design.md in the docs of
ros2/rmw_zenoh), its attachment against zenoh-ext's serializer, and the REP-103 frames."""

from __future__ import annotations

import math

import numpy as np
import pytest
from zenoh import ext

from bridges.zenoh_io.ros2 import messages as m
from bridges.zenoh_io.ros2.endpoints import Ros2Node, Ros2Settings
from bridges.zenoh_io.ros2.graph import (
    ATTACHMENT_SIZE,
    Attachment,
    Durability,
    EntityKind,
    NodeName,
    Qos,
    Reliability,
    data_key,
    parse_token,
    qualified_name,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import Odometry
from ftcap_hil.core.status import Mode

STRING = "std_msgs::msg::dds_::String_"
STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS = "example_interfaces::srv::dds_::AddTwoInts_"
ADD_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
# The design document's examples, verbatim.
DOC_KEYS = {
    (0, "/chatter", STRING, STRING_HASH): f"0/chatter/{STRING}/{STRING_HASH}",
    (0, "/robot1/chatter", STRING, STRING_HASH): f"0/robot1/chatter/{STRING}/{STRING_HASH}",
    (2, "/add_two_ints", ADD_TWO_INTS, ADD_HASH): f"2/add_two_ints/{ADD_TWO_INTS}/{ADD_HASH}",
}
LISTENER = "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
LISTENER_SUB = (
    "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/10/MS/%/%/listener/%chatter/"
    f"{STRING}/{STRING_HASH}/::,10:,:,:,,"
)
TALKER_PUB = (
    "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
    f"{STRING}/{STRING_HASH}/::,7:,:,:,,"
)


@pytest.mark.parametrize(("args", "key"), DOC_KEYS.items())
def test_data_keys_are_the_documented_ones(args: tuple[int, str, str, str], key: str) -> None:
    assert data_key(*args) == key


def test_relative_names_go_under_the_namespace() -> None:
    assert qualified_name("/robot1", "chatter") == "/robot1/chatter"
    assert qualified_name("/", "chatter") == "/chatter"
    assert qualified_name("/robot1", "/diagnostics") == "/diagnostics"
    with pytest.raises(ValueError):
        qualified_name("robot1", "chatter")  # a namespace is absolute
    with pytest.raises(ValueError):
        qualified_name("/a", "b//c")


def test_tokens_are_the_documented_ones() -> None:
    listener = NodeName(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert listener.node_token() == LISTENER
    sub = listener.entity_token(
        10, EntityKind.SUBSCRIPTION, "/chatter", STRING, STRING_HASH, Qos(depth=10)
    )
    assert sub == LISTENER_SUB
    talker = NodeName(2, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    pub = talker.entity_token(
        10, EntityKind.PUBLISHER, "/chatter", STRING, STRING_HASH, Qos(depth=7)
    )
    assert pub == TALKER_PUB


def test_documented_tokens_parse() -> None:
    node = parse_token(LISTENER)
    assert (node.domain_id, node.kind, node.namespace, node.node) == (
        2,
        EntityKind.NODE,
        "/",
        "listener",
    )
    pub = parse_token(TALKER_PUB)
    assert (pub.entity_id, pub.kind, pub.topic, pub.dds_type) == (
        10,
        EntityKind.PUBLISHER,
        "/chatter",
        STRING,
    )
    assert (pub.type_hash, pub.qos) == (STRING_HASH, "::,7:,:,:,,")
    for bad in (
        LISTENER.replace("@ros2_lv", "@ros2"),
        LISTENER + "/x",
        TALKER_PUB.replace("/MP/", "/NN/"),
    ):
        with pytest.raises(ValueError):
            parse_token(bad)


def test_qos_text_leaves_out_rmw_zenohs_defaults() -> None:
    assert Qos(depth=42).keyexpr() == "::,:,:,:,,"
    best_effort = Qos(Reliability.BEST_EFFORT, Durability.TRANSIENT_LOCAL, 5)
    assert best_effort.keyexpr() == "2:1:,5:,:,:,,"


def test_our_node_names_its_endpoints_under_its_namespace() -> None:
    node = Ros2Node(0, "abc", "/ship", "ftcap_allocator")
    assert node.token() == "@ros2_lv/0/abc/0/0/NN/%/%ship/ftcap_allocator"
    pub = node.publisher("allocator/status", "ftcap_msgs/msg/AllocatorStatus")
    sub = node.subscription("setpoint/wrench", "geometry_msgs/msg/WrenchStamped")
    assert pub.key.startswith(
        "0/ship/allocator/status/ftcap_msgs::msg::dds_::AllocatorStatus_/RIHS01_"
    )
    assert parse_token(pub.token).entity_id == 1 and parse_token(sub.token).entity_id == 2
    assert parse_token(sub.token).topic == "/ship/setpoint/wrench"
    assert parse_token(pub.token).kind is EntityKind.PUBLISHER
    assert len(pub.gid) == 16 and pub.gid != node.publisher("x", "std_msgs/msg/String").gid


def test_settings_refuse_a_bad_domain_or_namespace() -> None:
    assert Ros2Settings().namespace_for("ship") == "/ship"
    assert Ros2Settings(3, "/fleet/a").namespace_for("ship") == "/fleet/a"
    with pytest.raises(ValueError):
        Ros2Settings(domain_id=233)
    with pytest.raises(ValueError):
        Ros2Settings(namespace="fleet")


def test_the_attachment_is_zenoh_exts_serialization() -> None:
    gid = bytes(range(200, 216))
    ours = Attachment(7, 1_700_000_000_123_456_789, gid).encode()
    theirs = ext.z_serialize((ext.Int64(7), ext.Int64(1_700_000_000_123_456_789), gid))
    assert len(ours) == ATTACHMENT_SIZE == 33
    assert ours == theirs.to_bytes()
    assert Attachment.decode(ours) == Attachment(7, 1_700_000_000_123_456_789, gid)


def test_publishers_number_their_samples_from_one() -> None:
    pub = Ros2Node(0, "abc", "/", "n").publisher("t", "std_msgs/msg/String")
    first, second = (Attachment.decode(pub.next_attachment(5)) for _ in range(2))
    assert (first.sequence_number, second.sequence_number) == (1, 2)
    assert first.gid == pub.gid and first.source_timestamp_ns == 5


@pytest.mark.parametrize("cut", [lambda b: b[:-1], lambda b: b[:16] + b"\x08" + b[17:]])
def test_a_wrong_attachment_is_malformed(cut: object) -> None:
    good = Attachment(1, 2, bytes(16)).encode()
    with pytest.raises(MalformedMessage):
        Attachment.decode(cut(good))  # type: ignore[operator]


# --------------------------------------------------------------------------- frames


def test_a_heading_north_is_yaw_pi_2_in_enu() -> None:
    msg = m.odometry_msg(Odometry.checked([10.0, -4.0, 0.0], [1.0, 0.5, 0.1], 2.5))
    pose, twist = msg["pose"]["pose"], msg["twist"]["twist"]
    assert (pose["position"]["x"], pose["position"]["y"]) == (-4.0, 10.0)  # east, north
    assert pose["orientation"]["z"] == pytest.approx(math.sin(math.pi / 4))
    assert (twist["linear"]["y"], twist["angular"]["z"]) == (-0.5, -0.1)  # port, up
    assert msg["header"]["stamp"] == {"sec": 2, "nanosec": 500_000_000}
    assert (msg["header"]["frame_id"], msg["child_frame_id"]) == ("odom", "base_link")


@pytest.mark.parametrize("psi", [0.0, 0.3, -2.0, 3.0])
def test_odometry_comes_back(psi: float) -> None:
    odom = Odometry.checked([10.0, -4.0, psi], [1.0, 0.5, 0.1], 7.25)
    back = m.odometry_from(m.odometry_msg(odom))
    np.testing.assert_allclose(back.eta, odom.eta, atol=1e-12)
    np.testing.assert_allclose(back.nu, odom.nu, atol=1e-12)
    assert back.time_s == 7.25


def test_wrench_frames() -> None:
    msg = m.wrench_stamped([100.0, 20.0, -3.0], 1.0)
    assert (msg["wrench"]["force"]["y"], msg["wrench"]["torque"]["z"]) == (-20.0, 3.0)
    np.testing.assert_array_equal(m.setpoint_from(msg).tau, [100.0, 20.0, -3.0])
    msg["header"]["frame_id"] = "base_link_frd"
    np.testing.assert_array_equal(m.setpoint_from(msg).tau, [100.0, -20.0, 3.0])
    msg["header"]["frame_id"] = "map"
    with pytest.raises(MalformedMessage, match="frame_id"):
        m.setpoint_from(msg)
    with pytest.raises(MalformedMessage, match="limit"):
        m.setpoint_from(m.wrench_stamped([100.0, 0.0, 0.0], 0.0), limit=(50.0, 50.0, 50.0))


def test_mode_and_fault_topics_refuse_what_the_allocator_cannot_do() -> None:
    assert m.mode_from({"data": "cap"}) is Mode.CAP
    with pytest.raises(MalformedMessage):
        m.mode_from({"data": "oracle"})  # needs the truth
    assert m.fault_from({"thruster": 1, "kind": "weak", "value": 0.4}, m=4).index == 1
    bad_faults = [(4, "off", 0.0), (0, "weak", 1.5), (0, "melt", 0.0)]
    for thruster, kind, value in bad_faults:
        bad = {"thruster": thruster, "kind": kind, "value": value}
        with pytest.raises(MalformedMessage):
            m.fault_from(bad, m=4)
