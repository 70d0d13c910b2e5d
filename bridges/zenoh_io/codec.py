"""Key expressions and payload encoding for the ftcap Zenoh bridge (pure: no zenoh import).

Encoding: one UTF-8 JSON object per sample, SI units spelled in the field names, and a version
field ``"v": 1``. JSON rather than a fixed binary struct: any Zenoh tool can read a payload
(``z_sub``) or send one by hand (``z_put``), and the thruster count m varies (its cost against
the latency budget: docs/decisions.md).

Rules shared by every payload (their readers and writers: :mod:`bridges.zenoh_io.fields`):

* a wrench is always an object ``{"X_N": X, "Y_N": Y, "N_Nm": N}`` (body frame, Fossen);
* per-thruster quantities are arrays in the order of the vessel file;
* numbers must be finite; ``null`` is used where the message type allows "unknown"
  (``time_s``, a fault ``value``, a port age that is +inf);
* decoders ignore unknown fields (additive changes keep ``v = 1``; a breaking change bumps it)
  and raise :class:`~ftcap_hil.core.errors.MalformedMessage` for anything else that is wrong:
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

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from bridges.zenoh_io.fields import (
    MAX_PAYLOAD_BYTES,
    VERSION,
    WRENCH_FIELDS,
    boolean,
    dump,
    finite_list,
    get_field,
    integer,
    load,
    number,
    optional_float,
    vector,
    wrench,
    wrench_obj,
)
from ftcap_hil.core.errors import MalformedMessage
from ftcap_hil.core.messages import (
    FaultInjection,
    FaultKind,
    Odometry,
    ThrusterCommand,
    WrenchSetpoint,
)
from ftcap_hil.core.status import AllocatorStatus, Mode

__all__ = [
    "KEY_PREFIX",
    "MAX_PAYLOAD_BYTES",
    "VERSION",
    "WRENCH_FIELDS",
    "ZenohKeys",
    "decode_fault_injection",
    "decode_odometry",
    "decode_status",
    "decode_thruster_command",
    "decode_wrench_setpoint",
    "encode_fault_injection",
    "encode_odometry",
    "encode_status",
    "encode_thruster_command",
    "encode_wrench_setpoint",
]

KEY_PREFIX = "ftcap"
_VESSEL_NAME = re.compile(r"[A-Za-z0-9_-]+")
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


# --------------------------------------------------------------------------- messages


def encode_wrench_setpoint(msg: WrenchSetpoint) -> bytes:
    """``setpoint/wrench`` payload; MalformedMessage for a non-finite wrench."""
    return dump(wrench_obj("wrench", msg.tau))


def decode_wrench_setpoint(
    payload: bytes | str, limit: tuple[float, float, float] | None = None
) -> WrenchSetpoint:
    """The wrench of a ``setpoint/wrench`` payload; MalformedMessage if invalid or, with
    ``limit`` (N, N, N*m), if a component exceeds it in magnitude (a sanity bound)."""
    tau = wrench(load(payload))
    if limit is not None and np.any(np.abs(tau) > np.asarray(limit)):
        raise MalformedMessage(f"wrench {tau.tolist()} beyond the limit +-{list(limit)}")
    return WrenchSetpoint(tau)


def encode_odometry(msg: Odometry) -> bytes:
    """``telemetry/odometry`` payload (NaN ``time_s`` as null); MalformedMessage if not finite."""
    eta = dict(zip(_ETA_FIELDS, finite_list("eta", msg.eta, 3), strict=True))
    nu = dict(zip(_NU_FIELDS, finite_list("nu", msg.nu, 3), strict=True))
    return dump({**eta, **nu, "time_s": optional_float(msg.time_s)})


def decode_odometry(payload: bytes | str) -> Odometry:
    """eta, nu and time_s (NaN if null or absent) of a payload; MalformedMessage if invalid."""
    obj = load(payload)
    eta = np.array([number(obj, k) for k in _ETA_FIELDS], dtype=np.float64)
    nu = np.array([number(obj, k) for k in _NU_FIELDS], dtype=np.float64)
    time_s = number(obj, "time_s", nullable=True) if "time_s" in obj else math.nan
    return Odometry(eta, nu, time_s)


def encode_thruster_command(msg: ThrusterCommand) -> bytes:
    """``thrusters/command`` payload (u in N); MalformedMessage for a non-finite force."""
    return dump({"u_N": finite_list("u_N", msg.u)})


def decode_thruster_command(payload: bytes | str, m: int | None = None) -> ThrusterCommand:
    """``m``: expected number of thrusters, or None to accept any non-empty length."""
    u = vector(load(payload), "u_N", m)
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
    body = {"index": msg.index, "kind": msg.kind.value, "value": optional_float(msg.value)}
    return dump(body)


def decode_fault_injection(payload: bytes | str, m: int | None = None) -> FaultInjection:
    """``m``: number of thrusters, to refuse an index that does not exist (None: no check)."""
    obj = load(payload)
    index = integer(obj, "index")
    kind_text = get_field(obj, "kind")
    try:
        kind = FaultKind(kind_text)
    except ValueError:
        known = [k.value for k in FaultKind]
        raise MalformedMessage(f"kind: {kind_text!r} is not one of {known}") from None
    value = number(obj, "value", nullable=True) if "value" in obj else math.nan
    _check_fault(index, kind, value, m)
    return FaultInjection(index, kind, value)


# --------------------------------------------------------------------------- status


def encode_status(status: AllocatorStatus) -> bytes:
    """Encode a status (checked when built: :meth:`AllocatorStatus.checked`); a wrench it
    does not carry is written as zeros. ``u``, ``f_hat`` and ``saturated`` are v1 fields a
    reader needs for every thruster: a status without them (one decoded from MAVLink) is
    written as it is and refused by :func:`decode_status`. MalformedMessage for a NaN that
    JSON cannot carry (a ``delta_std`` of NaN: unknown)."""
    s = status
    ages = {"setpoint": s.setpoint_age_s, "telemetry": s.telemetry_age_s}
    ages |= {f"esc{i + 1}": a for i, a in enumerate(s.esc_age_s)}
    body = {
        "mode": None if s.mode is None else s.mode.value,
        "cycle": s.cycle,
        "overruns": s.overruns,
        "degraded": s.degraded,
        "estimation_frozen": s.estimation_frozen,
        "delta_hat": list(s.delta_hat),
        "delta_std": list(s.delta_std),
        "f_hat_N": list(s.f_hat),
        "bf_hat": _wrench(s.bf_hat),
        "u_N": list(s.u),
        "tau_demand": _wrench(s.tau_demand),
        "tau_unallocated": _wrench(s.unallocated),
        **{name: list(getattr(s, name)) for name in _FLAG_FIELDS},
        "port_age_s": {k: (None if math.isinf(v) else v) for k, v in ages.items()},
        "stale": {"setpoint": s.setpoint_stale, "telemetry": s.telemetry_stale},
        "malformed": s.malformed,
        "esc_rpm": [optional_float(v) for v in s.esc_rpm],
        "esc_current_A": [optional_float(v) for v in s.esc_current_a],
        "hypothesis": list(s.hypothesis),
    }
    return dump(body)


def _wrench(tau: tuple[float, ...]) -> dict[str, float]:
    return dict(zip(WRENCH_FIELDS, tau or (0.0,) * 3, strict=True))


_FLAG_FIELDS = ("saturated", "faulty", "esc_failed", "probing", "observable")


def _flag_lengths(name: str, m: int) -> tuple[int, ...]:
    # ``saturated`` is v1 and always has m flags; the fields added after v1 may be empty.
    return (m,) if name == "saturated" else (0, m)


def decode_status(payload: bytes | str) -> AllocatorStatus:
    """The status of a payload (built by :meth:`AllocatorStatus.checked`); fields added
    after v1 are optional (their defaults)."""
    obj = load(payload)
    delta_hat = vector(obj, "delta_hat")
    m = delta_hat.shape[0]
    ages = _port_ages(get_field(obj, "port_age_s"))
    stale = _port_flags(get_field(obj, "stale"))
    flags: dict[str, Any] = {
        name: _flag_list(obj, name, m)
        for name in _FLAG_FIELDS
        if name == "saturated" or name in obj
    }
    esc: dict[str, Any] = {
        attr: _optional_vector(obj, key, m)
        for attr, key in (("esc_rpm", "esc_rpm"), ("esc_current_a", "esc_current_A"))
        if key in obj
    }
    esc_ages = tuple(ages[f"esc{i + 1}"] for i in range(m) if f"esc{i + 1}" in ages)
    return AllocatorStatus.checked(
        mode=_mode(get_field(obj, "mode")),
        cycle=integer(obj, "cycle"),
        overruns=integer(obj, "overruns"),
        degraded=boolean(obj, "degraded"),
        estimation_frozen=boolean(obj, "estimation_frozen")
        if "estimation_frozen" in obj
        else False,
        delta_hat=delta_hat,
        delta_std=vector(obj, "delta_std") if obj.get("delta_std") else (),
        f_hat=vector(obj, "f_hat_N", m),
        bf_hat=wrench(obj, "bf_hat"),
        u=vector(obj, "u_N", m),
        tau_demand=wrench(obj, "tau_demand") if "tau_demand" in obj else (),
        unallocated=wrench(obj, "tau_unallocated"),
        setpoint_stale=stale.get("setpoint", False),
        telemetry_stale=stale.get("telemetry", False),
        setpoint_age_s=ages.get("setpoint", math.inf),
        telemetry_age_s=ages.get("telemetry", math.inf),
        malformed=integer(obj, "malformed") if "malformed" in obj else 0,
        esc_age_s=esc_ages if len(esc_ages) == m else (),
        hypothesis=tuple(_strings(obj, "hypothesis")) if "hypothesis" in obj else (),
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
    """The flags of field ``key``, as many as :func:`_flag_lengths` allows."""
    value = get_field(obj, key)
    if not isinstance(value, list) or len(value) not in _flag_lengths(key, m):
        raise MalformedMessage(f"{key}: expected a list of {m} flags, got {value!r:.80}")
    if not all(isinstance(x, bool) for x in value):
        raise MalformedMessage(f"{key}: expected true/false flags, got {value!r:.80}")
    return tuple(value)


def _optional_vector(obj: Mapping[str, Any], key: str, m: int) -> list[float]:
    """A list of m numbers or nulls (null: unknown, NaN)."""
    value = get_field(obj, key)
    if not isinstance(value, list) or len(value) not in (0, m):
        raise MalformedMessage(f"{key}: expected a list of {m} numbers or nulls, got {value!r:.80}")
    named = {f"{key}[{i}]": x for i, x in enumerate(value)}
    return [number(named, f"{key}[{i}]", nullable=True) for i in range(len(value))]


def _port_ages(value: object) -> dict[str, float]:
    if not isinstance(value, dict):
        raise MalformedMessage(f"port_age_s: expected an object, got {value!r:.80}")
    named = {f"port_age_s.{port}": age for port, age in value.items()}
    ages = {port: number(named, f"port_age_s.{port}", nullable=True) for port in value}
    if any(age < 0.0 for age in ages.values()):
        raise MalformedMessage(f"port_age_s: negative age in {ages}")
    return {port: math.inf if math.isnan(age) else age for port, age in ages.items()}


def _port_flags(value: object) -> dict[str, bool]:
    if not isinstance(value, dict):
        raise MalformedMessage(f"stale: expected an object, got {value!r:.80}")
    named = {f"stale.{port}": flag for port, flag in value.items()}
    return {port: boolean(named, f"stale.{port}") for port in value}


def _strings(obj: Mapping[str, Any], key: str) -> list[str]:
    """A list of strings (its values judged by the status itself)."""
    value = get_field(obj, key)
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise MalformedMessage(f"field {key!r}: expected a list of strings, got {value!r:.60}")
    return value
