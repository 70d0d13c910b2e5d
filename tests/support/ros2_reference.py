"""rosbags as the independent reference for the ROS 2 wire format (tests only).

:func:`typestore` is rosbags' Jazzy type store with the shipped ``ftcap_msgs`` registered
from their ``.msg`` files by rosbags' own parser; :func:`to_rosbags` builds rosbags'
message object of a value (a dict as :mod:`bridges.zenoh_io.ros2.cdr` takes it), so that
rosbags serializes it with its own field order and types; :func:`plain` turns a rosbags
object back into plain dicts and lists for comparisons; :func:`read_mcap` decodes a
recording with the schemas it carries (the mcap package reads it, CRCs checked).
"""

from __future__ import annotations

import dataclasses
import functools
import re
from pathlib import Path
from typing import Any

import numpy as np
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from bridges.zenoh_io.ros2.msgdef import PRIMITIVES, STRING
from bridges.zenoh_io.ros2.std_types import ftcap_msg_files, registry

_NUMPY = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}  # fmt: skip


@functools.cache
def typestore() -> Typestore:
    store = get_typestore(Stores.ROS2_JAZZY)
    for name, path in ftcap_msg_files().items():
        store.register(get_types_from_msg(path.read_text(), name))
    return store


def to_rosbags(type_name: str, value: dict[str, Any]) -> Any:
    """rosbags' object of type ``type_name`` holding ``value`` (every field given)."""
    store, reg = typestore(), registry()
    kwargs = {}
    for f in reg[type_name].fields:
        v = value[f.name]
        if f.nested:
            kwargs[f.name] = (
                [to_rosbags(f.base, x) for x in v]
                if (f.sequence or f.array)
                else to_rosbags(f.base, v)
            )
        elif f.base in PRIMITIVES and (f.sequence or f.array):
            kwargs[f.name] = np.array(v, dtype=_NUMPY[f.base])
        elif f.base == STRING:
            kwargs[f.name] = [str(x) for x in v] if (f.sequence or f.array) else str(v)
        else:
            kwargs[f.name] = v
    return store.types[type_name](**kwargs)


def serialize(type_name: str, value: dict[str, Any]) -> bytes:
    """rosbags' CDR bytes of ``value``."""
    return bytes(typestore().serialize_cdr(to_rosbags(type_name, value), type_name))


def deserialize(type_name: str, payload: bytes) -> Any:
    """rosbags' object of a CDR payload."""
    return typestore().deserialize_cdr(payload, type_name)


def plain(obj: Any) -> Any:
    """A rosbags object as dicts, lists and Python numbers."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, list | tuple):
        return [plain(x) for x in obj]
    if dataclasses.is_dataclass(obj):
        fields = [f.name for f in dataclasses.fields(obj) if f.name.islower() and f.name[0] != "_"]
        return {name: plain(getattr(obj, name)) for name in fields}
    return obj.item() if isinstance(obj, np.generic) else obj


def read_mcap(path: Path) -> dict[str, list[tuple[int, Any]]]:
    """topic -> [(log time, rosbags object)], decoded with the file's own schemas."""
    out: dict[str, list[tuple[int, Any]]] = {}
    store = get_typestore(Stores.EMPTY)
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh, validate_crcs=True).iter_messages():
            assert schema is not None and schema.encoding == "ros2msg"
            if schema.name not in store.types:
                store.register(schema_types(schema.name, schema.data.decode()))
            obj = store.deserialize_cdr(message.data, schema.name)
            out.setdefault(channel.topic, []).append((message.log_time, obj))
    return out


def schema_types(name: str, text: str) -> dict[str, Any]:
    """rosbags' types of a ros2msg schema: the main .msg, then ``MSG: pkg/Name`` sections."""
    sections = re.split(r"^={80}\nMSG: (\S+)\n", text, flags=re.M)
    types = get_types_from_msg(sections[0], name)
    for dep, body in zip(sections[1::2], sections[2::2], strict=True):
        pkg, short = dep.split("/")
        types |= get_types_from_msg(body, f"{pkg}/msg/{short}")
    return types
