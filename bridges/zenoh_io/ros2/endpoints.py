"""One ROS 2 node's endpoints on Zenoh: their keys, tokens, GIDs and sequence numbers.

:class:`Ros2Node` hands out a :class:`Ros2Publisher` or :class:`Ros2Subscription` per
topic, numbered within the node (node id 0, entities from 1), each with its data key and
liveliness token (:mod:`~.graph`) and, for a publisher, its GID and the attachment of its
next sample. Relative topic names are under the node's namespace. Declaring them on a
session is :class:`bridges.zenoh_io.session.ZenohLink`'s part. Pure: no zenoh import.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from bridges.zenoh_io.ros2 import cdr
from bridges.zenoh_io.ros2.graph import (
    Attachment,
    EntityKind,
    NodeName,
    Qos,
    check_namespace,
    data_key,
    gid_of,
    qualified_name,
)
from bridges.zenoh_io.ros2.msgdef import Registry, dds_type_name
from bridges.zenoh_io.ros2.std_types import registry
from bridges.zenoh_io.ros2.type_hash import type_hash


@dataclass(frozen=True)
class Ros2Settings:
    """The ROS 2 mapping of a Zenoh link: ``domain_id`` (ROS_DOMAIN_ID, 0..232) and the
    ``namespace`` of its node (``""``: ``/<vessel>``)."""

    domain_id: int = 0
    namespace: str = ""

    def __post_init__(self) -> None:
        if not 0 <= self.domain_id <= 232:
            raise ValueError(f"ROS 2 domain_id {self.domain_id}: expected 0..232")
        if self.namespace:
            check_namespace(self.namespace)

    def namespace_for(self, vessel: str) -> str:
        """The namespace in force for ``vessel``."""
        return self.namespace or f"/{vessel}"


@dataclass
class Ros2Endpoint:
    """A topic endpoint: fully qualified ``topic``, message ``type_name``, ``key``, ``token``."""

    topic: str
    type_name: str
    key: str
    token: str
    registry: Registry

    def encode(self, value: dict[str, Any]) -> bytes:
        """A message value as its CDR payload."""
        return cdr.encode(self.registry, self.type_name, value)

    def decode(self, payload: bytes) -> dict[str, Any]:
        """A CDR payload as its message value (MalformedMessage if it is not one)."""
        return cdr.decode(self.registry, self.type_name, payload)

    def decoder(self, convert: Callable[[dict[str, Any]], Any]) -> Callable[[bytes], Any]:
        """payload -> ``convert(message value)``, for a subscriber callback."""
        return lambda payload: convert(self.decode(payload))


@dataclass
class Ros2Publisher(Ros2Endpoint):
    """A publisher: also its ``gid`` and its last sequence number (the first sample is 1)."""

    gid: bytes = b""
    sequence_number: int = 0

    def next_attachment(self, now_ns: int) -> bytes:
        """The attachment of the next sample, sent at ``now_ns`` (ns since the epoch)."""
        self.sequence_number += 1
        return Attachment(self.sequence_number, now_ns, self.gid).encode()


Ros2Subscription = Ros2Endpoint


@dataclass
class Ros2Node:
    """A node ``name`` in ``namespace`` of the Zenoh session ``session_id`` (hex)."""

    domain_id: int
    session_id: str
    namespace: str
    name: str
    qos: Qos = field(default_factory=Qos)
    registry: Registry = field(default_factory=registry)
    _ids: itertools.count[int] = field(default_factory=lambda: itertools.count(1))

    @property
    def graph_name(self) -> NodeName:
        return NodeName(self.domain_id, self.session_id, 0, self.namespace, self.name)

    def token(self) -> str:
        """The node's liveliness token."""
        return self.graph_name.node_token()

    def _endpoint(self, topic: str, type_name: str, kind: EntityKind) -> tuple[str, str, str]:
        fq = qualified_name(self.namespace, topic)
        dds, digest = dds_type_name(type_name), type_hash(self.registry, type_name)
        token = self.graph_name.entity_token(next(self._ids), kind, fq, dds, digest, self.qos)
        return fq, data_key(self.domain_id, fq, dds, digest), token

    def publisher(self, topic: str, type_name: str) -> Ros2Publisher:
        """A new publisher on ``topic`` (relative: under the namespace)."""
        fq, key, token = self._endpoint(topic, type_name, EntityKind.PUBLISHER)
        return Ros2Publisher(fq, type_name, key, token, self.registry, gid_of(token))

    def subscription(self, topic: str, type_name: str) -> Ros2Subscription:
        """A new subscription on ``topic`` (relative: under the namespace)."""
        fq, key, token = self._endpoint(topic, type_name, EntityKind.SUBSCRIPTION)
        return Ros2Subscription(fq, type_name, key, token, self.registry)
