"""Key expressions and payload encoding for the ftcap Zenoh bridge (pure: no zenoh import).

Encoding: one UTF-8 JSON object per sample, SI units spelled in the field names, and a version
field ``"v": 1``. JSON rather than a fixed binary struct: any Zenoh tool can read a payload
(``z_sub``) or send one by hand (``z_put``), and the thruster count m varies (its cost against
the latency budget: docs/decisions.md).

Rules shared by every payload:

* a wrench is always an object ``{"X_N": X, "Y_N": Y, "N_Nm": N}`` (body frame, Fossen);
* per-thruster quantities are arrays in the order of the vessel file;
* numbers must be finite; ``null`` is used where the message type allows "unknown"
  (``time_s``, a fault ``value``, a port age that is +inf);
* decoders ignore unknown fields (additive changes keep ``v = 1``; a breaking change bumps it)
  and raise :class:`~ftcap_hil.core.messages.MalformedMessage` for anything else that is wrong:
  not JSON, wrong ``v``, missing field, wrong type (``true`` is not a number), wrong length,
  NaN/Infinity, out-of-range value, or a payload above :data:`MAX_PAYLOAD_BYTES`.

Key expressions are ``ftcap/<vessel>/<topic>`` (:class:`ZenohKeys`); W is a wrench object.

| topic | direction | payload fields (besides ``"v": 1``) | units |
|---|---|---|---|
| ``setpoint/wrench`` | GCS -> allocator | ``X_N, Y_N, N_Nm`` | N, N, N*m (body) |
| ``telemetry/odometry`` | vessel -> all | ``north_m, east_m, psi_rad``, | m, m, rad (NED) |
| | | ``u_mps, v_mps, r_radps``, | m/s, m/s, rad/s |
| | | ``time_s`` (number or null) | s, sender sim clock |
| ``thrusters/command`` | allocator -> all | ``u_N: [m numbers]`` | N per thruster |
| ``fault/inject`` | GCS -> vessel | ``index`` (int >= 0), | 0-based thruster |
| | | ``kind``: ok, off, stuck, weak, bias | |
| | | ``value`` (number or null = default) | weak: delta 0..1; N |
| ``allocator/status`` | allocator -> all | ``mode`` (str), ``cycle``, ``overruns`` (int), | |
| (and the reply of | | ``degraded`` (bool), ``delta_hat: [m]``, | 1 = healthy |
| ``allocator/state``) | | ``f_hat_N: [m]``, ``bf_hat: W``, ``u_N: [m]``, | N, W = B f_hat |
| | | ``tau_unallocated: W``, ``saturated: [m bool]``, | demanded - achieved |
| | | ``port_age_s: {port: number or null}``, | s; null = never |
| | | ``stale: {port: bool}`` | |

Example setpoint: ``{"v":1,"X_N":1200.0,"Y_N":0.0,"N_Nm":-350.0}``.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import (
    FaultInjection,
    FaultKind,
    FloatArray,
    Odometry,
    ThrusterCommand,
    WrenchSetpoint,
)
from ftcap_hil.core.status import AllocatorStatus, Mode

VERSION = 1
MAX_PAYLOAD_BYTES = 65536
KEY_PREFIX = "ftcap"
_VESSEL_NAME = re.compile(r"[A-Za-z0-9_-]+")
_WRENCH_FIELDS = ("X_N", "Y_N", "N_Nm")
_ETA_FIELDS = ("north_m", "east_m", "psi_rad")
_NU_FIELDS = ("u_mps", "v_mps", "r_radps")


@dataclass(frozen=True)
class ZenohKeys:
    """The key expressions of one vessel: ``ftcap/<vessel>/<topic>``."""

    vessel: str
    setpoint_wrench: str
    odometry: str
    thruster_command: str
    status: str
    state: str
    fault_inject: str

    @classmethod
    def for_vessel(cls, vessel: str) -> ZenohKeys:
        """Raise ValueError unless ``vessel`` is one plain key chunk ([A-Za-z0-9_-]+)."""
        if not _VESSEL_NAME.fullmatch(vessel):
            raise ValueError(f"vessel name {vessel!r}: use letters, digits, '_' or '-' only")
        base = f"{KEY_PREFIX}/{vessel}"
        return cls(
            vessel=vessel,
            setpoint_wrench=f"{base}/setpoint/wrench",
            odometry=f"{base}/telemetry/odometry",
            thruster_command=f"{base}/thrusters/command",
            status=f"{base}/allocator/status",
            state=f"{base}/allocator/state",
            fault_inject=f"{base}/fault/inject",
        )


# --------------------------------------------------------------------------- helpers


def _dump(obj: dict[str, Any]) -> bytes:
    try:
        return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
    except ValueError as e:  # allow_nan=False: a NaN/inf reached the encoder
        raise MalformedMessage(f"cannot encode non-finite value: {e}") from e


def _finite_list(name: str, value: object, length: int | None = None) -> list[float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise MalformedMessage(f"{name}: not a numeric vector: {e}") from e
    if arr.ndim != 1 or (length is not None and arr.shape[0] != length):
        raise MalformedMessage(f"{name}: expected a vector of length {length}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise MalformedMessage(f"{name}: non-finite value in {arr.tolist()}")
    out: list[float] = arr.tolist()
    return out


def _wrench_obj(name: str, tau: object) -> dict[str, float]:
    return dict(zip(_WRENCH_FIELDS, _finite_list(name, tau, 3), strict=True))


def _optional_float(value: float) -> float | None:
    return None if math.isnan(value) else float(value)


def _load(payload: bytes | bytearray | memoryview | str) -> dict[str, Any]:
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MalformedMessage(f"payload of {len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        text = payload if isinstance(payload, str) else bytes(payload).decode("utf-8")
        obj = json.loads(text, parse_constant=_reject_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise MalformedMessage(f"not a JSON payload: {e}") from e
    if not isinstance(obj, dict):
        raise MalformedMessage(f"expected a JSON object, got {type(obj).__name__}")
    if obj.get("v") != VERSION or isinstance(obj.get("v"), bool):
        raise MalformedMessage(f"unsupported version v={obj.get('v')!r} (expected {VERSION})")
    return obj


def _reject_constant(name: str) -> float:
    raise MalformedMessage(f"non-finite constant {name} in payload")


def _get(obj: Mapping[str, Any], key: str) -> Any:
    try:
        return obj[key]
    except KeyError:
        raise MalformedMessage(f"missing field {key!r}") from None


def _number(obj: Mapping[str, Any], key: str, *, nullable: bool = False) -> float:
    value = _get(obj, key)
    if value is None and nullable:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise MalformedMessage(f"{key}: expected a number, got {value!r}")
    if not math.isfinite(value):  # 1e999 parses to inf
        raise MalformedMessage(f"{key}: non-finite value {value!r}")
    return float(value)


def _integer(obj: Mapping[str, Any], key: str, minimum: int = 0) -> int:
    value = _get(obj, key)
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise MalformedMessage(f"{key}: expected an integer >= {minimum}, got {value!r}")
    return value


def _boolean(obj: Mapping[str, Any], key: str) -> bool:
    value = _get(obj, key)
    if not isinstance(value, bool):
        raise MalformedMessage(f"{key}: expected true/false, got {value!r}")
    return value


def _vector(obj: Mapping[str, Any], key: str, length: int | None = None) -> FloatArray:
    value = _get(obj, key)
    if not isinstance(value, list) or (length is not None and len(value) != length):
        want = "a list" if length is None else f"a list of {length}"
        raise MalformedMessage(f"{key}: expected {want} numbers, got {value!r:.80}")
    if any(isinstance(x, bool) or not isinstance(x, int | float) for x in value):
        raise MalformedMessage(f"{key}: expected numbers only, got {value!r:.80}")
    arr = np.array(value, dtype=np.float64)
    if not np.all(np.isfinite(arr)):
        raise MalformedMessage(f"{key}: non-finite value in {value!r:.80}")
    return arr


def _wrench(obj: Mapping[str, Any], key: str | None = None) -> FloatArray:
    """Read {X_N, Y_N, N_Nm} from ``obj`` itself (key None) or from ``obj[key]``."""
    src = obj if key is None else _get(obj, key)
    if not isinstance(src, dict):
        raise MalformedMessage(f"{key}: expected a wrench object, got {src!r:.80}")
    return np.array([_number(src, k) for k in _WRENCH_FIELDS], dtype=np.float64)


# --------------------------------------------------------------------------- messages


def encode_wrench_setpoint(msg: WrenchSetpoint) -> bytes:
    """``setpoint/wrench`` payload; MalformedMessage for a non-finite wrench."""
    return _dump({"v": VERSION, **_wrench_obj("wrench", msg.tau)})


def decode_wrench_setpoint(payload: bytes | str) -> WrenchSetpoint:
    """The wrench of a ``setpoint/wrench`` payload; MalformedMessage if invalid."""
    return WrenchSetpoint(_wrench(_load(payload)))


def encode_odometry(msg: Odometry) -> bytes:
    """``telemetry/odometry`` payload (NaN ``time_s`` as null); MalformedMessage if not finite."""
    eta = dict(zip(_ETA_FIELDS, _finite_list("eta", msg.eta, 3), strict=True))
    nu = dict(zip(_NU_FIELDS, _finite_list("nu", msg.nu, 3), strict=True))
    return _dump({"v": VERSION, **eta, **nu, "time_s": _optional_float(msg.time_s)})


def decode_odometry(payload: bytes | str) -> Odometry:
    """eta, nu and time_s (NaN if null or absent) of a payload; MalformedMessage if invalid."""
    obj = _load(payload)
    eta = np.array([_number(obj, k) for k in _ETA_FIELDS], dtype=np.float64)
    nu = np.array([_number(obj, k) for k in _NU_FIELDS], dtype=np.float64)
    time_s = _number(obj, "time_s", nullable=True) if "time_s" in obj else math.nan
    return Odometry(eta, nu, time_s)


def encode_thruster_command(msg: ThrusterCommand) -> bytes:
    """``thrusters/command`` payload (u in N); MalformedMessage for a non-finite force."""
    return _dump({"v": VERSION, "u_N": _finite_list("u_N", msg.u)})


def decode_thruster_command(payload: bytes | str, m: int | None = None) -> ThrusterCommand:
    """``m``: expected number of thrusters, or None to accept any non-empty length."""
    u = _vector(_load(payload), "u_N", m)
    if u.shape[0] == 0:
        raise MalformedMessage("u_N: empty thruster command")
    return ThrusterCommand(u)


def _check_fault(index: int, kind: FaultKind, value: float, m: int | None) -> None:
    if m is not None and index >= m:
        raise MalformedMessage(f"index: thruster {index} does not exist (m = {m})")
    if kind is FaultKind.WEAK and not (math.isnan(value) or 0.0 <= value <= 1.0):
        raise MalformedMessage(f"value: weak fault needs delta in [0, 1], got {value}")


def encode_fault_injection(msg: FaultInjection) -> bytes:
    """``fault/inject`` payload (NaN value as null); MalformedMessage for a bad index/value."""
    if isinstance(msg.index, bool) or not isinstance(msg.index, int) or msg.index < 0:
        raise MalformedMessage(f"index: expected an integer >= 0, got {msg.index!r}")
    if math.isinf(msg.value):
        raise MalformedMessage(f"value: non-finite value {msg.value}")
    _check_fault(msg.index, msg.kind, msg.value, None)
    body = {"index": msg.index, "kind": msg.kind.value, "value": _optional_float(msg.value)}
    return _dump({"v": VERSION, **body})


def decode_fault_injection(payload: bytes | str, m: int | None = None) -> FaultInjection:
    """``m``: number of thrusters, to refuse an index that does not exist (None: no check)."""
    obj = _load(payload)
    index = _integer(obj, "index")
    kind_text = _get(obj, "kind")
    try:
        kind = FaultKind(kind_text)
    except ValueError:
        known = [k.value for k in FaultKind]
        raise MalformedMessage(f"kind: {kind_text!r} is not one of {known}") from None
    value = _number(obj, "value", nullable=True) if "value" in obj else math.nan
    _check_fault(index, kind, value, m)
    return FaultInjection(index, kind, value)


# --------------------------------------------------------------------------- status


def encode_status(status: AllocatorStatus) -> bytes:
    """Encode a status; raise MalformedMessage for mismatched lengths or non-finite values."""
    s = status
    delta_hat = _finite_list("delta_hat", s.delta_hat)
    m = len(delta_hat)
    flags = {name: _flags(name, getattr(s, name), m) for name in _FLAG_FIELDS}
    if any(len(v) not in (0, m) for v in (s.esc_rpm, s.esc_current_a, s.esc_age_s, s.delta_std)):
        raise MalformedMessage(f"esc telemetry: expected {m} entries per field")
    ages = {"setpoint": s.setpoint_age_s, "telemetry": s.telemetry_age_s}
    ages |= {f"esc{i + 1}": a for i, a in enumerate(s.esc_age_s)}
    body = {
        "mode": None if s.mode is None else s.mode.value,
        "cycle": int(s.cycle),
        "overruns": int(s.overruns),
        "degraded": bool(s.degraded),
        "estimation_frozen": bool(s.estimation_frozen),
        "delta_hat": delta_hat,
        "delta_std": _finite_list("delta_std", s.delta_std) if s.delta_std else [],
        "f_hat_N": _finite_list("f_hat", s.f_hat, m),
        "bf_hat": _wrench_obj("bf_hat", s.bf_hat),
        "u_N": _finite_list("u", s.u, m),
        "tau_demand": _wrench_obj("tau_demand", s.tau_demand or (0.0,) * 3),
        "tau_unallocated": _wrench_obj("tau_unallocated", s.unallocated),
        **flags,
        "port_age_s": {k: (None if math.isinf(v) else float(v)) for k, v in ages.items()},
        "stale": {"setpoint": bool(s.setpoint_stale), "telemetry": bool(s.telemetry_stale)},
        "malformed": int(s.malformed),
        "esc_rpm": [_optional_float(float(v)) for v in s.esc_rpm],
        "esc_current_A": [_optional_float(float(v)) for v in s.esc_current_a],
    }
    return _dump({"v": VERSION, **body})


_FLAG_FIELDS = ("saturated", "faulty", "esc_failed", "probing", "observable")


def _flags(name: str, value: tuple[bool, ...], m: int) -> list[bool]:
    flags = [bool(f) for f in value]
    if len(flags) not in ((m,) if name == "saturated" else (0, m)):
        raise MalformedMessage(f"{name}: expected {m} flags, got {len(flags)}")
    return flags


def decode_status(payload: bytes | str) -> AllocatorStatus:
    """The status of a payload; fields added after v1 are optional (their defaults)."""
    obj = _load(payload)
    delta_hat = _vector(obj, "delta_hat")
    m = delta_hat.shape[0]
    ages = _port_ages(_get(obj, "port_age_s"))
    stale = _port_flags(_get(obj, "stale"))
    flags: dict[str, Any] = {
        name: _flag_list(obj, name, m)
        for name in _FLAG_FIELDS
        if name == "saturated" or name in obj
    }
    esc: dict[str, Any] = {
        attr: tuple(_optional_vector(obj, key, m))
        for attr, key in (("esc_rpm", "esc_rpm"), ("esc_current_a", "esc_current_A"))
        if key in obj
    }
    esc_ages = tuple(ages[f"esc{i + 1}"] for i in range(m) if f"esc{i + 1}" in ages)
    return AllocatorStatus(
        mode=_mode(_get(obj, "mode")),
        cycle=_integer(obj, "cycle"),
        overruns=_integer(obj, "overruns"),
        degraded=_boolean(obj, "degraded"),
        estimation_frozen=_boolean(obj, "estimation_frozen")
        if "estimation_frozen" in obj
        else False,
        delta_hat=tuple(delta_hat.tolist()),
        delta_std=tuple(_vector(obj, "delta_std").tolist()) if obj.get("delta_std") else (),
        f_hat=tuple(_vector(obj, "f_hat_N", m).tolist()),
        bf_hat=tuple(_wrench(obj, "bf_hat").tolist()),
        u=tuple(_vector(obj, "u_N", m).tolist()),
        tau_demand=tuple(_wrench(obj, "tau_demand").tolist()) if "tau_demand" in obj else (),
        unallocated=tuple(_wrench(obj, "tau_unallocated").tolist()),
        setpoint_stale=stale.get("setpoint", False),
        telemetry_stale=stale.get("telemetry", False),
        setpoint_age_s=ages.get("setpoint", math.inf),
        telemetry_age_s=ages.get("telemetry", math.inf),
        malformed=_integer(obj, "malformed") if "malformed" in obj else 0,
        esc_age_s=esc_ages if len(esc_ages) == m else (),
        **flags,
        **esc,
    )


def _mode(value: object) -> Mode | None:
    if value is None:
        return None
    try:
        return Mode(value)
    except ValueError:
        raise MalformedMessage(
            f"mode: {value!r:.40} is not one of {[m.value for m in Mode]}"
        ) from None


def _flag_list(obj: Mapping[str, Any], key: str, m: int) -> tuple[bool, ...]:
    """m flags (``saturated``), or m or none (the fields added after v1)."""
    value = _get(obj, key)
    lengths = (m,) if key == "saturated" else (0, m)
    if not isinstance(value, list) or len(value) not in lengths:
        raise MalformedMessage(f"{key}: expected a list of {m} flags, got {value!r:.80}")
    if not all(isinstance(x, bool) for x in value):
        raise MalformedMessage(f"{key}: expected true/false flags, got {value!r:.80}")
    return tuple(value)


def _optional_vector(obj: Mapping[str, Any], key: str, m: int) -> list[float]:
    """A list of m numbers or nulls (null: unknown, NaN)."""
    value = _get(obj, key)
    if not isinstance(value, list) or len(value) not in (0, m):
        raise MalformedMessage(f"{key}: expected a list of {m} numbers or nulls, got {value!r:.80}")
    named = {f"{key}[{i}]": x for i, x in enumerate(value)}
    return [_number(named, f"{key}[{i}]", nullable=True) for i in range(len(value))]


def _port_ages(value: object) -> dict[str, float]:
    if not isinstance(value, dict):
        raise MalformedMessage(f"port_age_s: expected an object, got {value!r:.80}")
    named = {f"port_age_s.{port}": age for port, age in value.items()}
    ages = {port: _number(named, f"port_age_s.{port}", nullable=True) for port in value}
    if any(age < 0.0 for age in ages.values()):
        raise MalformedMessage(f"port_age_s: negative age in {ages}")
    return {port: math.inf if math.isnan(age) else age for port, age in ages.items()}


def _port_flags(value: object) -> dict[str, bool]:
    if not isinstance(value, dict):
        raise MalformedMessage(f"stale: expected an object, got {value!r:.80}")
    named = {f"stale.{port}": flag for port, flag in value.items()}
    return {port: _boolean(named, f"stale.{port}") for port in value}
