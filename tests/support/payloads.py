"""Seeded generators of hostile inputs for the Zenoh and CAN fuzz tests and benchmarks.

Zenoh: mutations of a valid JSON payload (byte flips, truncation, a field replaced by a
nasty value, garbage, oversize, wrong version, deep nesting), plus some valid payloads so
the accepting path runs too. CAN: frames with our data type IDs and random source nodes,
tails and lengths, service and anonymous frames, 11-bit IDs, and well-formed starts of
multi-frame transfers that never end. Deterministic for a given seed.
"""

from __future__ import annotations

import json
import random
from collections.abc import Iterator

NASTY: tuple[str, ...] = (
    "9" * 19, "-" + "9" * 400, "9" * 5000, "1e999", "-1e999", "NaN", "Infinity", "-0.0",
    "1.7976931348623157e308", "true", "null", "[]", "{}", '"12"', '"' + "x" * 70000 + '"',
    "[" * 5000 + "]" * 5000, '"\\ud800"', "0." + "0" * 5000 + "1", "1" + "0" * 400 + ".0",
)  # fmt: skip


def _mutate(rng: random.Random, base: bytes, fields: list[str]) -> bytes:
    kind = rng.randrange(9)
    if kind == 0:  # flip bytes
        b = bytearray(base)
        for _ in range(rng.randint(1, 5)):
            b[rng.randrange(len(b))] = rng.randrange(256)
        return bytes(b)
    if kind == 1:
        return base[: rng.randrange(len(base))]
    if kind in (2, 3, 4):  # one field made nasty
        obj = json.loads(base)
        text = json.dumps(obj)
        key = rng.choice(fields)
        old = json.dumps(obj[key])
        return text.replace(f'"{key}": {old}', f'"{key}": {rng.choice(NASTY)}', 1).encode()
    if kind == 5:
        return rng.randbytes(rng.randint(0, 200))
    if kind == 6:
        return base[:-1] + b',"pad":"' + b"y" * 70000 + b'"}'
    if kind == 7:
        return base.replace(b'"v": 1', rng.choice([b'"v": 2', b'"v": true', b'"v": "1"']))
    return base  # valid


def zenoh_payloads(base: dict[str, object], n: int, seed: int = 1) -> Iterator[bytes]:
    """n payloads derived from the valid object ``base`` (must hold ``"v": 1``)."""
    rng = random.Random(seed)
    text = json.dumps(base).encode()
    fields = [k for k in base if k != "v"]
    for _ in range(n):
        yield _mutate(rng, text, fields)


OUR_TYPES = (341, 1030, 1034)


def can_frames(n: int, seed: int = 2) -> Iterator[tuple[int, bool, bytes]]:
    """n (arbitration_id, extended, data) frames aimed at a DroneCAN receiver."""
    rng = random.Random(seed)
    for _ in range(n):
        kind = rng.randrange(6)
        prio, node = rng.randrange(32), rng.randrange(128)
        dtid = rng.choice(OUR_TYPES) if kind < 4 else rng.randrange(1 << 16)
        can_id = prio << 24 | dtid << 8 | node
        if kind == 4:
            can_id |= 0x80  # service frame
        data = rng.randbytes(rng.randint(0, 8))
        if kind == 1 and data:  # start of a multi-frame transfer that never ends
            data = rng.randbytes(7) + bytes([0x80 | rng.randrange(32)])
        if kind == 5:
            yield rng.randrange(1 << 11), False, data
            continue
        yield can_id, True, data
