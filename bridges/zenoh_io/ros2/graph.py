"""rmw_zenoh's names on Zenoh: data key expressions, liveliness tokens, QoS text, attachments.

As the design document of ros2/rmw_zenoh (``design.md`` in its ``docs`` folder) states them:

* data of a topic on ``<domain_id>/<fully qualified name without its leading />/<DDS type
  name>/<type hash>``, e.g. ``0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66...``;
* a node's liveliness token ``@ros2_lv/<domain_id>/<session id>/<node id>/<node id>/NN/
  <enclave>/<namespace>/<node name>``, and a publisher's (``MP``) or subscription's
  (``MS``) ``@ros2_lv/<domain_id>/<session id>/<node id>/<entity id>/<kind>/<enclave>/
  <namespace>/<node name>/<topic>/<DDS type name>/<type hash>/<qos>``, where enclave,
  namespace and topic are *mangled* (every ``/`` as ``%``; an empty namespace is ``%``);
* the QoS as ``reliability:durability:history,depth:deadline s,ns:lifespan s,ns:
  liveliness,lease s,ns``, each number left out when it is rmw_zenoh's default
  (reliable, volatile, keep-last, depth 42, infinite durations, automatic), so a
  reliable, volatile, keep-last-10 endpoint is ``::,10:,:,:,,``;
* every sample's attachment: the publisher's sequence number (int64 LE, from 1), the
  source timestamp (int64 LE, ns since the UNIX epoch), the GID's length (one byte, 16)
  and the publisher's 16-byte GID: 33 bytes.

rmw_zenoh derives an entity's GID from its token with XXH3-128; this bridge uses the first
16 bytes of the token's SHA-256 (the standard library has no XXH3): the GID stays unique
and constant per entity, which is what a subscriber uses it for. Pure: no zenoh import.
"""

from __future__ import annotations

import enum
import hashlib
import re
import struct
from dataclasses import dataclass

from ftcap_hil.core.errors import MalformedMessage

ADMIN_SPACE = "@ros2_lv"
GID_SIZE = 16
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
DEFAULT_DEPTH = 42  # rmw_zenoh's default history depth
_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


class EntityKind(enum.Enum):
    """The ``<entity_kind>`` chunk of a liveliness token."""

    NODE = "NN"
    PUBLISHER = "MP"
    SUBSCRIPTION = "MS"
    SERVICE = "SS"
    CLIENT = "SC"


class Reliability(enum.IntEnum):
    """rmw's reliability policy numbers."""

    SYSTEM_DEFAULT = 0
    RELIABLE = 1
    BEST_EFFORT = 2


class Durability(enum.IntEnum):
    """rmw's durability policy numbers."""

    SYSTEM_DEFAULT = 0
    TRANSIENT_LOCAL = 1
    VOLATILE = 2


@dataclass(frozen=True)
class Qos:
    """The QoS of an endpoint, as far as this bridge sets it (keep-last, infinite
    deadline, lifespan and lease, automatic liveliness)."""

    reliability: Reliability = Reliability.RELIABLE
    durability: Durability = Durability.VOLATILE
    depth: int = 10

    def keyexpr(self) -> str:
        """The QoS chunk of a liveliness token (module docstring)."""
        rel = "" if self.reliability is Reliability.RELIABLE else str(int(self.reliability))
        dur = "" if self.durability is Durability.VOLATILE else str(int(self.durability))
        depth = "" if self.depth == DEFAULT_DEPTH else str(self.depth)
        return f"{rel}:{dur}:,{depth}:,:,:,,"


def check_namespace(namespace: str) -> str:
    """A ROS namespace (``/`` or ``/a/b``), ValueError otherwise; ``""`` reads as ``/``."""
    ns = namespace or "/"
    parts = ns.split("/")[1:] if ns != "/" else []
    if not ns.startswith("/") or not all(_TOKEN.fullmatch(p) for p in parts):
        raise ValueError(f"ROS namespace {namespace!r}: expected '/' or '/name[/name...]'")
    return ns


