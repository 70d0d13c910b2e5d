"""FTCAP_STATUS encoded and decoded by field name, as the dialect lays its fields out."""

from __future__ import annotations

import math

import pytest

from bridges.mavlink.codec import dialect_message, status_fields, status_from_message
from bridges.mavlink.dialect import load
from ftcap_hil.core.status import AllocatorStatus

DIALECT = load()


def test_ftcap_status_is_built_and_read_by_field_name() -> None:
    status = AllocatorStatus.checked(
        tau_demand=(10.0, 0.0, 5.0),
        unallocated=(0.0, 0.0, 1.5),
        delta_hat=(1.0, 0.0, 0.5),
        f_hat=(0.0, 0.0, 3.0),
        delta_std=(0.0, 0.25, math.nan),
        faulty=(False, True, False),
        esc_failed=(True, False, False),
        saturated=(False, False, True),
        probing=(False, True, False),
    )
    fields = status_fields(status, time_boot_ms=1234)
    assert list(fields) == DIALECT.MAVLink_ftcap_status_message.fieldnames  # dialect order
    msg = dialect_message(DIALECT, "FTCAP_STATUS", fields)
    mav = DIALECT.MAVLink(None, srcSystem=1, srcComponent=191)
    wire = DIALECT.MAVLink(None).parse_buffer(msg.pack(mav))[0]
    assert (wire.time_boot_ms, wire.n_thrusters, wire.faulty, wire.saturated) == (1234, 3, 3, 4)
    assert wire.delta_hat[:4] == [1.0, 0.0, 0.5, 0.0]  # zero-padded to the dialect's 16
    back = status_from_message(wire)
    assert (back.delta_hat, back.f_hat, back.unallocated) == (
        status.delta_hat,
        status.f_hat,
        status.unallocated,
    )
    assert back.faulty == (True, True, False)  # an ESC failure is a fault on the wire
    assert back.delta_std[:2] == (0.0, 0.25) and math.isnan(back.delta_std[2])


def test_a_dialect_message_needs_exactly_its_fields() -> None:
    fields = status_fields(AllocatorStatus.checked(delta_hat=(1.0,)), time_boot_ms=0)
    without = {k: v for k, v in fields.items() if k != "probing"}
    with pytest.raises(ValueError, match=r"FTCAP_STATUS: missing fields \['probing'\]"):
        dialect_message(DIALECT, "FTCAP_STATUS", without)
    with pytest.raises(ValueError, match=r"unknown fields \['mode'\]"):
        dialect_message(DIALECT, "FTCAP_STATUS", {**fields, "mode": 1})
    with pytest.raises(ValueError, match=r"FTCAP_STATUS.delta_hat: at most 16"):
        dialect_message(DIALECT, "FTCAP_STATUS", {**fields, "delta_hat": [1.0] * 17})


def test_the_drives_hypotheses_cross_the_wire_by_code() -> None:
    status = AllocatorStatus.checked(
        delta_hat=(1.0, 0.0, 1.0), f_hat=(0.0,) * 3,
        hypothesis=("healthy", "jammed", "telemetry-lost"),
    )  # fmt: skip
    msg = dialect_message(DIALECT, "FTCAP_STATUS", status_fields(status, time_boot_ms=0))
    mav = DIALECT.MAVLink(None, srcSystem=1, srcComponent=191)
    wire = DIALECT.MAVLink(None).parse_buffer(msg.pack(mav))[0]
    assert wire.hypothesis[:4] == [1, 4, 2, 0]  # 0: no diagnosis, then the enum's order
    assert status_from_message(wire).hypothesis == status.hypothesis
    none = AllocatorStatus.checked(delta_hat=(1.0,), f_hat=(0.0,))
    msg = dialect_message(DIALECT, "FTCAP_STATUS", status_fields(none, time_boot_ms=0))
    assert (
        status_from_message(DIALECT.MAVLink(None).parse_buffer(msg.pack(mav))[0]).hypothesis == ()
    )
