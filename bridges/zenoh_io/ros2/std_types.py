"""The standard ROS 2 message types this bridge and the MCAP recordings use, as ``.msg`` text.

Fields as the ROS 2 interface packages define them (``builtin_interfaces``, ``std_msgs``,
``geometry_msgs``, ``nav_msgs``, ``diagnostic_msgs``, ``rcl_interfaces``, ``tf2_msgs``),
comments left out; nested types spelled ``pkg/Name``. Their REP-2011 hashes are checked against the
published ones in ``tests/unit/test_ros2_type_hash.py``: a wrong field name, type or order
changes the hash. The project's own types (``ftcap_msgs``) are the shipped ``.msg`` files
of :data:`FTCAP_MSGS_DIR`; :func:`registry` holds both.
"""

from __future__ import annotations

import functools
from pathlib import Path

from bridges.zenoh_io.ros2.msgdef import Registry, parse

FTCAP_MSGS_DIR = Path(__file__).resolve().parent / "ftcap_msgs"
WRENCH_STAMPED = "geometry_msgs/msg/WrenchStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
FLOAT64_ARRAY = "std_msgs/msg/Float64MultiArray"
STRING_MSG = "std_msgs/msg/String"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
ALLOCATOR_STATUS = "ftcap_msgs/msg/AllocatorStatus"
FAULT_INJECTION = "ftcap_msgs/msg/FaultInjection"

STANDARD: dict[str, str] = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "std_msgs/msg/String": "string data\n",
    "std_msgs/msg/MultiArrayDimension": "string label\nuint32 size\nuint32 stride\n",
    "std_msgs/msg/MultiArrayLayout": "std_msgs/MultiArrayDimension[] dim\nuint32 data_offset\n",
    "std_msgs/msg/Float64MultiArray": "std_msgs/MultiArrayLayout layout\nfloat64[] data\n",
    "geometry_msgs/msg/Vector3": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z\n",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1\n",
    "geometry_msgs/msg/Pose": (
        "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"
    ),
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\ngeometry_msgs/Pose pose\n",
    "geometry_msgs/msg/PoseWithCovariance": "geometry_msgs/Pose pose\nfloat64[36] covariance\n",
    "geometry_msgs/msg/Twist": "geometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n",
    "geometry_msgs/msg/TwistWithCovariance": "geometry_msgs/Twist twist\nfloat64[36] covariance\n",
    "geometry_msgs/msg/Wrench": "geometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n",
    "geometry_msgs/msg/WrenchStamped": "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n",
    "geometry_msgs/msg/Transform": (
        "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"
    ),
    "geometry_msgs/msg/TransformStamped": (
        "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"
    ),
    "tf2_msgs/msg/TFMessage": "geometry_msgs/TransformStamped[] transforms\n",
    "nav_msgs/msg/Odometry": (
        "std_msgs/Header header\nstring child_frame_id\n"
        "geometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n"
    ),
    "nav_msgs/msg/Path": "std_msgs/Header header\ngeometry_msgs/PoseStamped[] poses\n",
    "diagnostic_msgs/msg/KeyValue": "string key\nstring value\n",
    "diagnostic_msgs/msg/DiagnosticStatus": (
        "byte OK=0\nbyte WARN=1\nbyte ERROR=2\nbyte STALE=3\n"
        "byte level\nstring name\nstring message\nstring hardware_id\n"
        "diagnostic_msgs/KeyValue[] values\n"
    ),
    "diagnostic_msgs/msg/DiagnosticArray": (
        "std_msgs/Header header\ndiagnostic_msgs/DiagnosticStatus[] status\n"
    ),
    "rcl_interfaces/msg/Log": (
        "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n"
        "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\n"
        "string file\nstring function\nuint32 line\n"
    ),
}


def ftcap_msg_files() -> dict[str, Path]:
    """The shipped ``ftcap_msgs/msg/*.msg`` files by type name."""
    return {f"ftcap_msgs/msg/{p.stem}": p for p in sorted((FTCAP_MSGS_DIR / "msg").glob("*.msg"))}


@functools.cache
def registry() -> Registry:
    """Every type of this module and of the shipped ``ftcap_msgs`` package."""
    reg = Registry(parse(name, text) for name, text in STANDARD.items())
    for name, path in ftcap_msg_files().items():
        reg.add(parse(name, path.read_text()))
    return reg
