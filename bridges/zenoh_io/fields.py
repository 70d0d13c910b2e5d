"""The JSON rules every ftcap Zenoh payload follows (pure: no zenoh import).

Writers turn our values into JSON-ready fields and refuse what JSON must not carry; readers
take one field of a decoded payload and raise :class:`~ftcap_hil.core.errors.MalformedMessage`
for anything wrong: a missing field, a wrong type (``true`` is not a number), a wrong length,
NaN/Infinity, an out-of-range value. :func:`load` also refuses a payload that is not a UTF-8
JSON object, has another ``"v"`` than :data:`VERSION`, exceeds :data:`MAX_PAYLOAD_BYTES`, or
holds an integer literal of more than :data:`MAX_INT_DIGITS` digits (no field needs one, and
converting a long one costs time and then overflows a float).
The payloads themselves are in :mod:`bridges.zenoh_io.codec`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import FloatArray, finite_vector

VERSION = 1
MAX_PAYLOAD_BYTES = 65536
MAX_INT_DIGITS = 18  # every integer field fits: int64 has 19 digits, a float 15-17
WRENCH_FIELDS = ("X_N", "Y_N", "N_Nm")


def dump(body: dict[str, Any]) -> bytes:
    """``{"v": VERSION, **body}`` as compact UTF-8 JSON; MalformedMessage for NaN or inf."""
    try:
        return json.dumps({"v": VERSION, **body}, separators=(",", ":"), allow_nan=False).encode()
    except ValueError as e:  # allow_nan=False: a NaN/inf reached the encoder
        raise MalformedMessage(f"cannot encode non-finite value: {e}") from e


def finite_list(name: str, value: object, length: int | None = None) -> list[float]:
    """``value`` as a list of finite floats (of ``length`` if given), for a writer."""
    try:
        out: list[float] = finite_vector(name, value, length).tolist()
    except MalformedMessage:
        raise
    except (TypeError, ValueError) as e:  # not numbers at all
        raise MalformedMessage(f"{name}: not a numeric vector: {e}") from e
    return out


def wrench_obj(name: str, tau: object) -> dict[str, float]:
    """``tau`` (3,) as the wrench object ``{"X_N": X, "Y_N": Y, "N_Nm": N}``."""
    return dict(zip(WRENCH_FIELDS, finite_list(name, tau, 3), strict=True))


def optional_float(value: float) -> float | None:
    """``value``, or None (JSON null: unknown) for NaN."""
    return None if math.isnan(value) else float(value)


def load(payload: bytes | bytearray | memoryview | str) -> dict[str, Any]:
    """The JSON object of a payload, checked (module docstring)."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MalformedMessage(f"payload of {len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        text = payload if isinstance(payload, str) else bytes(payload).decode("utf-8")
        obj = json.loads(text, parse_constant=_reject_constant, parse_int=_parse_int)
    except (UnicodeDecodeError, ValueError, RecursionError) as e:  # JSONDecodeError too
        raise MalformedMessage(f"not a JSON payload: {e}") from e
    if not isinstance(obj, dict):
        raise MalformedMessage(f"expected a JSON object, got {type(obj).__name__}")
    if obj.get("v") != VERSION or isinstance(obj.get("v"), bool):
        raise MalformedMessage(f"unsupported version v={obj.get('v')!r} (expected {VERSION})")
    return obj


def _reject_constant(name: str) -> float:
    raise MalformedMessage(f"non-finite constant {name} in payload")


def _parse_int(literal: str) -> int:
    if len(literal.lstrip("-")) > MAX_INT_DIGITS:
        raise MalformedMessage(f"integer literal of {len(literal)} characters in payload")
    return int(literal)


def get_field(obj: Mapping[str, Any], key: str) -> Any:
    """``obj[key]``; MalformedMessage naming the field if it is missing."""
    try:
        return obj[key]
    except KeyError:
        raise MalformedMessage(f"missing field {key!r}") from None


def number(obj: Mapping[str, Any], key: str, *, nullable: bool = False) -> float:
    """A finite number; ``nullable``: null reads as NaN."""
    value = get_field(obj, key)
    if value is None and nullable:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MalformedMessage(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):  # 1e999 parses to inf
        raise MalformedMessage(f"{key}: non-finite value {value!r}")
    return float(value)


def integer(obj: Mapping[str, Any], key: str, minimum: int = 0) -> int:
    """An integer >= ``minimum`` (a bool is not one)."""
    value = get_field(obj, key)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise MalformedMessage(f"{key}: expected an integer >= {minimum}, got {value!r}")
    return value


def boolean(obj: Mapping[str, Any], key: str) -> bool:
    """``true`` or ``false``."""
    value = get_field(obj, key)
    if not isinstance(value, bool):
        raise MalformedMessage(f"{key}: expected true/false, got {value!r}")
    return value


def vector(obj: Mapping[str, Any], key: str, length: int | None = None) -> FloatArray:
    """A list of finite numbers (of ``length`` if given) as an array."""
    value = get_field(obj, key)
    if not isinstance(value, list) or (length is not None and len(value) != length):
        want = "a list" if length is None else f"a list of {length}"
        raise MalformedMessage(f"{key}: expected {want} numbers, got {value!r:.80}")
    if any(isinstance(x, bool) or not isinstance(x, int | float) for x in value):
        raise MalformedMessage(f"{key}: expected numbers only, got {value!r:.80}")
    arr = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise MalformedMessage(f"{key}: non-finite value in {value!r:.80}")
    return arr


def wrench(obj: Mapping[str, Any], key: str | None = None) -> FloatArray:
    """Read {X_N, Y_N, N_Nm} from ``obj`` itself (key None) or from ``obj[key]``."""
    src = obj if key is None else get_field(obj, key)
    if not isinstance(src, dict):
        raise MalformedMessage(f"{key}: expected a wrench object, got {src!r:.80}")
    return np.array([number(src, k) for k in WRENCH_FIELDS], dtype=np.float64)