def qualified_name(namespace: str, name: str) -> str:
    """The fully qualified topic name: ``name`` if absolute, else under ``namespace``."""
    if not all(_TOKEN.fullmatch(p) for p in name.strip("/").split("/")):
        raise ValueError(f"ROS topic name {name!r}: expected name[/name...]")
    if name.startswith("/"):
        return name
    ns = check_namespace(namespace)
    return f"{ns.rstrip('/')}/{name}"


def mangle(name: str) -> str:
    """Every ``/`` of ``name`` as ``%`` (an empty name as ``%``)."""
    return name.replace("/", "%") or "%"


def data_key(domain_id: int, topic: str, dds_type: str, type_hash: str) -> str:
    """``<domain_id>/<topic>/<type>/<hash>`` for a fully qualified ``topic``."""
    return f"{domain_id}/{topic.lstrip('/')}/{dds_type}/{type_hash}"


@dataclass(frozen=True)
class NodeName:
    """Where a node is: domain, the Zenoh session id (hex), its id in the session, its
    namespace and name; ``enclave`` the SROS enclave (``/``: none)."""

    domain_id: int
    session_id: str
    node_id: int
    namespace: str
    name: str
    enclave: str = "/"

    def _head(self, entity_id: int, kind: EntityKind) -> str:
        return (
            f"{ADMIN_SPACE}/{self.domain_id}/{self.session_id}/{self.node_id}/{entity_id}/"
            f"{kind.value}/{mangle(self.enclave)}/{mangle(self.namespace)}/{self.name}"
        )

    def node_token(self) -> str:
        """The node's liveliness token (``NN``)."""
        return self._head(self.node_id, EntityKind.NODE)

    def entity_token(
        self, entity_id: int, kind: EntityKind, topic: str, dds_type: str, type_hash: str, qos: Qos
    ) -> str:
        """A publisher's or subscription's token for a fully qualified ``topic``."""
        tail = f"{mangle(topic)}/{dds_type}/{type_hash}/{qos.keyexpr()}"
        return f"{self._head(entity_id, kind)}/{tail}"


@dataclass(frozen=True)
class ParsedToken:
    """The chunks of a liveliness token (topic, type, hash and qos empty for a node)."""

    domain_id: int
    session_id: str
    node_id: int
    entity_id: int
    kind: EntityKind
    enclave: str
    namespace: str
    node: str
    topic: str = ""
    dds_type: str = ""
    type_hash: str = ""
    qos: str = ""


def parse_token(key: str) -> ParsedToken:
    """Split a liveliness token into its chunks, demangled; ValueError if it is not one."""
    parts = key.split("/")
    if parts[0] != ADMIN_SPACE or len(parts) not in (9, 13):
        raise ValueError(f"not an rmw_zenoh liveliness token: {key!r}")
    kind = EntityKind(parts[5])
    if (kind is EntityKind.NODE) != (len(parts) == 9):
        raise ValueError(f"{kind.value} token with {len(parts)} chunks: {key!r}")
    topic_parts = parts[9:] if len(parts) == 13 else ["", "", "", ""]
    return ParsedToken(
        int(parts[1]), parts[2], int(parts[3]), int(parts[4]), kind,
        parts[6].replace("%", "/"), parts[7].replace("%", "/"), parts[8],
        topic_parts[0].replace("%", "/"), *topic_parts[1:],
    )  # fmt: skip


def gid_of(token: str) -> bytes:
    """A 16-byte GID of an entity, from its liveliness token (module docstring)."""
    return hashlib.sha256(token.encode("utf-8")).digest()[:GID_SIZE]


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to a sample (module docstring)."""

    sequence_number: int
    source_timestamp_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """The 33 attachment bytes."""
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"GID of {len(self.gid)} bytes, expected {GID_SIZE}")
        head = struct.pack("<qqB", self.sequence_number, self.source_timestamp_ns, GID_SIZE)
        return head + self.gid

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """The attachment of a sample; MalformedMessage unless it is the 33-byte layout."""
        if len(data) != ATTACHMENT_SIZE or data[16] != GID_SIZE:
            raise MalformedMessage(f"not an rmw_zenoh attachment: {bytes(data[:40]).hex()}")
        seq, stamp = struct.unpack_from("<qq", data)
        return cls(seq, stamp, bytes(data[17:]))
