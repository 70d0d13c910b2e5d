"""REP-2011 type hashes (``RIHS01_<sha256 hex>``) computed from message definitions.

The hash of a type is the SHA-256 of its *type description* written as JSON: an object
``{"type_description": T, "referenced_type_descriptions": [R, ...]}`` where T describes the
type and each R one type it refers to (directly or not), sorted by type name, each
``{"type_name": "pkg/msg/Name", "fields": [F, ...]}`` with, per field in order,
``{"name": ..., "type": {"type_id": N, "capacity": N, "string_capacity": N,
"nested_type_name": "pkg/msg/Name" or ""}}`` (default values are not hashed). The JSON is
written with ``", "`` and ``": "`` as separators, keys in that order, ASCII only.

``type_id`` is ``type_description_interfaces/msg/FieldType``'s number: a base id per element
type (:data:`BASE_TYPE_IDS`) plus 48 for a fixed array, 144 for an unbounded sequence;
``capacity`` is a fixed array's length (else 0); ``string_capacity`` a ``string<=N``'s N.
The hash names a type in rmw_zenoh's key expressions and liveliness tokens: a publisher and
a subscriber only meet when their hashes are equal. Pure: no zenoh import.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from bridges.zenoh_io.ros2.msgdef import STRING, Field, Registry

RIHS01_PREFIX = "RIHS01_"
BASE_TYPE_IDS = {
    "nested": 1,
    "int8": 2,
    "uint8": 3,
    "char": 3,  # char is uint8 in ROS 2 IDL
    "int16": 4,
    "uint16": 5,
    "int32": 6,
    "uint32": 7,
    "int64": 8,
    "uint64": 9,
    "float32": 10,
    "float64": 11,
    "bool": 15,
    "byte": 16,
    "string": 17,
    "bounded_string": 21,
}
ARRAY_OFFSET = 48
UNBOUNDED_SEQUENCE_OFFSET = 144


def field_type_id(f: Field) -> int:
    """The FieldType number of ``f`` (module docstring)."""
    if f.nested:
        base = BASE_TYPE_IDS["nested"]
    elif f.base == STRING and f.string_bound:
        base = BASE_TYPE_IDS["bounded_string"]
    else:
        base = BASE_TYPE_IDS[f.base]
    if f.array is not None:
        return base + ARRAY_OFFSET
    return base + UNBOUNDED_SEQUENCE_OFFSET if f.sequence else base


def _field(f: Field) -> dict[str, Any]:
    return {
        "name": f.name,
        "type": {
            "type_id": field_type_id(f),
            "capacity": f.array or 0,
            "string_capacity": f.string_bound,
            "nested_type_name": f.base if f.nested else "",
        },
    }


def _individual(registry: Registry, name: str) -> dict[str, Any]:
    return {"type_name": name, "fields": [_field(f) for f in registry[name].fields]}


def type_description(registry: Registry, name: str) -> dict[str, Any]:
    """The hashed type description of ``name`` (module docstring)."""
    return {
        "type_description": _individual(registry, name),
        "referenced_type_descriptions": [
            _individual(registry, dep) for dep in sorted(registry.dependencies(name))
        ],
    }


def type_hash(registry: Registry, name: str) -> str:
    """``RIHS01_`` and the SHA-256 (hex) of ``name``'s type description as JSON."""
    text = json.dumps(type_description(registry, name), separators=(", ", ": "), ensure_ascii=True)
    return RIHS01_PREFIX + hashlib.sha256(text.encode("utf-8")).hexdigest()
